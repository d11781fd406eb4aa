//! Linear (DLT) triangulation with the checks mapping needs: cheirality, parallax, reprojection.

use nalgebra::{Matrix3x4, Matrix4, Vector2, Vector3};

use super::Se3;

/// Triangulates normalised rays `x1` (camera 1, z = 1) and `x2` (camera 2) with camera 2's pose
/// `t_21` relative to camera 1. Returns the point in camera-1 coordinates, or `None` at infinity
/// or when not finite.
pub fn triangulate_linear(
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
    t_21: &Se3,
) -> Option<Vector3<f64>> {
    let p1 = Matrix3x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    let r = t_21.rotation.to_rotation_matrix();
    let t = t_21.translation.vector;
    let mut p2 = Matrix3x4::zeros();
    p2.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    p2.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
    triangulate_projections(x1, x2, &p1, &p2)
}

/// DLT with two 3x4 projection matrices; the homogeneous solution is the right singular
/// vector of the smallest singular value, taken as the eigenvector of the smallest eigenvalue
/// of `A^T A` (the same vector; the 4x4 symmetric eigensolver costs 0.4x the SVD, and
/// initialisation triangulates every match for each of up to 12 motion hypotheses). The
/// inhomogeneous method (fix the last coordinate, a 3x3 solve) is 15x cheaper but measurably
/// less accurate: desk 0.33 -> 0.48 cm.
pub fn triangulate_projections(
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
    p1: &Matrix3x4<f64>,
    p2: &Matrix3x4<f64>,
) -> Option<Vector3<f64>> {
    let mut a = Matrix4::zeros();
    a.set_row(0, &(p1.row(2) * x1.x - p1.row(0)));
    a.set_row(1, &(p1.row(2) * x1.y - p1.row(1)));
    a.set_row(2, &(p2.row(2) * x2.x - p2.row(0)));
    a.set_row(3, &(p2.row(2) * x2.y - p2.row(1)));
    let eig = (a.transpose() * a).try_symmetric_eigen(f64::EPSILON, 1000)?;
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = eig.eigenvectors.column(imin);
    if h[3].abs() < 1e-14 {
        return None;
    }
    let p = Vector3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
    p.iter().all(|v| v.is_finite()).then_some(p)
}

/// Why a triangulation was rejected.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TriangulationReject {
    Degenerate,
    /// Rays closer than the parallax threshold.
    LowParallax,
    /// Behind one of the cameras.
    BehindCamera,
    /// Reprojection error (squared, pixels) above the gate in one view.
    Reprojection,
}

/// Gates of [`triangulate_checked`].
#[derive(Clone, Copy, Debug)]
pub struct TriangulationChecks {
    /// Minimum parallax: rays must satisfy cos(angle) < this (ORB-SLAM: 0.9998).
    pub max_cos_parallax: f64,
    /// Squared reprojection gate in pixels² per view, already scaled by the observation's
    /// sigma² (ORB-SLAM: 5.991 sigma²).
    pub max_sq_error_1: f64,
    pub max_sq_error_2: f64,
    /// The (undistorted) pinhole camera of both views.
    pub k: super::Intrinsics,
}

/// Triangulates undistorted pixels `u1`, `u2` and applies parallax, cheirality and reprojection
/// checks. Returns the point in camera-1 coordinates.
pub fn triangulate_checked(
    u1: &Vector2<f64>,
    u2: &Vector2<f64>,
    t_21: &Se3,
    c: &TriangulationChecks,
) -> Result<Vector3<f64>, TriangulationReject> {
    let (x1, x2) = (c.k.normalise(u1), c.k.normalise(u2));
    let ray1 = Vector3::new(x1.x, x1.y, 1.0);
    let ray2_c2 = Vector3::new(x2.x, x2.y, 1.0);
    let ray2 = t_21.rotation.inverse() * ray2_c2;
    let cos = ray1.dot(&ray2) / (ray1.norm() * ray2.norm());
    if cos >= c.max_cos_parallax {
        return Err(TriangulationReject::LowParallax);
    }
    let p = triangulate_linear(&x1, &x2, t_21).ok_or(TriangulationReject::Degenerate)?;
    let p2 = t_21 * nalgebra::Point3::from(p);
    if p.z <= 0.0 || p2.z <= 0.0 {
        return Err(TriangulationReject::BehindCamera);
    }
    let proj = |q: &Vector3<f64>| c.k.project(q);
    if (proj(&p) - u1).norm_squared() > c.max_sq_error_1
        || (proj(&p2.coords) - u2).norm_squared() > c.max_sq_error_2
    {
        return Err(TriangulationReject::Reprojection);
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use proptest::prelude::*;

    fn checks() -> TriangulationChecks {
        TriangulationChecks {
            max_cos_parallax: 0.9998,
            max_sq_error_1: 5.991,
            max_sq_error_2: 5.991,
            k: crate::geometry::Intrinsics::new(500.0, 500.0, 320.0, 240.0),
        }
    }

    proptest! {
        #[test]
        fn recovers_random_points(x in -2.0f64..2.0, y in -1.5f64..1.5, z in 1.0f64..10.0, tx in 0.1f64..0.5, yaw in -0.2f64..0.2) {
            let t_21 = Se3::from_parts(Translation3::new(-tx, 0.02, 0.01), UnitQuaternion::from_euler_angles(0.01, yaw, 0.0));
            let p = Vector3::new(x, y, z);
            let p2 = t_21 * nalgebra::Point3::from(p);
            prop_assume!(p2.z > 0.1);
            let x1 = Vector2::new(p.x / p.z, p.y / p.z);
            let x2 = Vector2::new(p2.x / p2.z, p2.y / p2.z);
            let q = triangulate_linear(&x1, &x2, &t_21).unwrap();
            prop_assert!((q - p).norm() < 1e-6 * z * z);
        }
    }

    #[test]
    fn checks_reject_low_parallax_behind_and_bad_reprojection() {
        let c = checks();
        let t_21 = Se3::from_parts(
            Translation3::new(-0.2, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        let pix = |p: &Vector3<f64>, t: &Se3| {
            let q = t * nalgebra::Point3::from(*p);
            Vector2::new(500.0 * q.x / q.z + 320.0, 500.0 * q.y / q.z + 240.0)
        };
        let p = Vector3::new(0.1, 0.2, 3.0);
        let (u1, u2) = (pix(&p, &Se3::identity()), pix(&p, &t_21));
        assert!((triangulate_checked(&u1, &u2, &t_21, &c).unwrap() - p).norm() < 1e-6);
        // Far point: parallax below the gate.
        let far = Vector3::new(0.1, 0.2, 3000.0);
        assert_eq!(
            triangulate_checked(&pix(&far, &Se3::identity()), &pix(&far, &t_21), &t_21, &c),
            Err(TriangulationReject::LowParallax)
        );
        // Inconsistent pair: rays cross behind the cameras.
        let u2_bad = Vector2::new(u2.x + 60.0, u2.y);
        assert!(triangulate_checked(&u1, &u2_bad, &t_21, &c).is_err());
        // Slightly inconsistent: triangulates but reprojects badly.
        let u2_off = Vector2::new(u2.x, u2.y + 8.0);
        assert_eq!(
            triangulate_checked(&u1, &u2_off, &t_21, &c),
            Err(TriangulationReject::Reprojection)
        );
    }
}
