//! The SLAM system in deterministic single-thread mode: each frame is tracked, and a new
//! keyframe is mapped (local mapping) before the next frame. Same algorithms as the threaded
//! runtime; identical results on re-runs.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Instant;

use crossbeam_channel::{bounded, Sender, TrySendError};

use crate::camera_model::{Calibration, PinholeRadtan};
use crate::config::Config;
use crate::eval::TimedPose;
use crate::features::OrbExtractor;
use crate::geometry::{CameraFromWorld, Se3, WorldFromCamera};
use crate::local_mapping::{median_depth, LocalMapper};
use crate::loop_closing::{GlobalBaJob, LoopCloser, PlaceIndex};
use crate::map::persist::{MapFileError, MapOrigin, MapSnapshot};
use crate::map::{KeyFrameId, Map, MapConfig};
use crate::runtime::ForegroundGate;

use crate::place_recognition::{default_vocabulary, KeyFrameDatabase, Vocabulary};
use crate::runtime::semidense_worker::SemiDenseWorker;
use crate::runtime::StageTimer;
use crate::semidense::SemiDenseMapper;
use crate::tracking::{
    CollapseMonitor, InitAttempt, Initializer, TrackedFrame, Tracker, TrackingState,
};
use std::collections::HashMap;

mod atlas;
mod backfill;
mod finish;
mod init_solver;
mod initialisation;
mod map_files;
mod mapping_thread;
mod relocalisation;
mod reserved;
mod rollback;
mod semidense;
mod trajectory;

pub use atlas::AtlasSummary;
pub use reserved::ReservedMemory;

use backfill::{Backfill, BACKFILL_PER_FRAME};
use mapping_thread::{spawn_mapper, MapperSetup, Mapping, REPLAY_MAPPING_WAIT};
use relocalisation::RelocCandidates;
use semidense::FinalSemiDense;

/// Frames slower than this are logged (debug) with their stage times.
const SLOW_FRAME: std::time::Duration = std::time::Duration::from_millis(20);

/// What happened to one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameResult {
    pub state: TrackingState,
    pub t_wc: Option<WorldFromCamera>,
    /// The atlas map `t_wc` is in (see [`crate::map::Map::active_map`]): poses of different
    /// maps are in different frames until the maps are merged.
    pub map: Option<u32>,
    pub new_keyframe: bool,
    /// How well the pose is determined (`Ok` and `Degraded` frames): the camera centre's
    /// 1-sigma uncertainty in map units, the scene depth, the reprojection fit.
    pub quality: Option<crate::tracking::PoseQuality>,
    /// Why the pose is `Degraded`.
    pub degraded: Option<crate::tracking::DegradedReason>,
}

struct TrajectoryEntry {
    timestamp: f64,
    reference: Option<KeyFrameId>,
    t_c_ref: Se3,
    t_cw: CameraFromWorld,
}

/// Counters and stage timers for `report.json`.
pub struct SystemStats {
    pub frames: usize,
    pub tracked_frames: usize,
    pub keyframes_created: usize,
    pub resets: usize,
    /// Poses dropped from the trajectory by resets and roll-backs (in a discarded map's
    /// frame, or tracked while a map collapsed).
    pub poses_discarded_by_reset: usize,
    /// Maps found diverging (scale collapse), rolled back or discarded: frame and reason of each.
    pub divergences: Vec<String>,
    /// Frames before initialisation tracked afterwards against the first map.
    pub backfilled_frames: usize,
    /// Frames tracked with a pose that failed a check of `tracking::quality` (reported
    /// `Degraded`, not in the trajectory), by reason (in `DegradedReason::ALL` order).
    pub degraded_frames: [usize; 3],
    /// The camera centre's 1-sigma uncertainty of `Ok` frames, in percent of the scene depth
    /// (a `StageTimer` for its bounded storage and percentiles; the values are not times).
    pub centre_sigma_pct: StageTimer,
    /// Maps initialised over the run (the first included; see `new_map_when_lost`).
    pub maps_made: usize,
    pub orb_extraction: StageTimer,
    /// Initialisation attempts (matching, H/F, reconstruction, two-view BA), on the tracking
    /// thread: the frames before the map exists.
    pub initialisation: StageTimer,
    /// Threaded mode: solving an attempt on the initialisation thread.
    pub initialisation_solve: StageTimer,
    pub tracking: StageTimer,
    /// Detection + correction time of each closed loop.
    pub loop_closing: StageTimer,
    pub loops_closed: usize,
    /// Of `loops_closed`, those tracking had already joined (see `loop_closing::revisit`).
    pub loops_closed_by_revisit: usize,
    /// Each loop closed (kind, keyframe timestamps, matches).
    pub loop_closures: Vec<crate::loop_closing::LoopRecord>,
    /// Duration of the final full BA (0 when off or not run).
    pub final_ba_ms: f64,
    /// Making a keyframe on the tracking thread (map insertion, observations, database).
    pub keyframe_insertion: StageTimer,
    pub local_mapping: StageTimer,
    /// Waiting for the map lock per frame.
    pub map_lock_wait: StageTimer,
}

