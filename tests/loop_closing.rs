//! Loop closing end to end on a keyframe map built from exact poses of the built-in orbit
//! (which returns to its start) with triangulation only between consecutive keyframes, so the
//! end is not connected to the start; the keyframes are then given a growing drift. The
//! loop must be detected at the end, corrected, and the keyframe error must drop.

mod common;

use std::collections::HashMap;

use nalgebra::UnitQuaternion;
use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::eval::{ate, TimedPose};
use sdslam::geometry::{CameraFromWorld, Se3};
use sdslam::loop_closing::{GlobalBaJob, LoopCloser, PlaceIndex};
use sdslam::place_recognition::{default_vocabulary, KeyFrameDatabase};
use sdslam::semidense::Densifier;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

#[test]
fn a_drifted_loop_is_detected_and_corrected() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let cam = seq.config.camera();
    let gt = seq.ground_truth();
    let mut config = Config::default();
    config.semidense.enabled = false;
    let mut d = Densifier::new(&cam, &config, 80);
    let mut f = Frame::new(cam.width, cam.height);
    // One and a fifth turns: the orbit is periodic, the last keyframes revisit the first.
    let frames: Vec<usize> = (0..360).step_by(6).collect();
    let truth: Vec<TimedPose> = frames
        .iter()
        .map(|&i| TimedPose {
            timestamp: seq.config.timestamp(i),
            t_wc: gt[i % 300].t_wc,
        })
        .collect();
    for (&i, t) in frames.iter().zip(&truth) {
        seq.render_frame(i, &mut f);
        assert!(d.add_keyframe(&f.gray, Some(&f.rgb), t.timestamp, i as u64, &t.t_wc));
    }
    d.connect();
    let kfs = d.keyframes().to_vec();
    let n = kfs.len();
    let mut map = d.map().lock().unwrap();
    assert!(
        map.keyframe(kfs[n - 1])
            .unwrap()
            .covisibles
            .iter()
            .all(|(k, _)| !kfs[..5].contains(k)),
        "the end must not be connected to the start for this test"
    );
    let kf_poses = |map: &sdslam::map::Map| -> Vec<TimedPose> {
        kfs.iter()
            .map(|&k| {
                let kf = map.keyframe(k).unwrap();
                TimedPose {
                    timestamp: kf.timestamp,
                    t_wc: kf.t_cw.inverse(),
                }
            })
            .collect()
    };
    // Drift accumulating along the trajectory: keyframes (and the points they made) rotate
    // and shift more and more about the world origin.
    let drift = |i: usize| {
        let a = i as f64 / n as f64;
        Se3::from_parts(
            nalgebra::Translation3::new(0.06 * a, -0.03 * a, 0.04 * a),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 3f64.to_radians() * a),
        )
    };
    let slot: HashMap<_, usize> = kfs.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let points: Vec<_> = map.points().map(|(id, p)| (id, p.reference_kf)).collect();
    for (p, r) in points {
        let Some(&i) = r.and_then(|r| slot.get(&r)) else {
            continue;
        };
        let dr = drift(i);
        let mp = map.point_mut(p).unwrap();
        mp.position = (dr * nalgebra::Point3::from(mp.position)).coords;
    }
    for (i, &k) in kfs.iter().enumerate() {
        let kf = map.keyframe_mut(k).unwrap();
        kf.t_cw = CameraFromWorld(kf.t_cw.0 * drift(i).inverse());
    }
    let before = ate(&truth, &kf_poses(&map), 0.02, true).unwrap().rmse_m;

    // Place recognition index of every keyframe.
    let vocab = default_vocabulary().unwrap();
    let mut index = PlaceIndex {
        database: KeyFrameDatabase::new(vocab.n_words()),
        keys: HashMap::new(),
    };
    for &k in &kfs {
        let kf = map.keyframe(k).unwrap();
        let (bow, _) = vocab.transform(&kf.descriptors, 2);
        index.database.add(kf.serial as u32, &bow);
        index.keys.insert(kf.serial as u32, k);
    }
    let scales: Vec<f64> = (0..config.orb.n_levels)
        .map(|l| config.orb.scale_factor.powi(l as i32))
        .collect();
    let mut closer = LoopCloser::new(cam, &scales);
    let mut closed = None;
    let mut detection_ms = Vec::new();
    for &k in &kfs[n - 12..] {
        let t = std::time::Instant::now();
        let r = closer.process(&mut map, &index, k);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if let Some(r) = r {
            eprintln!("loop detection + correction: {ms:.1} ms");
            closed = Some(r);
            break;
        }
        detection_ms.push(ms);
    }
    detection_ms.sort_by(|a, b| a.total_cmp(b));
    if let Some(m) = detection_ms.get(detection_ms.len() / 2) {
        eprintln!("loop detection without a loop: median {m:.2} ms per keyframe");
    }
    let r = closed.expect("no loop closed at the end of the orbit");
    let loop_slot = slot[&r.loop_keyframe];
    eprintln!(
        "loop: keyframe {} -> {} ({} matches, {} fused)",
        slot[&r.keyframe], loop_slot, r.matches, r.fused_points
    );
    assert!(
        loop_slot < n / 4,
        "loop keyframe {loop_slot} is not near the start"
    );
    let after = ate(&truth, &kf_poses(&map), 0.02, true).unwrap().rmse_m;
    if std::env::var_os("SDSLAM_LOOP_DEBUG").is_some() {
        for (i, p) in kf_poses(&map).iter().enumerate() {
            let e = (p.t_wc.position() - truth[i].t_wc.position()).norm();
            let a = p
                .t_wc
                .0
                .rotation
                .angle_to(&truth[i].t_wc.0.rotation)
                .to_degrees();
            let dr = drift(i);
            eprintln!(
                "kf {i}: {e:.4} m {a:.2} deg (drift was {:.4} m)",
                dr.translation.vector.norm()
            );
        }
    }
    eprintln!("keyframe ATE: drifted {before:.4} m, after loop closing {after:.4} m");
    assert!(after < 0.5 * before, "{before} -> {after}");
}

