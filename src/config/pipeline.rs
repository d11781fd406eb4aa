//! The published parameters of tracking, pose optimisation, local mapping and loop closing
//! (ORB-SLAM's values): here, below the modules that use them, so that one configuration
//! tree (`[tracking]`, `[motion_only]`, `[local_mapping]`, `[loop_closing]`) reaches them.

use serde::{Deserialize, Serialize};

/// Published tracking parameters (ORB-SLAM's values).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingConfig {
    /// Search radius (pixels at level 0) of the motion-model projection; doubled on failure.
    pub motion_search_radius: f32,
    /// Matches needed after the motion-model search before optimising.
    pub min_motion_matches: usize,
    /// Inliers for tracking to succeed.
    pub min_inliers: usize,
    /// New keyframe when tracked points fall below this share of the reference's.
    pub keyframe_ratio: f64,
    /// Frames between keyframes at most (fps) and at least.
    pub max_frames_between_keyframes: u64,
    pub min_frames_between_keyframes: u64,
    /// Local keyframes considered at most.
    pub max_local_keyframes: usize,
    /// Viewing angle limit for local-map points: cos(60 deg).
    pub min_view_cos: f64,
    /// ORB-SLAM's bars after a relocalisation: it succeeds with this many inliers (once the
    /// local map is tracked), and for `relocalisation_settle_frames` after it tracking needs
    /// as many and makes no keyframe (while the map has more keyframes than that). A
    /// relocalised pose rests on few matches and no motion model; a wrong one is lost again
    /// instead of being mapped and reported `Ok`.
    pub min_inliers_after_relocalisation: usize,
    pub relocalisation_settle_frames: u64,
    /// Keyframes the place database proposes to relocalise against (best bag-of-words
    /// scores; ORB-SLAM takes every keyframe above a score, at most about this many matter).
    pub relocalisation_candidates: usize,
    /// Real-time use: a lost frame stops trying relocalisation candidates once this much
    /// time went into them (at least one is tried per frame; ours, not ORB-SLAM's), and the
    /// next lost frame starts with the candidates not yet tried, so a large map's candidates
    /// are spread over frames instead of holding one past its deadline. 0: no bound. Not
    /// applied in the deterministic mode or to replayed recordings (no clock in the result).
    pub relocalisation_budget_ms: f64,
    /// A map of at most this many keyframes is young: lost in it for more than
    /// `young_map_patience_frames` consecutive frames, it is discarded and initialisation
    /// starts over (ORB-SLAM resets at once; a short blackout should not cost the map).
    pub young_map_keyframes: usize,
    pub young_map_patience_frames: usize,
    /// The atlas (ORB-SLAM3): lost in an established map, start a new map at once (while
    /// still trying to relocalise in every map), merged later when place recognition joins
    /// it to an older one. Off: stay lost until relocalisation succeeds.
    pub new_map_when_lost: bool,
    /// Lost within this many frames of the last tracked frame, a frame is first tracked as
    /// usual from that frame's pose carried at its velocity, before relocalisation (ours, not
    /// ORB-SLAM's; see `tracking::recovery`). 0: relocalisation only.
    pub recovery_frames: usize,
    /// Scale collapse (see `tracking::collapse`): over `collapse_keyframes` keyframes the
    /// median scene depth fell below `collapse_depth_shrink` of its value while the camera
    /// travelled less than `collapse_path_ratio` of the depth lost and turned less than
    /// `collapse_max_turn_deg` (or turned, but with new points nearer than the old ones, see
    /// `collapse_young_over_old`): the map is rolled back to the window's first keyframe (what
    /// it made after it erased, with those frames' poses; see `runtime::system::rollback`),
    /// or discarded when no more than `young_map_keyframes` would be left, or when what would
    /// be left never had a baseline (`collapse_min_kept_baseline`).
    pub collapse_path_ratio: f64,
    pub collapse_depth_shrink: f64,
    pub collapse_max_turn_deg: f64,
    pub collapse_keyframes: usize,
    /// The turn is no excuse when the points the window's keyframes made sit nearer than
    /// this share of the depth of the older points beside them (median over image cells
    /// holding both; `tracking::collapse`). On the same surfaces the two agree: a map whose
    /// motion shrank triangulates its new points from too short baselines, too near.
    pub collapse_young_over_old: f64,
    /// A collapsing map is rolled back only when the keyframes it would keep span at least
    /// this share of their median scene depth (ours): a roll-back trusts what came before the
    /// window, and keyframes that never moved further apart than that (a turn on the spot)
    /// stood on sub-degree parallax from the start. Otherwise it is discarded. 0.035 is
    /// twice the initialisation's 1 degree (`tan 2 deg`); the suite's roll-backs keep 0.25-1.3.
    pub collapse_min_kept_baseline: f64,
    /// A tracked pose is `Degraded`, not `Ok` (see `tracking::quality`; ours, not ORB-SLAM's),
    /// when its camera centre's 1-sigma uncertainty exceeds this share of the median scene
    /// depth (every sequence of the robustness suite stays below 0.011)...
    pub max_centre_sigma_ratio: f64,
    /// ...when its inliers' mean squared reprojection error, in octave sigma², exceeds this
    /// (keypoint noise gives about 1; the suite stays below 2.2)...
    pub max_mean_chi2: f64,
    /// ...or when its centre lands farther than this share of the scene depth from the
    /// constant-velocity prediction (the suite stays below 0.065).
    pub max_jump_ratio: f64,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        TrackingConfig {
            motion_search_radius: 15.0,
            min_motion_matches: 20,
            min_inliers: 30,
            keyframe_ratio: 0.9,
            max_frames_between_keyframes: 30,
            min_frames_between_keyframes: 0,
            max_local_keyframes: 80,
            min_view_cos: 0.5,
            min_inliers_after_relocalisation: 50,
            relocalisation_settle_frames: 20,
            relocalisation_candidates: 10,
            relocalisation_budget_ms: 10.0,
            young_map_keyframes: 5,
            young_map_patience_frames: 30,
            new_map_when_lost: true,
            recovery_frames: 10,
            collapse_path_ratio: 0.1,
            collapse_depth_shrink: 0.25,
            collapse_max_turn_deg: 15.0,
            collapse_keyframes: 5,
            collapse_young_over_old: 0.5,
            collapse_min_kept_baseline: 0.035,
            max_centre_sigma_ratio: 0.02,
            max_mean_chi2: 3.0,
            max_jump_ratio: 0.15,
        }
    }
}

