//! Levenberg-Marquardt refinement of all parameters (intrinsics, distortion, one pose per view)
//! on the reprojection error, with the parameter covariance from the final normal matrix.

use nalgebra::{DMatrix, DVector, Point3, Translation3, UnitQuaternion, Vector2, Vector3};

use crate::camera_model::{KannalaBrandt, Lens, PinholeRadtan};
use crate::geometry::Se3;

/// Intrinsic parameters in the order fx, fy, cx, cy, k1, k2, p1, p2, k3 (radial-tangential) or
/// fx, fy, cx, cy, k1, k2, k3, k4, - (Kannala-Brandt; the last slot unused).
pub const INTRINSICS: usize = 9;
/// The last slot: k3 of radial-tangential (fixed unless asked for), unused by Kannala-Brandt.
const LAST: usize = 8;

/// What the refinement produced.
pub struct Refined {
    pub camera: Lens,
    pub poses: Vec<Se3>,
    /// Standard deviation of each intrinsic (same order as [`INTRINSICS`]); 0 for fixed ones.
    pub std_dev: [f64; INTRINSICS],
    pub iterations: usize,
}

fn intrinsics_of(c: &Lens) -> [f64; INTRINSICS] {
    match c {
        Lens::Pinhole(c) => [c.fx, c.fy, c.cx, c.cy, c.k1, c.k2, c.p1, c.p2, c.k3],
        Lens::KannalaBrandt(c) => [c.fx, c.fy, c.cx, c.cy, c.k1, c.k2, c.k3, c.k4, 0.0],
    }
}

/// The lens of parameters `p`, of the same model as `like`.
fn camera_from(p: &[f64], like: &Lens) -> Lens {
    match like {
        Lens::Pinhole(c) => Lens::Pinhole(PinholeRadtan {
            k1: p[4],
            k2: p[5],
            p1: p[6],
            p2: p[7],
            k3: p[8],
            ..PinholeRadtan::pinhole(p[0], p[1], p[2], p[3], c.width, c.height)
        }),
        Lens::KannalaBrandt(c) => Lens::KannalaBrandt(KannalaBrandt {
            fx: p[0],
            fy: p[1],
            cx: p[2],
            cy: p[3],
            k1: p[4],
            k2: p[5],
            k3: p[6],
            k4: p[7],
            ..*c
        }),
    }
}

