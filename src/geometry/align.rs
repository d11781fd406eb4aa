//! Closed-form alignment of two 3D point sets: Umeyama's SVD method (IEEE PAMI 1991, used by
//! trajectory evaluation) and Horn's quaternion method (JOSA 1987, used by loop closing).

use nalgebra::{Matrix3, Matrix4, UnitQuaternion, Vector3, Vector4};

use super::Sim3;

/// Iteration bound of the SVD and eigen solvers: they converge in tens of sweeps on 3x3 and
/// 4x4 matrices; the bound turns a pathological input into `None` instead of a hang.
const SOLVER_MAX_ITERATIONS: usize = 1000;

/// The similarity `dst ≈ s R src + t` minimising squared error; `with_scale = false` gives the
/// rigid (SE3) solution. `None` with fewer than 3 pairs or degenerate (collinear) sets.
pub fn umeyama(src: &[Vector3<f64>], dst: &[Vector3<f64>], with_scale: bool) -> Option<Sim3> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let nf = n as f64;
    let mu_s = src.iter().sum::<Vector3<f64>>() / nf;
    let mu_d = dst.iter().sum::<Vector3<f64>>() / nf;
    let mut cov = Matrix3::zeros();
    let mut var_s = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (ds, dd) = (s - mu_s, d - mu_d);
        cov += dd * ds.transpose();
        var_s += ds.norm_squared();
    }
    cov /= nf;
    var_s /= nf;
    // Non-finite sums (coordinates near 1e300 overflow) would make the iterative SVD spin.
    if var_s < 1e-18 || !var_s.is_finite() || cov.iter().any(|x| !x.is_finite()) {
        return None;
    }
    let svd = cov.try_svd(true, true, f64::EPSILON, SOLVER_MAX_ITERATIONS)?;
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut sgn = Matrix3::identity();
    if u.determinant() * vt.determinant() < 0.0 {
        sgn[(2, 2)] = -1.0;
    }
    // Rank check: two small singular values mean the points are (nearly) collinear.
    let mut sv = svd.singular_values;
    sv.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if sv[1] <= 1e-12 * sv[0].max(1e-300) {
        return None;
    }
    let r = u * sgn * vt;
    let scale = if with_scale {
        (svd.singular_values.component_mul(&sgn.diagonal())).sum() / var_s
    } else {
        1.0
    };
    let rotation =
        UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r));
    let translation = mu_d - scale * (rotation * mu_s);
    Some(Sim3 {
        scale,
        rotation,
        translation,
    })
}

