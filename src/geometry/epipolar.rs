//! Epipolar geometry helpers: essential and fundamental matrices from poses, epipolar lines and
//! the segment of a pixel's epipolar line between two inverse depths.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::{CameraFromWorld, Se3};

/// Skew-symmetric matrix of `v` (`[v]x w = v x w`).
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Essential matrix `E_21 = [t_21]x R_21` for normalised coordinates: `x2^T E x1 = 0`.
pub fn essential_from_relative(t_21: &Se3) -> Matrix3<f64> {
    skew(&t_21.translation.vector) * t_21.rotation.to_rotation_matrix().matrix()
}

/// Fundamental matrix between two posed cameras: `x2^T F_21 x1 = 0` for pixels `x1` in camera 1
/// and `x2` in camera 2.
pub fn fundamental_from_poses(
    k1: &Matrix3<f64>,
    t_1w: &CameraFromWorld,
    k2: &Matrix3<f64>,
    t_2w: &CameraFromWorld,
) -> Option<Matrix3<f64>> {
    let t_21 = t_2w.0 * t_1w.0.inverse();
    let e = essential_from_relative(&t_21);
    Some(k2.try_inverse()?.transpose() * e * k1.try_inverse()?)
}

/// Epipolar line `l = F x1` in image 2, as (a, b, c) with a x + b y + c = 0.
pub fn epipolar_line(f_21: &Matrix3<f64>, x1: &Vector2<f64>) -> Vector3<f64> {
    f_21 * Vector3::new(x1.x, x1.y, 1.0)
}

/// Distance of `x2` to line `l` in pixels (infinite for a degenerate line).
pub fn point_line_distance(l: &Vector3<f64>, x2: &Vector2<f64>) -> f64 {
    let n = (l.x * l.x + l.y * l.y).sqrt();
    if n < 1e-15 {
        f64::INFINITY
    } else {
        (l.x * x2.x + l.y * x2.y + l.z).abs() / n
    }
}

/// Endpoints in image j of the epipolar segment of pixel `u_i` of image i for inverse depths in
/// `[rho_min, rho_max]` (rho_min may be 0: the point at infinity). Pinhole intrinsics `k`
/// shared; `t_ji` is camera j from camera i. `None` when an end falls behind camera j.
pub fn epipolar_segment(
    k: &Matrix3<f64>,
    t_ji: &Se3,
    u_i: &Vector2<f64>,
    rho_min: f64,
    rho_max: f64,
) -> Option<(Vector2<f64>, Vector2<f64>)> {
    let ray = Vector3::new(
        (u_i.x - k[(0, 2)]) / k[(0, 0)],
        (u_i.y - k[(1, 2)]) / k[(1, 1)],
        1.0,
    );
    let r = t_ji.rotation * ray;
    let t = t_ji.translation.vector;
    // A point at inverse depth rho: X_j = R ray / rho + t ~ R ray + rho t (homogeneous).
    let project = |rho: f64| -> Option<Vector2<f64>> {
        let h = r + t * rho;
        (h.z > 1e-9).then(|| {
            Vector2::new(
                k[(0, 0)] * h.x / h.z + k[(0, 2)],
                k[(1, 1)] * h.y / h.z + k[(1, 2)],
            )
        })
    };
    Some((project(rho_min)?, project(rho_max)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    #[test]
    fn fundamental_from_poses_satisfies_the_epipolar_constraint() {
        let k = Matrix3::new(520.0, 0.0, 319.5, 0.0, 520.0, 239.5, 0.0, 0.0, 1.0);
        let t_1w = CameraFromWorld(Se3::from_parts(
            Translation3::new(0.1, -0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.1, 0.2, -0.1),
        ));
        let t_2w = CameraFromWorld(Se3::from_parts(
            Translation3::new(-0.3, 0.1, 0.2),
            UnitQuaternion::from_euler_angles(-0.05, 0.3, 0.05),
        ));
        let f = fundamental_from_poses(&k, &t_1w, &k, &t_2w).unwrap();
        for p in [
            Vector3::new(0.5, 0.2, 4.0),
            Vector3::new(-1.0, 0.3, 6.0),
            Vector3::new(0.0, -0.4, 3.0),
        ] {
            let pix = |t: &CameraFromWorld| {
                let q = t.0 * Point3::from(p);
                Vector2::new(520.0 * q.x / q.z + 319.5, 520.0 * q.y / q.z + 239.5)
            };
            let (x1, x2) = (pix(&t_1w), pix(&t_2w));
            assert!(point_line_distance(&epipolar_line(&f, &x1), &x2) < 1e-6);
        }
    }

    #[test]
    fn segment_ends_are_the_projections_at_the_depth_bounds() {
        let k = Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0);
        let t_ji = Se3::from_parts(
            Translation3::new(-0.2, 0.0, 0.05),
            UnitQuaternion::from_euler_angles(0.0, 0.05, 0.0),
        );
        let u = Vector2::new(300.0, 200.0);
        let (a, b) = epipolar_segment(&k, &t_ji, &u, 1.0 / 8.0, 1.0 / 2.0).unwrap();
        for (end, d) in [(a, 8.0), (b, 2.0)] {
            let x = Vector3::new((u.x - 320.0) / 500.0, (u.y - 240.0) / 500.0, 1.0) * d;
            let q = t_ji * Point3::from(x);
            let p = Vector2::new(500.0 * q.x / q.z + 320.0, 500.0 * q.y / q.z + 240.0);
            assert!((p - end).norm() < 1e-9);
        }
    }
}