/// Locks the map; a panicked mapping thread must not take tracking down with it.
fn lock(map: &Mutex<Map>) -> MutexGuard<'_, Map> {
    map.lock().unwrap_or_else(|e| e.into_inner())
}

/// The pipeline for one camera: ORB extraction, tracking and the keyframe decision on the
/// caller's thread; local mapping, loop closing and semi-dense mapping inline (deterministic)
/// or on their own threads; the place index shared by relocalisation and loop detection.
pub struct System {
    pub camera: PinholeRadtan,
    extractor: OrbExtractor,
    map: Arc<Mutex<Map>>,
    pub tracker: Tracker,
    mapping: Mapping,
    semidense: SemiDenseWorker,
    /// Keyframes made while processing the current frame (told to semi-dense mapping after
    /// the map is unlocked).
    fresh_keyframes: heapless::Vec<KeyFrameId, 4>,
    /// Run a full BA when the run finishes (`[map] final_global_ba`).
    final_ba: bool,
    /// Held while a frame is processed: semi-dense workers wait meanwhile.
    gate: ForegroundGate,
    /// Held while tracking waits for the map lock: local mapping does not start its next
    /// step meanwhile (so tracking waits for one short step at most).
    map_wanted: ForegroundGate,
    finished: bool,
    /// Place recognition for relocalisation: the vocabulary (the shipped default unless one is
    /// given) and the keyframe database, keyed by keyframe serial.
    vocabulary: Option<Arc<Vocabulary>>,
    places: Arc<Mutex<PlaceIndex>>,
    init: Initializer,
    /// Threaded mode: the costly half of initialisation attempts on its own thread.
    init_solver: Option<init_solver::InitSolver>,
    /// Poses of the frames before initialisation, computed a few per frame after it.
    backfill: Backfill,
    /// Track against the map without changing it (no keyframes, no BA, no reset).
    localize_only: bool,
    /// A recording fed as fast as it is processed ([`set_replay`](Self::set_replay)).
    replay: bool,
    frame: TrackedFrame,
    trajectory: Vec<TrajectoryEntry>,
    /// Undistorts raw frames for [`process_frame`](Self::process_frame) (taken out while used).
    rectifier: Option<crate::camera_model::FrameRectifier>,
    /// Consecutive lost frames while the map is young (`[tracking] young_map_keyframes`).
    young_map_lost_frames: usize,
    /// Scale-collapse watch on the keyframes ([`CollapseMonitor`]).
    collapse: CollapseMonitor,
    limits: SystemLimits,
    /// What the end-of-session semi-dense reconstruction is built with, and its result
    /// ([`reconstruct_semidense_final`](Self::reconstruct_semidense_final)).
    final_semidense: FinalSemiDense,
    /// Consecutive frames initialisation has failed (for a warning).
    uninitialised_frames: usize,
    /// Relocalisation candidates of the current lost episode (budgeted real-time use).
    reloc: RelocCandidates,
    pub stats: SystemStats,
}

/// The configured numbers `System` itself applies (the stages keep their own).
struct SystemLimits {
    young_map_keyframes: usize,
    young_map_patience_frames: usize,
    relocalisation_candidates: usize,
    /// `[tracking] relocalisation_budget_ms` (None: no bound).
    relocalisation_budget: Option<std::time::Duration>,
    final_ba_iterations: usize,
    new_map_when_lost: bool,
}