/// Horn's closed form: the similarity `dst ≈ s R src + t` from the unit quaternion of the
/// largest eigenvalue of Horn's 4x4 matrix; scale by Horn's symmetric formula
/// `sqrt(Σ|dst'|² / Σ|src'|²)` when `with_scale`. `None` with fewer than 3 pairs or degenerate sets.
pub fn horn(src: &[Vector3<f64>], dst: &[Vector3<f64>], with_scale: bool) -> Option<Sim3> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let nf = n as f64;
    let c_s = src.iter().sum::<Vector3<f64>>() / nf;
    let c_d = dst.iter().sum::<Vector3<f64>>() / nf;
    let mut m = Matrix3::zeros(); // Σ src' dst'^T
    let (mut ss, mut sd) = (0.0, 0.0);
    for (a, b) in src.iter().zip(dst) {
        let (a, b) = (a - c_s, b - c_d);
        m += a * b.transpose();
        ss += a.norm_squared();
        sd += b.norm_squared();
    }
    if ss < 1e-18 || sd < 1e-18 || !(ss + sd).is_finite() || m.iter().any(|x| !x.is_finite()) {
        return None;
    }
    let (sxx, sxy, sxz) = (m[(0, 0)], m[(0, 1)], m[(0, 2)]);
    let (syx, syy, syz) = (m[(1, 0)], m[(1, 1)], m[(1, 2)]);
    let (szx, szy, szz) = (m[(2, 0)], m[(2, 1)], m[(2, 2)]);
    let nmat = Matrix4::new(
        sxx + syy + szz,
        syz - szy,
        szx - sxz,
        sxy - syx,
        syz - szy,
        sxx - syy - szz,
        sxy + syx,
        szx + sxz,
        szx - sxz,
        sxy + syx,
        -sxx + syy - szz,
        syz + szy,
        sxy - syx,
        szx + sxz,
        syz + szy,
        -sxx - syy + szz,
    );
    let eig = nmat.try_symmetric_eigen(f64::EPSILON, SOLVER_MAX_ITERATIONS)?;
    let (imax, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    let mut sorted: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    sorted.sort_by(|a, b| b.total_cmp(a));
    // Equal top eigenvalues: rotation not determined (collinear points).
    if (sorted[0] - sorted[1]).abs() <= 1e-12 * sorted[0].abs().max(1e-300) {
        return None;
    }
    let q: Vector4<f64> = eig.eigenvectors.column(imax).into_owned();
    let rotation =
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
    let scale = if with_scale { (sd / ss).sqrt() } else { 1.0 };
    let translation = c_d - scale * (rotation * c_s);
    Some(Sim3 {
        scale,
        rotation,
        translation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn recovers_random_similarity(
            roll in -3.0f64..3.0, pitch in -1.5f64..1.5, yaw in -3.0f64..3.0,
            s in 0.05f64..20.0, tx in -10.0f64..10.0, seed in 0u64..1000,
        ) {
            let truth = Sim3 {
                scale: s,
                rotation: UnitQuaternion::from_euler_angles(roll, pitch, yaw),
                translation: Vector3::new(tx, -tx * 0.5, 2.0),
            };
            let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
            let mut rnd = || {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            };
            let src: Vec<_> = (0..20).map(|_| Vector3::new(rnd(), rnd(), rnd()) * 3.0).collect();
            let dst: Vec<_> = src.iter().map(|p| truth.transform(p)).collect();
            let est = umeyama(&src, &dst, true).unwrap();
            prop_assert!((est.scale - s).abs() < 1e-9 * s.max(1.0));
            prop_assert!(est.rotation.angle_to(&truth.rotation) < 1e-9);
            prop_assert!((est.translation - truth.translation).norm() < 1e-7 * s.max(1.0));
        }
    }

    #[test]
    fn horn_agrees_with_umeyama_on_noisy_data() {
        let truth = Sim3 {
            scale: 1.7,
            rotation: UnitQuaternion::from_euler_angles(0.4, -0.3, 2.0),
            translation: Vector3::new(0.5, 1.0, -2.0),
        };
        let src: Vec<_> = (0..30)
            .map(|i| {
                Vector3::new(
                    (i as f64 * 0.7).sin(),
                    (i as f64 * 1.3).cos(),
                    (i as f64 * 0.37).sin() * 2.0,
                )
            })
            .collect();
        let dst: Vec<_> = src
            .iter()
            .enumerate()
            .map(|(i, p)| {
                truth.transform(p) + Vector3::new(0.001 * ((i % 3) as f64 - 1.0), 0.0, 0.001)
            })
            .collect();
        let h = horn(&src, &dst, true).unwrap();
        let u = umeyama(&src, &dst, true).unwrap();
        assert!(h.rotation.angle_to(&truth.rotation) < 2e-3);
        assert!((h.scale - 1.7).abs() < 5e-3);
        assert!(h.rotation.angle_to(&u.rotation) < 2e-3);
        let exact: Vec<_> = src.iter().map(|p| truth.transform(p)).collect();
        let e = horn(&src, &exact, true).unwrap();
        assert!((e.scale - 1.7).abs() < 1e-9 && e.rotation.angle_to(&truth.rotation) < 1e-9);
        assert!((e.translation - truth.translation).norm() < 1e-9);
    }

    #[test]
    fn degenerate_inputs_give_none() {
        let p = vec![Vector3::new(1.0, 0.0, 0.0); 5];
        assert!(umeyama(&p, &p, true).is_none());
        let line: Vec<_> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(umeyama(&line, &line, true).is_none());
        assert!(umeyama(&line[..2], &line[..2], true).is_none());
        assert!(horn(&p, &p, true).is_none());
        assert!(horn(&line, &line, true).is_none());
    }
}
