//! Scale-collapse detection. A monocular map can shrink while the camera moves on (distant
//! structure, forward motion: the highway failure): tracking keeps enough inliers, so every
//! frame looks `Ok`, but each new keyframe sits where the last one was (a small wrong
//! rotation stands in for the motion) and the scene depth the map sees shrinks with it. The
//! median depth of what a camera sees can only fall several-fold if it travels about as far
//! as the depth it lost (walking up to a wall) or turns to look at something nearer; a map
//! whose keyframes did neither while their depth collapsed is wrong, not the world. A turn is
//! no excuse when the points made during it sit much nearer than the older points beside them
//! in the image: a nearer view puts its new points on nearer surfaces, a shrinking map puts
//! them nearer on the same surfaces (its baselines are too short). `kitti01_51` with 2000
//! features collapses that way in a real 29 deg highway curve.

use crate::config::TrackingConfig;
use crate::geometry::CameraFromWorld;
use crate::map::Map;

use super::TrackedFrame;

/// Keyframes a collapse is judged over (at most; `[tracking] collapse_keyframes`).
const MAX_WINDOW: usize = 32;

/// What the monitor measured over its window when it flagged a collapse (for the report).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollapseEvidence {
    /// Frame of the first keyframe of the window (and its timestamp) and of the flagged one.
    pub from_frame: u64,
    pub from_timestamp: f64,
    pub frame: u64,
    /// Median inlier depth now over the window's first.
    pub depth_ratio: f64,
    /// Distance travelled over the depth lost.
    pub path_per_depth_lost: f64,
    pub turn_deg: f64,
    /// Inliers the median depth was taken over.
    pub inliers: usize,
    /// Depth of the inliers made in the window over that of the older ones in the same part
    /// of the view (median over image cells holding both), when enough cells do; weighed
    /// only for a collapse the map's turn would excuse.
    pub young_over_old: Option<f64>,
}

impl std::fmt::Display for CollapseEvidence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "frames {}-{}: median depth x{:.2}, travelled {:.3} of the depth lost, turned {:.1} deg ({} inliers)",
            self.from_frame,
            self.frame,
            self.depth_ratio,
            self.path_per_depth_lost,
            self.turn_deg,
            self.inliers
        )?;
        if let Some(r) = self.young_over_old {
            write!(
                f,
                ", new points at x{r:.2} of the old ones' depth beside them"
            )?;
        }
        Ok(())
    }
}

/// Watches the keyframes of one map.
pub struct CollapseMonitor {
    path_ratio: f64,
    depth_shrink: f64,
    max_turn_rad: f64,
    young_over_old: f64,
    window: usize,
    last: Option<CameraFromWorld>,
    /// The last `window + 1` keyframes: (baseline from the one before, rotation from it,
    /// median scene depth, frame index and timestamp).
    recent: heapless::Deque<(f64, f64, f64, u64, f64), MAX_WINDOW>,
    /// Serial of each recent keyframe (parallel to `recent`).
    serials: heapless::Deque<u64, MAX_WINDOW>,
    depths: Vec<f64>,
    /// (image cell, depth, made after the window's first keyframe) of the inliers.
    cells: Vec<(u32, f64, bool)>,
}

