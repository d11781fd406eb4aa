//! H and F estimation: normalised DLT and 8-point, symmetric scores with chi² gates, RANSAC on
//! shared minimal sets, and the refit of the selected model on its inliers.

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};

use super::TwoViewModel;

pub(super) const TH_H: f64 = 5.991; // chi² 2 DoF, 95%
pub(super) const TH_F: f64 = 3.841; // chi² 1 DoF, 95%

/// Hartley normalisation: zero mean, mean distance sqrt(2). Returns points and T (x_n = T x).
pub(super) fn normalize(p: &[Vector2<f64>]) -> (Vec<Vector2<f64>>, Matrix3<f64>) {
    let n = p.len() as f64;
    let c = p.iter().sum::<Vector2<f64>>() / n;
    let d = p.iter().map(|q| (q - c).norm()).sum::<f64>() / n;
    let s = if d > 1e-12 {
        std::f64::consts::SQRT_2 / d
    } else {
        1.0
    };
    let t = Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0);
    (p.iter().map(|q| (q - c) * s).collect(), t)
}

/// Smallest eigenvector of `A^T A` accumulated from rows.
fn null_vector(ata: &SMatrix<f64, 9, 9>) -> SMatrix<f64, 9, 1> {
    let e = ata.symmetric_eigen();
    let (i, _) = e
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .unwrap_or((0, &0.0));
    e.eigenvectors.column(i).into_owned()
}

/// Normalised DLT homography `x2 ~ H x1` from >= 4 pairs.
pub fn homography_dlt(p1: &[Vector2<f64>], p2: &[Vector2<f64>]) -> Matrix3<f64> {
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (a, b) in p1.iter().zip(p2) {
        let r1 = SMatrix::<f64, 1, 9>::from_row_slice(&[
            0.0,
            0.0,
            0.0,
            -a.x,
            -a.y,
            -1.0,
            b.y * a.x,
            b.y * a.y,
            b.y,
        ]);
        let r2 = SMatrix::<f64, 1, 9>::from_row_slice(&[
            a.x,
            a.y,
            1.0,
            0.0,
            0.0,
            0.0,
            -b.x * a.x,
            -b.x * a.y,
            -b.x,
        ]);
        ata += r1.transpose() * r1 + r2.transpose() * r2;
    }
    let h = null_vector(&ata);
    Matrix3::from_row_slice(h.as_slice())
}

/// Normalised 8-point fundamental matrix `x2^T F x1 = 0`, rank 2 enforced.
pub fn fundamental_8point(p1: &[Vector2<f64>], p2: &[Vector2<f64>]) -> Matrix3<f64> {
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (a, b) in p1.iter().zip(p2) {
        let r = SMatrix::<f64, 1, 9>::from_row_slice(&[
            b.x * a.x,
            b.x * a.y,
            b.x,
            b.y * a.x,
            b.y * a.y,
            b.y,
            a.x,
            a.y,
            1.0,
        ]);
        ata += r.transpose() * r;
    }
    let f = Matrix3::from_row_slice(null_vector(&ata).as_slice());
    let mut svd = f.svd(true, true);
    svd.singular_values[2] = 0.0;
    svd.recompose().unwrap_or(f)
}

/// Symmetric transfer score of H (both directions) and the inlier mask.
fn score_h(
    h21: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inv_s2: f64,
    inl: &mut [bool],
) -> f64 {
    let Some(h12) = h21.try_inverse() else {
        return 0.0;
    };
    let mut score = 0.0;
    let tr = |h: &Matrix3<f64>, p: &Vector2<f64>| {
        let q = h * Vector3::new(p.x, p.y, 1.0);
        Vector2::new(q.x / q.z, q.y / q.z)
    };
    for i in 0..x1.len() {
        let d2 = (tr(h21, &x1[i]) - x2[i]).norm_squared() * inv_s2;
        let d1 = (tr(&h12, &x2[i]) - x1[i]).norm_squared() * inv_s2;
        let ok = d1.is_finite() && d2.is_finite() && d1 <= TH_H && d2 <= TH_H;
        if ok {
            score += (TH_H - d1) + (TH_H - d2);
        }
        inl[i] = ok;
    }
    score
}

