//! Motion hypotheses and their check: the 4 decompositions of E = K^T F K, Faugeras' 8 of H,
//! triangulation of the inliers under each, and the choice of the clearly best one.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::refine::{refine_motion, refine_planar_motion};
use super::{TwoViewConfig, TwoViewError, TwoViewModel, TwoViewMotion};
use crate::geometry::triangulate::triangulate_projections;
use crate::geometry::Se3;

/// Result of checking one motion hypothesis.
struct Check {
    good: usize,
    /// Good points with parallax (angle > 0.36 deg, ORB-SLAM's triangulation limit): the only
    /// ones whose cheirality depends on the hypothesis. Points near the focus of expansion
    /// (forward motion) or far away pass every hypothesis alike, so hypotheses are ranked and
    /// told apart by these.
    decisive: usize,
    parallax_deg: f64,
    points: Vec<Option<Vector3<f64>>>,
    /// Matches that triangulated in front of both cameras within the reprojection gate.
    consistent: Vec<bool>,
}

/// Triangulates the inliers under (R, t) and counts points in front of both cameras with low
/// reprojection error; parallax is the 50th largest (ORB-SLAM's robust parallax).
fn check_rt(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inl: &[bool],
    k: &Matrix3<f64>,
    th2: f64,
) -> Check {
    let mut p1 = nalgebra::Matrix3x4::zeros();
    p1.fixed_view_mut::<3, 3>(0, 0).copy_from(k);
    let mut rt = nalgebra::Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    rt.fixed_view_mut::<3, 1>(0, 3).copy_from(t);
    let p2 = k * rt;
    let o2 = -r.transpose() * t;
    let mut points = vec![None; x1.len()];
    let mut consistent = vec![false; x1.len()];
    let mut cos_par = Vec::new();
    let mut good = 0;
    let mut decisive = 0;
    let proj = |p: &Vector3<f64>| {
        let q = k * p;
        Vector2::new(q.x / q.z, q.y / q.z)
    };
    for i in 0..x1.len() {
        if !inl[i] {
            continue;
        }
        let Some(p) = triangulate_projections(&x1[i], &x2[i], &p1, &p2) else {
            continue;
        };
        let (n1, n2) = (p, p - o2);
        let cos = n1.dot(&n2) / (n1.norm() * n2.norm());
        let pc2 = r * p + t;
        if (p.z <= 0.0 || pc2.z <= 0.0) && cos < 0.99998 {
            continue;
        }
        if p.z <= 0.0 || pc2.z <= 0.0 {
            continue;
        }
        if (proj(&p) - x1[i]).norm_squared() > th2 || (proj(&pc2) - x2[i]).norm_squared() > th2 {
            continue;
        }
        cos_par.push(cos);
        good += 1;
        consistent[i] = true;
        if cos < 0.99998 {
            points[i] = Some(p);
            decisive += 1;
        }
    }
    let parallax_deg = if cos_par.is_empty() {
        0.0
    } else {
        cos_par.sort_by(|a, b| a.total_cmp(b));
        cos_par[cos_par.len().min(50) - 1]
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    };
    Check {
        good,
        decisive,
        parallax_deg,
        points,
        consistent,
    }
}

/// How well the motion `(r, t)` explains all matches: the truncated epipolar score of its
/// essential matrix (ORB-SLAM's F score, `sum(th - d^2 / sigma^2)` over both images). Counting
/// triangulated points does not tell motions apart at low parallax (a free depth absorbs a
/// wrong motion within the reprojection gate); the epipolar residual does.
pub(super) fn epipolar_score(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    k: &Matrix3<f64>,
    inv_s2: f64,
) -> f64 {
    let Some(kinv) = k.try_inverse() else {
        return 0.0;
    };
    let f = kinv.transpose() * t.cross_matrix() * r * kinv;
    let mut cur = vec![false; x1.len()];
    super::models::score_f(&f, x1, x2, inv_s2, &mut cur)
}

/// The decomposition of `E = K^T F K`: its two rotations and the translation direction; the
/// four motions are `(R1 | R2, +-t)`, all with the same essential matrix.
fn essential_parts(
    f21: &Matrix3<f64>,
    k: &Matrix3<f64>,
) -> Option<(Matrix3<f64>, Matrix3<f64>, Vector3<f64>)> {
    let e = k.transpose() * f21 * k;
    let svd = e.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let fix = |m: Matrix3<f64>| if m.determinant() < 0.0 { -m } else { m };
    Some((
        fix(u * w * vt),
        fix(u * w.transpose() * vt),
        u.column(2).normalize(),
    ))
}