impl System {
    /// Builds every buffer for images of the calibration's size. Frames passed to [`process`](Self::process)
    /// must be undistorted (rectified) images of that size.
    /// `threaded`: local mapping on its own thread (real-time use); otherwise inline and
    /// deterministic.
    pub fn new(
        calib: &Calibration,
        config: &Config,
        expected_frames: usize,
        threaded: bool,
    ) -> Self {
        let camera = calib.camera.undistorted();
        let (w, h) = (camera.width as usize, camera.height as usize);
        let extractor = OrbExtractor::new(w, h, &config.orb);
        let scales = extractor.pyramid().scales.clone();
        let max_features = config.orb.n_features * 2;
        let map = Arc::new(Mutex::new(Map::new(MapConfig {
            max_features,
            width: w,
            height: h,
            scale_factor: config.orb.scale_factor,
            n_levels: config.orb.n_levels,
            max_keyframes: config.map.max_keyframes,
            max_map_points: config.map.max_map_points,
            ..MapConfig::default()
        })));
        let vocabulary = default_vocabulary().ok().map(Arc::new);
        let places = Arc::new(Mutex::new(PlaceIndex {
            database: KeyFrameDatabase::new(vocabulary.as_ref().map_or(0, |v| v.n_words())),
            keys: HashMap::new(),
        }));
        let gate = ForegroundGate::default();
        let map_wanted = ForegroundGate::default();
        let setup = MapperSetup {
            camera,
            scales: scales.clone(),
            local_mapping: config.local_mapping.clone(),
            loop_closing: config.loop_closing.clone(),
            global_ba_after_loop: config.map.global_ba_after_loop,
            global_ba_iterations: config.map.global_ba_iterations,
        };
        let mapping = if threaded {
            spawn_mapper(
                &setup,
                Arc::clone(&map),
                expected_frames,
                config.runtime.mapping_cpus.clone(),
                Arc::clone(&places),
                gate.clone(),
                map_wanted.clone(),
            )
        } else {
            setup.inline()
        };
        let semidense = if config.semidense.enabled {
            let k = camera.intrinsics();
            let mut mapper = Box::new(SemiDenseMapper::new(
                k,
                w,
                h,
                &config.semidense,
                config.map.max_keyframes,
                max_features,
            ));
            if threaded {
                if config.semidense.yield_to_tracking {
                    mapper.set_foreground_gate(gate.clone());
                }
                SemiDenseWorker::spawn(
                    mapper,
                    Arc::clone(&map),
                    config.semidense.nice,
                    config.semidense.sched_idle,
                    config.semidense.cpus.clone(),
                )
            } else {
                SemiDenseWorker::Inline(mapper)
            }
        } else {
            SemiDenseWorker::Off
        };
        System {
            vocabulary,
            places,
            tracker: Tracker::new(camera, scales.clone(), max_features).with_config(
                config.tracking.clone(),
                config.motion_only.clone(),
                config.relocalisation.clone(),
            ),
            mapping,
            semidense,
            fresh_keyframes: heapless::Vec::new(),
            final_ba: config.map.final_global_ba,
            gate,
            map_wanted,
            localize_only: false,
            replay: false,
            finished: false,
            init: Initializer::new(max_features, w, h).with_config(config.initialisation.clone()),
            init_solver: if threaded {
                init_solver::InitSolver::spawn(
                    camera.k(),
                    config.initialisation.clone(),
                    max_features,
                    w,
                    h,
                )
            } else {
                None
            },
            backfill: Backfill::default(),
            frame: TrackedFrame::new(max_features, w, h),
            trajectory: Vec::with_capacity(expected_frames),
            rectifier: Some(crate::camera_model::FrameRectifier::new(calib)),
            young_map_lost_frames: 0,
            collapse: CollapseMonitor::new(&config.tracking, max_features),
            limits: SystemLimits {
                young_map_keyframes: config.tracking.young_map_keyframes,
                young_map_patience_frames: config.tracking.young_map_patience_frames,
                relocalisation_candidates: config.tracking.relocalisation_candidates,
                relocalisation_budget: (config.tracking.relocalisation_budget_ms > 0.0).then(
                    || {
                        std::time::Duration::from_secs_f64(
                            config.tracking.relocalisation_budget_ms * 1e-3,
                        )
                    },
                ),
                final_ba_iterations: config.map.final_ba_iterations,
                new_map_when_lost: config.tracking.new_map_when_lost,
            },
            final_semidense: FinalSemiDense::new(config, max_features),
            uninitialised_frames: 0,
            reloc: RelocCandidates::with_capacity(config.tracking.relocalisation_candidates),
            stats: SystemStats {
                frames: 0,
                tracked_frames: 0,
                poses_discarded_by_reset: 0,
                divergences: Vec::new(),
                keyframes_created: 0,
                resets: 0,
                backfilled_frames: 0,
                degraded_frames: [0; 3],
                centre_sigma_pct: StageTimer::with_capacity(expected_frames.max(16)),
                maps_made: 0,
                orb_extraction: StageTimer::with_capacity(expected_frames.max(16)),
                initialisation: StageTimer::with_capacity(1024),
                initialisation_solve: StageTimer::with_capacity(1024),
                tracking: StageTimer::with_capacity(expected_frames.max(16)),
                loop_closing: StageTimer::with_capacity(64),
                loops_closed: 0,
                loops_closed_by_revisit: 0,
                loop_closures: Vec::new(),
                final_ba_ms: 0.0,
                keyframe_insertion: StageTimer::with_capacity(expected_frames.max(16)),
                local_mapping: StageTimer::with_capacity(expected_frames.max(16)),
                map_lock_wait: StageTimer::with_capacity(expected_frames.max(16)),
            },
            camera,
            extractor,
            map,
        }
    }

