//! Refinement of a chosen motion: robust Levenberg-Marquardt on the Sampson error (general
//! scenes) or on the transfer error of the plane-induced homography (planar scenes).

use nalgebra::{Matrix3, Vector2, Vector3};

/// Huber threshold of the motion refinement, pixels.
const HUBER_PX: f64 = 1.5;

/// The matches a refinement uses: pixels of both images and the selected indices.
struct Pairs<'a> {
    x1: &'a [Vector2<f64>],
    x2: &'a [Vector2<f64>],
    idx: Vec<usize>,
}

/// Sampson distances (pixels) of the selected pairs under `(r, t)`, written to `out`.
fn sampson(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    kinv: &Matrix3<f64>,
    pairs: &Pairs,
    out: &mut [f64],
) {
    let (x1, x2, idx) = (pairs.x1, pairs.x2, &pairs.idx);
    let f = kinv.transpose() * crate::geometry::epipolar::skew(t) * r * kinv;
    for (o, &i) in out.iter_mut().zip(idx) {
        let (a, b) = (
            Vector3::new(x1[i].x, x1[i].y, 1.0),
            Vector3::new(x2[i].x, x2[i].y, 1.0),
        );
        let fa = f * a;
        let fb = f.transpose() * b;
        let den = (fa.x * fa.x + fa.y * fa.y + fb.x * fb.x + fb.y * fb.y).sqrt();
        *o = if den > 1e-15 { b.dot(&fa) / den } else { 0.0 };
    }
}

/// Symmetric transfer residuals (4 per inlier, pixels) of the plane-induced homography
/// `H = K (R + t n^T) K^-1`.
fn plane_transfer(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    n: &Vector3<f64>,
    k: &Matrix3<f64>,
    kinv: &Matrix3<f64>,
    pairs: &Pairs,
    out: &mut [f64],
) {
    let (x1, x2, idx) = (pairs.x1, pairs.x2, &pairs.idx);
    let h = k * (r + t * n.transpose()) * kinv;
    let hi = h.try_inverse().unwrap_or_else(Matrix3::identity);
    let tr = |m: &Matrix3<f64>, p: &Vector2<f64>| {
        let q = m * Vector3::new(p.x, p.y, 1.0);
        if q.z.abs() < 1e-12 {
            Vector2::new(1e3, 1e3)
        } else {
            Vector2::new(q.x / q.z, q.y / q.z)
        }
    };
    for (o, &i) in out.chunks_exact_mut(4).zip(idx) {
        let (a, b) = (tr(&h, &x1[i]) - x2[i], tr(&hi, &x2[i]) - x1[i]);
        o.copy_from_slice(&[a.x, a.y, b.x, b.y]);
    }
}

/// Huber cost with threshold [`HUBER_PX`].
fn huber(v: f64) -> f64 {
    if v.abs() <= HUBER_PX {
        v * v
    } else {
        2.0 * HUBER_PX * v.abs() - HUBER_PX * HUBER_PX
    }
}