/// The background BA's merge: a keyframe and a point made after the problem was copied move
/// with their parent / reference keyframe's correction.
#[test]
fn global_ba_merge_carries_keyframes_made_meanwhile() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let cam = seq.config.camera();
    let gt = seq.ground_truth();
    let config = Config::default();
    let mut d = Densifier::new(&cam, &config, 16);
    let mut f = Frame::new(cam.width, cam.height);
    for i in (0..60).step_by(6) {
        seq.render_frame(i, &mut f);
        d.add_keyframe(&f.gray, Some(&f.rgb), f.timestamp, i as u64, &gt[i].t_wc);
    }
    d.connect();
    let kfs = d.keyframes().to_vec();
    let mut map = d.map().lock().unwrap();
    // Disturb the last keyframe so the BA has something to correct.
    let last = *kfs.last().unwrap();
    let shift = Se3::from_parts(
        nalgebra::Translation3::new(0.02, 0.0, 0.0),
        UnitQuaternion::identity(),
    );
    map.keyframe_mut(last).unwrap().t_cw =
        CameraFromWorld(shift * map.keyframe(last).unwrap().t_cw.0);
    let scales: Vec<f64> = (0..8).map(|l| 1.2f64.powi(l)).collect();
    let mut job = GlobalBaJob::prepare(&map, &cam, &scales, 10).unwrap();
    // Meanwhile: a new keyframe, child of the last, 5 cm ahead of it, with a point.
    let parent_before = map.keyframe(last).unwrap().t_cw;
    let offset = Se3::from_parts(
        nalgebra::Translation3::new(0.0, 0.0, -0.05),
        UnitQuaternion::identity(),
    );
    let new_kf = map
        .insert_keyframe(|k| {
            k.t_cw = CameraFromWorld(offset * parent_before.0);
            k.timestamp = 99.0;
        })
        .unwrap();
    map.keyframe_mut(new_kf).unwrap().parent = Some(last);
    map.keyframe_mut(last).unwrap().children.push(new_kf);
    let p = map
        .insert_point(nalgebra::Vector3::new(1.0, 0.5, 1.0), new_kf)
        .unwrap();
    let p_cam_before = map
        .keyframe(new_kf)
        .unwrap()
        .t_cw
        .transform(&map.point(p).unwrap().position);
    job.solve();
    job.merge(&mut map);
    let parent_after = map.keyframe(last).unwrap().t_cw;
    assert!(
        (parent_after.0.translation.vector - parent_before.0.translation.vector).norm() > 1e-3,
        "the BA did not move the disturbed keyframe"
    );
    // The child keeps its pose relative to its parent, the point its camera coordinates.
    let child = map.keyframe(new_kf).unwrap().t_cw;
    let rel = child.0 * parent_after.0.inverse();
    assert!((rel.translation.vector - offset.translation.vector).norm() < 1e-9);
    let p_cam_after = child.transform(&map.point(p).unwrap().position);
    assert!((p_cam_after - p_cam_before).norm() < 1e-9);
}