/// One of the four motions of `E` (any one scores the epipolar geometry of F).
pub(super) fn essential_motion(
    f21: &Matrix3<f64>,
    k: &Matrix3<f64>,
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    essential_parts(f21, k).map(|(r1, _, t)| (r1, t))
}

fn finish(
    model: TwoViewModel,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    c: Check,
    inliers: usize,
) -> TwoViewMotion {
    let rot = nalgebra::UnitQuaternion::from_matrix(r);
    TwoViewMotion {
        model,
        t_21: Se3::from_parts(nalgebra::Translation3::from(*t), rot),
        points: c.points,
        parallax_deg: c.parallax_deg,
        score_ratio: 0.0,
        inliers,
        needs_confirmation: false,
    }
}

pub(super) fn reconstruct_f(
    f21: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inl: &[bool],
    k: &Matrix3<f64>,
    th2: f64,
    cfg: &TwoViewConfig,
) -> Result<TwoViewMotion, TwoViewError> {
    let n_inl = inl.iter().filter(|&&b| b).count();
    let (r1, r2, t) = essential_parts(f21, k).ok_or(TwoViewError::NoModel)?;
    let hyps = [(r1, t), (r2, t), (r1, -t), (r2, -t)];
    let checks: Vec<Check> = hyps
        .iter()
        .map(|(r, t)| check_rt(r, t, x1, x2, inl, k, th2))
        .collect();
    let (bi, best) = checks
        .iter()
        .enumerate()
        .max_by_key(|(_, c)| (c.decisive, c.good))
        .ok_or(TwoViewError::NoModel)?;
    let max_good = best.good;
    let max_decisive = best.decisive;
    let needed = ((cfg.min_good_share * n_inl as f64) as usize).max(cfg.min_triangulated);
    // No parallax: nothing can be decided about the motion (pure rotation, tiny baseline).
    if best.parallax_deg < cfg.min_parallax_deg {
        return Err(TwoViewError::Degenerate {
            parallax_deg: best.parallax_deg,
        });
    }
    // ORB-SLAM's test (another hypothesis with > 70% of the best's points), on the points
    // that can tell the hypotheses apart.
    let similar = checks
        .iter()
        .filter(|c| c.decisive as f64 > 0.7 * max_decisive as f64)
        .count();
    if similar > 1 {
        let mut goods: Vec<usize> = checks.iter().map(|c| c.decisive).collect();
        goods.sort_unstable_by(|a, b| b.cmp(a));
        return Err(TwoViewError::Ambiguous {
            best: goods[0],
            second: goods[1],
        });
    }
    // Refine on the matches the chosen motion triangulates consistently: epipolar-gate inliers
    // still include outliers lying near their epipolar line.
    let (r, t) = refine_motion(&hyps[bi].0, &hyps[bi].1, x1, x2, &checks[bi].consistent, k);
    let c = check_rt(&r, &t, x1, x2, inl, k, th2);
    // The refined motion must still carry the parallax (refinement can trade it away).
    if c.parallax_deg < cfg.min_parallax_deg {
        return Err(TwoViewError::Degenerate {
            parallax_deg: c.parallax_deg,
        });
    }
    if c.good < needed {
        return Err(TwoViewError::TooFewTriangulated {
            good: c.good.max(max_good),
            needed,
        });
    }
    Ok(finish(TwoViewModel::Fundamental, &r, &t, c, n_inl))
}

