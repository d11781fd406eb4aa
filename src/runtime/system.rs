//! The SLAM system in deterministic single-thread mode: each frame is tracked, and a new
//! keyframe is mapped (local mapping) before the next frame. Same algorithms as the threaded
//! runtime; identical results on re-runs.

use std::time::Instant;

use crate::camera_model::{Calibration, PinholeRadtan};
use crate::config::Config;
use crate::eval::TimedPose;
use crate::features::OrbExtractor;
use crate::geometry::{CameraFromWorld, Se3, WorldFromCamera};
use crate::local_mapping::{median_depth, LocalMapper};
use crate::map::{KeyFrameId, Map, MapConfig};
use crate::optimize::{BaObservation, BaOptions, BaProblem, BundleAdjuster};
use crate::runtime::StageTimer;
use crate::tracking::{InitAttempt, Initializer, TrackedFrame, Tracker, TrackingState};

/// What happened to one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameResult {
    pub state: TrackingState,
    pub t_wc: Option<WorldFromCamera>,
    pub new_keyframe: bool,
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
    pub orb_extraction: StageTimer,
    pub tracking: StageTimer,
    pub local_mapping: StageTimer,
}

pub struct System {
    pub camera: PinholeRadtan,
    extractor: OrbExtractor,
    pub map: Map,
    pub tracker: Tracker,
    mapper: LocalMapper,
    init: Initializer,
    frame: TrackedFrame,
    trajectory: Vec<TrajectoryEntry>,
    pub stats: SystemStats,
}

impl System {
    /// Builds every buffer for images of the calibration's size. Frames passed to [`process`]
    /// must be undistorted (rectified) images of that size.
    pub fn new(calib: &Calibration, config: &Config, expected_frames: usize) -> Self {
        let camera = calib.camera.undistorted();
        let (w, h) = (camera.width as usize, camera.height as usize);
        let extractor = OrbExtractor::new(w, h, &config.orb);
        let scales = extractor.pyramid().scales.clone();
        let max_features = config.orb.n_features * 2;
        let map = Map::new(MapConfig {
            max_features,
            width: w,
            height: h,
            scale_factor: config.orb.scale_factor,
            n_levels: config.orb.n_levels,
            ..MapConfig::default()
        });
        System {
            tracker: Tracker::new(camera, scales.clone(), max_features),
            mapper: LocalMapper::new(camera, &scales),
            init: Initializer::new(max_features, w, h),
            frame: TrackedFrame::new(max_features, w, h),
            trajectory: Vec::with_capacity(expected_frames),
            stats: SystemStats {
                frames: 0,
                tracked_frames: 0,
                keyframes_created: 0,
                resets: 0,
                orb_extraction: StageTimer::with_capacity(expected_frames.max(16)),
                tracking: StageTimer::with_capacity(expected_frames.max(16)),
                local_mapping: StageTimer::with_capacity(expected_frames.max(16)),
            },
            camera,
            extractor,
            map,
        }
    }

    pub fn state(&self) -> TrackingState {
        self.tracker.state
    }

    /// Tracks one undistorted frame (grey, optional RGB of the same size).
    pub fn process(
        &mut self,
        gray: &[u8],
        rgb: Option<&[u8]>,
        timestamp: f64,
        index: u64,
    ) -> FrameResult {
        let t0 = Instant::now();
        self.stats.frames += 1;
        let f = &mut self.frame;
        f.index = index;
        f.timestamp = timestamp;
        let te = Instant::now();
        self.extractor.extract(gray, None, &mut f.features);
        self.stats.orb_extraction.record(te.elapsed());
        f.reset_matches();
        let mut new_keyframe = false;
        let state = if self.tracker.state == TrackingState::NotInitialised {
            self.initialize(gray, rgb)
        } else {
            let st = self.tracker.track(&mut self.map, &mut self.frame);
            if st == TrackingState::Ok && self.tracker.need_keyframe(&self.map, &self.frame) {
                self.stats.tracking.record(t0.elapsed());
                let tm = Instant::now();
                new_keyframe = self.insert_keyframe(gray, rgb);
                self.stats.local_mapping.record(tm.elapsed());
            }
            if st == TrackingState::Lost && self.map.n_keyframes() <= 5 {
                // Lost right after initialisation: start over (ORB-SLAM's policy).
                self.reset();
            }
            self.tracker.state
        };
        if !new_keyframe {
            self.stats.tracking.record(t0.elapsed());
        }
        let mut t_wc = None;
        if state == TrackingState::Ok {
            self.stats.tracked_frames += 1;
            let f = &self.frame;
            let reference = self.tracker.reference_kf;
            let t_c_ref = reference
                .and_then(|r| self.map.keyframe(r))
                .map(|k| f.t_cw.0 * k.t_cw.0.inverse())
                .unwrap_or(f.t_cw.0);
            self.trajectory.push(TrajectoryEntry {
                timestamp: f.timestamp,
                reference,
                t_c_ref,
                t_cw: f.t_cw,
            });
            t_wc = Some(f.t_cw.inverse());
        }
        self.tracker.last.copy_from(&self.frame);
        FrameResult {
            state,
            t_wc,
            new_keyframe,
        }
    }

