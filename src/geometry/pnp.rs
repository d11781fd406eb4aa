//! Camera pose from 2D-3D correspondences: EPnP (Lepetit, Moreno-Noguer & Fua, IJCV 2009) inside
//! seeded RANSAC with a minimum-inlier rule, then Gauss-Newton refinement of the reprojection
//! error on the inliers.

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector2, Vector3};

use super::ransac::{adaptive_ransac, RansacStop, SeededRng};
use super::{umeyama, CameraFromWorld, Se3};

type Mat12 = SMatrix<f64, 12, 12>;

/// Normalised image coordinates of a pixel.
fn normalized(k: &Matrix3<f64>, u: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new((u.x - k[(0, 2)]) / k[(0, 0)], (u.y - k[(1, 2)]) / k[(1, 1)])
}

/// EPnP on >= 4 correspondences (world points, undistorted pixels). `None` when degenerate.
pub fn epnp(
    pw: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    k: &Matrix3<f64>,
) -> Option<CameraFromWorld> {
    let n = pw.len();
    if n < 4 || pixels.len() != n {
        return None;
    }
    let xs: Vec<Vector2<f64>> = pixels.iter().map(|u| normalized(k, u)).collect();
    // Control points: centroid and the principal axes of the points.
    let c0 = pw.iter().sum::<Vector3<f64>>() / n as f64;
    let mut cov = Matrix3::zeros();
    for p in pw {
        let d = p - c0;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let scale = eig.eigenvalues.max().max(1e-300).sqrt();
    let mut cws = [c0; 4];
    for j in 0..3 {
        // Planar sets have one vanishing axis: keep it tiny but non-zero so barycentrics exist.
        let k_j = (eig.eigenvalues[j].max(0.0) / n as f64)
            .sqrt()
            .max(1e-3 * scale / (n as f64).sqrt());
        cws[j + 1] = c0 + eig.eigenvectors.column(j).into_owned() * k_j;
    }
    let cc = Matrix3::from_columns(&[cws[1] - c0, cws[2] - c0, cws[3] - c0]);
    let cc_inv = cc.try_inverse()?;
    let alphas: Vec<[f64; 4]> = pw
        .iter()
        .map(|p| {
            let a = cc_inv * (p - c0);
            [1.0 - a.x - a.y - a.z, a.x, a.y, a.z]
        })
        .collect();
    let mut mtm = Mat12::zeros();
    for (a, x) in alphas.iter().zip(&xs) {
        let mut r1 = SVector::<f64, 12>::zeros();
        let mut r2 = SVector::<f64, 12>::zeros();
        for j in 0..4 {
            r1[3 * j] = a[j];
            r1[3 * j + 2] = -a[j] * x.x;
            r2[3 * j + 1] = a[j];
            r2[3 * j + 2] = -a[j] * x.y;
        }
        mtm += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let e = mtm.symmetric_eigen();
    let mut order: Vec<usize> = (0..12).collect();
    order.sort_by(|&a, &b| e.eigenvalues[a].total_cmp(&e.eigenvalues[b]));
    let v: [SVector<f64, 12>; 4] =
        std::array::from_fn(|i| e.eigenvectors.column(order[i]).into_owned());
    // Distances between control points and the L matrix (6 x 10).
    const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
    let mut l = SMatrix::<f64, 6, 10>::zeros();
    let mut rho = SVector::<f64, 6>::zeros();
    for (p, &(a, b)) in PAIRS.iter().enumerate() {
        rho[p] = (cws[a] - cws[b]).norm_squared();
        let dv: [Vector3<f64>; 4] = std::array::from_fn(|i| {
            Vector3::new(
                v[i][3 * a] - v[i][3 * b],
                v[i][3 * a + 1] - v[i][3 * b + 1],
                v[i][3 * a + 2] - v[i][3 * b + 2],
            )
        });
        let row = [
            dv[0].dot(&dv[0]),
            2.0 * dv[0].dot(&dv[1]),
            dv[1].dot(&dv[1]),
            2.0 * dv[0].dot(&dv[2]),
            2.0 * dv[1].dot(&dv[2]),
            dv[2].dot(&dv[2]),
            2.0 * dv[0].dot(&dv[3]),
            2.0 * dv[1].dot(&dv[3]),
            2.0 * dv[2].dot(&dv[3]),
            dv[3].dot(&dv[3]),
        ];
        for (c, val) in row.iter().enumerate() {
            l[(p, c)] = *val;
        }
    }
    let mut best: Option<(f64, CameraFromWorld)> = None;
    for init in [
        betas_approx_1(&l, &rho),
        betas_approx_2(&l, &rho),
        betas_approx_3(&l, &rho),
    ]
    .into_iter()
    .flatten()
    {
        let betas = gauss_newton_betas(&l, &rho, init);
        if let Some(pose) = pose_from_betas(&betas, &v, &alphas, pw) {
            let err = mean_reprojection(&pose, pw, &xs);
            if best.as_ref().is_none_or(|(e, _)| err < *e) {
                best = Some((err, pose));
            }
        }
    }
    best.map(|(_, p)| p)
}

/// Least squares `L[:, idx] b = rho` by SVD.
fn solve_cols(
    l: &SMatrix<f64, 6, 10>,
    idx: &[usize],
    rho: &SVector<f64, 6>,
) -> Option<nalgebra::DVector<f64>> {
    let a = nalgebra::DMatrix::<f64>::from_fn(6, idx.len(), |r, c| l[(r, idx[c])]);
    let b = nalgebra::DVector::<f64>::from_column_slice(rho.as_slice());
    a.svd(true, true).solve(&b, 1e-12).ok()
}

/// N = 4 approximation: betas from columns b11, b12, b13, b14.
fn betas_approx_1(l: &SMatrix<f64, 6, 10>, rho: &SVector<f64, 6>) -> Option<[f64; 4]> {
    let b = solve_cols(l, &[0, 1, 3, 6], rho)?;
    if b[0].abs() < 1e-300 {
        return None;
    }
    let s = b[0].abs().sqrt();
    let sign = if b[0] < 0.0 { -1.0 } else { 1.0 };
    Some([s, sign * b[1] / s, sign * b[2] / s, sign * b[3] / s])
}

/// N = 2 approximation: columns b11, b12, b22.
fn betas_approx_2(l: &SMatrix<f64, 6, 10>, rho: &SVector<f64, 6>) -> Option<[f64; 4]> {
    let b = solve_cols(l, &[0, 1, 2], rho)?;
    let (mut b0, b1) = if b[0] < 0.0 {
        (
            (-b[0]).sqrt(),
            if b[2] < 0.0 { (-b[2]).sqrt() } else { 0.0 },
        )
    } else {
        (b[0].sqrt(), if b[2] > 0.0 { b[2].sqrt() } else { 0.0 })
    };
    if b[1] < 0.0 {
        b0 = -b0;
    }
    Some([b0, b1, 0.0, 0.0])
}

/// N = 3 approximation: columns b11, b12, b22, b13, b23.
fn betas_approx_3(l: &SMatrix<f64, 6, 10>, rho: &SVector<f64, 6>) -> Option<[f64; 4]> {
    let b = solve_cols(l, &[0, 1, 2, 3, 4], rho)?;
    let (mut b0, b1) = if b[0] < 0.0 {
        (
            (-b[0]).sqrt(),
            if b[2] < 0.0 { (-b[2]).sqrt() } else { 0.0 },
        )
    } else {
        (b[0].sqrt(), if b[2] > 0.0 { b[2].sqrt() } else { 0.0 })
    };
    if b[1] < 0.0 {
        b0 = -b0;
    }
    if b0.abs() < 1e-300 {
        return None;
    }
    Some([b0, b1, b[3] / b0, 0.0])
}

fn gauss_newton_betas(l: &SMatrix<f64, 6, 10>, rho: &SVector<f64, 6>, mut b: [f64; 4]) -> [f64; 4] {
    for _ in 0..5 {
        let mut j = SMatrix::<f64, 6, 4>::zeros();
        let mut r = SVector::<f64, 6>::zeros();
        for p in 0..6 {
            let lr = |c: usize| l[(p, c)];
            let q = [
                b[0] * b[0],
                b[0] * b[1],
                b[1] * b[1],
                b[0] * b[2],
                b[1] * b[2],
                b[2] * b[2],
                b[0] * b[3],
                b[1] * b[3],
                b[2] * b[3],
                b[3] * b[3],
            ];
            r[p] = rho[p] - (0..10).map(|c| lr(c) * q[c]).sum::<f64>();
            j[(p, 0)] = 2.0 * lr(0) * b[0] + lr(1) * b[1] + lr(3) * b[2] + lr(6) * b[3];
            j[(p, 1)] = lr(1) * b[0] + 2.0 * lr(2) * b[1] + lr(4) * b[2] + lr(7) * b[3];
            j[(p, 2)] = lr(3) * b[0] + lr(4) * b[1] + 2.0 * lr(5) * b[2] + lr(8) * b[3];
            j[(p, 3)] = lr(6) * b[0] + lr(7) * b[1] + lr(8) * b[2] + 2.0 * lr(9) * b[3];
        }
        let Ok(d) = j.svd(true, true).solve(&r, 1e-12) else {
            break;
        };
        for k in 0..4 {
            b[k] += d[k];
        }
    }
    b
}

fn pose_from_betas(
    b: &[f64; 4],
    v: &[SVector<f64, 12>; 4],
    alphas: &[[f64; 4]],
    pw: &[Vector3<f64>],
) -> Option<CameraFromWorld> {
    let mut ccs = [Vector3::zeros(); 4];
    for (j, c) in ccs.iter_mut().enumerate() {
        for i in 0..4 {
            *c += Vector3::new(v[i][3 * j], v[i][3 * j + 1], v[i][3 * j + 2]) * b[i];
        }
    }
    let mut pcs: Vec<Vector3<f64>> = alphas
        .iter()
        .map(|a| ccs[0] * a[0] + ccs[1] * a[1] + ccs[2] * a[2] + ccs[3] * a[3])
        .collect();
    // The null-space solution has an arbitrary sign: points must be in front of the camera.
    let front = pcs.iter().filter(|p| p.z > 0.0).count();
    if front * 2 < pcs.len() {
        for p in &mut pcs {
            *p = -*p;
        }
    }
    let s = umeyama(pw, &pcs, false)?;
    Some(CameraFromWorld(Se3::from_parts(
        nalgebra::Translation3::from(s.translation),
        s.rotation,
    )))
}

fn mean_reprojection(t: &CameraFromWorld, pw: &[Vector3<f64>], xs: &[Vector2<f64>]) -> f64 {
    pw.iter()
        .zip(xs)
        .map(|(p, x)| {
            let q = t.transform(p);
            if q.z <= 0.0 {
                1e3
            } else {
                (Vector2::new(q.x / q.z, q.y / q.z) - x).norm()
            }
        })
        .sum::<f64>()
        / pw.len() as f64
}

/// Squared pixel reprojection error of `p` under `t` (infinite behind the camera).
fn sq_error(t: &CameraFromWorld, k: &Matrix3<f64>, p: &Vector3<f64>, u: &Vector2<f64>) -> f64 {
    let q = t.transform(p);
    if q.z <= 0.0 {
        return f64::INFINITY;
    }
    let x = Vector2::new(
        k[(0, 0)] * q.x / q.z + k[(0, 2)],
        k[(1, 1)] * q.y / q.z + k[(1, 2)],
    );
    (x - u).norm_squared()
}

/// Gauss-Newton (with a small Levenberg damping) on the pose, minimising
/// `Σ inv_sigma2_i |π(T p_i) - u_i|²` over the inliers; left perturbation `T <- exp(δ) T`.
pub fn refine_pose(
    pw: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    inv_sigma2: &[f64],
    inliers: &[bool],
    k: &Matrix3<f64>,
    mut t: CameraFromWorld,
    iterations: usize,
) -> CameraFromWorld {
    let (fx, fy, cx, cy) = (k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]);
    let cost = |t: &CameraFromWorld| -> f64 {
        (0..pw.len())
            .filter(|&i| inliers[i])
            .map(|i| sq_error(t, k, &pw[i], &pixels[i]).min(1e6) * inv_sigma2[i])
            .sum()
    };
    let mut current = cost(&t);
    let mut lambda = 1e-4;
    for _ in 0..iterations {
        let mut h = SMatrix::<f64, 6, 6>::zeros();
        let mut g = SVector::<f64, 6>::zeros();
        for i in 0..pw.len() {
            if !inliers[i] {
                continue;
            }
            let p = t.transform(&pw[i]);
            if p.z <= 1e-9 {
                continue;
            }
            let iz = 1.0 / p.z;
            let r = Vector2::new(
                fx * p.x * iz + cx - pixels[i].x,
                fy * p.y * iz + cy - pixels[i].y,
            );
            let jp = SMatrix::<f64, 2, 3>::new(
                fx * iz,
                0.0,
                -fx * p.x * iz * iz,
                0.0,
                fy * iz,
                -fy * p.y * iz * iz,
            );
            let mut jd = SMatrix::<f64, 3, 6>::zeros();
            jd.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-super::epipolar::skew(&p)));
            jd.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&Matrix3::identity());
            let j = jp * jd;
            h += j.transpose() * j * inv_sigma2[i];
            g += j.transpose() * r * inv_sigma2[i];
        }
        let mut improved = false;
        for _ in 0..5 {
            let mut hd = h;
            for d in 0..6 {
                hd[(d, d)] *= 1.0 + lambda;
            }
            let Some(delta) = hd.cholesky().map(|c| -c.solve(&g)) else {
                lambda *= 10.0;
                continue;
            };
            let w = Vector3::new(delta[0], delta[1], delta[2]);
            let step = Se3::from_parts(
                nalgebra::Translation3::new(delta[3], delta[4], delta[5]),
                UnitQuaternion::from_scaled_axis(w),
            );
            let cand = CameraFromWorld(step * t.0);
            let c = cost(&cand);
            if c <= current {
                t = cand;
                improved = current - c > 1e-12 * current.max(1e-12);
                current = c;
                lambda = (lambda * 0.3).max(1e-9);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    t
}

/// Parameters of [`pnp_ransac`] (ORB-SLAM's relocalisation values).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PnpRansacConfig {
    pub probability: f64,
    pub min_inliers: usize,
    pub max_iterations: usize,
    /// chi² gate on the squared reprojection error divided by sigma² (2 DoF, 95%).
    pub chi2: f64,
    pub seed: u64,
}

