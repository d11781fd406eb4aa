//! Scale-collapse detection. A monocular map can shrink while the camera moves on (distant
//! structure, forward motion: the highway failure): tracking keeps enough inliers, so every
//! frame looks `Ok`, but each new keyframe sits where the last one was (a small wrong
//! rotation stands in for the motion) and the scene depth the map sees shrinks with it. The
//! median depth of what a camera sees can only fall several-fold if it travels about as far
//! as the depth it lost (walking up to a wall) or turns to look at something nearer; a map
//! whose keyframes did neither while their depth collapsed is wrong, not the world.

use crate::config::TrackingConfig;
use crate::geometry::CameraFromWorld;
use crate::map::Map;

use super::TrackedFrame;

/// Keyframes a collapse is judged over (at most; `[tracking] collapse_keyframes`).
const MAX_WINDOW: usize = 32;

/// Watches the keyframes of one map.
pub struct CollapseMonitor {
    path_ratio: f64,
    depth_shrink: f64,
    max_turn_rad: f64,
    window: usize,
    last: Option<CameraFromWorld>,
    /// The last `window + 1` keyframes: (baseline from the one before, rotation from it,
    /// median scene depth).
    recent: heapless::Deque<(f64, f64, f64), MAX_WINDOW>,
    depths: Vec<f64>,
}

impl CollapseMonitor {
    pub fn new(cfg: &TrackingConfig, max_features: usize) -> Self {
        CollapseMonitor {
            path_ratio: cfg.collapse_path_ratio,
            depth_shrink: cfg.collapse_depth_shrink,
            max_turn_rad: cfg.collapse_max_turn_deg.to_radians(),
            window: cfg.collapse_keyframes.clamp(1, MAX_WINDOW - 1),
            last: None,
            recent: heapless::Deque::new(),
            depths: Vec::with_capacity(max_features),
        }
    }

    /// A new map: its last keyframe so far.
    pub fn start(&mut self, t_cw: CameraFromWorld) {
        self.reset();
        self.last = Some(t_cw);
    }

    pub fn reset(&mut self) {
        self.last = None;
        self.recent.clear();
    }

    /// Keyframes the last judgement spanned.
    pub fn window(&self) -> usize {
        self.window
    }

    /// A keyframe was made of `f`: true when, over the last `collapse_keyframes` keyframes,
    /// the median scene depth fell below `collapse_depth_shrink` of its value while the camera
    /// travelled less than `collapse_path_ratio` of the depth lost and turned less than
    /// `collapse_max_turn_deg`.
    pub fn keyframe(&mut self, map: &Map, f: &TrackedFrame) -> bool {
        let Some(last) = self.last.replace(f.t_cw) else {
            return false;
        };
        self.depths.clear();
        for (_, p) in f.inlier_points() {
            if let Some(mp) = map.point(p) {
                let z = (f.t_cw.0 * nalgebra::Point3::from(mp.position)).z;
                if z > 0.0 {
                    self.depths.push(z);
                }
            }
        }
        if self.depths.is_empty() {
            return false;
        }
        let mid = self.depths.len() / 2;
        let median = *self
            .depths
            .select_nth_unstable_by(mid, |a, b| a.total_cmp(b))
            .1;
        let baseline = (f.t_cw.inverse().position() - last.inverse().position()).norm();
        let turned = f.t_cw.0.rotation.angle_to(&last.0.rotation);
        if self.recent.len() > self.window {
            self.recent.pop_front();
        }
        let _ = self.recent.push_back((baseline, turned, median));
        if self.recent.len() <= self.window {
            return false;
        }
        // The first entry's depth is the start; the others' motions lead from it to now.
        let mut it = self.recent.iter();
        let Some(&(_, _, start)) = it.next() else {
            return false;
        };
        let (path, turn) = it.fold((0.0, 0.0), |(p, t), &(b, r, _)| (p + b, t + r));
        tracing::trace!(
            frame = f.index,
            inliers = self.depths.len(),
            depth_ratio = median / start,
            path_per_depth_lost = path / (start - median),
            turn_deg = turn.to_degrees(),
            "collapse monitor"
        );
        median < self.depth_shrink * start
            && path < self.path_ratio * (start - median)
            && turn < self.max_turn_rad
    }
}