/// Desk and posters each end where they started: the loop must be closed (tracking joins the
/// old map as soon as the camera is back, so it is found as a revisit or by bag of words);
/// every loop must join keyframes that ground truth puts close together compared with the path
/// between them (no false loop), no old place may be joined twice, and the keyframe error
/// stays within 5 mm. Deterministic mode, so the run is the same every time.
#[test]
fn desk_and_posters_close_their_loop_and_no_false_one() {
    let Some(data) = common::shared_data() else {
        return;
    };
    for seq in ["desk", "posters"] {
        let dir = data.join("synthetic").join(seq);
        let out = tempfile::tempdir().unwrap();
        let (ok, _, err) = common::sdslam(&[
            "run",
            dir.to_str().unwrap(),
            "--out",
            out.path().to_str().unwrap(),
            "--no-semidense",
            "--no-plots",
            "--quiet",
            // Reproducible: the same map, loops and error on every run.
            "--deterministic",
        ]);
        assert!(ok, "{seq}: {err}");
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.path().join("report.json")).unwrap())
                .unwrap();
        let loops = report["loop_closures"].as_array().unwrap();
        eprintln!(
            "{seq}: loops {loops:?}, keyframe ATE {}",
            report["keyframe_ate_rmse_m"]
        );
        assert!(
            !loops.is_empty(),
            "{seq}: the loop at the end is not closed"
        );
        assert_eq!(
            report["loops_closed"].as_u64().unwrap() as usize,
            loops.len()
        );
        let gt = sdslam::io::read_tum_trajectory(&dir.join("groundtruth.txt")).unwrap();
        let at = |t: f64| {
            gt.iter()
                .min_by(|a, b| (a.timestamp - t).abs().total_cmp(&(b.timestamp - t).abs()))
                .unwrap()
                .t_wc
                .position()
        };
        for l in loops {
            let (t1, t0) = (
                l["timestamp"].as_f64().unwrap(),
                l["loop_timestamp"].as_f64().unwrap(),
            );
            let travelled: f64 = gt
                .windows(2)
                .filter(|w| w[0].timestamp >= t0.min(t1) && w[1].timestamp <= t0.max(t1))
                .map(|w| (w[1].t_wc.position() - w[0].t_wc.position()).norm())
                .sum();
            let apart = (at(t1) - at(t0)).norm();
            assert!(
                apart < 0.2 * travelled,
                "{seq}: false loop {l}: {apart:.2} m apart after {travelled:.2} m"
            );
        }
        // No place joined twice: each loop reaches back to a different old keyframe.
        let mut olds: Vec<u64> = loops
            .iter()
            .map(|l| (l["loop_timestamp"].as_f64().unwrap() * 1e3) as u64)
            .collect();
        olds.sort_unstable();
        olds.dedup();
        assert_eq!(
            olds.len(),
            loops.len(),
            "{seq}: a place joined twice: {loops:?}"
        );
        let ate = report["keyframe_ate_rmse_m"].as_f64().unwrap();
        assert!(ate <= 0.005, "{seq}: keyframe ATE {ate} m");
    }
}
