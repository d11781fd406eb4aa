//! Poses for the frames seen between the initialisation reference and the frame that
//! initialised the map, tracked against the new map a few per frame after initialisation
//! (doing all of them at once took ~15 ms and made the initialising frame miss its deadline).

use super::*;
use crate::matching::search::{search_by_projection, ProjectedPoint, ProjectionSearch};
use nalgebra::Vector3;

/// Pending frames tracked per processed frame (each ~0.5 ms); 30 pending frames are done
/// within 10 frames.
pub(super) const BACKFILL_PER_FRAME: usize = 3;

/// The backfill in progress and its reused buffers (allocated when initialisation starts it).
#[derive(Default)]
pub(super) struct Backfill {
    /// The two initial keyframes and how many pending frames are done (newest first).
    job: Option<(KeyFrameId, KeyFrameId, usize)>,
    /// The two keyframes' timestamps.
    stamps: (f64, f64),
    /// The pose of the last frame tracked (the guess for the next older one) and the motion
    /// from it to the one before it (a constant-velocity step back).
    guess: Option<Se3>,
    step: Option<Se3>,
    /// The chain has passed the first keyframe (frames kept from before the reference).
    passed_kf0: bool,
    frame: Option<TrackedFrame>,
    /// Map points now: (id, position, descriptor, max distance).
    points: Vec<(
        crate::map::MapPointId,
        Vector3<f64>,
        crate::features::Descriptor,
        f64,
    )>,
    projected: Vec<ProjectedPoint>,
    matches: Vec<Option<u32>>,
    scratch: Vec<u32>,
}

impl Backfill {
    /// Starts backfilling the frames kept between keyframes `kf0` and `kf1` (made at times
    /// `stamps`).
    pub(super) fn start(
        &mut self,
        kf0: KeyFrameId,
        kf1: KeyFrameId,
        stamps: (f64, f64),
        n_points: usize,
    ) {
        self.job = Some((kf0, kf1, 0));
        self.stamps = stamps;
        self.guess = None;
        self.step = None;
        self.passed_kf0 = false;
        self.points.reserve(2 * n_points);
        self.projected.reserve(2 * n_points);
    }

    pub(super) fn active(&self) -> bool {
        self.job.is_some()
    }
}

