//! `report.json`: what a run did and how long each stage took. Key names are a stable contract.

use serde::Serialize;

use super::Percentiles;

/// Per-stage timing percentiles (milliseconds).
#[derive(Clone, Debug, Default, Serialize)]
pub struct TimingReport {
    /// Frame available -> pose out.
    pub tracking: Percentiles,
    pub orb_extraction: Percentiles,
    /// One initialisation attempt (a frame before the map exists, on the tracking thread).
    pub initialisation: Percentiles,
    /// Threaded mode: solving one attempt on the initialisation thread (off the frame path).
    pub initialisation_solve: Percentiles,
    /// Motion-model (or reference-keyframe) matching and pose optimisation.
    pub pose_prediction: Percentiles,
    pub local_map_tracking: Percentiles,
    /// Tracking waiting for the map lock (held by local mapping, loop closing or semi-dense
    /// copies): the part of a slow frame that is not tracking's own work.
    pub map_lock_wait: Percentiles,
    /// On the tracking thread, when a keyframe is made (inline mode: includes local mapping).
    pub keyframe_insertion: Percentiles,
    pub relocalisation: Percentiles,
    /// Local mapping per keyframe (point culling, triangulation, fusion, local BA, keyframe
    /// culling), on its thread.
    pub local_ba: Percentiles,
    pub loop_closing: Percentiles,
    pub semidense_keyframe: Percentiles,
    pub semidense_depth: Percentiles,
    pub semidense_intra: Percentiles,
    pub semidense_inter: Percentiles,
}

/// One map of the atlas at the end of the run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MapRecord {
    pub id: u32,
    pub tracked_frames: usize,
    pub keyframes: usize,
}

