//! Map save / load / localisation: a map built on the built-in sequence is saved, loaded into a
//! fresh system, and the same sequence is tracked against it in localisation-only mode: the
//! trajectory matches the mapping run within 1 cm and the map is not changed. Damaged or foreign
//! map files are refused with the reason.

use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::eval::ate;
use sdslam::map::persist::{MapFileError, MapSnapshot};
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn config() -> Config {
    let mut c = Config::default();
    c.semidense.enabled = false;
    c
}

fn poses_and_points(system: &System) -> (Vec<[f64; 7]>, usize) {
    let map = system.map();
    let mut kfs: Vec<[f64; 7]> = map
        .keyframes()
        .map(|(_, k)| {
            let q = k.t_cw.0.rotation;
            let t = k.t_cw.0.translation.vector;
            [q.w, q.i, q.j, q.k, t.x, t.y, t.z]
        })
        .collect();
    kfs.sort_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal));
    (kfs, map.n_points())
}

#[test]
fn saved_map_relocalises_and_tracks_the_same_sequence_without_changing() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let gt = seq.ground_truth();
    let mut f = Frame::new(c.width, c.height);
    // Mapping run.
    let mut a = System::new(&c.calibration(), &config(), 300, false);
    for i in 0..300 {
        seq.render_frame(i, &mut f);
        a.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64);
    }
    assert!(a.finish());
    let ate_a = ate(&gt, &a.trajectory(), 0.02, true)
        .expect("aligned")
        .rmse_m;
    let bytes = a.save_map().encode().unwrap();
    let snap = MapSnapshot::decode(&bytes).unwrap();
    eprintln!(
        "map: {} keyframes, {} points, {} kB",
        snap.n_keyframes(),
        snap.n_points(),
        bytes.len() / 1024
    );

    // Localisation run against the loaded map.
    let mut b = System::new(&c.calibration(), &config(), 300, false);
    let loaded = b.load_map(&snap).unwrap();
    assert_eq!(loaded, snap.n_keyframes());
    b.set_localize_only(true);
    let before = poses_and_points(&b);
    let mut tracked = 0;
    let mut first = None;
    for i in 0..300 {
        seq.render_frame(i, &mut f);
        if b.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64)
            .t_wc
            .is_some()
        {
            tracked += 1;
            first.get_or_insert(i);
        }
    }
    assert!(b.finish());
    let after = poses_and_points(&b);
    assert_eq!(before, after, "localisation changed the map");
    let ate_b = ate(&gt, &b.trajectory(), 0.02, true)
        .expect("aligned")
        .rmse_m;
    eprintln!(
        "mapping ATE {:.2} cm; localisation: first pose at frame {first:?}, {tracked}/300 tracked, ATE {:.2} cm",
        ate_a * 100.0,
        ate_b * 100.0
    );
    assert!(
        first.is_some_and(|i| i < 5),
        "first relocalisation at {first:?}"
    );
    assert!(tracked >= 290, "{tracked}/300 tracked");
    assert!(
        (ate_b - ate_a).abs() < 0.01,
        "ATE {ate_b} vs mapping {ate_a}"
    );
}

#[test]
fn damaged_or_foreign_map_files_are_refused_with_the_reason() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut f = Frame::new(c.width, c.height);
    let mut a = System::new(&c.calibration(), &config(), 80, false);
    for i in 0..80 {
        seq.render_frame(i, &mut f);
        a.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64);
    }
    assert!(a.finish());
    let bytes = a.save_map().encode().unwrap();
    assert!(MapSnapshot::decode(&bytes).is_ok());
    let e = MapSnapshot::decode(&bytes[..bytes.len() - 10]).unwrap_err();
    assert!(matches!(e, MapFileError::Truncated { .. }), "{e}");
    let mut flipped = bytes.clone();
    let n = flipped.len();
    flipped[n / 2] ^= 0x10;
    assert!(matches!(
        MapSnapshot::decode(&flipped).unwrap_err(),
        MapFileError::Checksum
    ));
    let mut v2 = bytes.clone();
    v2[8] = 99;
    let e = MapSnapshot::decode(&v2).unwrap_err();
    assert!(e.to_string().contains("version 99"), "{e}");
    assert!(matches!(
        MapSnapshot::decode(b"PK\x03\x04 a zip file").unwrap_err(),
        MapFileError::NotAMap
    ));
    assert!(matches!(
        MapSnapshot::decode(&[]).unwrap_err(),
        MapFileError::NotAMap
    ));
    // Another camera.
    let mut other = c.calibration();
    other.camera.fx *= 1.1;
    let mut b = System::new(&other, &config(), 10, false);
    let e = b
        .load_map(&MapSnapshot::decode(&bytes).unwrap())
        .unwrap_err();
    assert!(e.to_string().contains("another camera"), "{e}");
    // A map bigger than this run's capacity.
    let mut small = config();
    small.map.max_keyframes = 2;
    let mut b = System::new(&c.calibration(), &small, 10, false);
    let e = b
        .load_map(&MapSnapshot::decode(&bytes).unwrap())
        .unwrap_err();
    assert!(e.to_string().contains("max_keyframes"), "{e}");
}

/// A run with two maps in its atlas (a blackout in unmapped space started the second, not
/// merged yet) saves both: a loaded map has the same maps with the same keyframes, and new
/// maps made after loading get fresh ids.
#[test]
fn a_map_file_keeps_every_map_of_the_atlas() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut f = Frame::new(c.width, c.height);
    let mut a = System::new(&c.calibration(), &config(), 300, false);
    // Frames 150..195 withheld: the camera moves on to a place no map has seen.
    for i in (0..150).chain(195..235) {
        seq.render_frame(i, &mut f);
        a.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64);
    }
    assert!(a.finish());
    let atlas = a.atlas();
    assert_eq!(atlas.maps.len(), 2, "{atlas:?}");
    assert_eq!(atlas.primary, Some(0));
    let second = atlas.maps[1];
    assert!(second.1 >= 30 && second.2 >= 3, "{atlas:?}");
    assert_eq!(a.trajectory_of(second.0).len(), second.1);
    let per_map = |s: &System| {
        let m = s.map();
        m.map_ids()
            .into_iter()
            .map(|id| (id, m.n_keyframes_of(id)))
            .collect::<Vec<_>>()
    };
    let saved = per_map(&a);
    let snap = MapSnapshot::decode(&a.save_map().encode().unwrap()).unwrap();
    let mut b = System::new(&c.calibration(), &config(), 10, false);
    b.load_map(&snap).unwrap();
    assert_eq!(per_map(&b), saved);
    let mut m = b.map();
    assert_eq!(m.active_map(), second.0);
    assert_eq!(m.start_new_map(), second.0 + 1);
}