impl System {
    /// Tracks up to `max_frames` pending frames against the map, newest first, each from the
    /// pose of the one after it (the second keyframe's for the first): projection search,
    /// motion-only BA. Chaining back from the second keyframe follows any speed profile (a
    /// start from rest is far from a linear interpolation between the keyframes). Frames with
    /// too few inliers stay without a pose. Ends the backfill when every pending frame is done.
    pub(super) fn backfill_step(&mut self, map: &mut Map, max_frames: usize) {
        let Some((kf0, kf1, next)) = self.backfill.job else {
            return;
        };
        let pending = self.init.pending();
        // Keyframe 1 may have been culled meanwhile (a young map on fast motion): its pose
        // then comes through its parent.
        let poses = (
            map.keyframe_pose_or_tombstone(kf0),
            map.keyframe_pose_or_tombstone(kf1),
            map.map_of(kf0),
        );
        let (Some(p0), Some(p1), Some(map_id)) = poses else {
            self.backfill.job = None;
            return;
        };
        let (p0, p1) = (p0.0, p1.0);
        let (ts0, ts1) = self.backfill.stamps;
        if ts1 <= ts0 || next >= pending.len() {
            self.backfill.job = None;
            return;
        }
        let (sf, nl) = (map.config.scale_factor, map.config.n_levels);
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let bf = &mut self.backfill;
        // Points of the keyframes' map as they are now (local mapping may have culled or added
        // some since; other maps of the atlas are in other frames).
        bf.points.clear();
        bf.points.extend(
            map.points()
                .filter(|(_, p)| {
                    p.observations
                        .first()
                        .and_then(|&(k, _)| map.keyframe(k))
                        .is_some_and(|k| k.map_id == map_id)
                })
                .map(|(id, p)| (id, p.position, p.descriptor, p.max_distance)),
        );
        let tf = bf.frame.get_or_insert_with(|| {
            TrackedFrame::new(self.frame.features.keypoints.capacity(), w, h)
        });
        let end = next.saturating_add(max_frames).min(pending.len());
        for pf in pending[..pending.len() - next]
            .iter()
            .rev()
            .take(end - next)
        {
            tf.index = pf.index;
            tf.timestamp = pf.timestamp;
            tf.features.copy_from(&pf.features);
            // Two guesses: the last frame done, stepped back at its velocity (any speed
            // profile, a start from rest), then the keyframes' interpolation at this time
            // (steady fast motion, where the first frame back has no velocity yet).
            if pf.timestamp < ts0 && !bf.passed_kf0 {
                // Past the first keyframe (the reference, not a pending frame): the chain
                // goes through its pose.
                bf.passed_kf0 = true;
                if let Some(g) = bf.guess {
                    bf.step = Some(p0 * g.inverse());
                }
                bf.guess = Some(p0);
            }
            let alpha = ((pf.timestamp - ts0) / (ts1 - ts0)).clamp(0.0, 1.0);
            let between = p0.inverse().lerp_slerp(&p1.inverse(), alpha).inverse();
            let chained = match (bf.guess, bf.step) {
                (Some(g), Some(v)) => v * g,
                (Some(g), None) => g,
                (None, _) => p1,
            };
            let mut n = 0;
            for guess in [chained, between] {
                tf.reset_matches();
                tf.t_cw = CameraFromWorld(guess);
                bf.projected.clear();
                for (k, &(_, pos, desc, max_d)) in bf.points.iter().enumerate() {
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
                    bf.projected.push(ProjectedPoint {
                        id: k as u32,
                        uv: uv.cast(),
                        level,
                        descriptor: desc,
                        radius_factor: 1.0,
                    });
                }
                bf.matches.clear();
                bf.matches.resize(tf.features.len(), None);
                // The motion model's search (ORB-SLAM: 15 px, ratio 0.9).
                let search = ProjectionSearch {
                    scales: &self.tracker.scales,
                    radius: self.tracker.config.motion_search_radius,
                    ratio: 0.9,
                };
                search_by_projection(
                    &bf.projected,
                    tf.features.view(),
                    &tf.grid,
                    search,
                    &mut bf.matches,
                    &mut bf.scratch,
                );
                for (j, m) in bf.matches.iter().enumerate() {
                    tf.points[j] = m.map(|k| bf.points[k as usize].0);
                }
                n = self.tracker.optimize_pose(map, tf);
                if n >= self.tracker.config.min_inliers {
                    break;
                }
            }
            // A backfilled pose passes the same checks as a tracked one (no motion model here,
            // so no jump check); a doubtful one is left out and counted.
            let judged =
                (n >= self.tracker.config.min_inliers).then(|| self.tracker.judge_pose(tf, None).1);
            if let Some(Some(reason)) = judged {
                self.stats.degraded_frames[reason as usize] += 1;
            }
            if judged != Some(None) {
                // Not posed: the chain goes on at the last velocity (dead reckoning), so the
                // next older frame is searched from one more step back.
                if bf.step.is_some() {
                    bf.guess = Some(chained);
                }
            } else {
                bf.step = Some(tf.t_cw.0 * bf.guess.unwrap_or(p1).inverse());
                bf.guess = Some(tf.t_cw.0);
                self.trajectory.push(TrajectoryEntry {
                    timestamp: tf.timestamp,
                    reference: Some(kf0),
                    t_c_ref: tf.t_cw.0 * p0.inverse(),
                    t_cw: tf.t_cw,
                });
                self.stats.tracked_frames += 1;
                self.stats.backfilled_frames += 1;
            }
        }
        self.backfill.job = (end < pending.len()).then_some((kf0, kf1, end));
    }
}
