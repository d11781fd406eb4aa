//! Semi-dense reconstruction of one keyframe of the built-in sequence (640x480, 7 neighbours
//! at exact poses): the depth stage (epipolar search + fusion) and the intra stage, on 1 and
//! 2 worker threads. `cargo bench --bench semidense`.

use criterion::{criterion_group, criterion_main, Criterion};
use sdslam::camera::Frame;
use sdslam::config::SemiDenseConfig;
use sdslam::semidense::{prior_range, Intrinsics, KeyframeReconstructor};
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn semidense(c: &mut Criterion) {
    sdslam::simd::cap_from_env().expect("SDSLAM_SIMD");
    let seq = SyntheticSequence::new(SyntheticConfig {
        frames: 300,
        ..SyntheticConfig::default()
    });
    let cam = seq.config.camera();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let gt = seq.ground_truth();
    let render = |i: usize| {
        let mut f = Frame::new(cam.width, cam.height);
        let mut depth = vec![0.0f32; w * h];
        seq.render_with_depth(i, &mut f, &mut depth);
        (f.gray.clone(), depth, gt[i].t_wc.inverse())
    };
    let (gray, depth, t_cw) = render(150);
    let neighbours: Vec<_> = [-15i64, -10, -5, 5, 10, 15, 20]
        .iter()
        .map(|o| render((150 + o) as usize))
        .collect();
    // The prior a keyframe's map points would give: sampled true inverse depths.
    let inv: Vec<f32> = depth
        .iter()
        .step_by(97)
        .filter(|d| **d > 0.0)
        .map(|d| 1.0 / d)
        .collect();
    let range = prior_range(&inv).expect("enough depth samples");
    let k = Intrinsics {
        fx: cam.fx,
        fy: cam.fy,
        cx: cam.cx,
        cy: cam.cy,
    };
    let mut g = sdslam::semidense::GradientImage::new(w, h);
    c.bench_function("semidense_gradients", |b| b.iter(|| g.compute(&gray, 8.0)));
    for threads in [1usize, 2] {
        let cfg = SemiDenseConfig {
            threads,
            ..SemiDenseConfig::default()
        };
        let mut rec = KeyframeReconstructor::new(k, w, h, &cfg);
        rec.set_reference(1000, Some(&gray));
        for (i, (g, _, t)) in neighbours.iter().enumerate() {
            rec.add_neighbour(i as u64, Some(g), &(t.0 * t_cw.0.inverse()), 0.0, 1.0);
        }
        let s = rec.reconstruct(range);
        eprintln!(
            "{threads} thread(s): {} pixels searched, {} samples ({:.0} per pixel and neighbour)",
            s.searched_pixels,
            s.samples,
            s.samples as f64 / (s.searched_pixels as f64 * 7.0)
        );
        c.bench_function(&format!("semidense_keyframe_{threads}_threads"), |b| {
            b.iter(|| rec.reconstruct(range))
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = semidense
}
criterion_main!(benches);
