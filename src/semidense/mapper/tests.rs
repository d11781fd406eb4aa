//! The mapper's bookkeeping in situations the pipeline rarely makes: a neighbour whose
//! notification is still in the channel, a keyframe whose anchor points were all fused
//! before a loop correction rescaled the map, a culled one in the same state.

use super::*;
use crate::camera::Frame;
use crate::config::Config;
use crate::semidense::Densifier;
use crate::synthetic::{SyntheticConfig, SyntheticSequence};

/// Keyframes every 8th frame of the built-in orbit at their true poses, connected.
fn densifier(config: &Config) -> Densifier {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let cam = seq.config.camera();
    let mut d = Densifier::new(&cam, config, 32);
    let gt = seq.ground_truth();
    let mut f = Frame::new(cam.width, cam.height);
    for i in (60..200).step_by(8) {
        seq.render_frame(i, &mut f);
        assert!(d.add_keyframe(&f.gray, Some(&f.rgb), f.timestamp, i as u64, &gt[i].t_wc));
    }
    d.connect();
    d
}

fn mapper_for(config: &SemiDenseConfig) -> SemiDenseMapper {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let cam = seq.config.camera();
    SemiDenseMapper::new(
        cam.intrinsics(),
        cam.width as usize,
        cam.height as usize,
        config,
        64,
        4000,
    )
}

#[test]
fn a_neighbour_not_yet_received_holds_the_check_back() {
    let config = Config::default();
    let d = densifier(&config);
    let sd = SemiDenseConfig {
        keyframe_delay: 2,
        ..config.semidense.clone()
    };
    let mut mapper = mapper_for(&sd);
    let kfs = d.keyframes().to_vec();
    // The map already holds every keyframe (as when the channel lags behind tracking); the
    // mapper has received the first 8.
    let m = 8;
    for &k in &kfs[..m] {
        mapper.on_keyframe(d.map(), k);
    }
    let waiting: Vec<bool> = mapper
        .entries()
        .iter()
        .map(|e| e.neighbours.iter().any(|n| !kfs[..m].contains(n)))
        .collect();
    assert!(
        waiting.iter().any(|&w| w),
        "no reconstructed keyframe has a neighbour beyond the first {m}: the test proves nothing"
    );
    for (e, &w) in mapper.entries().iter().zip(&waiting) {
        assert!(
            !(w && e.checked),
            "keyframe at {} was checked before its neighbours were reconstructed",
            e.timestamp
        );
    }
    for &k in &kfs[m..] {
        mapper.on_keyframe(d.map(), k);
    }
    mapper.flush(d.map());
    assert!(mapper.entries().iter().all(|e| e.checked));
    assert!(mapper.n_points() > 0);
}

/// Scales the whole map about the world origin by `s` (what a Sim3 loop correction does to
/// the part it moves): points and keyframe centres.
fn scale_map(map: &mut Map, s: f64) {
    let ids: Vec<MapPointId> = map.points().map(|(id, _)| id).collect();
    for id in ids {
        if let Some(p) = map.point_mut(id) {
            p.position *= s;
        }
    }
    let kfs: Vec<KeyFrameId> = map.keyframes().map(|(id, _)| id).collect();
    for id in kfs {
        if let Some(k) = map.keyframe_mut(id) {
            k.t_cw.0.translation.vector *= s;
        }
    }
}

/// Replaces every point `kf` observes by a duplicate at the same place (loop fusion).
fn fuse_points_of(map: &mut Map, kf: KeyFrameId) {
    let observed: Vec<MapPointId> = map
        .keyframe(kf)
        .map(|k| k.observed().map(|(_, p)| p).collect())
        .unwrap_or_default();
    for old in observed {
        let Some(pos) = map.point(old).map(|p| p.position) else {
            continue;
        };
        if let Ok(new) = map.insert_point(pos, kf) {
            map.replace_point(old, new);
        }
    }
}

fn cloud_at(mapper: &SemiDenseMapper, map: &Mutex<Map>, t: f64) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    mapper.cloud(&map.lock().unwrap(), &mut out);
    out.into_iter()
        .filter(|p| p.timestamp == t)
        .map(|p| p.position)
        .collect()
}