    pub fn state(&self) -> TrackingState {
        self.tracker.state()
    }

    /// Keyframes and map points in the map now.
    pub fn map_size(&self) -> (usize, usize) {
        let m = lock(&self.map);
        (m.n_keyframes(), m.n_points())
    }

    /// Read access to the map (locks it; keep the guard short in threaded mode).
    pub fn map(&self) -> MutexGuard<'_, Map> {
        lock(&self.map)
    }

    /// Localisation only: track (and relocalise) against the map without adding keyframes,
    /// running BA or resetting it.
    pub fn set_localize_only(&mut self, on: bool) {
        self.localize_only = on;
    }

    /// Frames come from a recording, fed as fast as they are processed (not from a camera,
    /// nor paced in real time): initialisation attempts run on the tracking thread, one per
    /// frame, as in the deterministic mode. Off the tracking thread (for the frame deadline)
    /// one attempt is in flight at a time and the frames meanwhile are not attempted; replayed
    /// back to back, a highway clip then initialised 27 frames late and its map was lost at
    /// once (kitti01_51: 2-17 of 51 frames posed, against 42 replayed in real time). Each
    /// frame also waits for local mapping to catch up (`Mapping::wait_until_idle`).
    pub fn set_replay(&mut self, on: bool) {
        self.replay = on;
    }

    /// The worker thread that has died (panicked) during the run, if any: the caller should
    /// stop feeding frames, call [`finish`](Self::finish) and write what it has.
    pub fn failed_thread(&self) -> Option<&'static str> {
        if let Mapping::Thread { handle, closer, .. } = &self.mapping {
            if handle.as_ref().is_some_and(|h| h.is_finished()) {
                return Some("local-mapping");
            }
            if closer.as_ref().is_some_and(|h| h.is_finished()) {
                return Some("loop-closing");
            }
        }
        self.semidense.has_failed().then_some("semi-dense")
    }

    /// Tracks one undistorted frame (grey, optional RGB of the same size).
    /// Processes a raw frame of the source: undistorted first (the calibration's distortion),
    /// then [`process`](Self::process).
    pub fn process_frame(&mut self, frame: &crate::camera::Frame) -> FrameResult {
        let mut rectifier = self.rectifier.take();
        let result = match rectifier.as_mut() {
            Some(r) => {
                let f = r.apply(frame);
                let rgb = f.has_color.then_some(&f.rgb[..]);
                self.process(&f.gray, rgb, f.timestamp, f.index)
            }
            None => {
                let rgb = frame.has_color.then_some(&frame.rgb[..]);
                self.process(&frame.gray, rgb, frame.timestamp, frame.index)
            }
        };
        self.rectifier = rectifier;
        result
    }

    /// Processes one undistorted frame (grey, and colour for the semi-dense cloud).
    pub fn process(
        &mut self,
        gray: &[u8],
        rgb: Option<&[u8]>,
        timestamp: f64,
        index: u64,
    ) -> FrameResult {
        if self.replay {
            self.mapping.wait_until_idle(REPLAY_MAPPING_WAIT); // before `busy`: mapping waits for it
        }
        let t0 = Instant::now();
        let gate = self.gate.clone();
        let _busy = gate.busy();
        self.stats.frames += 1;
        let f = &mut self.frame;
        f.index = index;
        f.timestamp = timestamp;
        let te = Instant::now();
        self.extractor.extract(gray, None, &mut f.features);
        let orb_time = te.elapsed();
        self.stats.orb_extraction.record(orb_time);
        f.reset_matches();
        // The map is locked for tracking only (extraction runs unlocked).
        let map_arc = Arc::clone(&self.map);
        let tl = Instant::now();
        let wanted = self.map_wanted.busy();
        let mut map_guard = lock(&map_arc);
        drop(wanted);
        let lock_time = tl.elapsed();
        self.stats.map_lock_wait.record(lock_time);
        let map = &mut *map_guard;
        let mut new_keyframe = false;
        let state = if self.tracker.state() == TrackingState::NotInitialised {
            self.initialize(map, gray, rgb)
        } else {
            let st = if self.tracker.state() == TrackingState::Lost {
                self.relocalise_or_start_map(map, gray, rgb)
            } else {
                let st = self.tracker.track(map, &mut self.frame);
                if st == TrackingState::Lost {
                    // A new map, if one is needed, starts from the frames after the loss.
                    self.forget_initialisation();
                }
                st
            };
            self.backfill_step(map, BACKFILL_PER_FRAME);
            let idle = match &self.mapping {
                Mapping::Inline(_) => true,
                Mapping::Thread { idle, .. } => idle.load(Ordering::Acquire),
            };
            if st == TrackingState::Ok
                && !self.localize_only
                && self.tracker.need_keyframe(map, &self.frame, idle)
            {
                let tk = Instant::now();
                new_keyframe = self.insert_keyframe(map, gray, rgb, t0);
                self.stats.keyframe_insertion.record(tk.elapsed());
                if new_keyframe {
                    self.watch_for_collapse(map);
                }
            }
            if st == TrackingState::Lost && self.active_map_is_young(map) && !self.localize_only {
                // Lost right after initialisation: relocalise in the young map for a while (a
                // short blackout, a covered lens), then start over (ORB-SLAM resets at once).
                self.young_map_lost_frames += 1;
                if self.young_map_lost_frames > self.limits.young_map_patience_frames {
                    self.young_map_lost_frames = 0;
                    tracing::warn!(
                        "lost right after initialisation: map reset, initialising again"
                    );
                    self.discard_active_map(map);
                }
            } else if st != TrackingState::Lost {
                self.young_map_lost_frames = 0;
            }
            self.tracker.state()
        };
        let total = t0.elapsed();
        if !new_keyframe {
            self.stats.tracking.record(total);
        }
        if total > SLOW_FRAME {
            // Which stage a slow frame spent its time in (the report has percentiles only).
            tracing::debug!(
                frame = index,
                total_ms = total.as_secs_f64() * 1e3,
                orb_ms = orb_time.as_secs_f64() * 1e3,
                lock_wait_ms = lock_time.as_secs_f64() * 1e3,
                keyframe = new_keyframe,
                "slow frame"
            );
        }
        let mut t_wc = None;
        let mut map_id = None;
        let (quality, degraded) = match state {
            TrackingState::Ok | TrackingState::Degraded => {
                (self.tracker.quality(), self.tracker.degraded())
            }
            _ => (None, None),
        };
        if let Some(q) = quality.filter(|_| state == TrackingState::Ok) {
            self.stats
                .centre_sigma_pct
                .record_ms(100.0 * q.centre_sigma_ratio());
        }
        if let Some(r) = degraded {
            self.stats.degraded_frames[r as usize] += 1;
            map_id = Some(map.active_map());
            t_wc = Some(self.frame.t_cw.inverse());
        }
        if state == TrackingState::Ok {
            map_id = Some(map.active_map());
            self.stats.tracked_frames += 1;
            let f = &self.frame;
            let reference = self.tracker.reference_kf();
            // A frame that became a keyframe is its own reference: the keyframe may have been
            // moved already (inline loop closing or a map merge ran on it), the frame's pose not.
            let t_c_ref = if new_keyframe {
                Se3::identity()
            } else {
                reference
                    .and_then(|r| map.keyframe(r))
                    .map(|k| f.t_cw.0 * k.t_cw.0.inverse())
                    .unwrap_or(f.t_cw.0)
            };
            self.trajectory.push(TrajectoryEntry {
                timestamp: f.timestamp,
                reference,
                t_c_ref,
                t_cw: f.t_cw,
            });
            t_wc = Some(f.t_cw.inverse());
        }
        self.tracker.commit(&self.frame);
        drop(map_guard);
        // Semi-dense mapping hears of keyframes without the map locked (it locks briefly).
        for kf in std::mem::take(&mut self.fresh_keyframes) {
            self.semidense.keyframe(&map_arc, kf);
        }
        FrameResult {
            state,
            t_wc,
            map: map_id,
            new_keyframe,
            quality,
            degraded,
        }
    }

    /// Whether frames have a real-time deadline here (threaded, not a replayed recording):
    /// only then may a frame's work be cut by the clock.
    fn bounds_frame_time(&self) -> bool {
        matches!(self.mapping, Mapping::Thread { .. }) && !self.replay
    }

    /// Adds a keyframe to the place-recognition database.
    fn index_keyframe(&mut self, map: &Map, kf: KeyFrameId) {
        let (Some(v), Some(k)) = (self.vocabulary.as_ref(), map.keyframe(kf)) else {
            return;
        };
        let (bow, _) = v.transform(&k.descriptors, 2);
        let key = k.serial as u32;
        let mut places = self.places.lock().unwrap_or_else(|e| e.into_inner());
        places.database.add(key, &bow);
        places.keys.insert(key, kf);
    }

    fn reset(&mut self, map: &mut Map) {
        // Frames tracked in the discarded map keep no pose; an unfinished backfill ends.
        self.backfill = Backfill::default();
        map.reset();
        {
            let n = self.vocabulary.as_ref().map_or(0, |v| v.n_words());
            let mut places = self.places.lock().unwrap_or_else(|e| e.into_inner());
            places.database = KeyFrameDatabase::new(n);
            places.keys.clear();
        }
        self.semidense.reset();
        self.tracker.reset(TrackingState::NotInitialised);
        self.init.reset();
        if let Some(s) = self.init_solver.as_mut() {
            s.generation += 1;
        }
        self.collapse.reset();
        self.stats.resets += 1;
        // The poses so far are in the discarded map's world frame (every reset discards the
        // whole map): a trajectory must never mix two frames, so they are dropped and counted.
        let discarded = self.trajectory.len();
        self.trajectory.clear();
        self.stats.tracked_frames = self.stats.tracked_frames.saturating_sub(discarded);
        self.stats.poses_discarded_by_reset += discarded;
    }

    /// Makes a keyframe of the current frame and maps it (inline) or queues it (thread).
    fn insert_keyframe(
        &mut self,
        map: &mut Map,
        gray: &[u8],
        rgb: Option<&[u8]>,
        t0: Instant,
    ) -> bool {
        if let Mapping::Thread { tx: Some(tx), .. } = &self.mapping {
            if tx.is_full() {
                return false;
            }
        }
        let f = &self.frame;
        let res = map.insert_keyframe(|kf| {
            kf.keypoints.extend_from_slice(&f.features.keypoints);
            kf.descriptors.extend_from_slice(&f.features.descriptors);
            kf.frame_index = f.index;
            kf.timestamp = f.timestamp;
            kf.t_cw = f.t_cw;
            kf.set_images(gray, rgb);
        });
        let Ok(kf) = res else { return false };
        let obs: Vec<_> = self.frame.inlier_points().collect();
        for (i, mp) in obs {
            map.add_observation(mp, kf, i);
        }
        self.index_keyframe(map, kf);
        match &mut self.mapping {
            Mapping::Inline(m) => {
                self.stats.tracking.record(t0.elapsed());
                let tm = Instant::now();
                let (mapper, loops) = &mut **m;
                mapper.process(map, kf);
                self.stats.local_mapping.record(tm.elapsed());
                let places = self.places.lock().unwrap_or_else(|e| e.into_inner());
                let closed = loops.process_inline(map, &places, kf);
                drop(places);
                (self.stats.loops_closed, self.stats.loops_closed_by_revisit) = loops.counts();
                if closed {
                    self.stats.loop_closures.clear();
                    self.stats.loop_closures.extend_from_slice(loops.history());
                }
            }
            Mapping::Thread { tx, idle, .. } => {
                idle.store(false, Ordering::Release);
                match tx.as_ref().map(|t| t.try_send(kf)) {
                    Some(Ok(())) => {}
                    Some(Err(TrySendError::Full(_)))
                    | Some(Err(TrySendError::Disconnected(_)))
                    | None => {}
                }
            }
        }
        // The frame's matches may have been culled: keep only live points.
        for p in self.frame.points.iter_mut() {
            if p.is_some_and(|id| map.point(id).is_none()) {
                *p = None;
            }
        }
        self.tracker.keyframe_made(kf, self.frame.index);
        self.stats.keyframes_created += 1;
        let _ = self.fresh_keyframes.push(kf);
        true
    }

    /// Full BA of the map (first keyframe fixed).
    fn global_ba(&mut self, map: &mut Map, iterations: usize) {
        if let Some(mut job) =
            GlobalBaJob::prepare(map, &self.camera, &self.tracker.scales, iterations)
        {
            job.solve();
            job.merge(map);
        }
    }
}
