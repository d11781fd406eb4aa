//! Tracking loss and relocalisation: the built-in sequence is tracked for 200 frames, the lens
//! is covered for 60 frames (black images: tracking is lost), then the camera is back at a
//! mapped place (frames 100.. again). Relocalisation (bag-of-words candidates, EPnP-RANSAC,
//! pose optimisation, local map) must recover within 10 frames, at the right pose.

mod common;

use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::eval::ate;
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
use sdslam::tracking::TrackingState;

#[test]
fn relocalises_within_10_frames_after_a_60_frame_blackout() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut config = Config::default();
    config.semidense.enabled = false;
    let mut system = System::new(&c.calibration(), &config, 400, false);
    let mut f = Frame::new(c.width, c.height);
    let mut t = c.t0;
    let mut next_index = 0u64;
    let mut feed = |system: &mut System, f: &Frame, t: f64| {
        next_index += 1;
        system.process(&f.gray, Some(&f.rgb), t, next_index)
    };
    let mut first_pass = Vec::new();
    for i in 0..200 {
        seq.render_frame(i, &mut f);
        t = f.timestamp;
        first_pass.push(feed(&mut system, &f, t).t_wc);
    }
    assert_eq!(system.state(), TrackingState::Ok);
    let dt = 1.0 / c.fps;
    // Lens covered: black frames.
    f.gray.fill(0);
    f.rgb.fill(0);
    for _ in 0..60 {
        t += dt;
        let r = feed(&mut system, &f, t);
        assert!(r.t_wc.is_none(), "a pose from a black frame");
    }
    assert_eq!(system.state(), TrackingState::Lost);
    // Back at a mapped place: frames 100.. of the sequence again.
    let gt = seq.ground_truth();
    let mut recovered = None;
    let mut worst: f64 = 0.0;
    let (mut est, mut truth) = (Vec::new(), Vec::new());
    for (n, i) in (100..160).enumerate() {
        seq.render_frame(i, &mut f);
        t += dt;
        let r = feed(&mut system, &f, t);
        if let Some(t_wc) = r.t_wc {
            recovered.get_or_insert(n);
            // The same place as in the first pass, in the map's frame.
            if let Some(before) = first_pass[i] {
                let d = (t_wc.position() - before.position()).norm();
                worst = worst.max(d);
            }
            est.push(sdslam::eval::TimedPose { timestamp: t, t_wc });
            truth.push(sdslam::eval::TimedPose {
                timestamp: t,
                t_wc: gt[i].t_wc,
            });
        }
    }
    let n = recovered.expect("never relocalised");
    eprintln!("relocalised {n} frames after the camera came back");
    assert!(n < 10, "relocalised only after {n} frames");
    assert!(system.tracker.relocalisations >= 1);
    // Map units: the first pass's extent over frames 100..160.
    let extent_map = match (first_pass[100], first_pass[159]) {
        (Some(a), Some(b)) => (a.position() - b.position()).norm(),
        _ => panic!("first pass not tracked at 100 and 159"),
    };
    eprintln!("relocalised poses within {worst:.4} of the first pass's (extent {extent_map:.3})");
    assert!(worst < 0.02 * extent_map, "{worst} vs extent {extent_map}");
    // The relocalised poses agree with the map built before the blackout: compare their
    // trajectory shape with ground truth (Sim3, as the map's scale is arbitrary).
    let r = ate(&truth, &est, 1e-6, true).expect("aligned");
    let extent = (gt[100].t_wc.position() - gt[159].t_wc.position()).norm();
    eprintln!(
        "ATE after relocalisation {:.4} m over {extent:.2} m",
        r.rmse_m
    );
    assert!(r.rmse_m < 0.02 * extent.max(0.1), "{} m", r.rmse_m);
}

