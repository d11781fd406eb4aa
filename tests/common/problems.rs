//! Synthetic optimisation problems with known solutions (shared by tests and benches).
#![allow(dead_code)]

use nalgebra::{Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use sdslam::geometry::{CameraFromWorld, Se3, Sim3};
use sdslam::optimize::lie::se3_retract;
use sdslam::optimize::{BaObservation, BaProblem, PoseGraph, PoseGraphEdge};

pub struct Rng(pub u64);
impl Rng {
    pub fn f(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.f()
    }
    pub fn gauss(&mut self) -> f64 {
        (-2.0 * self.f().ln()).sqrt() * (std::f64::consts::TAU * self.f()).cos()
    }
}

/// `n_kf` keyframes on an arc looking at a cloud of `n_pts` points, each point observed by
/// `per_point` keyframes; 1 px noise; `outliers` share of observations corrupted by 20-50 px.
/// Returns (ground truth, perturbed problem, outlier mask).
pub fn ba_problem(
    n_kf: usize,
    n_pts: usize,
    per_point: usize,
    outliers: f64,
    seed: u64,
) -> (BaProblem, BaProblem, Vec<bool>) {
    let mut rng = Rng(seed);
    let (fx, fy, cx, cy) = (520.0, 520.0, 320.0, 240.0);
    let poses: Vec<CameraFromWorld> = (0..n_kf)
        .map(|k| {
            let a = -0.4 + 0.8 * k as f64 / (n_kf.max(2) - 1) as f64;
            let c = Vector3::new(3.0 * a.sin(), 0.1 * (k as f64).sin(), -3.0 * a.cos());
            // Look at the origin.
            let f = (-c).normalize();
            let right = f.cross(&Vector3::new(0.0, -1.0, 0.0)).normalize();
            let down = f.cross(&right);
            let r_wc =
                nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
                    right, down, f,
                ]));
            let t_wc = Se3::from_parts(
                Translation3::from(c),
                UnitQuaternion::from_rotation_matrix(&r_wc),
            );
            CameraFromWorld(t_wc.inverse())
        })
        .collect();
    let mut points = Vec::new();
    let mut obs = Vec::new();
    let mut bad = Vec::new();
    while points.len() < n_pts {
        let p = Vector3::new(
            rng.range(-1.5, 1.5),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        );
        let first = (rng.f() * n_kf as f64) as usize % n_kf;
        let mut seen = Vec::new();
        for d in 0..n_kf {
            let k = (first + d) % n_kf;
            let pc = poses[k].transform(&p);
            let u = Vector2::new(fx * pc.x / pc.z + cx, fy * pc.y / pc.z + cy);
            if pc.z > 0.5 && u.x > 0.0 && u.y > 0.0 && u.x < 640.0 && u.y < 480.0 {
                seen.push((k, u));
            }
            if seen.len() == per_point {
                break;
            }
        }
        if seen.len() < per_point.min(2) {
            continue;
        }
        let j = points.len() as u32;
        points.push(p);
        for (k, u) in seen {
            let octave = (rng.f() * 3.0) as i32;
            let s2 = 1.44f64.powi(octave);
            let is_bad = rng.f() < outliers;
            let noise = Vector2::new(rng.gauss(), rng.gauss()) * s2.sqrt();
            let off = if is_bad {
                Vector2::new(rng.range(20.0, 50.0), rng.range(-50.0, 50.0))
            } else {
                Vector2::zeros()
            };
            obs.push(BaObservation {
                pose: k as u32,
                point: j,
                uv: u + noise + off,
                inv_sigma2: 1.0 / s2,
            });
            bad.push(is_bad);
        }
    }
    let mut fixed = vec![false; n_kf];
    fixed[0] = true;
    fixed[1] = true;
    let truth = BaProblem {
        k: sdslam::geometry::Intrinsics::new(fx, fy, cx, cy),
        poses: poses.clone(),
        pose_fixed: fixed.clone(),
        points: points.clone(),
        observations: obs.clone(),
        excluded: vec![false; obs.len()],
    };
    let mut perturbed = truth.clone();
    for (k, p) in perturbed.poses.iter_mut().enumerate() {
        if !fixed[k] {
            let d = [
                rng.range(-0.01, 0.01),
                rng.range(-0.01, 0.01),
                rng.range(-0.01, 0.01),
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
            ];
            *p = CameraFromWorld(se3_retract(&p.0, &d));
        }
    }
    for p in &mut perturbed.points {
        *p += Vector3::new(rng.gauss(), rng.gauss(), rng.gauss()) * 0.03;
    }
    (truth, perturbed, bad)
}

/// A ring of `n` Sim3 poses with odometry edges (i, i+1) and extra edges to neighbours up to
/// `edges` in total, measurements from the truth; then drift injected into the initial guess
/// (scale and heading creeping along the ring). Edge measurements carry `noise` (rad, m; a tenth
/// of it on log-scale). Vertex 0 fixed.
pub fn pose_graph_problem(n: usize, edges: usize, noise: f64, seed: u64) -> (Vec<Sim3>, PoseGraph) {
    let mut rng = Rng(seed);
    let truth: Vec<Sim3> = (0..n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let t_wc = Sim3 {
                scale: 1.0,
                rotation: UnitQuaternion::from_euler_angles(0.0, -a, 0.0),
                translation: Vector3::new(5.0 * a.cos(), 0.0, 5.0 * a.sin()),
            };
            t_wc.inverse()
        })
        .collect();
    let mut list = Vec::new();
    for i in 0..n {
        list.push((i, (i + 1) % n));
    }
    let mut k = 2;
    while list.len() < edges {
        for i in 0..n {
            if list.len() >= edges {
                break;
            }
            list.push((i, (i + k) % n));
        }
        k += 1;
    }
    let edges: Vec<PoseGraphEdge> = list
        .into_iter()
        .map(|(i, j)| {
            let exact = sdslam::optimize::lie::sim3_compose(&truth[j], &truth[i].inverse());
            let d: [f64; 7] =
                std::array::from_fn(|k| rng.gauss() * noise * if k == 6 { 0.1 } else { 1.0 });
            let s_ji = sdslam::optimize::lie::sim3_retract(&exact, &d);
            PoseGraphEdge {
                i: i as u32,
                j: j as u32,
                s_ji,
                weight: 1.0,
            }
        })
        .collect();
    // Initial guess: drifting odometry.
    let mut poses = truth.clone();
    for (i, p) in poses.iter_mut().enumerate().skip(1) {
        let f = i as f64 / n as f64;
        let drift = Sim3 {
            scale: 1.0 + 0.2 * f,
            rotation: UnitQuaternion::from_euler_angles(0.0, 0.15 * f, 0.02 * f),
            translation: Vector3::new(0.3 * f, 0.1 * f, -0.2 * f)
                + Vector3::new(rng.gauss(), rng.gauss(), rng.gauss()) * 0.01,
        };
        *p = sdslam::optimize::lie::sim3_compose(p, &drift);
    }
    let mut fixed = vec![false; n];
    fixed[0] = true;
    (truth, PoseGraph::new(poses, fixed, edges))
}

pub fn point(p: &Vector3<f64>) -> Point3<f64> {
    Point3::from(*p)
}