/// Faugeras & Lustman's decomposition of a calibrated homography into 8 (R, t, n) hypotheses.
fn decompose_h(h21: &Matrix3<f64>, k: &Matrix3<f64>) -> Option<Vec<(Matrix3<f64>, Vector3<f64>)>> {
    let kinv = k.try_inverse()?;
    let a = kinv * h21 * k;
    let svd = a.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    // Sort singular values descending (nalgebra does not guarantee order).
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
    let u = Matrix3::from_columns(&[u.column(idx[0]), u.column(idx[1]), u.column(idx[2])]);
    let v = Matrix3::from_columns(&[
        vt.row(idx[0]).transpose(),
        vt.row(idx[1]).transpose(),
        vt.row(idx[2]).transpose(),
    ]);
    let (d1, d2, d3) = (
        svd.singular_values[idx[0]],
        svd.singular_values[idx[1]],
        svd.singular_values[idx[2]],
    );
    if d1 / d2 < 1.00001 || d2 / d3 < 1.00001 {
        return None;
    }
    let s = u.determinant() * v.determinant();
    let vt = v.transpose();
    let aux1 = ((d1 * d1 - d2 * d2) / (d1 * d1 - d3 * d3)).sqrt();
    let aux3 = ((d2 * d2 - d3 * d3) / (d1 * d1 - d3 * d3)).sqrt();
    let x1 = [aux1, aux1, -aux1, -aux1];
    let x3 = [aux3, -aux3, aux3, -aux3];
    let root = ((d1 * d1 - d2 * d2) * (d2 * d2 - d3 * d3)).sqrt();
    let mut out = Vec::with_capacity(8);
    // d' = d2 > 0.
    let st = root / ((d1 + d3) * d2);
    let ct = (d2 * d2 + d1 * d3) / ((d1 + d3) * d2);
    let sts = [st, -st, -st, st];
    for i in 0..4 {
        let rp = Matrix3::new(ct, 0.0, -sts[i], 0.0, 1.0, 0.0, sts[i], 0.0, ct);
        let r = s * u * rp * vt;
        let tp = Vector3::new(x1[i], 0.0, -x3[i]) * (d1 - d3);
        out.push((r, (u * tp).normalize()));
    }
    // d' = -d2 < 0.
    let sp = root / ((d1 - d3) * d2);
    let cp = (d1 * d3 - d2 * d2) / ((d1 - d3) * d2);
    let sps = [sp, -sp, -sp, sp];
    for i in 0..4 {
        let rp = Matrix3::new(cp, 0.0, sps[i], 0.0, -1.0, 0.0, sps[i], 0.0, -cp);
        let r = s * u * rp * vt;
        let tp = Vector3::new(x1[i], 0.0, x3[i]) * (d1 + d3);
        out.push((r, (u * tp).normalize()));
    }
    Some(out)
}

pub(super) fn reconstruct_h(
    h21: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inl: &[bool],
    k: &Matrix3<f64>,
    th2: f64,
    cfg: &TwoViewConfig,
) -> Result<TwoViewMotion, TwoViewError> {
    let n_inl = inl.iter().filter(|&&b| b).count();
    // Equal singular values: a homography of pure rotation (or a degenerate fit).
    let hyps = decompose_h(h21, k).ok_or(TwoViewError::Degenerate { parallax_deg: 0.0 })?;
    let checks: Vec<Check> = hyps
        .iter()
        .map(|(r, t)| check_rt(r, t, x1, x2, inl, k, th2))
        .collect();
    let mut order: Vec<usize> = (0..checks.len()).collect();
    let rank = |c: &Check| (c.decisive, c.good);
    order.sort_by(|&a, &b| rank(&checks[b]).cmp(&rank(&checks[a])));
    let (bi, si) = (order[0], order[1]);
    let (best, second) = (checks[bi].decisive, checks[si].decisive);
    // ORB-SLAM's count test on all good points: ambiguous there, only the decisive points
    // chose, so the motion must be confirmed by F (see `cross_check`).
    let mut goods: Vec<usize> = checks.iter().map(|c| c.good).collect();
    goods.sort_unstable_by(|a, b| b.cmp(a));
    let needs_confirmation = goods[1] as f64 >= 0.75 * goods[0] as f64;
    let needed = ((cfg.min_good_share * n_inl as f64) as usize).max(cfg.min_triangulated);
    if checks[bi].parallax_deg < cfg.min_parallax_deg {
        return Err(TwoViewError::Degenerate {
            parallax_deg: checks[bi].parallax_deg,
        });
    }
    if second as f64 >= 0.75 * best as f64 {
        return Err(TwoViewError::Ambiguous { best, second });
    }
    let (r, t) = refine_planar_motion(
        &hyps[bi].0,
        &hyps[bi].1,
        h21,
        x1,
        x2,
        &checks[bi].consistent,
        k,
    );
    let c = check_rt(&r, &t, x1, x2, inl, k, th2);
    // The refined motion must still carry the parallax (refinement can trade it away).
    if c.parallax_deg < cfg.min_parallax_deg {
        return Err(TwoViewError::Degenerate {
            parallax_deg: c.parallax_deg,
        });
    }
    if c.good < needed {
        return Err(TwoViewError::TooFewTriangulated {
            good: c.good.max(checks[bi].good),
            needed,
        });
    }
    let mut m = finish(TwoViewModel::Homography, &r, &t, c, n_inl);
    m.needs_confirmation = needs_confirmation;
    Ok(m)
}
