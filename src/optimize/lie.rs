//! Retractions and adjoints for SE3 and Sim3 in the module's left-perturbation convention.

use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};

use crate::geometry::{Se3, Sim3};

/// `Exp(δ) T` for `δ = [ω, v]`: rotate by `exp(ω)`, then translate by `v`.
#[inline]
pub fn se3_retract(t: &Se3, d: &[f64; 6]) -> Se3 {
    let dq = UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2]));
    // Renormalised: products of unit quaternions drift off the unit sphere over many steps.
    Se3::from_parts(
        nalgebra::Translation3::from(dq * t.translation.vector + Vector3::new(d[3], d[4], d[5])),
        UnitQuaternion::new_normalize((dq * t.rotation).into_inner()),
    )
}

/// `Exp(δ) S` for `δ = [ω, v, σ]`: rotate by `exp(ω)` and scale by `e^σ`, then translate by `v`.
#[inline]
pub fn sim3_retract(s: &Sim3, d: &[f64; 7]) -> Sim3 {
    let dq = UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2]));
    let ds = d[6].exp();
    Sim3 {
        scale: ds * s.scale,
        rotation: UnitQuaternion::new_normalize((dq * s.rotation).into_inner()),
        translation: ds * (dq * s.translation) + Vector3::new(d[3], d[4], d[5]),
    }
}

/// Composition `a ∘ b` (apply b, then a).
#[inline]
pub fn sim3_compose(a: &Sim3, b: &Sim3) -> Sim3 {
    Sim3 {
        scale: a.scale * b.scale,
        rotation: a.rotation * b.rotation,
        translation: a.scale * (a.rotation * b.translation) + a.translation,
    }
}

/// Coordinates `[log R, t, ln s]` of a similarity near the identity (the residual of an edge).
#[inline]
pub fn sim3_log_decoupled(s: &Sim3) -> [f64; 7] {
    let w = s.rotation.scaled_axis();
    let t = s.translation;
    [w.x, w.y, w.z, t.x, t.y, t.z, s.scale.ln()]
}

/// Adjoint of `M` in the `[ω, v, σ]` coordinates: `M Exp(δ) M⁻¹ ≈ Exp(Adj_M δ)`.
pub fn sim3_adjoint(m: &Sim3) -> SMatrix<f64, 7, 7> {
    let r = m.rotation.to_rotation_matrix().into_inner();
    let t = m.translation;
    let tx = crate::geometry::epipolar::skew(&t);
    let mut a = SMatrix::<f64, 7, 7>::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 0).copy_from(&(tx * r));
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&(r * m.scale));
    a.fixed_view_mut::<3, 1>(3, 6).copy_from(&(-t));
    a[(6, 6)] = 1.0;
    a
}

/// Pinhole projection Jacobian `∂π/∂p_c` (2x3) for focal lengths `fx, fy`.
#[inline]
pub fn projection_jacobian(p: &Vector3<f64>, fx: f64, fy: f64) -> SMatrix<f64, 2, 3> {
    let iz = 1.0 / p.z;
    let iz2 = iz * iz;
    SMatrix::<f64, 2, 3>::new(fx * iz, 0.0, -fx * p.x * iz2, 0.0, fy * iz, -fy * p.y * iz2)
}

/// `∂p_c/∂δ` for the SE3 left perturbation: `[-[p_c]x, I]`.
#[inline]
pub fn point_pose_jacobian(pc: &Vector3<f64>) -> SMatrix<f64, 3, 6> {
    let mut j = SMatrix::<f64, 3, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-crate::geometry::epipolar::skew(pc)));
    j.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    j
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sim(seed: f64) -> Sim3 {
        Sim3 {
            scale: 1.0 + 0.3 * seed.sin(),
            rotation: UnitQuaternion::from_euler_angles(0.3 * seed, -0.2, 0.5 * seed.cos()),
            translation: Vector3::new(seed, -0.5, 2.0 * seed.sin()),
        }
    }

    #[test]
    fn adjoint_matches_conjugation_to_first_order() {
        let m = sim(0.7);
        let d = [1e-6, -2e-6, 0.5e-6, 3e-6, -1e-6, 2e-6, 1.5e-6];
        // M Exp(d) M^-1 vs Exp(Adj d).
        let lhs = sim3_compose(
            &sim3_compose(&m, &sim3_retract(&Sim3::identity(), &d)),
            &m.inverse(),
        );
        let ad = sim3_adjoint(&m) * nalgebra::SVector::<f64, 7>::from_row_slice(&d);
        let l = sim3_log_decoupled(&lhs);
        for k in 0..7 {
            assert!((l[k] - ad[k]).abs() < 1e-10, "{k}: {} vs {}", l[k], ad[k]);
        }
    }

    #[test]
    fn pose_jacobian_matches_finite_differences() {
        let t = Se3::from_parts(
            nalgebra::Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.2, 0.1, -0.3),
        );
        let pw = nalgebra::Point3::new(0.5, -0.4, 3.0);
        let pc = (t * pw).coords;
        let j = point_pose_jacobian(&pc);
        for c in 0..6 {
            let mut d = [0.0; 6];
            d[c] = 1e-7;
            let num = ((se3_retract(&t, &d) * pw).coords - pc) / 1e-7;
            for r in 0..3 {
                assert!((num[r] - j[(r, c)]).abs() < 1e-5);
            }
        }
    }
}