    fn reset(&mut self) {
        self.map.reset();
        self.tracker.state = TrackingState::NotInitialised;
        self.tracker.reference_kf = None;
        self.tracker.velocity = None;
        self.init.reset();
        self.stats.resets += 1;
    }

    fn initialize(&mut self, gray: &[u8], rgb: Option<&[u8]>) -> TrackingState {
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
        let Ok(kf0) = self.map.insert_keyframe(|kf| {
            kf.keypoints.extend_from_slice(&reference.keypoints);
            kf.descriptors.extend_from_slice(&reference.descriptors);
            kf.frame_index = init.reference_index;
            kf.timestamp = init.reference_timestamp;
            kf.gray.extend_from_slice(&init.reference_gray);
            kf.rgb.extend_from_slice(&init.reference_rgb);
            kf.has_color = init.reference_has_color;
        }) else {
            return TrackingState::NotInitialised;
        };
        let f = &self.frame;
        let Ok(kf1) = self.map.insert_keyframe(|kf| {
            kf.keypoints.extend_from_slice(&f.features.keypoints);
            kf.descriptors.extend_from_slice(&f.features.descriptors);
            kf.frame_index = f.index;
            kf.timestamp = f.timestamp;
            kf.t_cw = CameraFromWorld(motion.t_21);
            kf.gray.extend_from_slice(gray);
            if let Some(c) = rgb {
                kf.rgb.extend_from_slice(c);
                kf.has_color = true;
            }
        }) else {
            self.map.reset();
            return TrackingState::NotInitialised;
        };
        for (m, &(i, j)) in pairs.iter().enumerate() {
            let Some(p) = motion.points[m] else { continue };
            let Ok(mp) = self.map.insert_point(p, kf0) else {
                break;
            };
            self.map.add_observation(mp, kf0, i as usize);
            self.map.add_observation(mp, kf1, j as usize);
            self.map.update_point_geometry(mp);
        }
        self.map.update_connections(kf0);
        self.map.update_connections(kf1);
        self.global_ba(20);
        // Scale the map to median depth 1.
        let Some(median) = median_depth(&self.map, kf0).filter(|m| *m > 0.0) else {
            self.map.reset();
            return TrackingState::NotInitialised;
        };
        let tracked = self.map.keyframe(kf1).map_or(0, |k| k.observed().count());
        if tracked < 100 {
            self.map.reset();
            return TrackingState::NotInitialised;
        }
        let inv = 1.0 / median;
        if let Some(k) = self.map.keyframe_mut(kf1) {
            k.t_cw.0.translation.vector *= inv;
        }
        let pts: Vec<_> = self.map.points().map(|(id, _)| id).collect();
        for p in pts {
            if let Some(mp) = self.map.point_mut(p) {
                mp.position *= inv;
            }
            self.map.update_point_geometry(p);
        }
        // The current frame continues from keyframe 1.
        let k1 = self.map.keyframe(kf1).map(|k| (k.t_cw, k.points.clone()));
        if let Some((t, pts)) = k1 {
            self.frame.t_cw = t;
            self.frame.points.copy_from_slice(&pts);
        }
        self.tracker.reference_kf = Some(kf1);
        self.tracker.last_keyframe_frame = self.frame.index;
        self.tracker.velocity = None;
        self.tracker.state = TrackingState::Ok;
        self.stats.keyframes_created += 2;
        // Keyframe 0's pose enters the trajectory too.
        self.trajectory.push(TrajectoryEntry {
            timestamp: self.init.reference_timestamp,
            reference: Some(kf0),
            t_c_ref: Se3::identity(),
            t_cw: CameraFromWorld::identity(),
        });
        TrackingState::Ok
    }

