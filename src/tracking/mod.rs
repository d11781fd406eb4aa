//! Tracking (ORB-SLAM, section "Tracking"): constant-velocity prediction with search by
//! projection of the last frame's points (window widened once), reference-keyframe fallback,
//! motion-only BA, local-map tracking (frustum, scale and viewing-angle tests), and the keyframe
//! decision. The state (NotInitialised, Ok, Degraded, Lost) is exposed; losing track is a
//! state, not an error.

pub mod collapse;
pub mod frame;
pub mod initializer;
mod local_map;
pub mod quality;
mod recovery;
mod relocalisation;

use nalgebra::{Vector2, Vector3};

pub use collapse::{CollapseEvidence, CollapseMonitor};
pub use frame::{KeptImages, TrackedFrame};
pub use initializer::{
    solve as solve_initialisation, InitAttempt, InitProblem, Initializer, Prepared,
};
pub use quality::{DegradedReason, PoseQuality};

use crate::camera_model::PinholeRadtan;
use crate::geometry::{CameraFromWorld, Se3};
use crate::map::{KeyFrameId, Map};
use crate::matching::search::{search_by_projection, ProjectedPoint, ProjectionSearch};
use crate::matching::{hamming, RotationHistogram, TH_LOW};
use crate::optimize::MotionOnlyBa;

/// The tracking state reported for every frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrackingState {
    NotInitialised,
    /// Tracked, and the pose passed every check of [`quality`]: one to drive on.
    Ok,
    /// Tracked against the map, but the pose failed a check of [`quality`] (the reason is
    /// [`Tracker::degraded`]): reported, not to be driven on; it makes no keyframe and tracking
    /// carries on from it.
    Degraded,
    Lost,
}

pub use crate::config::TrackingConfig;

/// Tracks frames against the map. Owns its state machine (NotInitialised -> Ok <-> Lost, with
/// `Degraded` beside Ok for a tracked pose that fails a [`quality`] check):
/// the state and what the motion model carries between frames change only through its
/// methods ([`start`](Self::start), [`reset`](Self::reset), [`keyframe_made`](Self::keyframe_made),
/// [`commit`](Self::commit), tracking and relocalisation).
pub struct Tracker {
    pub config: TrackingConfig,
    /// EPnP + RANSAC of relocalisation.
    relocalisation: crate::geometry::pnp::PnpRansacConfig,
    state: TrackingState,
    pub camera: PinholeRadtan,
    pub motion_ba: MotionOnlyBa,
    pub scales: Vec<f64>,
    pub inv_sigma2: Vec<f64>,
    /// Last tracked frame's pose and matched points (the motion model's source).
    last: TrackedFrame,
    velocity: Option<Se3>,
    reference_kf: Option<KeyFrameId>,
    /// The reference keyframe's pose when the last frame was tracked: if the map moves it
    /// (local BA, loop correction), the last pose is re-based on it before predicting.
    reference_pose: Option<(KeyFrameId, CameraFromWorld)>,
    last_keyframe_frame: u64,
    pub lost_episodes: usize,
    /// Successful relocalisations.
    pub relocalisations: usize,
    /// Lost frames tracked again from the last tracked pose (see `tracking::recovery`).
    pub recoveries: usize,
    last_tracked: Option<recovery::LastTracked>,
    /// Frame of the last relocalisation in the current map (see `relocalisation`).
    last_relocalisation: Option<u64>,
    /// Lost frames whose relocalisation stopped at its time budget.
    pub relocalisation_budget_cuts: usize,
    /// Candidates the last relocalisation tried.
    reloc_tried: usize,
    /// Stage timers: pose prediction and matching (motion model, or the reference keyframe,
    /// with pose optimisation), local-map tracking, relocalisation attempts.
    pub t_prediction: crate::timing::StageTimer,
    pub t_local_map: crate::timing::StageTimer,
    pub t_relocalisation: crate::timing::StageTimer,
    projected: Vec<ProjectedPoint>,
    proj_ids: Vec<crate::map::MapPointId>,
    /// Per projected point: its keypoint index in the last frame (rotation check).
    proj_kp: Vec<usize>,
    /// Per keypoint of the current frame: matched projected point (reused every frame).
    matches: Vec<Option<u32>>,
    rot: RotationHistogram,
    scratch: Vec<u32>,
    pts: Vec<Vector3<f64>>,
    obs: Vec<Vector2<f64>>,
    inv: Vec<f64>,
    out: Vec<bool>,
    idx: Vec<usize>,
    local: local_map::LocalMap,
    /// The motion model's prediction for the frame being tracked (the jump check's anchor).
    prediction: Option<CameraFromWorld>,
    /// The last tracked (or relocalised) frame's pose quality and the check it failed.
    quality: Option<PoseQuality>,
    degraded: Option<DegradedReason>,
    depths: Vec<f64>,
}

