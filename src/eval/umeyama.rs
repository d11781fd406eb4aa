//! Umeyama's closed-form similarity between two point sets (IEEE PAMI 1991).

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::geometry::Sim3;

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
    if var_s < 1e-18 {
        return None;
    }
    let svd = cov.svd(true, true);
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
    let rotation = UnitQuaternion::from_matrix(&r);
    let translation = mu_d - scale * (rotation * mu_s);
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
    fn degenerate_inputs_give_none() {
        let p = vec![Vector3::new(1.0, 0.0, 0.0); 5];
        assert!(umeyama(&p, &p, true).is_none());
        let line: Vec<_> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(umeyama(&line, &line, true).is_none());
        assert!(umeyama(&line[..2], &line[..2], true).is_none());
    }
}
