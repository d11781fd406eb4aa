//! ORB extraction (one thread, and two lanes) and brute-force matching on 640x480 frames of
//! the built-in sequence; and its kernels one by one (pyramid, blur, Harris), so a change to
//! one is measurable above the host's noise (`SDSLAM_SIMD=128` for the 128-bit profile).

use criterion::{criterion_group, criterion_main, Criterion};
use sdslam::camera::Frame;
use sdslam::config::OrbConfig;
use sdslam::features::harris::harris_response;
use sdslam::features::{Features, OrbExtractor};
use sdslam::image::{Pyramid, PyramidConfig};
use sdslam::matching::hamming;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn orb(c: &mut Criterion) {
    sdslam::simd::cap_from_env().expect("SDSLAM_SIMD");
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let mut f = Frame::new(640, 480);
    seq.render_frame(30, &mut f);
    let mut g = Frame::new(640, 480);
    seq.render_frame(33, &mut g);
    let one = OrbConfig {
        threads: 1,
        ..OrbConfig::default()
    };
    let mut ex = OrbExtractor::new(640, 480, &one);
    let mut out = Features::with_capacity(1000);
    c.bench_function("orb_extract_640x480_1000", |b| {
        b.iter(|| ex.extract(&f.gray, None, &mut out))
    });
    // Two lanes (the tracking default, `[orb] threads = 2`).
    let mut ex2 = OrbExtractor::new(640, 480, &OrbConfig::default());
    c.bench_function("orb_extract_640x480_1000_two_threads", |b| {
        b.iter(|| ex2.extract(&f.gray, None, &mut out))
    });
    kernels(c, &f.gray);
    let mut a = Features::with_capacity(1000);
    let mut bfe = Features::with_capacity(1000);
    ex.extract(&f.gray, None, &mut a);
    ex.extract(&g.gray, None, &mut bfe);
    c.bench_function("hamming_brute_force_1000x1000", |b| {
        b.iter(|| {
            let mut s = 0u32;
            for da in &a.descriptors {
                s += bfe
                    .descriptors
                    .iter()
                    .map(|db| hamming(da, db))
                    .min()
                    .unwrap_or(0);
            }
            s
        })
    });
}

/// The pyramid's build (bilinear resampling), its blur, and the Harris response at 1000
/// positions of level 0.
fn kernels(c: &mut Criterion, gray: &[u8]) {
    let mut p = Pyramid::new(
        640,
        480,
        PyramidConfig {
            levels: 8,
            scale_factor: 1.2,
            pad: 24,
            filled: 24,
        },
    );
    c.bench_function("pyramid_build_640x480_8_levels", |b| {
        b.iter(|| p.build(gray))
    });
    c.bench_function("pyramid_blur_8_levels", |b| b.iter(|| p.blur()));
    let level = &p.levels[0];
    let at: Vec<(isize, isize)> = (0..1000)
        .map(|i| (8 + (i * 37) % 620, 8 + (i * 101) % 460))
        .collect();
    c.bench_function("harris_response_1000", |b| {
        b.iter(|| {
            at.iter()
                .map(|&(x, y)| harris_response(level, x, y))
                .sum::<f32>()
        })
    });
}

criterion_group!(benches, orb);
criterion_main!(benches);
