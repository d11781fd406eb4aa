//! Relocalisation of a lost frame against candidate keyframes (ORB-SLAM's procedure with its
//! published bars: EPnP-RANSAC on >= 15 descriptor matches, success with
//! `min_inliers_after_relocalisation` inliers once the local map is tracked). A relocalised
//! pose is the least certain a tracker makes (few matches, no motion model to agree with), so
//! for `relocalisation_settle_frames` after it tracking needs that many inliers too and makes
//! no keyframe: a wrong relocalisation is lost again instead of being mapped.

use nalgebra::Vector2;

use super::{recovery, TrackedFrame, Tracker, TrackingState};
use crate::map::{KeyFrameId, Map};

impl Tracker {
    /// Whether frame `index` is within `relocalisation_settle_frames` of the last
    /// relocalisation.
    pub(super) fn settling(&self, index: u64) -> bool {
        self.last_relocalisation
            .is_some_and(|r| index < r + self.config.relocalisation_settle_frames)
    }

    /// Inliers a relocalised frame (and one settling after it) needs.
    fn relocalised_inliers(&self) -> usize {
        self.config
            .min_inliers
            .max(self.config.min_inliers_after_relocalisation)
    }

    /// Inliers frame `index` needs to be tracked: `min_inliers`, or ORB-SLAM's higher bar
    /// while settling after a relocalisation.
    pub(super) fn inliers_needed(&self, index: u64) -> usize {
        if self.settling(index) {
            self.relocalised_inliers()
        } else {
            self.config.min_inliers
        }
    }

    /// Relocalisation (tracking lost): for each candidate keyframe (from the place-recognition
    /// database, best first) match its map points to `f` by descriptor (ratio 0.75, rotation
    /// consistency), solve EPnP-RANSAC on >= 15 matches, optimise the pose on the inliers and,
    /// with >= 10 left, track the local map from there; success when the local map gives
    /// `min_inliers_after_relocalisation`. Returns the state (Ok on success; Lost otherwise).
    /// With a `budget`, candidates after the first are tried only while the time spent is
    /// below it ([`relocalisation_candidates_tried`](Self::relocalisation_candidates_tried)
    /// says how many were).
    pub fn relocalise(
        &mut self,
        map: &mut Map,
        f: &mut TrackedFrame,
        candidates: &[KeyFrameId],
        budget: Option<std::time::Duration>,
    ) -> TrackingState {
        let started = std::time::Instant::now();
        let state = self.relocalise_with(map, f, candidates, started, budget);
        self.t_relocalisation.record(started.elapsed());
        state
    }

    /// Candidates the last [`relocalise`](Self::relocalise) tried (all of them unless its
    /// budget ran out first).
    pub fn relocalisation_candidates_tried(&self) -> usize {
        self.reloc_tried
    }

