//! Map initialisation from two views (the first keyframes, scaled to median depth 1).

use super::*;
use crate::geometry::two_view::TwoViewMotion;
use crate::tracking::Prepared;

/// Consecutive frames without initialisation after which a warning says why.
const NOT_INITIALISED_WARNING_FRAMES: usize = 90;
/// Mean grey level under which the warning blames the exposure.
const DARK_MEAN_GREY: f64 = 20.0;
/// Features per frame under which the warning blames the view (ORB-SLAM starts from 100
/// matches).
const FEW_FEATURES: usize = 100;

impl System {
    pub(super) fn initialize(
        &mut self,
        map: &mut Map,
        gray: &[u8],
        rgb: Option<&[u8]>,
    ) -> TrackingState {
        // Off the tracking thread for the frame deadline; a replay has none, and attempts
        // made on every frame (not only when the solver is free) start the map sooner.
        if self.init_solver.is_some() && !self.replay {
            return self.initialize_async(map, gray, rgb);
        }
        let mut ready = None;
        let k = self.camera.k();
        let t_attempt = std::time::Instant::now();
        let attempt = self.init.attempt(&self.frame, gray, rgb, &k, &mut ready);
        self.stats.initialisation.record(t_attempt.elapsed());
        self.note_attempt(self.frame.index, gray, &attempt);
        let Some((motion, pairs)) = ready else {
            return TrackingState::NotInitialised;
        };
        self.build_initial_map(map, gray, rgb, motion, pairs)
    }

    /// The threaded mode: concludes the attempt in flight when its result has come, and sends
    /// the current frame's problem to the solver when none is in flight. On a map, keyframe 1
    /// is the attempt's frame and the current frame is tracked in the new map.
    fn initialize_async(
        &mut self,
        map: &mut Map,
        gray: &[u8],
        rgb: Option<&[u8]>,
    ) -> TrackingState {
        let t0 = std::time::Instant::now();
        let state = self.initialize_async_step(map, gray, rgb);
        self.stats.initialisation.record(t0.elapsed());
        state
    }

    fn initialize_async_step(
        &mut self,
        map: &mut Map,
        gray: &[u8],
        rgb: Option<&[u8]>,
    ) -> TrackingState {
        let Some(solver) = self.init_solver.as_mut() else {
            return TrackingState::NotInitialised;
        };
        let received = match solver.try_result() {
            Ok(r) => r,
            Err(()) => {
                // The solver thread is gone: attempt on this thread from now on.
                tracing::warn!(
                    "initialisation solver stopped: attempts run on the tracking thread"
                );
                self.init_solver = None;
                return self.initialize(map, gray, rgb);
            }
        };
        let current = solver.generation;
        let busy = solver.outstanding > 0;
        let Some(mut c) = solver.candidate.take() else {
            return TrackingState::NotInitialised;
        };
        if let Some((generation, problem, solved, solve_ms)) = received {
            self.stats.initialisation_solve.record_ms(solve_ms);
            if generation == current {
                let mut ready = None;
                let attempt = self.init.conclude(
                    &c.frame,
                    &c.images.gray,
                    c.images.rgb(),
                    problem,
                    solved,
                    &mut ready,
                );
                self.note_attempt(c.frame.index, gray, &attempt);
                if let Some((motion, pairs)) = ready {
                    let state = self.initialise_from_candidate(map, &mut c, motion, pairs);
                    self.put_candidate(c);
                    return state;
                }
            }
        }
        self.put_candidate(c);
        if busy {
            // An attempt is still being solved: this frame is not attempted.
            return TrackingState::NotInitialised;
        }
        match self.init.prepare(&self.frame, gray, rgb) {
            Prepared::Done(attempt) => self.note_attempt(self.frame.index, gray, &attempt),
            Prepared::Solve(problem) => {
                let frame = &self.frame;
                if let Some(solver) = self.init_solver.as_mut() {
                    if let Some(c) = solver.candidate.as_mut() {
                        c.frame.copy_from(frame);
                        c.images.set(gray, rgb);
                    }
                    solver.send(problem);
                }
            }
        }
        TrackingState::NotInitialised
    }

    fn put_candidate(&mut self, c: Box<init_solver::Candidate>) {
        if let Some(s) = self.init_solver.as_mut() {
            s.candidate = Some(c);
        }
    }