/// Robust Levenberg-Marquardt with a forward-difference Jacobian over a small parameter
/// vector: `residuals(params, out)` fills `m` residuals; `params` is updated in place.
fn robust_lm(
    params: &mut nalgebra::DVector<f64>,
    m: usize,
    residuals: impl Fn(&nalgebra::DVector<f64>, &mut [f64]),
) {
    let p = params.len();
    let (mut res, mut res2) = (vec![0.0; m], vec![0.0; m]);
    residuals(params, &mut res);
    let mut cost: f64 = res.iter().map(|&v| huber(v)).sum();
    let mut lambda = 1e-3;
    let mut jac = nalgebra::DMatrix::<f64>::zeros(m, p);
    for _ in 0..20 {
        for c in 0..p {
            let mut q = params.clone();
            q[c] += 1e-7;
            residuals(&q, &mut res2);
            for j in 0..m {
                jac[(j, c)] = (res2[j] - res[j]) / 1e-7;
            }
        }
        let w = nalgebra::DVector::<f64>::from_iterator(
            m,
            res.iter().map(|e| {
                if e.abs() <= HUBER_PX {
                    1.0
                } else {
                    HUBER_PX / e.abs()
                }
            }),
        );
        let jw = nalgebra::DMatrix::<f64>::from_fn(m, p, |i, j| jac[(i, j)] * w[i]);
        let h = jac.transpose() * &jw;
        let g = jw.transpose() * nalgebra::DVector::<f64>::from_column_slice(&res);
        let mut accepted = false;
        for _ in 0..6 {
            let mut hd = h.clone();
            for d in 0..p {
                hd[(d, d)] += lambda * (h[(d, d)] + 1e-9);
            }
            let Some(ch) = hd.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let cand = &*params - ch.solve(&g);
            residuals(&cand, &mut res2);
            let c: f64 = res2.iter().map(|&v| huber(v)).sum();
            if c < cost {
                accepted = (cost - c) > 1e-10 * cost;
                *params = cand;
                cost = c;
                std::mem::swap(&mut res, &mut res2);
                lambda = (lambda * 0.3).max(1e-12);
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            break;
        }
    }
}

/// Applies a rotation increment (axis-angle, first three params) to `r`.
fn rotated(r: &Matrix3<f64>, p: &nalgebra::DVector<f64>) -> Matrix3<f64> {
    nalgebra::Rotation3::new(Vector3::new(p[0], p[1], p[2])).matrix() * r
}

/// The inverse intrinsics and the inlier pairs a refinement works on; `None` when `k` is
/// singular or fewer than 8 inliers remain (the motion is then kept as it is).
fn setup<'a>(
    x1: &'a [Vector2<f64>],
    x2: &'a [Vector2<f64>],
    inl: &[bool],
    k: &Matrix3<f64>,
) -> Option<(Matrix3<f64>, Pairs<'a>)> {
    let kinv = k.try_inverse()?;
    let pairs = Pairs {
        x1,
        x2,
        idx: (0..x1.len()).filter(|&i| inl[i]).collect(),
    };
    (pairs.idx.len() >= 8).then_some((kinv, pairs))
}

/// Refines a general motion on the Sampson error of the inliers (the linear F keeps the noise of
/// its fit); `|t| = 1` by normalisation.
pub(super) fn refine_motion(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inl: &[bool],
    k: &Matrix3<f64>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let Some((kinv, pairs)) = setup(x1, x2, inl, k) else {
        return (*r, *t);
    };
    let mut p = nalgebra::DVector::<f64>::from_column_slice(&[0.0, 0.0, 0.0, t.x, t.y, t.z]);
    robust_lm(&mut p, pairs.idx.len(), |q, out| {
        sampson(
            &rotated(r, q),
            &Vector3::new(q[3], q[4], q[5]).normalize(),
            &kinv,
            &pairs,
            out,
        )
    });
    let rr = nalgebra::Rotation3::from_matrix(&rotated(r, &p)).into_inner();
    (rr, Vector3::new(p[3], p[4], p[5]).normalize())
}

/// Refines a planar motion on the symmetric transfer error of `H = K (R + t n^T) K^-1`, the
/// plane's normal `n` (scaled by 1/distance) estimated with it; `|t| = 1`.
pub(super) fn refine_planar_motion(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    h21: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inl: &[bool],
    k: &Matrix3<f64>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let Some((kinv, pairs)) = setup(x1, x2, inl, k) else {
        return (*r, *t);
    };
    // Initial plane: least squares of A - R = t n^T with A = K^-1 H K scaled to R's size.
    let mut a = kinv * h21 * k;
    let scale = {
        let sv = a.svd(false, false).singular_values;
        let mut v: Vec<f64> = sv.iter().copied().collect();
        v.sort_by(|x, y| x.total_cmp(y));
        v[1]
    };
    if scale.abs() < 1e-12 {
        return (*r, *t);
    }
    a /= scale;
    // Sign: A should agree with R on a ray in front of both cameras.
    if (a - r).norm() > (-a - r).norm() {
        a = -a;
    }
    let n0 = (a - r).transpose() * t / t.norm_squared();
    let mut p = nalgebra::DVector::<f64>::from_column_slice(&[
        0.0, 0.0, 0.0, t.x, t.y, t.z, n0.x, n0.y, n0.z,
    ]);
    robust_lm(&mut p, pairs.idx.len() * 4, |q, out| {
        let tt = Vector3::new(q[3], q[4], q[5]);
        let s = tt.norm().max(1e-12);
        // Keep |t| = 1 by moving its scale into n (t n^T is invariant).
        plane_transfer(
            &rotated(r, q),
            &(tt / s),
            &(Vector3::new(q[6], q[7], q[8]) * s),
            k,
            &kinv,
            &pairs,
            out,
        )
    });
    let rr = nalgebra::Rotation3::from_matrix(&rotated(r, &p)).into_inner();
    (rr, Vector3::new(p[3], p[4], p[5]).normalize())
}
