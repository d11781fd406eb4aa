//! Similarity between two keyframes' 3D points for loop closing: Horn's closed form on minimal
//! sets of 3 inside seeded RANSAC, inliers by reprojection in both images (as ORB-SLAM), then
//! Horn on all inliers.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::ransac::{adaptive_ransac, RansacStop, SeededRng};
use super::{horn, Sim3};

/// Matched 3D points of two cameras with their observations.
pub struct Sim3Matches<'a> {
    /// Points in camera-1 coordinates and their undistorted pixels in image 1.
    pub p1: &'a [Vector3<f64>],
    pub u1: &'a [Vector2<f64>],
    pub sigma2_1: &'a [f64],
    /// The same points as seen from camera 2.
    pub p2: &'a [Vector3<f64>],
    pub u2: &'a [Vector2<f64>],
    pub sigma2_2: &'a [f64],
}

#[derive(Clone, Debug)]
pub struct Sim3RansacConfig {
    pub probability: f64,
    pub min_inliers: usize,
    pub max_iterations: usize,
    /// chi² gate on squared reprojection error / sigma² (2 DoF, 99%: 9.21).
    pub chi2: f64,
    /// Solve for scale (monocular) or not (metric).
    pub with_scale: bool,
    pub seed: u64,
}

impl Default for Sim3RansacConfig {
    fn default() -> Self {
        Sim3RansacConfig {
            probability: 0.99,
            min_inliers: 20,
            max_iterations: 300,
            chi2: 9.21,
            with_scale: true,
            seed: 0,
        }
    }
}

#[derive(Clone, Debug)]
pub struct Sim3Solution {
    /// Maps camera-2 points into camera 1: `p1 ≈ S12 p2`.
    pub s12: Sim3,
    pub inliers: Vec<bool>,
    pub n_inliers: usize,
}

fn project(k: &Matrix3<f64>, p: &Vector3<f64>) -> Option<Vector2<f64>> {
    (p.z > 0.0).then(|| {
        Vector2::new(
            k[(0, 0)] * p.x / p.z + k[(0, 2)],
            k[(1, 1)] * p.y / p.z + k[(1, 2)],
        )
    })
}

fn classify(
    s12: &Sim3,
    m: &Sim3Matches,
    k1: &Matrix3<f64>,
    k2: &Matrix3<f64>,
    chi2: f64,
    out: &mut [bool],
) -> usize {
    let s21 = s12.inverse();
    let mut n = 0;
    for (i, o) in out.iter_mut().enumerate().take(m.p1.len()) {
        let ok1 = project(k1, &s12.transform(&m.p2[i]))
            .is_some_and(|u| (u - m.u1[i]).norm_squared() < chi2 * m.sigma2_1[i]);
        let ok2 = ok1
            && project(k2, &s21.transform(&m.p1[i]))
                .is_some_and(|u| (u - m.u2[i]).norm_squared() < chi2 * m.sigma2_2[i]);
        *o = ok2;
        n += ok2 as usize;
    }
    n
}

/// RANSAC over Horn's closed form. `None` with fewer than `min_inliers` consistent matches.
pub fn sim3_ransac(
    m: &Sim3Matches,
    k1: &Matrix3<f64>,
    k2: &Matrix3<f64>,
    cfg: &Sim3RansacConfig,
) -> Option<Sim3Solution> {
    let n = m.p1.len();
    if n < 3.max(cfg.min_inliers)
        || [
            m.u1.len(),
            m.sigma2_1.len(),
            m.p2.len(),
            m.u2.len(),
            m.sigma2_2.len(),
        ]
        .iter()
        .any(|&l| l != n)
    {
        return None;
    }
    let mut rng = SeededRng::new(cfg.seed);
    let stop = RansacStop {
        probability: cfg.probability,
        max_iterations: cfg.max_iterations,
    };
    let (_, best, best_n) = adaptive_ransac::<Sim3, 3>(
        n,
        &mut rng,
        stop,
        |set| horn(&set.map(|i| m.p2[i]), &set.map(|i| m.p1[i]), cfg.with_scale),
        |s12, out| classify(s12, m, k1, k2, cfg.chi2, out),
    )?;
    if best_n < cfg.min_inliers {
        return None;
    }
    let a: Vec<Vector3<f64>> = (0..n).filter(|&i| best[i]).map(|i| m.p2[i]).collect();
    let b: Vec<Vector3<f64>> = (0..n).filter(|&i| best[i]).map(|i| m.p1[i]).collect();
    let s12 = horn(&a, &b, cfg.with_scale)?;
    let mut inl = vec![false; n];
    let count = classify(&s12, m, k1, k2, cfg.chi2, &mut inl);
    (count >= cfg.min_inliers).then_some(Sim3Solution {
        s12,
        inliers: inl,
        n_inliers: count,
    })
}
