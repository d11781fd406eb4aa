//! Optimiser costs against the issue figures: motion-only BA with 300 observations; local BA of
//! 10 keyframes / 2,000 points / 10,000 observations, 10 LM iterations; Sim3 pose graph of 300
//! keyframes / 2,000 edges.

#[path = "../tests/common/problems.rs"]
mod problems;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, Vector2};
use problems::{ba_problem, pose_graph_problem, Rng};
use sdslam::geometry::CameraFromWorld;
use sdslam::optimize::lie::se3_retract;
use sdslam::optimize::{BaOptions, BundleAdjuster, MotionOnlyBa};

fn optimize(c: &mut Criterion) {
    sdslam::simd::cap_from_env().expect("SDSLAM_SIMD");
    // Motion-only: 300 observations of one frame, 10% outliers, perturbed start.
    let (truth, _, _) = ba_problem(2, 400, 2, 0.0, 11);
    let pose = truth.poses[1];
    let mut rng = Rng(5);
    let (mut pts, mut obs) = (Vec::new(), Vec::new());
    for (i, p) in truth.points.iter().enumerate().take(300) {
        let pc = pose.0 * Point3::from(*p);
        let mut u = Vector2::new(520.0 * pc.x / pc.z + 320.0, 520.0 * pc.y / pc.z + 240.0)
            + Vector2::new(rng.gauss(), rng.gauss());
        if i % 10 == 0 {
            u.x += 30.0;
        }
        pts.push(*p);
        obs.push(u);
    }
    let inv = vec![1.0; pts.len()];
    let ba = MotionOnlyBa::new(sdslam::geometry::Intrinsics::new(
        520.0, 520.0, 320.0, 240.0,
    ));
    let start = CameraFromWorld(se3_retract(
        &pose.0,
        &[0.01, -0.01, 0.005, 0.03, 0.02, -0.02],
    ));
    let mut outlier = vec![false; pts.len()];
    c.bench_function("motion_only_ba_300_observations", |b| {
        b.iter(|| {
            let mut t = start;
            outlier.fill(false);
            ba.optimize(&mut t, &pts, &obs, &inv, &mut outlier)
        })
    });

    let (_, p0, _) = ba_problem(10, 2000, 5, 0.1, 7);
    let mut adj = BundleAdjuster::new();
    let mut g = c.benchmark_group("ba");
    g.sample_size(20);
    g.bench_function("local_ba_10kf_2000pts_10000obs_10_iterations", |b| {
        b.iter_batched(
            || p0.clone(),
            |mut p| {
                adj.solve(
                    &mut p,
                    &BaOptions {
                        iterations: 10,
                        ..BaOptions::default()
                    },
                )
            },
            criterion::BatchSize::LargeInput,
        )
    });
    // Noisy edges (1 cm / 0.01 rad), as a real essential graph: no exact solution.
    let (_, g0) = pose_graph_problem(300, 2000, 0.01, 5);
    let poses0 = g0.poses.clone();
    let mut graph = g0;
    g.bench_function("sim3_pose_graph_300kf_2000edges", |b| {
        b.iter(|| {
            graph.poses.clone_from(&poses0);
            graph.optimize(20)
        })
    });
    g.finish();
}

criterion_group!(benches, optimize);
criterion_main!(benches);
