//! Loop closing end to end on a keyframe map built from exact poses of the built-in orbit
//! (which returns to its start) with triangulation only between consecutive keyframes, so the
//! end is not connected to the start; the keyframes are then given a growing drift. The
//! loop must be detected at the end, corrected, and the keyframe error must drop.

use std::collections::HashMap;

use nalgebra::UnitQuaternion;
use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::eval::{ate, TimedPose};
use sdslam::geometry::{CameraFromWorld, Se3};
use sdslam::loop_closing::{LoopCloser, PlaceIndex};
use sdslam::place_recognition::{default_vocabulary, KeyFrameDatabase};
use sdslam::semidense::Densifier;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

#[test]
fn a_drifted_loop_is_detected_and_corrected() {
    let seq = SyntheticSequence::new(SyntheticConfig {
        frames: 300,
        ..SyntheticConfig::default()
    });
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
