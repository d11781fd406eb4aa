//! A map found collapsing (see `tracking::collapse`) is rolled back, not thrown away. The
//! monitor judges a window of keyframes: the depth collapsed after the window's first one.
//! What came after it goes (keyframes, the points they created, the poses of those frames);
//! what came before stays, with every pose in it. Discarding the whole map cost real-time
//! runs of the outward loop 160-270 good poses for a collapse over 5 frames. There the alarm
//! was right: over frames 158-163 (264-271) the map's median inlier depth fell to 0.21 (0.18)
//! of itself while the scene's true median depth changed by under 8%; the reaction was too
//! wide.

use super::*;

/// What a roll-back erased.
struct RolledBack {
    keyframes: usize,
    points: usize,
    poses: usize,
}

/// Why a collapsing map is discarded rather than rolled back.
#[derive(Debug, PartialEq)]
enum NotRolledBack {
    /// No more than `young_map_keyframes` keyframes would be left.
    Young,
    /// The keyframes that would be left span this share of their median depth, under
    /// `collapse_min_kept_baseline`: they never had a baseline to be sound with.
    NoBaseline(f64),
}

impl System {
    /// A keyframe was made: the collapse monitor's turn. A map found collapsing is rolled
    /// back to the keyframe its window started from (the depth collapsed after it); a young
    /// map, with nothing to go back to, is discarded. The report keeps what the monitor
    /// measured and what went.
    pub(super) fn watch_for_collapse(&mut self, map: &mut Map) {
        let Some(evidence) = self.collapse.keyframe(map, &self.frame) else {
            return;
        };
        let c = &self.tracker.config;
        let turn = if evidence.turn_deg < c.collapse_max_turn_deg {
            format!("turned less than {} deg", c.collapse_max_turn_deg)
        } else {
            format!(
                "turned, but to no nearer view: its new points sit nearer than {} of the old ones' depth beside them",
                c.collapse_young_over_old
            )
        };
        let mut reason = format!(
            "frame {}: over {} keyframes the scene depth fell below {} of its value while the camera moved less than {} of the depth lost and {turn} (scale collapse; {evidence})",
            self.frame.index,
            self.collapse.window(),
            c.collapse_depth_shrink,
            c.collapse_path_ratio,
        );
        let min_kept_baseline = c.collapse_min_kept_baseline;
        match self.roll_back_active_map(map, &evidence, min_kept_baseline) {
            Ok(r) => {
                reason += &format!(
                    "; rolled back to frame {}: {} keyframes, {} points and {} poses after it erased",
                    evidence.from_frame, r.keyframes, r.points, r.poses
                );
                tracing::warn!(%reason, "map diverging: rolled back");
            }
            Err(why) => {
                reason += "; map discarded";
                if let NotRolledBack::NoBaseline(r) = why {
                    reason += &format!(
                        ": the keyframes before the window span {r:.3} of their depth, under {min_kept_baseline} (no baseline)"
                    );
                }
                tracing::warn!(%reason, "map diverging: discarded, initialising again");
                self.discard_active_map(map);
            }
        }
        self.stats.divergences.push(reason);
    }

    /// Erases what the active map made after the collapse window's first keyframe: the later
    /// keyframes, the points they created and the poses of the later frames. Tracking is lost
    /// and relocalises in what is left (or the atlas starts a new map). Nothing is erased
    /// when fewer than `young_map_keyframes` + 1 keyframes would be left, or when they span
    /// less than `min_kept_baseline` of their median depth.
    fn roll_back_active_map(
        &mut self,
        map: &mut Map,
        evidence: &crate::tracking::CollapseEvidence,
        min_kept_baseline: f64,
    ) -> Result<RolledBack, NotRolledBack> {
        let id = map.active_map();
        let kfs = map.keyframes_of(id);
        let mut later: Vec<(u64, KeyFrameId)> = kfs
            .iter()
            .filter_map(|&k| map.keyframe(k).map(|kf| (kf.frame_index, kf.serial, k)))
            .filter(|&(frame, _, _)| frame > evidence.from_frame)
            .map(|(_, serial, k)| (serial, k))
            .collect();
        if kfs.len() - later.len() <= self.limits.young_map_keyframes {
            return Err(NotRolledBack::Young);
        }
        let kept: Vec<KeyFrameId> = kfs
            .iter()
            .copied()
            .filter(|k| later.iter().all(|&(_, l)| l != *k))
            .collect();
        match baseline_over_depth(map, &kept) {
            Some(r) if r >= min_kept_baseline => {}
            Some(r) => return Err(NotRolledBack::NoBaseline(r)),
            None => return Err(NotRolledBack::NoBaseline(0.0)),
        }
        let Some(first_serial) = later.iter().map(|&(s, _)| s).min() else {
            return Err(NotRolledBack::Young);
        };
        let mut points: Vec<crate::map::MapPointId> = later
            .iter()
            .filter_map(|&(_, k)| map.keyframe(k))
            .flat_map(|kf| kf.observed().map(|(_, p)| p))
            .filter(|&p| {
                map.point(p)
                    .is_some_and(|mp| mp.first_kf_serial >= first_serial)
            })
            .collect();
        points.sort_unstable();
        points.dedup();
        let poses = self.drop_poses_in_map(map, id, |t| t > evidence.from_timestamp);
        for &p in &points {
            map.erase_point(p);
        }
        // Newest first: each is a leaf of the spanning tree when it goes.
        later.sort_unstable_by_key(|&(serial, _)| std::cmp::Reverse(serial));
        let keyframes = later
            .iter()
            .filter(|&&(_, k)| map.erase_keyframe(k))
            .count();
        self.lost_after_map_edit();
        Ok(RolledBack {
            keyframes,
            points: points.len(),
            poses,
        })
    }
}