fn pose_from(p: &[f64]) -> Se3 {
    Se3::from_parts(
        Translation3::new(p[3], p[4], p[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(p[0], p[1], p[2])),
    )
}

/// Pixel of board point `x` seen by `cam` at `pose` (camera from board). A fisheye point
/// outside the lens's range lands far off (a large residual, not a failure).
pub fn project(cam: &Lens, pose: &Se3, x: &Vector3<f64>) -> Vector2<f64> {
    let c = pose * Point3::from(*x);
    match cam {
        Lens::Pinhole(cam) => {
            let z = if c.z.abs() < 1e-9 { 1e-9 } else { c.z };
            let (xd, yd) = cam.distort_normalized(c.x / z, c.y / z);
            Vector2::new(cam.fx * xd + cam.cx, cam.fy * yd + cam.cy)
        }
        Lens::KannalaBrandt(k) => k
            .project(&c.coords)
            .unwrap_or_else(|| Vector2::new(-1e4, -1e4)),
    }
}

/// Residuals of one view into `out` (2 per corner).
fn view_residuals(
    cam: &Lens,
    pose: &Se3,
    board: &[Vector3<f64>],
    obs: &[Vector2<f64>],
    out: &mut [f64],
) {
    for (k, (x, o)) in board.iter().zip(obs).enumerate() {
        let p = project(cam, pose, x);
        out[2 * k] = p.x - o.x;
        out[2 * k + 1] = p.y - o.y;
    }
}

fn all_residuals(
    params: &[f64],
    like: &Lens,
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    out: &mut [f64],
) {
    let cam = camera_from(params, like);
    let m = 2 * board.len();
    for (v, obs) in views.iter().enumerate() {
        let pose = pose_from(&params[INTRINSICS + 6 * v..INTRINSICS + 6 * v + 6]);
        view_residuals(&cam, &pose, board, obs, &mut out[v * m..(v + 1) * m]);
    }
}

/// Refines `camera` and `poses` to minimise the reprojection error of `views` (corners of the
/// board points `board`, in the same order). `estimate_k3` frees radial-tangential's
/// sixth-order term; a Kannala-Brandt lens refines all of k1..k4.
pub fn refine(
    camera: &Lens,
    poses: &[Se3],
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    estimate_k3: bool,
    max_iterations: usize,
) -> Refined {
    let like = camera;
    let nv = views.len();
    let np = INTRINSICS + 6 * nv;
    let m = 2 * board.len();
    let nr = m * nv;
    let mut params = vec![0.0; np];
    params[..INTRINSICS].copy_from_slice(&intrinsics_of(camera));
    let fisheye = matches!(camera, Lens::KannalaBrandt(_));
    let last_free = estimate_k3 && !fisheye;
    if !last_free {
        params[LAST] = 0.0;
    }
    for (v, p) in poses.iter().enumerate() {
        let r = p.rotation.scaled_axis();
        let t = p.translation.vector;
        params[INTRINSICS + 6 * v..INTRINSICS + 6 * v + 6]
            .copy_from_slice(&[r.x, r.y, r.z, t.x, t.y, t.z]);
    }
    let free = |i: usize| last_free || i != LAST;
    let mut res = vec![0.0; nr];
    let mut trial = vec![0.0; nr];
    all_residuals(&params, like, board, views, &mut res);
    let mut cost: f64 = res.iter().map(|r| r * r).sum();
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut jac = DMatrix::<f64>::zeros(nr, np);
    let mut plus = vec![0.0; m];
    let mut minus = vec![0.0; m];
    for it in 0..max_iterations {
        iterations = it + 1;
        jacobian(
            &params, like, board, views, &free, &mut jac, &mut plus, &mut minus,
        );
        let jtj = jac.transpose() * &jac;
        let jtr = jac.transpose() * DVector::from_column_slice(&res);
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj.clone();
            for i in 0..np {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-9);
                if !free(i) {
                    a[(i, i)] = 1.0;
                }
            }
            let Some(chol) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let mut rhs = -jtr.clone();
            for i in 0..np {
                if !free(i) {
                    rhs[i] = 0.0;
                }
            }
            let delta = chol.solve(&rhs);
            let cand: Vec<f64> = params
                .iter()
                .zip(delta.iter())
                .map(|(p, d)| p + d)
                .collect();
            all_residuals(&cand, like, board, views, &mut trial);
            let c: f64 = trial.iter().map(|r| r * r).sum();
            if c.is_finite() && c < cost {
                let rel = (cost - c) / cost.max(1e-300);
                params = cand;
                std::mem::swap(&mut res, &mut trial);
                cost = c;
                lambda = (lambda * 0.3).max(1e-12);
                improved = rel > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    // Covariance of the intrinsics: sigma^2 (J^T J)^-1 at the optimum.
    jacobian(
        &params, like, board, views, &free, &mut jac, &mut plus, &mut minus,
    );
    let mut jtj = jac.transpose() * &jac;
    for i in 0..np {
        if !free(i) {
            jtj[(i, i)] = 1.0;
        }
    }
    let dof = (nr as f64 - np as f64).max(1.0);
    let sigma2 = cost / dof;
    let mut std_dev = [0.0; INTRINSICS];
    if let Some(inv) = jtj.try_inverse() {
        for (i, s) in std_dev.iter_mut().enumerate() {
            *s = if free(i) {
                (inv[(i, i)] * sigma2).max(0.0).sqrt()
            } else {
                0.0
            };
        }
    }
    Refined {
        camera: camera_from(&params, like),
        poses: (0..nv)
            .map(|v| pose_from(&params[INTRINSICS + 6 * v..INTRINSICS + 6 * v + 6]))
            .collect(),
        std_dev,
        iterations,
    }
}

/// Central-difference Jacobian exploiting the structure: a pose moves only its view's rows.
#[allow(clippy::too_many_arguments)]
fn jacobian(
    params: &[f64],
    like: &Lens,
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    free: &dyn Fn(usize) -> bool,
    jac: &mut DMatrix<f64>,
    plus: &mut [f64],
    minus: &mut [f64],
) {
    jac.fill(0.0);
    let m = 2 * board.len();
    let mut p = params.to_vec();
    for (v, obs) in views.iter().enumerate() {
        let base = INTRINSICS + 6 * v;
        for col in (0..INTRINSICS).chain(base..base + 6) {
            if !free(col) {
                continue;
            }
            let step = 1e-6 * params[col].abs().max(1e-2);
            p[col] = params[col] + step;
            let (cam, pose) = (camera_from(&p, like), pose_from(&p[base..base + 6]));
            view_residuals(&cam, &pose, board, obs, plus);
            p[col] = params[col] - step;
            let (cam, pose) = (camera_from(&p, like), pose_from(&p[base..base + 6]));
            view_residuals(&cam, &pose, board, obs, minus);
            p[col] = params[col];
            for r in 0..m {
                jac[(v * m + r, col)] = (plus[r] - minus[r]) / (2.0 * step);
            }
        }
    }
}