impl Tracker {
    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// The last tracked frame's pose quality (None when it was lost).
    pub fn quality(&self) -> Option<PoseQuality> {
        self.quality
    }

    /// Why the last frame is `Degraded`, if it is.
    pub fn degraded(&self) -> Option<DegradedReason> {
        self.degraded
    }

    /// Measures the pose the last [`optimize_pose`](Self::optimize_pose) left in `f` (its
    /// buffers still hold that optimisation) and judges it; `prediction` anchors the jump
    /// check.
    pub(crate) fn judge_pose(
        &mut self,
        f: &TrackedFrame,
        prediction: Option<CameraFromWorld>,
    ) -> (PoseQuality, Option<DegradedReason>) {
        let fit = quality::PoseFit {
            t_cw: &f.t_cw,
            pts: &self.pts,
            obs: &self.obs,
            inv_s2: &self.inv,
            outlier: &self.out,
        };
        let q = quality::measure(&self.motion_ba, &fit, prediction.as_ref(), &mut self.depths);
        (q, q.judge(&self.config))
    }

    /// The keyframe the current pose is expressed against (the trajectory's anchor).
    pub fn reference_kf(&self) -> Option<KeyFrameId> {
        self.reference_kf
    }

    /// The map was just initialised: tracking continues from keyframe `reference`, which
    /// frame `frame_index` made.
    pub fn start(&mut self, reference: KeyFrameId, frame_index: u64) {
        self.reset(TrackingState::Ok);
        self.reference_kf = Some(reference);
        self.last_keyframe_frame = frame_index;
    }

    /// The one way back to a state without a reference: `NotInitialised` (the map was
    /// discarded) or `Lost` (a map was loaded: relocalise in it). Forgets the reference,
    /// its pose and the motion model.
    pub fn reset(&mut self, state: TrackingState) {
        self.state = state;
        self.reference_kf = None;
        self.reference_pose = None;
        self.velocity = None;
        self.last_tracked = None;
        self.last_relocalisation = None;
    }

    /// Frame `frame_index` became keyframe `kf`: the new reference.
    pub fn keyframe_made(&mut self, kf: KeyFrameId, frame_index: u64) {
        self.reference_kf = Some(kf);
        self.last_keyframe_frame = frame_index;
    }

    /// The frame is done: it becomes the last frame the motion model predicts from.
    pub fn commit(&mut self, frame: &TrackedFrame) {
        self.last.copy_from(frame);
    }

    /// The published parameters in force (ORB-SLAM's by default).
    pub fn with_config(
        mut self,
        tracking: TrackingConfig,
        motion_only: crate::config::MotionOnlyConfig,
        relocalisation: crate::geometry::pnp::PnpRansacConfig,
    ) -> Self {
        self.config = tracking;
        self.motion_ba.config = motion_only;
        self.relocalisation = relocalisation;
        self
    }