/// The widest distance between the centres of `kfs` over the median of their median scene
/// depths (scale-free); `None` without a depth.
fn baseline_over_depth(map: &Map, kfs: &[KeyFrameId]) -> Option<f64> {
    let centres: Vec<nalgebra::Vector3<f64>> = kfs
        .iter()
        .filter_map(|&k| map.keyframe(k).map(|kf| kf.t_cw.inverse().position()))
        .collect();
    let mut depths: Vec<f64> = kfs
        .iter()
        .filter_map(|&k| crate::local_mapping::median_depth(map, k))
        .filter(|d| *d > 0.0)
        .collect();
    if depths.is_empty() {
        return None;
    }
    let mid = depths.len() / 2;
    let depth = *depths.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
    let widest = centres
        .iter()
        .flat_map(|a| centres.iter().map(move |b| (a - b).norm()))
        .fold(0.0, f64::max);
    Some(widest / depth)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Frame;
    use crate::synthetic::{SyntheticConfig, SyntheticSequence};
    use crate::tracking::{CollapseEvidence, TrackingConfig};

    /// The built-in orbit tracked for 120 frames, rolled back to its keyframe nearest frame
    /// 60, then frames 61.. again: what went, what stayed, and that tracking resumes in the
    /// same map at the poses of the first pass.
    #[test]
    fn a_roll_back_keeps_the_poses_before_the_window_and_tracking_resumes() {
        roll_back_and_resume(false);
    }

    /// The same with local mapping on its own thread: the roll-back erases keyframes it may
    /// still have queued or be working on.
    #[test]
    fn a_roll_back_under_a_running_mapping_thread() {
        roll_back_and_resume(true);
    }

    fn roll_back_and_resume(threaded: bool) {
        let seq = SyntheticSequence::new(SyntheticConfig::default());
        let c = &seq.config;
        let mut config = Config::default();
        config.semidense.enabled = false;
        let mut system = System::new(&c.calibration(), &config, 400, threaded);
        let mut f = Frame::new(c.width, c.height);
        let mut first_pass = Vec::new();
        for i in 0..120 {
            seq.render_frame(i, &mut f);
            first_pass.push(
                system
                    .process(&f.gray, Some(&f.rgb), f.timestamp, i as u64)
                    .t_wc,
            );
        }
        assert_eq!(system.state(), TrackingState::Ok);
        let traj_before = system.trajectory();
        // Chosen and rolled back under one lock: a mapping thread may cull keyframes between.
        let map_arc = Arc::clone(&system.map);
        let mut map = lock(&map_arc);
        let map_id = map.active_map();
        let kfs: Vec<(u64, f64)> = map
            .keyframes_of(map_id)
            .iter()
            .filter_map(|&k| map.keyframe(k).map(|k| (k.frame_index, k.timestamp)))
            .collect();
        let Some(&(from_frame, from_ts)) = kfs.iter().min_by_key(|(fi, _)| fi.abs_diff(60)) else {
            panic!("no keyframe");
        };
        let later = kfs.iter().filter(|(fi, _)| *fi > from_frame).count();
        let poses_later = system
            .trajectory
            .iter()
            .filter(|e| e.timestamp > from_ts)
            .count();
        assert!(
            later >= 3 && poses_later >= 20,
            "{later} keyframes, {poses_later} poses"
        );
        let evidence = CollapseEvidence {
            from_frame,
            from_timestamp: from_ts,
            frame: 119,
            depth_ratio: 0.2,
            path_per_depth_lost: 0.01,
            turn_deg: 1.0,
            inliers: 100,
            young_over_old: None,
        };
        let min_kept_baseline = TrackingConfig::default().collapse_min_kept_baseline;
        let Ok(r) = system.roll_back_active_map(&mut map, &evidence, min_kept_baseline) else {
            panic!("an established map was not rolled back");
        };
        assert_eq!(r.keyframes, later);
        assert_eq!(r.poses, poses_later);
        assert!(r.points > 0);
        assert_eq!(map.active_map(), map_id);
        let left = map.keyframes_of(map_id);
        assert!(left.len() <= kfs.len() - later);
        assert!(left
            .iter()
            .all(|&k| map.keyframe(k).is_some_and(|k| k.frame_index <= from_frame)));
        drop(map);
        assert_eq!(system.state(), TrackingState::Lost);
        assert_eq!(system.stats.resets, 0, "the map was discarded");
        let kept = system.trajectory();
        assert!(kept.iter().all(|p| p.timestamp <= from_ts));
        assert_eq!(kept.len(), traj_before.len() - poses_later);
        // The camera goes over frames after the window's start again (later timestamps).
        let dt = 1.0 / c.fps;
        let mut t = f.timestamp;
        let (mut resumed, mut worst) = (None, 0.0f64);
        for (n, i) in (from_frame as usize + 1..120).enumerate() {
            seq.render_frame(i, &mut f);
            t += dt;
            let r = system.process(&f.gray, Some(&f.rgb), t, 1000 + n as u64);
            if let (Some(now), Some(before)) = (r.t_wc, first_pass[i]) {
                resumed.get_or_insert(n);
                worst = worst.max((now.position() - before.position()).norm());
            }
        }
        let Some(resumed) = resumed else {
            panic!("tracking did not resume");
        };
        assert!(resumed < 10, "tracking resumed only after {resumed} frames");
        assert_eq!(system.atlas().maps.len(), 1, "a new map was started");
        // The same places as in the first pass, in the same map frame.
        let centres: Vec<_> = first_pass.iter().flatten().map(|p| p.position()).collect();
        let extent = centres
            .iter()
            .flat_map(|a| centres.iter().map(move |b| (a - b).norm()))
            .fold(0.0f64, f64::max);
        assert!(worst < 0.02 * extent, "{worst} vs extent {extent}");
    }

    /// The keyframes of the active map of a system fed `frames` frames of `scenario`
    /// (deterministic), with their baseline over depth.
    fn baseline_after(
        scenario: crate::synthetic::Scenario,
        frames: usize,
    ) -> (System, Vec<KeyFrameId>, Option<f64>) {
        let seq = SyntheticSequence::new(SyntheticConfig {
            scenario,
            ..SyntheticConfig::default()
        });
        let mut config = Config::default();
        config.semidense.enabled = false;
        let mut system = System::new(&seq.config.calibration(), &config, 400, false);
        let mut f = Frame::new(seq.config.width, seq.config.height);
        for i in 0..frames {
            seq.render_frame(i, &mut f);
            system.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64);
        }
        let kfs = {
            let map = lock(&system.map);
            map.keyframes_of(map.active_map()).to_vec()
        };
        let ratio = baseline_over_depth(&lock(&system.map), &kfs);
        (system, kfs, ratio)
    }

    /// A turn on the spot (an 8 cm arm, 3.3 m deep) makes keyframes that span well under
    /// the bar; the orbit's span many times it. So a collapse of the first is discarded and
    /// of the second rolled back, and the bar leaves room on both sides.
    #[test]
    fn a_turn_on_the_spot_has_no_baseline_to_roll_back_to_and_an_orbit_has() {
        let bar = TrackingConfig::default().collapse_min_kept_baseline;
        let (_, kfs, turn) = baseline_after(crate::synthetic::Scenario::Rotation, 45);
        assert!(kfs.len() >= 3, "the turn made {} keyframes", kfs.len());
        let Some(turn) = turn else {
            panic!("no depth in the turn's keyframes");
        };
        assert!(turn < bar, "turn on the spot: {turn}");
        let (mut system, kfs, orbit) = baseline_after(crate::synthetic::Scenario::Desk, 60);
        let Some(orbit) = orbit else {
            panic!("no depth in the orbit's keyframes");
        };
        assert!(orbit > 4.0 * bar, "orbit: {orbit}");
        // Asked to keep more baseline than its keyframes have, the orbit is not rolled back
        // and nothing is erased.
        let map_arc = Arc::clone(&system.map);
        let mut map = lock(&map_arc);
        let Some((from_frame, from_timestamp)) = kfs
            .iter()
            .filter_map(|&k| map.keyframe(k).map(|k| (k.frame_index, k.timestamp)))
            .filter(|&(fi, _)| fi >= 30)
            .min_by_key(|&(fi, _)| fi)
        else {
            panic!("no keyframe after frame 30");
        };
        let evidence = CollapseEvidence {
            from_frame,
            from_timestamp,
            frame: 59,
            depth_ratio: 0.2,
            path_per_depth_lost: 0.01,
            turn_deg: 1.0,
            inliers: 100,
            young_over_old: None,
        };
        match system.roll_back_active_map(&mut map, &evidence, 10.0) {
            Err(NotRolledBack::NoBaseline(r)) => assert!(r > 4.0 * bar && r < 10.0, "{r}"),
            Err(e) => panic!("not rolled back for another reason: {e:?}"),
            Ok(_) => panic!("rolled back although the bar was not met"),
        }
        assert_eq!(map.keyframes_of(map.active_map()).len(), kfs.len());
    }
}