/// The run report.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    pub sdslam_version: String,
    pub source: String,
    /// Frames delivered to tracking.
    pub frames: usize,
    pub tracked_frames: usize,
    /// Of `tracked_frames`: frames between the initialisation reference and the initialising
    /// frame, tracked against the first map once it existed (their poses came late).
    pub backfilled_frames: usize,
    pub lost_episodes: usize,
    /// The atlas: maps initialised over the run (the first included; a new one starts when
    /// tracking is lost where no map relocalises it), maps merged into older ones by place
    /// recognition, and the maps at the end. `trajectory.txt`, `keyframes.txt` and the cloud
    /// are the primary map's (the most tracked frames); any other map's poses are in
    /// `trajectory_map<id>.txt` and `keyframes_map<id>.txt`, in that map's own frame.
    pub maps_made: usize,
    /// Frames with a pose in any map (`tracked_frames` and `keyframes` count the primary
    /// map's, as in `trajectory.txt` and `keyframes.txt`).
    pub tracked_frames_all_maps: usize,
    pub maps_merged: usize,
    pub primary_map: Option<u32>,
    pub maps: Vec<MapRecord>,
    pub keyframes: usize,
    pub map_points: usize,
    pub loops_closed: usize,
    /// Of `loops_closed`, loops tracking had already joined when the camera came back (small
    /// drift): found as revisits, fused and followed by a full BA, without a pose correction.
    pub loops_closed_by_revisit: usize,
    /// Each loop: kind (`place` or `revisit`), the two keyframes' timestamps, matches, fused.
    pub loop_closures: Vec<crate::loop_closing::LoopRecord>,
    pub relocalisations: usize,
    /// Lost frames tracked again from the last tracked pose within `[tracking]
    /// recovery_frames`, before relocalisation was asked.
    pub recoveries: usize,
    /// Lost frames whose relocalisation stopped at `[tracking] relocalisation_budget_ms`
    /// (real-time use; the next lost frame went on with the other candidates).
    pub relocalisation_budget_cuts: usize,
    /// With `--drop START:COUNT`: frames withheld, and how many frames after the blackout
    /// tracking took to be Ok again (relocalisation), if it did.
    pub blackout_frames: usize,
    pub frames_to_recover: Option<u64>,
    /// Frames the source could not read (corrupt/unreadable images), skipped.
    pub skipped_frames: usize,
    pub deadline_misses: usize,
    /// Frames lost to real-time pacing because tracking was behind (the oldest queued frame
    /// goes; the newest always reaches tracking).
    pub dropped_frames: u64,
    /// Live cameras: frames the driver dropped before sdslam saw them (sequence gaps), and
    /// the mean time from capture (kernel timestamp) to sdslam dequeuing the buffer.
    pub driver_dropped_frames: u64,
    pub capture_to_dequeue_ms: Option<f64>,
    pub peak_rss_mb: f64,
    /// Keyframe ATE RMSE after Sim3 alignment, when ground truth is available (source units).
    pub keyframe_ate_rmse_m: Option<f64>,
    pub deadline_ms: f64,
    /// The widest SIMD the kernels were allowed (`--simd`): 128, 256 or 512 bits.
    pub simd_max_bits: u32,
    pub wall_time_s: f64,
    /// The final full BA (`[map] final_global_ba`), after the last frame, milliseconds.
    pub final_ba_ms: f64,
    /// Maps discarded (tracking lost right after initialisation, or a young map diverging),
    /// and the poses dropped with them or by a roll-back (below): they were in a discarded
    /// map's frame, or tracked while its scale collapsed.
    pub map_resets: usize,
    pub poses_discarded_by_reset: usize,
    /// Maps found diverging (a scale collapse: keyframes that neither move nor turn to a
    /// nearer view while the view's depth falls), each with its frame, the monitor's figures
    /// and what was done: rolled back to the collapse window's first keyframe (what came
    /// after it erased), or, when young, discarded. The erased frames' poses are not in the
    /// trajectory.
    pub divergences: Vec<String>,
    /// Frames tracked against the map whose pose failed a check of `tracking::quality`: reported
    /// `Degraded` (not to be driven on) and left out of `trajectory.txt`; by reason
    /// (`ambiguous`: the points leave the camera centre poorly fixed; `poor_fit`: reprojection
    /// errors far above keypoint noise; `jump`: far from the motion model's prediction).
    pub degraded_frames: usize,
    pub degraded_reasons: std::collections::BTreeMap<String, usize>,
    /// The camera centre's 1-sigma uncertainty of the `Ok` frames (one pixel of keypoint
    /// noise), in percent of the scene depth: how well the poses were determined.
    pub centre_sigma_pct_of_depth: super::Percentiles,
    /// Why the run ended early, if it did (error or interruption); outputs are still written.
    pub stopped_early: Option<String>,
    /// Keyframes reconstructed by semi-dense mapping, and those it skipped (culled before
    /// their turn, too few neighbours, or its queue was full under overload).
    pub semidense_keyframes: usize,
    pub semidense_skipped_keyframes: usize,
    /// Of those: culled by local mapping first, lacking wide-baseline neighbours or a depth
    /// prior, or dropped under overload (queue or store full).
    pub semidense_skipped_culled: usize,
    pub semidense_skipped_no_neighbours: usize,
    pub semidense_skipped_overload: usize,
    /// ... or not reconstructed because the run was interrupted (Ctrl-C) and the semi-dense
    /// backlog was cut so the run ends within about a second.
    pub semidense_skipped_cut: usize,
    /// Semi-dense thread busy time over the run, and how long after the last frame it
    /// finished (the keyframes still within the delay, then the final checks).
    pub semidense_busy_s: f64,
    pub semidense_finish_s: f64,
    /// Points in `semidense.ply`.
    pub semidense_points: usize,
    /// Cloud accuracy by the evaluation protocol, when the source has ground-truth depth.
    pub semidense_accuracy: Option<crate::eval::CloudAccuracy>,
    /// `[semidense] mode` ("paper" or "tuned"), the settings in force that are not the
    /// paper's, and how the paper's text was read where it is ambiguous.
    pub semidense_mode: Option<crate::config::SemiDenseMode>,
    /// Pixels through each stage (search, fusion, intra check, inter check), summed over
    /// the keyframes of the cloud in `semidense.ply`: what each check removes.
    pub semidense_pixels: crate::semidense::PixelCounts,
    pub semidense_non_paper_settings: std::collections::BTreeMap<String, String>,
    pub semidense_paper_readings: Vec<String>,
    /// End-of-session reconstruction (`--semidense-final`): every keyframe of the final map
    /// reconstructed after the final BA; `semidense.ply` is then that cloud and the online
    /// one is `semidense_online.ply`.
    pub semidense_final: Option<SemiDenseFinalReport>,
    pub timing_ms: TimingReport,
}

/// The end-of-session semi-dense reconstruction of a run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SemiDenseFinalReport {
    pub keyframes: usize,
    pub skipped_keyframes: usize,
    pub points: usize,
    /// The online reconstruction's pixels per stage (`semidense_pixels` is the end of
    /// session's).
    pub online_pixels: crate::semidense::PixelCounts,
    /// Wall time of the whole reconstruction (both cores), seconds.
    pub total_s: f64,
    /// Per keyframe: all its stages (one core), then the depth, intra (with the patch
    /// check) and inter-keyframe stages.
    pub keyframe_ms: Percentiles,
    pub depth_ms: Percentiles,
    pub intra_ms: Percentiles,
    pub inter_ms: Percentiles,
    /// Accuracy of the online cloud (`semidense_online.ply`) for comparison.
    pub online_accuracy: Option<crate::eval::CloudAccuracy>,
    pub online_points: usize,
}
