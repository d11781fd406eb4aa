//! Degenerate input to tracking: pure rotation, no texture, sensor noise only, very fast motion
//! (the lens cap is in tests/relocalisation.rs). Each must end in Ok, Lost or relocalisation
//! states — never a NaN pose, a map point at infinity, or a map beyond its configured capacity.

use nalgebra::{UnitQuaternion, Vector3};

use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::geometry::WorldFromCamera;
use sdslam::runtime::{FrameResult, System};
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
use sdslam::tracking::{DegradedReason, TrackingState};

struct Rig {
    seq: SyntheticSequence,
    system: System,
    config: Config,
    frame: Frame,
    t: f64,
    index: u64,
}

impl Rig {
    /// Tracks the first `n` frames of the built-in sequence (initialised, mapping).
    fn tracked(n: usize) -> Rig {
        let seq = SyntheticSequence::new(SyntheticConfig::default());
        let mut config = Config::default();
        config.semidense.enabled = false;
        let system = System::new(&seq.config.calibration(), &config, 2000, false);
        let frame = Frame::new(seq.config.width, seq.config.height);
        let mut rig = Rig {
            t: seq.config.t0,
            seq,
            system,
            config,
            frame,
            index: 0,
        };
        for i in 0..n {
            rig.path_frame(i);
        }
        assert_eq!(
            rig.system.state(),
            TrackingState::Ok,
            "not tracking after {n} frames"
        );
        rig
    }

    fn feed(&mut self) -> FrameResult {
        self.t += 1.0 / self.seq.config.fps;
        self.index += 1;
        let r = self
            .system
            .process(&self.frame.gray, Some(&self.frame.rgb), self.t, self.index);
        if let Some(p) = r.t_wc {
            let m = p.0.to_homogeneous();
            assert!(
                m.iter().all(|v| v.is_finite()),
                "non-finite pose at frame {}",
                self.index
            );
        }
        r
    }

    fn path_frame(&mut self, i: usize) -> FrameResult {
        self.seq.render_frame(i, &mut self.frame);
        self.feed()
    }

    fn pose_frame(&mut self, t_wc: &WorldFromCamera) -> FrameResult {
        let seed = self.index;
        self.seq.render_pose(t_wc, seed, &mut self.frame);
        self.feed()
    }

    /// Every keyframe pose and map point finite and within reach of the scene; counts within
    /// the configured capacity.
    fn check_map(&self) {
        let map = self.system.map();
        let (mut kfs, mut pts) = (0, 0);
        for (_, kf) in map.keyframes() {
            kfs += 1;
            let m = kf.t_cw.0.to_homogeneous();
            assert!(
                m.iter().all(|v| v.is_finite()),
                "keyframe with a non-finite pose"
            );
        }
        for (_, p) in map.points() {
            pts += 1;
            assert!(
                p.position.iter().all(|v| v.is_finite()),
                "map point at {:?}",
                p.position
            );
            assert!(
                p.position.norm() < 1e3,
                "map point at {:?} (far beyond the scene)",
                p.position
            );
        }
        assert!(kfs <= self.config.map.max_keyframes && pts <= self.config.map.max_map_points);
    }
}

#[test]
fn pure_rotation_in_place_keeps_a_sane_map() {
    let mut rig = Rig::tracked(90);
    let gt = rig.seq.ground_truth();
    let start = gt[89].t_wc;
    let mut tracked = 0;
    // 40 degrees about the camera's vertical axis and back, 1 degree per frame.
    for k in (0..40).chain((0..40).rev()) {
        let rot = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), (k as f64).to_radians());
        let t_wc = WorldFromCamera(nalgebra::Isometry3::from_parts(
            start.0.translation,
            start.0.rotation * rot,
        ));
        if rig.pose_frame(&t_wc).t_wc.is_some() {
            tracked += 1;
        }
    }
    rig.check_map();
    eprintln!(
        "pure rotation: {tracked} of 80 frames tracked, state {:?}",
        rig.system.state()
    );
    // Rotation about the optical centre keeps the map in view for most of the sweep.
    assert!(
        tracked >= 40,
        "only {tracked} of 80 pure-rotation frames tracked"
    );
}