impl CollapseMonitor {
    pub fn new(cfg: &TrackingConfig, max_features: usize) -> Self {
        CollapseMonitor {
            path_ratio: cfg.collapse_path_ratio,
            depth_shrink: cfg.collapse_depth_shrink,
            max_turn_rad: cfg.collapse_max_turn_deg.to_radians(),
            young_over_old: cfg.collapse_young_over_old,
            window: cfg.collapse_keyframes.clamp(1, MAX_WINDOW - 1),
            last: None,
            recent: heapless::Deque::new(),
            serials: heapless::Deque::new(),
            depths: Vec::with_capacity(max_features),
            cells: Vec::with_capacity(max_features),
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
        self.serials.clear();
    }

    /// Keyframes the last judgement spanned.
    pub fn window(&self) -> usize {
        self.window
    }

    /// A keyframe was made of `f`: the evidence when, over the last `collapse_keyframes`
    /// keyframes, the median scene depth fell below `collapse_depth_shrink` of its value while
    /// the camera travelled less than `collapse_path_ratio` of the depth lost and turned less
    /// than `collapse_max_turn_deg`.
    pub fn keyframe(&mut self, map: &Map, f: &TrackedFrame) -> Option<CollapseEvidence> {
        let last = self.last.replace(f.t_cw)?;
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
            return None;
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
            self.serials.pop_front();
        }
        let _ = self.serials.push_back(map.next_serial().saturating_sub(1));
        let _ = self
            .recent
            .push_back((baseline, turned, median, f.index, f.timestamp));
        if self.recent.len() <= self.window {
            return None;
        }
        // The first entry's depth is the start; the others' motions lead from it to now.
        let mut it = self.recent.iter();
        let &(_, _, start, from_frame, from_timestamp) = it.next()?;
        let (path, turn) = it.fold((0.0, 0.0), |(p, t), &(b, r, ..)| (p + b, t + r));
        let inliers = self.depths.len();
        let collapsed =
            median < self.depth_shrink * start && path < self.path_ratio * (start - median);
        let turned = turn >= self.max_turn_rad;
        // Only a turn's excuse needs the new points weighed against the old.
        let young_over_old = if collapsed && turned {
            let first_serial = self.serials.front().copied().unwrap_or(0);
            self.young_over_old_depth(map, f, first_serial)
        } else {
            None
        };
        let evidence = CollapseEvidence {
            from_frame,
            from_timestamp,
            frame: f.index,
            depth_ratio: median / start,
            path_per_depth_lost: path / (start - median),
            turn_deg: turn.to_degrees(),
            inliers,
            young_over_old,
        };
        tracing::trace!(%evidence, "collapse monitor");
        // A turn excuses the depth lost (the camera looks at nearer things), unless the
        // points made in the window sit much nearer than the older ones beside them.
        let turn_excuses = turned && young_over_old.is_none_or(|r| r >= self.young_over_old);
        (collapsed && !turn_excuses).then_some(evidence)
    }
}