    /// Builds the first map with the candidate as keyframe 1 (its pose enters the trajectory),
    /// then tracks the current frame in it.
    fn initialise_from_candidate(
        &mut self,
        map: &mut Map,
        c: &mut init_solver::Candidate,
        motion: TwoViewMotion,
        pairs: Vec<(u32, u32)>,
    ) -> TrackingState {
        std::mem::swap(&mut self.frame, &mut c.frame);
        let state = self.build_initial_map(map, &c.images.gray, c.images.rgb(), motion, pairs);
        if state != TrackingState::Ok {
            std::mem::swap(&mut self.frame, &mut c.frame);
            return state;
        }
        let f = &self.frame;
        self.trajectory.push(TrajectoryEntry {
            timestamp: f.timestamp,
            reference: self.tracker.reference_kf(),
            t_c_ref: Se3::identity(),
            t_cw: f.t_cw,
        });
        self.stats.tracked_frames += 1;
        self.tracker.commit(&self.frame);
        std::mem::swap(&mut self.frame, &mut c.frame);
        self.tracker.track(map, &mut self.frame)
    }

    /// Counts a failed attempt and says once, after about 3 s, why initialisation keeps failing
    /// (from the current frame, `gray`: too dark, too few features, or the motion).
    fn note_attempt(&mut self, frame: u64, gray: &[u8], attempt: &InitAttempt) {
        let features = self.frame.features.len();
        tracing::debug!(
            frame,
            reference = self.init.reference_index,
            features,
            ?attempt,
            "initialisation attempt"
        );
        if *attempt == InitAttempt::Ready {
            self.uninitialised_frames = 0;
            return;
        }
        self.uninitialised_frames += 1;
        if self.uninitialised_frames == NOT_INITIALISED_WARNING_FRAMES {
            let why = why_not_initialised(gray, features);
            tracing::warn!(
                frames = self.uninitialised_frames,
                last_attempt = ?attempt,
                "not initialised yet: {why}"
            );
        }
    }