/// Symmetric epipolar score of F (point-to-line distances in both images) and the inlier mask.
pub(super) fn score_f(
    f21: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inv_s2: f64,
    inl: &mut [bool],
) -> f64 {
    let mut score = 0.0;
    for i in 0..x1.len() {
        let (a, b) = (
            Vector3::new(x1[i].x, x1[i].y, 1.0),
            Vector3::new(x2[i].x, x2[i].y, 1.0),
        );
        let l2 = f21 * a;
        let l1 = f21.transpose() * b;
        let num = b.dot(&l2);
        let d2 = num * num / (l2.x * l2.x + l2.y * l2.y) * inv_s2;
        let d1 = num * num / (l1.x * l1.x + l1.y * l1.y) * inv_s2;
        let ok = d1.is_finite() && d2.is_finite() && d1 <= TH_F && d2 <= TH_F;
        if ok {
            // Each model's rho saturates at its own gate: a point-to-line distance (1 DoF) is
            // about half a point-to-point one (2 DoF), so a shared saturation would favour F on
            // planes that both models explain (see docs/DECISIONS.md).
            score += (TH_F - d1) + (TH_F - d2);
        }
        inl[i] = ok;
    }
    score
}

pub(super) struct ModelFit {
    pub(super) score: f64,
    pub(super) m: Matrix3<f64>,
    pub(super) inliers: Vec<bool>,
}

/// Matches in pixels and Hartley-normalised, with the normalising transforms.
pub(super) struct NormalizedMatches<'a> {
    pub(super) x1: &'a [Vector2<f64>],
    pub(super) x2: &'a [Vector2<f64>],
    pub(super) n1: Vec<Vector2<f64>>,
    pub(super) n2: Vec<Vector2<f64>>,
    pub(super) t1: Matrix3<f64>,
    pub(super) t2: Matrix3<f64>,
}

pub(super) fn ransac_model(
    m: &NormalizedMatches,
    sets: &[[usize; 8]],
    inv_s2: f64,
    homography: bool,
) -> ModelFit {
    let (x1, x2, n1, n2, t1, t2) = (m.x1, m.x2, &m.n1, &m.n2, &m.t1, &m.t2);
    let mut best = ModelFit {
        score: 0.0,
        m: Matrix3::zeros(),
        inliers: vec![false; x1.len()],
    };
    let mut cur = vec![false; x1.len()];
    let (mut s1, mut s2) = ([Vector2::zeros(); 8], [Vector2::zeros(); 8]);
    let t2inv = t2.try_inverse().unwrap_or_else(Matrix3::identity);
    for set in sets {
        for (k, &i) in set.iter().enumerate() {
            s1[k] = n1[i];
            s2[k] = n2[i];
        }
        let (m, score) = if homography {
            let h = t2inv * homography_dlt(&s1, &s2) * t1;
            (h, score_h(&h, x1, x2, inv_s2, &mut cur))
        } else {
            let f = t2.transpose() * fundamental_8point(&s1, &s2) * t1;
            (f, score_f(&f, x1, x2, inv_s2, &mut cur))
        };
        if score > best.score {
            best.score = score;
            best.m = m;
            best.inliers.copy_from_slice(&cur);
        }
    }
    best
}

/// Refits the selected model on all its inliers (the minimal-set model carries the noise of 8
/// points). Done after selection: a least-squares F fits a plane as well as H does, so refitting
/// before selection would defeat it.
pub(super) fn refit(
    model: TwoViewModel,
    m: &mut Matrix3<f64>,
    inl: &mut [bool],
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    inv_s2: f64,
) {
    let mut cur = vec![false; x1.len()];
    let mut best = if model == TwoViewModel::Homography {
        score_h(m, x1, x2, inv_s2, &mut cur)
    } else {
        score_f(m, x1, x2, inv_s2, &mut cur)
    };
    for _ in 0..3 {
        let idx: Vec<usize> = (0..x1.len()).filter(|&i| inl[i]).collect();
        if idx.len() < 8 {
            return;
        }
        let a: Vec<Vector2<f64>> = idx.iter().map(|&i| x1[i]).collect();
        let b: Vec<Vector2<f64>> = idx.iter().map(|&i| x2[i]).collect();
        let (na, ta) = normalize(&a);
        let (nb, tb) = normalize(&b);
        let Some(tbi) = tb.try_inverse() else { return };
        let (cand, score) = if model == TwoViewModel::Homography {
            let h = tbi * homography_dlt(&na, &nb) * ta;
            (h, score_h(&h, x1, x2, inv_s2, &mut cur))
        } else {
            let f = tb.transpose() * fundamental_8point(&na, &nb) * ta;
            (f, score_f(&f, x1, x2, inv_s2, &mut cur))
        };
        if score <= best {
            return;
        }
        best = score;
        *m = cand;
        inl.copy_from_slice(&cur);
    }
}