    fn insert_keyframe(&mut self, gray: &[u8], rgb: Option<&[u8]>) -> bool {
        let f = &self.frame;
        let res = self.map.insert_keyframe(|kf| {
            kf.keypoints.extend_from_slice(&f.features.keypoints);
            kf.descriptors.extend_from_slice(&f.features.descriptors);
            kf.frame_index = f.index;
            kf.timestamp = f.timestamp;
            kf.t_cw = f.t_cw;
            kf.gray.extend_from_slice(gray);
            if let Some(c) = rgb {
                kf.rgb.extend_from_slice(c);
                kf.has_color = true;
            }
        });
        let Ok(kf) = res else { return false };
        let obs: Vec<_> = self.frame.inlier_points().collect();
        for (i, mp) in obs {
            self.map.add_observation(mp, kf, i);
        }
        self.mapper.process(&mut self.map, kf);
        // The frame's matches may have been culled: keep only live points.
        for p in self.frame.points.iter_mut() {
            if p.is_some_and(|id| self.map.point(id).is_none()) {
                *p = None;
            }
        }
        self.tracker.reference_kf = Some(kf);
        self.tracker.last_keyframe_frame = self.frame.index;
        self.stats.keyframes_created += 1;
        true
    }

    /// Full BA of the map (first keyframe fixed).
    pub fn global_ba(&mut self, iterations: usize) {
        let kfs: Vec<KeyFrameId> = self.map.keyframes().map(|(id, _)| id).collect();
        let pts: Vec<_> = self.map.points().map(|(id, _)| id).collect();
        let mut index = std::collections::HashMap::new();
        let mut p = BaProblem {
            fx: self.camera.fx,
            fy: self.camera.fy,
            cx: self.camera.cx,
            cy: self.camera.cy,
            ..Default::default()
        };
        for (i, &k) in kfs.iter().enumerate() {
            index.insert(k, i as u32);
            let kf = self.map.keyframe(k);
            p.poses
                .push(kf.map_or(CameraFromWorld::identity(), |k| k.t_cw));
            p.pose_fixed
                .push(kf.is_none_or(|k| k.parent.is_none()) || i == 0);
        }
        let scales = &self.tracker.scales;
        for (j, &mp) in pts.iter().enumerate() {
            let Some(m) = self.map.point(mp) else {
                continue;
            };
            p.points.push(m.position);
            for &(kf, i) in &m.observations {
                let (Some(&pi), Some(k)) = (index.get(&kf), self.map.keyframe(kf)) else {
                    continue;
                };
                let kp = &k.keypoints[i as usize];
                let s = scales[kp.octave as usize];
                p.observations.push(BaObservation {
                    pose: pi,
                    point: j as u32,
                    uv: nalgebra::Vector2::new(kp.ux as f64, kp.uy as f64),
                    inv_sigma2: 1.0 / (s * s),
                });
            }
        }
        BundleAdjuster::new().solve(
            &mut p,
            &BaOptions {
                iterations,
                ..BaOptions::default()
            },
        );
        for (i, &k) in kfs.iter().enumerate() {
            if let Some(kf) = self.map.keyframe_mut(k) {
                kf.t_cw = p.poses[i];
            }
        }
        for (j, &mp) in pts.iter().enumerate() {
            if let Some(m) = self.map.point_mut(mp) {
                m.position = p.points[j];
            }
        }
    }

    /// Poses (`T_wc`) of every tracked frame, following their reference keyframe's correction.
    pub fn trajectory(&self) -> Vec<TimedPose> {
        self.trajectory
            .iter()
            .map(|e| {
                let t_cw = match e.reference.and_then(|r| self.map.keyframe(r)) {
                    Some(k) => CameraFromWorld(e.t_c_ref * k.t_cw.0),
                    None => e.t_cw,
                };
                TimedPose {
                    timestamp: e.timestamp,
                    t_wc: t_cw.inverse(),
                }
            })
            .collect()
    }

    /// Final keyframe poses, by time.
    pub fn keyframe_trajectory(&self) -> Vec<TimedPose> {
        let mut v: Vec<TimedPose> = self
            .map
            .keyframes()
            .map(|(_, k)| TimedPose {
                timestamp: k.timestamp,
                t_wc: k.t_cw.inverse(),
            })
            .collect();
        v.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        v
    }
}