    pub fn new(camera: PinholeRadtan, scales: Vec<f64>, max_features: usize) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let inv_sigma2 = scales.iter().map(|s| 1.0 / (s * s)).collect();
        Tracker {
            config: TrackingConfig::default(),
            relocalisation: Default::default(),
            state: TrackingState::NotInitialised,
            motion_ba: MotionOnlyBa::new(camera.intrinsics()),
            camera,
            scales,
            inv_sigma2,
            last: TrackedFrame::new(max_features, w, h),
            velocity: None,
            reference_kf: None,
            reference_pose: None,
            last_keyframe_frame: 0,
            lost_episodes: 0,
            relocalisations: 0,
            recoveries: 0,
            last_tracked: None,
            last_relocalisation: None,
            relocalisation_budget_cuts: 0,
            reloc_tried: 0,
            t_prediction: crate::timing::StageTimer::with_capacity(4096),
            t_local_map: crate::timing::StageTimer::with_capacity(4096),
            t_relocalisation: crate::timing::StageTimer::with_capacity(1024),
            projected: Vec::with_capacity(max_features * 8),
            proj_ids: Vec::with_capacity(max_features * 8),
            proj_kp: Vec::with_capacity(max_features),
            matches: Vec::with_capacity(max_features),
            rot: RotationHistogram::with_capacity(max_features / 8),
            scratch: Vec::with_capacity(256),
            pts: Vec::with_capacity(max_features),
            obs: Vec::with_capacity(max_features),
            inv: Vec::with_capacity(max_features),
            out: Vec::with_capacity(max_features),
            idx: Vec::with_capacity(max_features),
            local: local_map::LocalMap::with_capacity(max_features * 8),
            prediction: None,
            quality: None,
            degraded: None,
            depths: Vec::with_capacity(max_features),
        }
    }

    /// Motion-only BA of `f` over its matched points; outliers are unmatched. Returns inliers.
    pub(crate) fn optimize_pose(&mut self, map: &Map, f: &mut TrackedFrame) -> usize {
        self.pts.clear();
        self.obs.clear();
        self.inv.clear();
        self.out.clear();
        self.idx.clear();
        for (i, p) in f.points.iter().enumerate() {
            let Some(p) = p.and_then(|p| map.point(p)) else {
                continue;
            };
            let k = &f.features.keypoints[i];
            self.pts.push(p.position);
            self.obs.push(Vector2::new(k.ux as f64, k.uy as f64));
            self.inv.push(self.inv_sigma2[k.octave as usize]);
            self.out.push(false);
            self.idx.push(i);
        }
        if self.pts.len() < 4 {
            return 0;
        }
        let n =
            self.motion_ba
                .optimize(&mut f.t_cw, &self.pts, &self.obs, &self.inv, &mut self.out);
        for (k, &i) in self.idx.iter().enumerate() {
            f.outlier[i] = self.out[k];
            if self.out[k] {
                f.points[i] = None;
            }
        }
        n
    }

    /// Projects the last frame's points with the predicted pose and matches them.
    fn track_motion_model(&mut self, map: &Map, f: &mut TrackedFrame) -> usize {
        let pred = match self.velocity {
            Some(v) => v * self.last.t_cw.0,
            None => self.last.t_cw.0,
        };
        self.prediction = self.velocity.map(|_| CameraFromWorld(pred));
        f.t_cw = CameraFromWorld(pred);
        for radius in [
            self.config.motion_search_radius,
            2.0 * self.config.motion_search_radius,
        ] {
            f.points.iter_mut().for_each(|p| *p = None);
            self.projected.clear();
            self.proj_ids.clear();
            self.proj_kp.clear();
            for (i, mp) in self.last.inlier_points() {
                let Some(p) = map.point(mp) else { continue };
                let pc = f.t_cw.transform(&p.position);
                let Some(uv) = self.camera.project(&pc) else {
                    continue;
                };
                if !self.camera.in_image(uv.x, uv.y, 0.0) {
                    continue;
                }
                self.projected.push(ProjectedPoint {
                    id: self.proj_ids.len() as u32,
                    uv: uv.cast(),
                    level: self.last.features.keypoints[i].octave,
                    descriptor: p.descriptor,
                    radius_factor: 1.0,
                });
                self.proj_ids.push(mp);
                self.proj_kp.push(i);
            }
            let m = &mut self.matches;
            m.clear();
            m.resize(f.features.len(), None);
            let search = ProjectionSearch {
                scales: &self.scales,
                radius,
                ratio: 0.9,
            };
            search_by_projection(
                &self.projected,
                f.features.view(),
                &f.grid,
                search,
                m,
                &mut self.scratch,
            );
            rotation_filter(
                &self.proj_kp,
                &self.last,
                &f.features.keypoints,
                m,
                &mut self.rot,
            );
            let mut n = 0;
            for (j, mm) in m.iter().enumerate() {
                if let Some(id) = mm {
                    f.points[j] = Some(self.proj_ids[*id as usize]);
                    n += 1;
                }
            }
            if n >= self.config.min_motion_matches {
                break;
            }
        }
        self.optimize_pose(map, f)
    }

    /// Fallback: match all features of the reference keyframe by descriptor (ratio 0.7 and
    /// rotation consistency), optimise from the last pose.
    fn track_reference_keyframe(&mut self, map: &Map, f: &mut TrackedFrame) -> usize {
        let Some(kf) = self.reference_kf.filter(|r| map.keyframe(*r).is_some()) else {
            return 0;
        };
        f.t_cw = self.last.t_cw;
        f.points.iter_mut().for_each(|p| *p = None);
        if self.match_keyframe(map, kf, f, 0.7) < 15 {
            return 0;
        }
        self.optimize_pose(map, f)
    }

    /// When the reference keyframe moved since the last frame (a loop correction), moves the
    /// last frame's pose with it so the motion model predicts in the corrected map.
    fn rebase_last_frame(&mut self, map: &Map) {
        let Some((r, old)) = self.reference_pose else {
            return;
        };
        let Some(new) = map.keyframe(r).map(|k| k.t_cw) else {
            return;
        };
        let moved = (new.0.translation.vector - old.0.translation.vector).norm()
            + new.0.rotation.angle_to(&old.0.rotation);
        if moved > 1e-2 {
            let t_c_ref = self.last.t_cw.0 * old.0.inverse();
            self.last.t_cw = CameraFromWorld(t_c_ref * new.0);
        }
    }

    /// Matches the map points observed by keyframe `kf` to `f`'s features by descriptor
    /// (best below TH_LOW and `ratio` x the second best, one map point per feature, rotation
    /// consistency). Returns how many features got a map point.
    fn match_keyframe(
        &mut self,
        map: &Map,
        kf: KeyFrameId,
        f: &mut TrackedFrame,
        ratio: f32,
    ) -> usize {
        let Some(kf) = map.keyframe(kf) else {
            return 0;
        };
        let mut best_for: Vec<(u32, usize)> = vec![(u32::MAX, usize::MAX); f.features.len()];
        let rot = &mut self.rot;
        rot.clear();
        for (i, mp) in kf.observed() {
            let d1 = &kf.descriptors[i];
            let (mut b, mut s, mut bj) = (u32::MAX, u32::MAX, usize::MAX);
            for (j, d2) in f.features.descriptors.iter().enumerate() {
                let d = hamming(d1, d2);
                if d < b {
                    s = b;
                    b = d;
                    bj = j;
                } else if d < s {
                    s = d;
                }
            }
            if b <= TH_LOW && (b as f32) < ratio * s as f32 && b < best_for[bj].0 {
                best_for[bj] = (b, i);
                f.points[bj] = Some(mp);
            }
        }
        for (j, &(_, i)) in best_for.iter().enumerate() {
            if i != usize::MAX && f.points[j].is_some() {
                rot.add(
                    kf.keypoints[i].angle,
                    f.features.keypoints[j].angle,
                    j as u32,
                );
            }
        }
        rot.for_each_rejected(|j| f.points[j as usize] = None);
        f.points.iter().filter(|p| p.is_some()).count()
    }

    /// Tracks `f` (features extracted, matches reset). Updates the motion model and state.
    pub fn track(&mut self, map: &mut Map, f: &mut TrackedFrame) -> TrackingState {
        let t0 = std::time::Instant::now();
        self.rebase_last_frame(map);
        let mut n = self.track_motion_model(map, f);
        let (n_motion, mut n_reference) = (n, 0);
        if n < 10 {
            // The reference keyframe's search is for motion the model did not predict: no
            // jump check against that prediction.
            self.prediction = None;
            f.reset_matches();
            n = self.track_reference_keyframe(map, f);
            n_reference = n;
        }
        self.t_prediction.record(t0.elapsed());
        if n >= 10 {
            let t1 = std::time::Instant::now();
            let mut local = std::mem::take(&mut self.local);
            n = local.track(self, map, f);
            self.local = local;
            self.t_local_map.record(t1.elapsed());
        }
        let ok = n >= self.inliers_needed(f.index);
        tracing::trace!(
            frame = f.index,
            inliers = n,
            motion = n_motion,
            reference = n_reference,
            "tracked"
        );
        self.reference_pose = self
            .reference_kf
            .and_then(|r| map.keyframe(r).map(|k| (r, k.t_cw)));
        let prediction = self.prediction.take();
        if ok {
            let (q, degraded) = self.judge_pose(f, prediction);
            self.quality = Some(q);
            self.degraded = degraded;
            // After a jump the velocity it implies would mislead the next prediction.
            self.velocity = (degraded != Some(DegradedReason::Jump))
                .then(|| f.t_cw.0 * self.last.t_cw.0.inverse());
            self.last_tracked = Some(recovery::LastTracked {
                t_cw: f.t_cw,
                index: f.index,
                velocity: self.velocity,
            });
            self.state = if degraded.is_some() {
                tracing::debug!(
                    frame = f.index,
                    reason = degraded.map(|d| d.name()),
                    sigma_ratio = q.centre_sigma_ratio(),
                    mean_chi2 = q.mean_chi2,
                    "pose degraded"
                );
                TrackingState::Degraded
            } else {
                TrackingState::Ok
            };
        } else {
            self.quality = None;
            self.degraded = None;
            if self.state != TrackingState::Lost {
                self.lost_episodes += 1;
                tracing::warn!(frame = f.index, "tracking lost");
            }
            self.state = TrackingState::Lost;
            self.velocity = None;
        }
        self.state
    }

    /// ORB-SLAM's keyframe rule: enough frames since the last keyframe (or local mapping idle),
    /// and the frame tracks fewer than 90% of the reference's well-observed points but more
    /// than 15.
    pub fn need_keyframe(&self, map: &Map, f: &TrackedFrame, mapping_idle: bool) -> bool {
        if self.state != TrackingState::Ok {
            return false;
        }
        let Some(r) = self.reference_kf.and_then(|r| map.keyframe(r)) else {
            return true;
        };
        // ORB-SLAM counts points seen by >= 3 keyframes once the map has more than 2; a young
        // map's points mostly have 2 observations, which starves keyframe insertion and lets the
        // baseline grow past what epipolar matching can bridge. Use 3 only once the map is
        // established (the reference keyframe's map: a new map of the atlas is young).
        let min_obs = if map.n_keyframes_of(r.map_id) <= 5 {
            2
        } else {
            3
        };
        let ref_tracked = r
            .observed()
            .filter(|&(_, p)| {
                map.point(p)
                    .is_some_and(|p| p.observations.len() >= min_obs)
            })
            .count();
        if self.settling(f.index)
            && map.n_keyframes_of(r.map_id) > self.config.relocalisation_settle_frames as usize
        {
            return false;
        }
        let tracked = f.n_inliers();
        let since = f.index.saturating_sub(self.last_keyframe_frame);
        let c1 = since >= self.config.max_frames_between_keyframes
            || (since >= self.config.min_frames_between_keyframes && mapping_idle);
        let c2 = (tracked as f64) < self.config.keyframe_ratio * ref_tracked as f64 && tracked > 15;
        c1 && c2
    }
}

/// Rotation-consistency check on projection matches against the last frame's keypoints
/// (`proj_kp[id]` is the last-frame keypoint of projected point `id`).
fn rotation_filter(
    proj_kp: &[usize],
    last: &TrackedFrame,
    kps: &[crate::features::KeyPoint],
    m: &mut [Option<u32>],
    rot: &mut RotationHistogram,
) {
    rot.clear();
    for (j, mm) in m.iter().enumerate() {
        if let Some(&li) = mm.and_then(|id| proj_kp.get(id as usize)) {
            rot.add(last.features.keypoints[li].angle, kps[j].angle, j as u32);
        }
    }
    rot.for_each_rejected(|j| m[j as usize] = None);
}