/// Desk and posters (`../shared/data`) through the CLI: the first part of the sequence, the
/// lens covered for 60 frames (black images: tracking is lost), then the camera back at a
/// place mapped earlier (the sequence resumes from an earlier frame). The first pose after
/// the blackout must come within 10 frames, by relocalisation.
#[test]
fn desk_and_posters_relocalise_within_10_frames_of_returning_to_mapped_space() {
    let Some(data) = common::shared_data() else {
        return;
    };
    for (seq, covered_at, resume_at) in [("desk", 300, 150), ("posters", 250, 120)] {
        let src = data.join("synthetic").join(seq);
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("replay");
        std::fs::create_dir_all(dir.join("rgb")).unwrap();
        std::fs::copy(src.join("camera.yaml"), dir.join("camera.yaml")).unwrap();
        image::RgbImage::new(640, 480)
            .save(dir.join("rgb/black.png"))
            .unwrap();
        let list = std::fs::read_to_string(src.join("rgb.txt")).unwrap();
        let files: Vec<String> = list
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .map(|l| l.split_whitespace().nth(1).unwrap().to_string())
            .collect();
        let mut lines = Vec::new();
        let frames = (0..covered_at)
            .map(Some)
            .chain(std::iter::repeat_n(None, 60))
            .chain((resume_at..resume_at + 120).map(Some));
        for (k, f) in frames.enumerate() {
            let t = 1_700_000_000.0 + k as f64 / 30.0;
            let file = match f {
                Some(i) => src.join(&files[i]).display().to_string(),
                None => "rgb/black.png".to_string(),
            };
            lines.push(format!("{t:.6} {file}"));
        }
        std::fs::write(dir.join("rgb.txt"), lines.join("\n") + "\n").unwrap();
        let out = d.path().join("out");
        let (ok, _, err) = common::sdslam(&[
            "run",
            dir.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-semidense",
            "--no-plots",
            "--quiet",
        ]);
        assert!(ok, "{seq}: {err}");
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        assert!(
            report["lost_episodes"].as_u64().unwrap() >= 1,
            "{seq}: never lost"
        );
        assert!(
            report["relocalisations"].as_u64().unwrap() >= 1,
            "{seq}: not relocalised"
        );
        let back = (covered_at + 60) as f64;
        let first = sdslam::io::read_tum_trajectory(&out.join("trajectory.txt"))
            .unwrap()
            .iter()
            .map(|p| ((p.timestamp - 1_700_000_000.0) * 30.0).round())
            .filter(|&k| k >= back)
            .fold(f64::INFINITY, f64::min);
        eprintln!(
            "{seq}: first pose {} frames after the blackout",
            first - back
        );
        assert!(
            first - back <= 10.0,
            "{seq}: {} frames to recover",
            first - back
        );
    }
}

/// Feeds frames `range` of the built-in sequence (with `black` frames replaced by black ones)
/// through a fresh system; returns it with the index of the frame that initialised.
fn run_with_black(black: impl Fn(usize) -> bool, frames: usize) -> (System, SyntheticSequence) {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut config = Config::default();
    config.semidense.enabled = false;
    let mut system = System::new(&c.calibration(), &config, frames, false);
    let mut f = Frame::new(c.width, c.height);
    for i in 0..frames {
        seq.render_frame(i, &mut f);
        if black(i) {
            f.gray.fill(0);
            f.rgb.fill(0);
        }
        system.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64);
    }
    (system, seq)
}

/// The frame at which the built-in sequence initialises (no blackout).
fn init_frame() -> usize {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut config = Config::default();
    config.semidense.enabled = false;
    let mut system = System::new(&c.calibration(), &config, 100, false);
    let mut f = Frame::new(c.width, c.height);
    (0..100)
        .find(|&i| {
            seq.render_frame(i, &mut f);
            system
                .process(&f.gray, Some(&f.rgb), f.timestamp, i as u64)
                .state
                == TrackingState::Ok
        })
        .expect("the built-in sequence initialises")
}

#[test]
fn a_blackout_right_after_initialisation_keeps_the_map() {
    let i0 = init_frame();
    // Three black frames right after the map was made (2 keyframes).
    let (system, seq) = run_with_black(|i| (i0 + 2..i0 + 5).contains(&i), i0 + 80);
    assert_eq!(system.stats.resets, 0, "the young map was discarded");
    let traj = system.trajectory();
    let after = traj
        .iter()
        .filter(|p| p.timestamp > seq.ground_truth()[i0 + 5].timestamp);
    let n_after = after.count();
    assert!(
        n_after >= 70,
        "only {n_after} of 75 frames after the blackout tracked"
    );
    let r = ate(&seq.ground_truth(), &traj, 1e-6, true).expect("aligned");
    let gt = seq.ground_truth();
    let extent = (gt[0].t_wc.position() - gt[i0 + 79].t_wc.position()).norm();
    assert!(
        r.rmse_m < 0.02 * extent,
        "ATE {} m over {extent} m",
        r.rmse_m
    );
}

#[test]
fn a_discarded_young_map_leaves_no_pose_in_the_trajectory() {
    let i0 = init_frame();
    // A long blackout right after initialisation: the young map is given up.
    let end = i0 + 2 + 60;
    let (system, seq) = run_with_black(|i| (i0 + 2..end).contains(&i), end + 60);
    assert_eq!(system.stats.resets, 1);
    assert!(system.stats.poses_discarded_by_reset > 0);
    let t_end = seq.ground_truth()[end].timestamp;
    let traj = system.trajectory();
    assert!(
        traj.iter().all(|p| p.timestamp >= t_end),
        "the trajectory mixes poses of the discarded map with the new one's"
    );
    assert_eq!(system.stats.tracked_frames, traj.len());
}

