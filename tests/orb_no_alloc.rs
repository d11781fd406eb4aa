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
    let ba = MotionOnlyBa::new(sdslam::geometry::Intrinsics::new(
        520.0, 520.0, 320.0, 240.0,
    ));
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

/// Camera conversion: GREY and YUYV buffers into the preallocated frame allocate nothing (the
/// MJPEG path's JPEG decoder allocates inside; see docs/DECISIONS.md).
#[test]
fn camera_conversion_allocates_nothing() {
    use sdslam::camera::device::convert::{encode, Converter};
    use sdslam::camera::device::PixelFormat;
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let mut f = Frame::new(640, 480);
    seq.render_frame(0, &mut f);
    let mut yuyv = Vec::new();
    encode::yuyv_from_rgb(&f.rgb, 640, 480, 1280 + 64, &mut yuyv);
    let grey: Vec<u8> = f.gray.clone();
    let mut out = Frame::new(640, 480);
    let mut conv_y = Converter::new("cam", PixelFormat::Yuyv, 640, 480, 1280 + 64, true);
    let mut conv_g = Converter::new("cam", PixelFormat::Grey, 640, 480, 640, false);
    conv_y.convert(&yuyv, &mut out).unwrap();
    conv_g.convert(&grey, &mut out).unwrap();
    let (_, n) = allocations_in(|| {
        for _ in 0..5 {
            conv_y.convert(&yuyv, &mut out).unwrap();
            conv_g.convert(&grey, &mut out).unwrap();
        }
    });
    assert_eq!(n, 0, "{n} allocations converting 10 camera buffers");
}