#[test]
fn textureless_and_noise_frames_lose_tracking_without_poses_then_relocalise() {
    let mut rig = Rig::tracked(90);
    // A white wall: no features.
    rig.frame.gray.fill(128);
    rig.frame.rgb.fill(128);
    for _ in 0..15 {
        assert!(rig.feed().t_wc.is_none(), "a pose from a textureless frame");
    }
    assert_eq!(rig.system.state(), TrackingState::Lost);
    // Sensor noise only (a dark room at high gain): many corners, none of them the map's.
    let mut s = 12345u64;
    for _ in 0..15 {
        for (g, c) in rig
            .frame
            .gray
            .iter_mut()
            .zip(rig.frame.rgb.chunks_exact_mut(3))
        {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            *g = (s >> 56) as u8;
            c.fill(*g);
        }
        assert!(rig.feed().t_wc.is_none(), "a pose from a noise frame");
    }
    rig.check_map();
    // Back on the path: relocalised within 10 frames.
    let recovered = (60..80).position(|i| rig.path_frame(i).t_wc.is_some());
    assert!(
        recovered.is_some_and(|n| n < 10),
        "recovered after {recovered:?} frames"
    );
    rig.check_map();
}

#[test]
fn very_fast_motion_never_gives_nan_and_recovers() {
    let mut rig = Rig::tracked(90);
    // Jumps of 12 frames (0.4 s of motion) between consecutive images.
    let mut i = 90;
    let mut jumps_tracked = 0;
    while i + 12 < 280 {
        i += 12;
        if rig.path_frame(i).t_wc.is_some() {
            jumps_tracked += 1;
        }
    }
    rig.check_map();
    // Then normal speed again on a mapped stretch: tracking (or relocalisation) within 10 frames.
    let back = (100..130).position(|k| rig.path_frame(k).t_wc.is_some());
    eprintln!("fast motion: {jumps_tracked} jumps tracked, back after {back:?} frames");
    assert!(
        back.is_some_and(|n| n < 10),
        "not tracking 10 frames after the fast motion: {back:?}"
    );
    rig.check_map();
}

/// A pose the quality checks doubt (`tracking::quality`) is reported `Degraded`, with a pose,
/// its map and the reason, and is neither mapped nor written to the trajectory. With the
/// ambiguity bar set below what any pose reaches, every frame tracked after the initialising
/// one is such a frame (until, with no keyframe made, the map runs out of view and a new map
/// replaces it), and the frames before it are not backfilled.
#[test]
fn poses_failing_the_quality_checks_are_degraded_not_ok() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let mut config = Config::default();
    config.semidense.enabled = false;
    config.tracking.max_centre_sigma_ratio = 1e-7;
    let mut system = System::new(&seq.config.calibration(), &config, 100, false);
    let mut frame = Frame::new(seq.config.width, seq.config.height);
    let (mut ok, mut degraded) = (0, 0);
    for i in 0..60 {
        seq.render_frame(i, &mut frame);
        let t = seq.config.timestamp(i);
        let r = system.process(&frame.gray, Some(&frame.rgb), t, i as u64);
        match r.state {
            TrackingState::Ok => ok += 1,
            TrackingState::Degraded => {
                degraded += 1;
                assert_eq!(r.degraded, Some(DegradedReason::Ambiguous));
                assert!(r.t_wc.is_some() && r.map.is_some() && !r.new_keyframe);
                let q = r.quality.expect("a degraded frame has its quality");
                assert!(q.centre_sigma_ratio() > 1e-7 && q.inliers >= 30, "{q:?}");
            }
            _ => assert!(r.t_wc.is_none()),
        }
    }
    // Lost while young, the map is replaced by a new one (its initialising frame is Ok too).
    assert_eq!(
        ok, system.stats.maps_made,
        "only the initialising frames are Ok"
    );
    assert_eq!(system.stats.resets + 1, system.stats.maps_made);
    assert!(degraded >= 30, "{degraded} frames Degraded");
    assert_eq!(
        system.trajectory().len(),
        2,
        "only the last initialisation's two views have trajectory poses"
    );
    assert!(
        system.stats.degraded_frames[DegradedReason::Ambiguous as usize] >= degraded,
        "backfilled frames are judged too"
    );
    assert_eq!(
        system.stats.keyframes_created,
        2 * system.stats.maps_made,
        "no keyframe beyond each map's initial two"
    );
}