/// Lost right after initialisation in unmapped space (the view jumps to the far side of the
/// room two frames after the map began): the young map gets `young_map_patience_frames` to
/// relocalise, but a new map started meanwhile replaces it at once, so tracking resumes within
/// a few frames instead of after the patience window; the young map's poses are dropped.
#[test]
fn a_young_map_lost_in_unmapped_space_is_replaced_by_a_new_map_at_once() {
    let i0 = init_frame();
    let jump = i0 + 2;
    let frames = jump + 60;
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut config = Config::default();
    config.semidense.enabled = false;
    let patience = config.tracking.young_map_patience_frames;
    let mut system = System::new(&c.calibration(), &config, frames, false);
    let mut f = Frame::new(c.width, c.height);
    let mut first_ok_after_jump = None;
    for i in 0..frames {
        // After the jump: the views of the opposite side of the orbit, at this frame's time.
        let view = if i < jump { i } else { i + c.frames / 2 };
        seq.render_frame(view, &mut f);
        f.timestamp = c.timestamp(i);
        let r = system.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64);
        if i > jump && r.state == TrackingState::Ok && first_ok_after_jump.is_none() {
            first_ok_after_jump = Some(i - jump);
        }
    }
    let after = first_ok_after_jump.expect("tracking never resumed after the jump");
    eprintln!("tracking resumed {after} frames after the jump (patience {patience})");
    assert!(
        after < patience / 2,
        "tracking resumed {after} frames after the jump: the young map was kept for its patience"
    );
    assert_eq!(system.stats.resets, 1, "the young map is discarded once");
    let t_jump = c.timestamp(jump);
    let traj = system.trajectory();
    assert!(
        traj.iter().all(|p| p.timestamp >= t_jump),
        "the trajectory mixes poses of the discarded map with the new one's"
    );
    assert_eq!(system.stats.tracked_frames, traj.len());
}

/// Two black frames in the middle of the built-in orbit while the camera keeps moving (a
/// cable glitch, a hand over the lens): the frame after them is tracked again at once from
/// the last tracked pose carried at its velocity (`[tracking] recovery_frames`), in the same
/// map, at the right pose; place recognition is not needed. With recovery off, relocalisation
/// does the same job (slower and needing many matches to one keyframe).
#[test]
fn a_short_loss_is_tracked_again_from_the_last_pose() {
    let run = |recovery_frames: usize| {
        let seq = SyntheticSequence::new(SyntheticConfig::default());
        let c = &seq.config;
        let mut config = Config::default();
        config.semidense.enabled = false;
        config.tracking.recovery_frames = recovery_frames;
        let frames = 160;
        let mut system = System::new(&c.calibration(), &config, frames, false);
        let mut f = Frame::new(c.width, c.height);
        let mut states = Vec::new();
        for i in 0..frames {
            seq.render_frame(i, &mut f);
            if (120..122).contains(&i) {
                f.gray.fill(0);
                f.rgb.fill(0);
            }
            states.push(
                system
                    .process(&f.gray, Some(&f.rgb), f.timestamp, i as u64)
                    .state,
            );
        }
        (system, seq, states)
    };
    let (system, seq, states) = run(10);
    assert_eq!(states[121], TrackingState::Lost);
    assert_eq!(
        states[122],
        TrackingState::Ok,
        "not tracked right after the loss"
    );
    assert!(system.tracker.recoveries >= 1);
    assert_eq!(system.tracker.relocalisations, 0);
    assert_eq!(system.atlas().maps.len(), 1, "a new map was started");
    let traj = system.trajectory();
    let after = traj
        .iter()
        .filter(|p| p.timestamp >= seq.ground_truth()[122].timestamp)
        .count();
    assert_eq!(after, 38, "frames after the loss without a pose");
    let r = ate(&seq.ground_truth(), &traj, 1e-6, true).expect("aligned");
    let gt = seq.ground_truth();
    let extent = (gt[0].t_wc.position() - gt[159].t_wc.position()).norm();
    eprintln!("ATE {:.4} m over {extent:.2} m", r.rmse_m);
    assert!(
        r.rmse_m < 0.01 * extent,
        "ATE {} m over {extent} m",
        r.rmse_m
    );
    let (system, _, states) = run(0);
    assert_eq!(system.tracker.recoveries, 0);
    let back = (122..160).find(|&i| states[i] == TrackingState::Ok);
    eprintln!("without recovery, tracked again at frame {back:?}");
    assert!(system.tracker.relocalisations >= 1 || back.is_none());
}