    fn relocalise_with(
        &mut self,
        map: &mut Map,
        f: &mut TrackedFrame,
        candidates: &[KeyFrameId],
        started: std::time::Instant,
        budget: Option<std::time::Duration>,
    ) -> TrackingState {
        let k = self.camera.k();
        let cfg = self.relocalisation.clone();
        self.reloc_tried = 0;
        for &c in candidates {
            if self.reloc_tried > 0 && budget.is_some_and(|b| started.elapsed() >= b) {
                self.relocalisation_budget_cuts += 1;
                break;
            }
            self.reloc_tried += 1;
            f.reset_matches();
            let n = self.match_keyframe(map, c, f, 0.75);
            if n < 15 {
                tracing::trace!(frame = f.index, candidate = ?c, matches = n, observed = map.keyframe(c).map_or(0, |k| k.observed().count()), "relocalisation: too few matches");
                continue;
            }
            let (mut pw, mut px, mut s2, mut which) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for (j, p) in f.points.iter().enumerate() {
                let Some(mp) = p.and_then(|p| map.point(p)) else {
                    continue;
                };
                let kp = &f.features.keypoints[j];
                pw.push(mp.position);
                px.push(Vector2::new(kp.ux as f64, kp.uy as f64));
                let s = self.scales[kp.octave as usize];
                s2.push(s * s);
                which.push(j);
            }
            let Some(sol) = crate::geometry::pnp::pnp_ransac(&pw, &px, &s2, &k, &cfg) else {
                tracing::trace!(frame = f.index, candidate = ?c, matches = n, "relocalisation: no PnP solution");
                continue;
            };
            for (m, &j) in which.iter().enumerate() {
                if !sol.inliers[m] {
                    f.points[j] = None;
                }
            }
            f.t_cw = sol.t_cw;
            let refined = self.optimize_pose(map, f);
            if refined < 10 {
                tracing::trace!(frame = f.index, candidate = ?c, matches = n, refined, "relocalisation: too few inliers");
                continue;
            }
            self.reference_kf = Some(c);
            let mut local = std::mem::take(&mut self.local);
            let n = local.track(self, map, f);
            self.local = local;
            tracing::trace!(frame = f.index, candidate = ?c, refined, local = n, "relocalisation: local map tracked");
            if n >= self.relocalised_inliers() {
                // A relocalisation the checks doubt is not taken: the next candidate is tried.
                let (q, degraded) = self.judge_pose(f, None);
                if degraded.is_some() {
                    continue;
                }
                self.quality = Some(q);
                self.degraded = None;
                self.state = TrackingState::Ok;
                self.velocity = None;
                self.last_tracked = Some(recovery::LastTracked {
                    t_cw: f.t_cw,
                    index: f.index,
                    velocity: None,
                });
                self.relocalisations += 1;
                self.last_relocalisation = Some(f.index);
                tracing::info!(frame = f.index, inliers = n, "relocalised");
                return self.state;
            }
        }
        f.reset_matches();
        self.state = TrackingState::Lost;
        self.quality = None;
        self.degraded = None;
        self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::MapConfig;

    /// A tracker, a lost frame and `n` candidate keyframes that cannot match it.
    fn setup(n: usize) -> (Tracker, Map, TrackedFrame, Vec<KeyFrameId>) {
        let camera =
            crate::camera_model::PinholeRadtan::pinhole(500.0, 500.0, 320.0, 240.0, 640, 480);
        let scales: Vec<f64> = (0..8).map(|l| 1.2f64.powi(l)).collect();
        let tracker = Tracker::new(camera, scales, 100);
        let mut map = Map::new(MapConfig {
            max_keyframes: 16,
            max_map_points: 16,
            max_features: 100,
            ..MapConfig::default()
        });
        let candidates = (0..n)
            .filter_map(|_| map.insert_keyframe(|_| {}).ok())
            .collect();
        (tracker, map, TrackedFrame::new(100, 640, 480), candidates)
    }

    #[test]
    fn after_a_relocalisation_tracking_needs_50_inliers_for_20_frames() {
        let (mut t, ..) = setup(0);
        assert_eq!(t.inliers_needed(100), 30);
        t.last_relocalisation = Some(100);
        assert!(t.settling(100) && t.settling(119) && !t.settling(120));
        assert_eq!(t.inliers_needed(100), 50);
        assert_eq!(t.inliers_needed(119), 50);
        assert_eq!(t.inliers_needed(120), 30);
        // A new map (the tracker's reset) forgets it.
        t.reset(TrackingState::Lost);
        assert_eq!(t.inliers_needed(101), 30);
    }

    #[test]
    fn without_a_budget_every_candidate_is_tried() {
        let (mut t, mut map, mut f, c) = setup(5);
        assert_eq!(c.len(), 5);
        let st = t.relocalise(&mut map, &mut f, &c, None);
        assert_eq!(st, TrackingState::Lost);
        assert_eq!(t.relocalisation_candidates_tried(), 5);
        assert_eq!(t.relocalisation_budget_cuts, 0);
    }

    #[test]
    fn a_spent_budget_stops_after_the_first_candidate() {
        let (mut t, mut map, mut f, c) = setup(5);
        let st = t.relocalise(&mut map, &mut f, &c, Some(std::time::Duration::ZERO));
        assert_eq!(st, TrackingState::Lost);
        assert_eq!(t.relocalisation_candidates_tried(), 1);
        assert_eq!(t.relocalisation_budget_cuts, 1);
        // A generous budget tries them all again.
        t.relocalise(
            &mut map,
            &mut f,
            &c,
            Some(std::time::Duration::from_secs(60)),
        );
        assert_eq!(t.relocalisation_candidates_tried(), 5);
        assert_eq!(t.relocalisation_budget_cuts, 1);
    }
}