    /// The first two keyframes (the reference and `self.frame`) and their points, scaled to
    /// median depth 1; `self.frame` continues from keyframe 1.
    fn build_initial_map(
        &mut self,
        map: &mut Map,
        gray: &[u8],
        rgb: Option<&[u8]>,
        motion: TwoViewMotion,
        pairs: Vec<(u32, u32)>,
    ) -> TrackingState {
        let t_build = std::time::Instant::now();
        let min_points = self.init.required_map_points();
        let Some(reference) = self.init.reference.take() else {
            return TrackingState::NotInitialised;
        };
        tracing::debug!(
            model = ?motion.model,
            score_ratio = motion.score_ratio,
            parallax_deg = motion.parallax_deg,
            inliers = motion.inliers,
            t_21 = ?motion.t_21.translation.vector.normalize().as_slice(),
            rotation_deg = motion.t_21.rotation.angle().to_degrees(),
            "two-view motion"
        );
        // With maps already in the atlas (tracking was lost), this one starts beside them.
        let previous_map = map.active_map();
        let beside = map.n_keyframes() > 0;
        if beside {
            map.start_new_map();
        }
        let new_map = map.active_map();
        let discard = |map: &mut Map| {
            if beside {
                map.cancel_new_map(previous_map);
            } else {
                map.reset();
            }
        };
        let init = &self.init;
        let Ok(kf0) = map.insert_keyframe(|kf| {
            kf.keypoints.extend_from_slice(&reference.keypoints);
            kf.descriptors.extend_from_slice(&reference.descriptors);
            kf.frame_index = init.reference_index;
            kf.timestamp = init.reference_timestamp;
            kf.t_cw = CameraFromWorld::identity();
            kf.set_images(&init.reference_images.gray, init.reference_images.rgb());
        }) else {
            discard(map);
            return TrackingState::NotInitialised;
        };
        let f = &self.frame;
        let Ok(kf1) = map.insert_keyframe(|kf| {
            kf.keypoints.extend_from_slice(&f.features.keypoints);
            kf.descriptors.extend_from_slice(&f.features.descriptors);
            kf.frame_index = f.index;
            kf.timestamp = f.timestamp;
            kf.t_cw = CameraFromWorld(motion.t_21);
            kf.set_images(gray, rgb);
        }) else {
            discard(map);
            return TrackingState::NotInitialised;
        };
        let mut new_points = Vec::with_capacity(pairs.len());
        for (m, &(i, j)) in pairs.iter().enumerate() {
            let Some(p) = motion.points[m] else { continue };
            match map.insert_two_view_point(p, (kf0, i as usize), (kf1, j as usize)) {
                Ok(id) => new_points.push(id),
                Err(_) => break,
            }
        }
        map.update_connections(kf0);
        map.update_connections(kf1);
        // (The initialiser refined the two views with their own BA: a map of two keyframes
        // has nothing for a global BA to add.)
        let build_ms = t_build.elapsed().as_secs_f64() * 1e3;
        // Scale the map to median depth 1.
        let Some(median) = median_depth(map, kf0).filter(|m| *m > 0.0) else {
            discard(map);
            return TrackingState::NotInitialised;
        };
        let tracked = map.keyframe(kf1).map_or(0, |k| k.observed().count());
        if tracked < min_points {
            discard(map);
            return TrackingState::NotInitialised;
        }
        let inv = 1.0 / median;
        if let Some(k) = map.keyframe_mut(kf1) {
            k.t_cw.0.translation.vector *= inv;
        }
        for p in new_points {
            if let Some(mp) = map.point_mut(p) {
                mp.position *= inv;
            }
            map.update_point_geometry(p);
        }
        // The current frame continues from keyframe 1.
        let k1 = map.keyframe(kf1).map(|k| (k.t_cw, k.points.clone()));
        if let Some((t, pts)) = k1 {
            self.frame.t_cw = t;
            self.frame.points.copy_from_slice(&pts);
        }
        self.tracker.start(kf1, self.frame.index);
        self.collapse.start(self.frame.t_cw);
        tracing::info!(
            frame = self.frame.index,
            map = new_map,
            points = map.keyframe(kf1).map_or(0, |k| k.observed().count()),
            build_ms,
            "map initialised"
        );
        self.stats.maps_made += 1;
        self.stats.keyframes_created += 2;
        let _ = self.fresh_keyframes.push(kf0);
        let _ = self.fresh_keyframes.push(kf1);
        self.index_keyframe(map, kf0);
        self.index_keyframe(map, kf1);
        // Keyframe 0's pose enters the trajectory too.
        self.trajectory.push(TrajectoryEntry {
            timestamp: self.init.reference_timestamp,
            reference: Some(kf0),
            t_c_ref: Se3::identity(),
            t_cw: CameraFromWorld::identity(),
        });
        // The reference frame (keyframe 0) has a pose; the frames between it and this one get
        // theirs over the next frames (`backfill_step`), keeping this frame within its deadline.
        self.stats.tracked_frames += 1;
        let stamps = (self.init.reference_timestamp, self.frame.timestamp);
        self.backfill.start(kf0, kf1, stamps, map.n_points());
        let pending = self.init.pending();
        tracing::debug!(
            pending = pending.len(),
            oldest = pending.first().map(|p| p.index),
            newest = pending.last().map(|p| p.index),
            "backfill"
        );
        TrackingState::Ok
    }
}

/// Why initialisation keeps failing, judged from the current frame: its mean grey level, then
/// its feature count, else the motion (for the warning after `NOT_INITIALISED_WARNING_FRAMES`).
fn why_not_initialised(gray: &[u8], features: usize) -> String {
    let mean_grey = gray.iter().map(|&v| v as u64).sum::<u64>() as f64 / gray.len().max(1) as f64;
    if mean_grey < DARK_MEAN_GREY {
        format!("the images are nearly black (mean grey level {mean_grey:.0} of 255): raise exposure or gain")
    } else if features < FEW_FEATURES {
        format!("{features} features in the frame, fewer than the {FEW_FEATURES} matches a start needs: point the camera at texture (the view is blank, blurred or dark)")
    } else {
        "the camera needs to translate (not only rotate) over a textured, non-planar scene".into()
    }
}

#[cfg(test)]
mod tests {
    use super::why_not_initialised;

    #[test]
    fn the_warning_names_darkness_then_a_blank_view_then_the_motion() {
        let dark = vec![6u8; 64];
        assert!(why_not_initialised(&dark, 80).contains("nearly black (mean grey level 6 "));
        let grey = vec![120u8; 64];
        let blank = why_not_initialised(&grey, 40);
        assert!(
            blank.starts_with("40 features") && blank.contains("texture"),
            "{blank}"
        );
        assert!(why_not_initialised(&grey, 1000).contains("needs to translate"));
        assert!(why_not_initialised(&[], 0).contains("nearly black"));
    }
}