impl CollapseMonitor {
    /// Median over image cells of (median depth of the inliers made after keyframe
    /// `first_serial`) / (median depth of the older ones), in cells holding at least two of
    /// each. In a consistent map the two sets lie on the same surfaces; in a map whose motion
    /// shrank, the new points were triangulated from too short baselines and sit nearer.
    fn young_over_old_depth(
        &mut self,
        map: &Map,
        f: &TrackedFrame,
        first_serial: u64,
    ) -> Option<f64> {
        const CELL_PX: f32 = 64.0;
        self.cells.clear();
        for (i, p) in f.inlier_points() {
            let (Some(mp), Some(kp)) = (map.point(p), f.features.keypoints.get(i)) else {
                continue;
            };
            let z = (f.t_cw.0 * nalgebra::Point3::from(mp.position)).z;
            if z <= 0.0 {
                continue;
            }
            let cell = (kp.uy / CELL_PX).max(0.0) as u32 * 1024 + (kp.ux / CELL_PX).max(0.0) as u32;
            self.cells
                .push((cell, z, mp.first_kf_serial > first_serial));
        }
        self.cells
            .sort_unstable_by(|a, b| (a.0, a.2).cmp(&(b.0, b.2)).then(a.1.total_cmp(&b.1)));
        self.depths.clear();
        let median = |v: &[(u32, f64, bool)]| v[v.len() / 2].1;
        let mut i = 0;
        while i < self.cells.len() {
            let cell = self.cells[i].0;
            let j = i + self.cells[i..].iter().take_while(|c| c.0 == cell).count();
            let run = &self.cells[i..j];
            let split = run.iter().take_while(|c| !c.2).count();
            let (old, young) = run.split_at(split);
            if old.len() >= 2 && young.len() >= 2 {
                self.depths.push(median(young) / median(old));
            }
            i = j;
        }
        if self.depths.len() < 3 {
            return None;
        }
        let mid = self.depths.len() / 2;
        Some(
            *self
                .depths
                .select_nth_unstable_by(mid, |a, b| a.total_cmp(b))
                .1,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::WorldFromCamera;
    use crate::map::MapConfig;
    use nalgebra::{UnitQuaternion, Vector3};

    /// A camera at `pos` (world), turned by `yaw` (radians) about its y axis, seeing
    /// `depths.len()` points straight ahead at those depths (as its inliers).
    fn keyframe_at(
        map: &mut Map,
        f: &mut TrackedFrame,
        pos: Vector3<f64>,
        yaw: f64,
        depths: &[f64],
    ) {
        let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw);
        let t_wc = WorldFromCamera::from_parts(pos, q);
        f.t_cw = t_wc.inverse();
        f.points.clear();
        f.outlier.clear();
        let Ok(kf) = map.insert_keyframe(|_| {}) else {
            panic!("the test map has room for a keyframe");
        };
        for (i, &z) in depths.iter().enumerate() {
            // Spread the points a little across the view; depth along the optical axis.
            let x = 0.01 * z * (i as f64 - depths.len() as f64 / 2.0);
            let Ok(p) = map.insert_point(t_wc.transform(&Vector3::new(x, 0.0, z)), kf) else {
                panic!("the test map has room for the points");
            };
            f.points.push(Some(p));
            f.outlier.push(false);
        }
        f.index += 1;
    }

    fn setup() -> (CollapseMonitor, Map, TrackedFrame) {
        let cfg = TrackingConfig::default();
        let map = Map::new(MapConfig {
            max_keyframes: 64,
            max_map_points: 4096,
            max_features: 64,
            ..MapConfig::default()
        });
        let mut monitor = CollapseMonitor::new(&cfg, 64);
        monitor.start(CameraFromWorld::identity());
        (monitor, map, TrackedFrame::new(64, 640, 480))
    }

    /// Keyframes every `step` along z with the scene depth multiplied by `shrink` per keyframe
    /// and `yaw` turned per keyframe: the first keyframe the monitor flags, if any.
    fn first_alarm(step: f64, shrink: f64, yaw: f64, keyframes: usize) -> Option<usize> {
        let (mut monitor, mut map, mut f) = setup();
        let mut depth = 10.0;
        (1..=keyframes).find(|&k| {
            depth *= shrink;
            let depths: Vec<f64> = (0..40).map(|i| depth * (1.0 + 0.01 * i as f64)).collect();
            keyframe_at(
                &mut map,
                &mut f,
                Vector3::new(0.0, 0.0, step * k as f64),
                yaw * k as f64,
                &depths,
            );
            monitor.keyframe(&map, &f).is_some()
        })
    }

    #[test]
    fn depth_collapsing_while_the_camera_stands_still_is_flagged() {
        // Depth x0.6 per keyframe: below 0.25 of the start after 5 keyframes (0.6^5 = 0.08).
        assert_eq!(first_alarm(0.001, 0.6, 0.0, 12), Some(6));
    }

    #[test]
    fn a_steady_scene_depth_is_not_flagged() {
        assert_eq!(first_alarm(0.0, 1.0, 0.0, 20), None);
        // Slowly shrinking (x0.9 per keyframe: 0.59 over 5) stays above 0.25.
        assert_eq!(first_alarm(0.0, 0.9, 0.0, 20), None);
    }

    #[test]
    fn walking_up_to_a_wall_is_not_flagged() {
        // The depth falls as fast as in the collapse, but the camera travels 1 per keyframe:
        // 5 over the window, against the 5.5 of depth lost (the bar is 0.1 of it).
        assert_eq!(first_alarm(1.0, 0.6, 0.0, 12), None);
    }

    #[test]
    fn turning_towards_something_nearer_is_not_flagged() {
        // 5 deg per keyframe: 25 deg over the window, past collapse_max_turn_deg (15).
        assert_eq!(first_alarm(0.001, 0.6, 5f64.to_radians(), 12), None);
        // 2 deg per keyframe (10 over the window) is no excuse.
        assert!(first_alarm(0.001, 0.6, 2f64.to_radians(), 12).is_some());
    }

    /// Adds map point `p` to `f`'s inliers, its keypoint in image column `column` (64 px).
    fn observe(f: &mut TrackedFrame, p: crate::map::MapPointId, column: usize) {
        f.points.push(Some(p));
        f.outlier.push(false);
        f.features.keypoints.push(crate::features::KeyPoint {
            ux: 64.0 * column as f32 + 1.0,
            uy: 1.0,
            ..Default::default()
        });
    }

    /// Keyframes turning 5 deg each (past the turn excuse) while barely moving; each sees 20
    /// points made by the first keyframe at depth 10 (image columns 0-9) and 40 made by
    /// itself at depth 10 x 0.6^k, in columns `new_columns`: whether the monitor flags any.
    fn turning_with_new_points(new_columns: std::ops::Range<usize>) -> bool {
        let (mut monitor, mut map, mut f) = setup();
        let mut old = Vec::new();
        (0..=8).any(|k| {
            let yaw = 5f64.to_radians() * k as f64;
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw);
            let t_wc = WorldFromCamera::from_parts(Vector3::new(0.0, 0.0, 0.001 * k as f64), q);
            f.t_cw = t_wc.inverse();
            f.points.clear();
            f.outlier.clear();
            f.features.keypoints.clear();
            let Ok(kf) = map.insert_keyframe(|_| {}) else {
                panic!("the test map has room for a keyframe");
            };
            let (depth, columns, count) = if k == 0 {
                (10.0, 0..10, 20)
            } else {
                (10.0 * 0.6f64.powi(k), new_columns.clone(), 40)
            };
            // The old points again, where the first keyframe put them.
            for (i, &p) in old.iter().enumerate() {
                observe(&mut f, p, i % 10);
            }
            for i in 0..count {
                let column = columns.start + i % columns.len();
                let x = 0.01 * depth * column as f64;
                let Ok(p) = map.insert_point(t_wc.transform(&Vector3::new(x, 0.0, depth)), kf)
                else {
                    panic!("the test map has room for the points");
                };
                observe(&mut f, p, column);
                if k == 0 {
                    old.push(p);
                }
            }
            f.index += 1;
            if k == 0 {
                monitor.start(f.t_cw);
                return false;
            }
            monitor.keyframe(&map, &f).is_some()
        })
    }

    #[test]
    fn a_turn_excuses_new_points_on_nearer_surfaces_but_not_beside_the_old_ones() {
        // New points in their own part of the view: the camera turned to something nearer.
        assert!(!turning_with_new_points(10..20));
        // New points among the old ones, ever nearer: the map shrank.
        assert!(turning_with_new_points(0..10));
    }

    #[test]
    fn a_new_map_starts_a_new_window() {
        let (mut monitor, mut map, mut f) = setup();
        let mut depth = 10.0;
        // Keyframe k of the shrinking scene: whether the monitor flags it.
        let mut keyframe = |monitor: &mut CollapseMonitor, k: usize| {
            depth *= 0.6;
            let pos = Vector3::new(0.0, 0.0, 0.001 * k as f64);
            keyframe_at(&mut map, &mut f, pos, 0.0, &[depth; 20]);
            monitor.keyframe(&map, &f).is_some()
        };
        for k in 1..=4 {
            assert!(!keyframe(&mut monitor, k));
        }
        // A new map: the 4 keyframes before no longer count (without this, keyframe 6 is
        // flagged).
        monitor.start(CameraFromWorld::identity());
        for k in 5..=8 {
            assert!(!keyframe(&mut monitor, k), "keyframe {k}");
        }
    }
}