impl Default for PnpRansacConfig {
    fn default() -> Self {
        PnpRansacConfig {
            probability: 0.99,
            min_inliers: 10,
            max_iterations: 300,
            chi2: 5.991,
            seed: 0,
        }
    }
}

/// A PnP solution with its inliers.
#[derive(Clone, Debug)]
pub struct PnpSolution {
    pub t_cw: CameraFromWorld,
    pub inliers: Vec<bool>,
    pub n_inliers: usize,
}

fn classify(
    t: &CameraFromWorld,
    pw: &[Vector3<f64>],
    px: &[Vector2<f64>],
    sigma2: &[f64],
    k: &Matrix3<f64>,
    chi2: f64,
    out: &mut [bool],
) -> usize {
    let mut n = 0;
    for i in 0..pw.len() {
        out[i] = sq_error(t, k, &pw[i], &px[i]) < chi2 * sigma2[i];
        n += out[i] as usize;
    }
    n
}

/// Robust pose: EPnP on minimal sets of 4, inliers by `chi2 * sigma2_i`, then EPnP on all
/// inliers and Gauss-Newton refinement. `None` with fewer than `min_inliers` inliers.
pub fn pnp_ransac(
    pw: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    sigma2: &[f64],
    k: &Matrix3<f64>,
    cfg: &PnpRansacConfig,
) -> Option<PnpSolution> {
    let n = pw.len();
    if n < 4.max(cfg.min_inliers) || pixels.len() != n || sigma2.len() != n {
        return None;
    }
    let mut rng = SeededRng::new(cfg.seed);
    let stop = RansacStop {
        probability: cfg.probability,
        max_iterations: cfg.max_iterations,
    };
    let (_, best_inl, best_n) = adaptive_ransac::<CameraFromWorld, 4>(
        n,
        &mut rng,
        stop,
        |set| {
            let sp: [Vector3<f64>; 4] = set.map(|i| pw[i]);
            let su: [Vector2<f64>; 4] = set.map(|i| pixels[i]);
            epnp(&sp, &su, k)
        },
        |t, out| classify(t, pw, pixels, sigma2, k, cfg.chi2, out),
    )?;
    if best_n < cfg.min_inliers {
        return None;
    }
    // Re-estimate on all inliers, refine, re-classify.
    let idx: Vec<usize> = (0..n).filter(|&i| best_inl[i]).collect();
    let ip: Vec<Vector3<f64>> = idx.iter().map(|&i| pw[i]).collect();
    let iu: Vec<Vector2<f64>> = idx.iter().map(|&i| pixels[i]).collect();
    let mut t = epnp(&ip, &iu, k)?;
    let mut inl = vec![false; n];
    let mut count = classify(&t, pw, pixels, sigma2, k, cfg.chi2, &mut inl);
    if count < best_n {
        inl.copy_from_slice(&best_inl);
    }
    let inv_s2: Vec<f64> = sigma2.iter().map(|s| 1.0 / s).collect();
    for _ in 0..2 {
        t = refine_pose(pw, pixels, &inv_s2, &inl, k, t, 10);
        count = classify(&t, pw, pixels, sigma2, k, cfg.chi2, &mut inl);
    }
    (count >= cfg.min_inliers).then_some(PnpSolution {
        t_cw: t,
        inliers: inl,
        n_inliers: count,
    })
}