/// Published local-mapping parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LocalMappingConfig {
    /// Covisible keyframes used for triangulation (ORB-SLAM monocular: 20).
    pub triangulation_neighbours: usize,
    /// Culling: minimum found/visible ratio, and observations needed after 2 keyframes.
    pub min_found_ratio: f64,
    pub min_observations: usize,
    /// Keyframe culling: share of redundant points.
    pub redundancy: f64,
    /// Keyframe culling starts once the map holds this many keyframes (ours, not ORB-SLAM's):
    /// a young map's keyframes are its only baselines. Right after initialisation on slow
    /// forward or turning motion a keyframe is inserted every frame and each looks redundant
    /// to the next, so culling kept 4-5 keyframes a frame apart and the map never gained depth.
    pub cull_after_keyframes: usize,
    pub ba_iterations_robust: usize,
    pub ba_iterations: usize,
}

impl Default for LocalMappingConfig {
    fn default() -> Self {
        LocalMappingConfig {
            triangulation_neighbours: 20,
            min_found_ratio: 0.25,
            min_observations: 2,
            redundancy: 0.9,
            cull_after_keyframes: 10,
            ba_iterations_robust: 5,
            ba_iterations: 10,
        }
    }
}

/// Published parameters (ORB-SLAM's loop closing).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopClosingConfig {
    /// Consecutive keyframes whose candidates must be consistent.
    pub covisibility_consistency: usize,
    /// Keyframes since the last loop (and in the map) before detecting a new one.
    pub min_keyframes_between_loops: usize,
    /// Map-point matches needed after the projection search.
    pub min_matches: usize,
    /// Pose-graph iterations and covisibility weight of essential-graph edges.
    pub pose_graph_iterations: usize,
    /// Revisits (loops tracking has already joined): the path travelled from the old keyframe
    /// must be at least this many times the distance between the two camera centres...
    pub revisit_path_ratio: f64,
    /// ...and at least this many times the new keyframe's median scene depth (so that drift
    /// can have built up along it).
    pub revisit_min_path_depths: f64,
    /// A loop's similarity is taken only when the matches of its refinement window (the current
    /// keyframe and its best covisibles) fix the relative scale to this 1-sigma share (log
    /// scale, one pixel of keypoint noise; ours, not ORB-SLAM's): otherwise the correction
    /// would move a whole map by the error, and a later keyframe tries again.
    pub max_scale_sigma: f64,
}

impl Default for LoopClosingConfig {
    fn default() -> Self {
        LoopClosingConfig {
            covisibility_consistency: 3,
            min_keyframes_between_loops: 10,
            min_matches: 40,
            pose_graph_iterations: 20,
            revisit_path_ratio: 5.0,
            revisit_min_path_depths: 2.0,
            max_scale_sigma: 0.015,
        }
    }
}

/// Parameters (ORB-SLAM's values).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionOnlyConfig {
    pub rounds: usize,
    pub iterations: usize,
    /// chi² gate (2 DoF, 95%) for inlier classification and the Huber threshold.
    pub chi2: f64,
    /// Rounds from which the robust kernel is off.
    pub robust_rounds: usize,
}

impl Default for MotionOnlyConfig {
    fn default() -> Self {
        MotionOnlyConfig {
            rounds: 4,
            iterations: 10,
            chi2: 5.991,
            robust_rounds: 2,
        }
    }
}
