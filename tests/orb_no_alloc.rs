//! Per-frame paths allocate nothing once warmed up: ORB extraction and motion-only BA (a counting
//! global allocator, counting only the test's own thread).

mod common;

use common::counting_alloc::{allocations_in, Counting};
use nalgebra::{Vector2, Vector3};
use sdslam::camera::Frame;
use sdslam::camera_model::PinholeRadtan;
use sdslam::config::OrbConfig;
use sdslam::features::{Features, OrbExtractor};
use sdslam::geometry::{CameraFromWorld, Se3};
use sdslam::optimize::MotionOnlyBa;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

#[global_allocator]
static A: Counting = Counting;

#[test]
fn extraction_allocates_nothing_after_the_first_frame() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let frames: Vec<Frame> = [0usize, 50, 100, 150, 200]
        .iter()
        .map(|&i| {
            let mut f = Frame::new(640, 480);
            seq.render_frame(i, &mut f);
            f
        })
        .collect();
    // A distorted camera so undistortion of keypoints runs too.
    let cam = PinholeRadtan {
        k1: -0.2,
        k2: 0.05,
        ..PinholeRadtan::pinhole(520.0, 520.0, 319.5, 239.5, 640, 480)
    };
    let mut ex = OrbExtractor::new(640, 480, &OrbConfig::default());
    let mut out = Features::with_capacity(1000);
    ex.extract(&frames[0].gray, Some(&cam), &mut out); // warm-up
    let (_, n) = allocations_in(|| {
        for f in &frames[1..] {
            ex.extract(&f.gray, Some(&cam), &mut out);
            assert!(out.len() > 900, "{}", out.len());
        }
    });
    assert_eq!(n, 0, "{n} heap allocations in 4 extractions after warm-up");
}

#[test]
fn motion_only_ba_allocates_nothing() {
    let ba = MotionOnlyBa::new(520.0, 520.0, 320.0, 240.0);
    let pts: Vec<Vector3<f64>> = (0..300)
        .map(|i| {
            Vector3::new(
                (i % 20) as f64 * 0.1 - 1.0,
                (i / 20) as f64 * 0.1 - 0.7,
                3.0 + (i % 7) as f64 * 0.2,
            )
        })
        .collect();
    let obs: Vec<Vector2<f64>> = pts
        .iter()
        .map(|p| Vector2::new(520.0 * p.x / p.z + 320.5, 520.0 * p.y / p.z + 239.7))
        .collect();
    let inv = vec![1.0; 300];
    let mut outlier = vec![false; 300];
    let (_, n) = allocations_in(|| {
        for _ in 0..3 {
            let mut t = CameraFromWorld(Se3::identity());
            ba.optimize(&mut t, &pts, &obs, &inv, &mut outlier);
        }
    });
    assert_eq!(n, 0, "{n} heap allocations in 3 motion-only BA calls");
}