/// Every keyframe reconstructed and checked, and the middle one's entry index.
fn reconstructed() -> (Densifier, SemiDenseMapper, usize) {
    let config = Config::default();
    let d = densifier(&config);
    let mut mapper = mapper_for(&config.semidense);
    let kfs = d.keyframes().to_vec();
    mapper.reconstruct_all(d.map(), &kfs);
    (d, mapper, kfs.len() / 2)
}

#[test]
fn depths_follow_a_rescaling_after_every_anchor_was_fused() {
    let (d, mapper, mid) = reconstructed();
    let e = &mapper.entries()[mid];
    let (kf, t) = (e.keyframe, e.timestamp);
    let before = cloud_at(&mapper, d.map(), t);
    assert!(before.len() > 1000, "{} points", before.len());
    let s = 1.5;
    {
        let mut m = d.map().lock().unwrap();
        fuse_points_of(&mut m, kf);
        scale_map(&mut m, s);
    }
    let after = cloud_at(&mapper, d.map(), t);
    assert_eq!(before.len(), after.len());
    let worst = before
        .iter()
        .zip(&after)
        .map(|(b, a)| {
            let want = nalgebra::Vector3::new(b[0], b[1], b[2]) * s as f32;
            (nalgebra::Vector3::new(a[0], a[1], a[2]) - want).norm() / want.norm()
        })
        .fold(0.0f32, f32::max);
    assert!(
        worst < 1e-3,
        "a point is {:.2}% off the rescaled cloud",
        worst * 100.0
    );
}

#[test]
fn a_culled_keyframe_without_anchors_follows_a_correction() {
    let (d, mapper, mid) = reconstructed();
    let e = &mapper.entries()[mid];
    let (kf, c_before) = (e.keyframe, e.t_cw.center());
    let s = 1.5;
    {
        let mut m = d.map().lock().unwrap();
        fuse_points_of(&mut m, kf);
        assert!(m.erase_keyframe(kf));
        scale_map(&mut m, s);
    }
    let m = d.map().lock().unwrap();
    let e = mapper.entries().iter().find(|e| e.keyframe == kf).unwrap();
    let (t_cw, _) = output::pose_and_scale_now(
        &m,
        e,
        mapper.entries(),
        &mut Vec::with_capacity(MAX_ANCHORS),
    );
    let want = c_before * s;
    let moved = (t_cw.center() - want).norm();
    let stayed = (c_before - want).norm();
    assert!(
        moved < 0.1 * stayed,
        "centre {:.3} from the corrected place (the pre-loop centre is {stayed:.3} from it)",
        moved
    );
}

#[test]
fn two_keyframes_at_a_time_give_the_cloud_of_one_at_a_time() {
    let config = Config::default();
    let d = densifier(&config);
    let kfs = d.keyframes().to_vec();
    let run = |threads: usize| {
        let sd = SemiDenseConfig {
            threads,
            ..config.semidense.clone()
        };
        let mut mapper = mapper_for(&sd);
        mapper.reconstruct_all(d.map(), &kfs);
        let mut cloud = Vec::new();
        mapper.cloud(&d.map().lock().unwrap(), &mut cloud);
        let order: Vec<KeyFrameId> = mapper.entries().iter().map(|e| e.keyframe).collect();
        let stats = mapper.stats.clone();
        (cloud, order, stats)
    };
    let (one, order_one, stats_one) = run(1);
    let (two, order_two, stats_two) = run(2);
    assert_eq!(order_one, kfs, "entries not in keyframe order");
    assert_eq!(order_two, kfs, "entries not in keyframe order");
    assert_eq!(stats_one.pixels, stats_two.pixels);
    assert_eq!(
        stats_one.keyframes_reconstructed,
        stats_two.keyframes_reconstructed
    );
    assert!(one.len() > 10_000, "{} points", one.len());
    assert_eq!(one.len(), two.len());
    let same = one
        .iter()
        .zip(&two)
        .all(|(a, b)| a.position == b.position && a.rgb == b.rgb);
    assert!(same, "the clouds differ");
}
