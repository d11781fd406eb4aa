//! Map initialisation from two views (the first keyframes, scaled to median depth 1) and the
//! backfill of the frames seen before it.

use super::*;

impl System {
    pub(super) fn initialize(
        &mut self,
        map: &mut Map,
        gray: &[u8],
        rgb: Option<&[u8]>,
    ) -> TrackingState {
        let mut ready = None;
        let k = self.camera.k();
        if self.init.attempt(&self.frame, gray, rgb, &k, &mut ready) != InitAttempt::Ready {
            return TrackingState::NotInitialised;
        }
        let Some((motion, pairs)) = ready else {
            return TrackingState::NotInitialised;
        };
        let Some(reference) = self.init.reference.take() else {
            return TrackingState::NotInitialised;
        };
        let init = &self.init;
        let Ok(kf0) = map.insert_keyframe(|kf| {
            kf.keypoints.extend_from_slice(&reference.keypoints);
            kf.descriptors.extend_from_slice(&reference.descriptors);
            kf.frame_index = init.reference_index;
            kf.timestamp = init.reference_timestamp;
            kf.set_images(
                &init.reference_gray,
                init.reference_has_color.then_some(&init.reference_rgb[..]),
            );
        }) else {
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
            map.reset();
            return TrackingState::NotInitialised;
        };
        for (m, &(i, j)) in pairs.iter().enumerate() {
            let Some(p) = motion.points[m] else { continue };
            let Ok(mp) = map.insert_point(p, kf0) else {
                break;
            };
            map.add_observation(mp, kf0, i as usize);
            map.add_observation(mp, kf1, j as usize);
            map.update_point_geometry(mp);
        }
        map.update_connections(kf0);
        map.update_connections(kf1);
        self.global_ba(map, 20);
        // Scale the map to median depth 1.
        let Some(median) = median_depth(map, kf0).filter(|m| *m > 0.0) else {
            map.reset();
            return TrackingState::NotInitialised;
        };
        let tracked = map.keyframe(kf1).map_or(0, |k| k.observed().count());
        if tracked < 100 {
            map.reset();
            return TrackingState::NotInitialised;
        }
        let inv = 1.0 / median;
        if let Some(k) = map.keyframe_mut(kf1) {
            k.t_cw.0.translation.vector *= inv;
        }
        let pts: Vec<_> = map.points().map(|(id, _)| id).collect();
        for p in pts {
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
        self.tracker.reference_kf = Some(kf1);
        self.tracker.last_keyframe_frame = self.frame.index;
        self.tracker.velocity = None;
        self.tracker.state = TrackingState::Ok;
        tracing::info!(
            frame = self.frame.index,
            points = map.n_points(),
            "map initialised"
        );
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
        let backfilled = self.backfill(map, kf0, kf1);
        // The reference frame (keyframe 0) and the backfilled frames have poses.
        self.stats.tracked_frames += 1 + backfilled;
        self.stats.backfilled_frames += backfilled;
        TrackingState::Ok
    }

    /// Tracks the frames seen between the reference and initialisation against the new map
    /// (pose guess interpolated between the two keyframes, projection search, motion-only BA),
    /// so they get poses too. Returns how many did.
    fn backfill(&mut self, map: &mut Map, kf0: KeyFrameId, kf1: KeyFrameId) -> usize {
        let (Some(k0), Some(k1)) = (map.keyframe(kf0), map.keyframe(kf1)) else {
            return 0;
        };
        let (ts0, ts1) = (k0.timestamp, k1.timestamp);
        let (p0, p1) = (k0.t_cw.0, k1.t_cw.0);
        let (sf, nl) = (map.config.scale_factor, map.config.n_levels);
        let pts: Vec<_> = map
            .points()
            .map(|(id, p)| (id, p.position, p.descriptor, p.max_distance))
            .collect();
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let mut tf = TrackedFrame::new(self.frame.features.keypoints.capacity(), w, h);
        let mut projected = Vec::with_capacity(pts.len());
        let mut scratch = Vec::new();
        let mut done = 0;
        for pf in self.init.pending() {
            if ts1 <= ts0 {
                break;
            }
            let a = ((pf.timestamp - ts0) / (ts1 - ts0)).clamp(0.0, 1.0);
            let rot = p0.rotation.slerp(&p1.rotation, a);
            let trans = p0.translation.vector.lerp(&p1.translation.vector, a);
            tf.index = pf.index;
            tf.timestamp = pf.timestamp;
            tf.features.copy_from(&pf.features);
            tf.reset_matches();
            tf.t_cw = CameraFromWorld(Se3::from_parts(nalgebra::Translation3::from(trans), rot));
            projected.clear();
            for (k, &(_, pos, desc, max_d)) in pts.iter().enumerate() {
                let pc = tf.t_cw.transform(&pos);
                let Some(uv) = self.camera.project(&pc) else {
                    continue;
                };
                if !self.camera.in_image(uv.x, uv.y, 0.0) {
                    continue;
                }
                let level = ((max_d / pc.norm().max(1e-9)).ln() / sf.ln())
                    .ceil()
                    .clamp(0.0, (nl - 1) as f64) as u8;
                projected.push(crate::matching::search::ProjectedPoint {
                    id: k as u32,
                    uv: uv.cast(),
                    level,
                    descriptor: desc,
                    radius_factor: 1.0,
                });
            }
            let mut m: Vec<Option<u32>> = vec![None; tf.features.len()];
            crate::matching::search::search_by_projection(
                &projected,
                &tf.features.keypoints,
                &tf.features.descriptors,
                &tf.grid,
                &self.tracker.scales,
                15.0,
                0.9,
                &mut m,
                &mut scratch,
            );
            for (j, mm) in m.iter().enumerate() {
                tf.points[j] = mm.map(|k| pts[k as usize].0);
            }
            let n = self.tracker.optimize_pose(map, &mut tf);
            if n >= self.tracker.config.min_inliers {
                self.trajectory.push(TrajectoryEntry {
                    timestamp: tf.timestamp,
                    reference: Some(kf0),
                    t_c_ref: tf.t_cw.0 * p0.inverse(),
                    t_cw: tf.t_cw,
                });
                done += 1;
            }
        }
        done
    }
}
