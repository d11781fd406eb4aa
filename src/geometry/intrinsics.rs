//! Pinhole intrinsics of an undistorted image: the one camera description the solvers share
//! (triangulation, motion-only and full BA, the semi-dense epipolar search). Distortion lives
//! in `camera_model`; frames reach the solvers rectified.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::Se3;

/// Focal lengths and principal point, pixels ((0, 0) is the centre of the top-left pixel).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Intrinsics { fx, fy, cx, cy }
    }

    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// `K^-1`.
    pub fn k_inv(&self) -> Matrix3<f64> {
        Matrix3::new(
            1.0 / self.fx,
            0.0,
            -self.cx / self.fx,
            0.0,
            1.0 / self.fy,
            -self.cy / self.fy,
            0.0,
            0.0,
            1.0,
        )
    }

    /// Pixel of a point in camera coordinates (in front of the camera).
    #[inline]
    pub fn project(&self, p: &Vector3<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy)
    }

    /// Normalised image coordinates (`K^-1 x` without its 1) of a pixel.
    #[inline]
    pub fn normalise(&self, u: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new((u.x - self.cx) / self.fx, (u.y - self.cy) / self.fy)
    }

    /// The unit-depth ray `K^-1 x` through pixel (u, v).
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// The pixel-to-pixel form of `t_ji` (camera i to camera j): `(K R K^-1, K t)`, so a pixel
    /// x of i at inverse depth rho lands at the homogeneous pixel `K R K^-1 x + rho K t` of j
    /// (that is K X_j / depth_i, whose third coordinate is depth_j / depth_i).
    pub fn pixel_transform(&self, t_ji: &Se3) -> (Matrix3<f64>, Vector3<f64>) {
        let km = self.k();
        let r = t_ji.rotation.to_rotation_matrix();
        (km * r.matrix() * self.k_inv(), km * t_ji.translation.vector)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_and_ray_are_inverse() {
        let k = Intrinsics::new(520.0, 515.0, 319.5, 239.5);
        let p = Vector3::new(0.3, -0.2, 2.5);
        let u = k.project(&p);
        let r = k.ray(u.x, u.y);
        assert!((r * p.z - p).norm() < 1e-12);
        assert!((k.k() * k.k_inv() - Matrix3::identity()).norm() < 1e-12);
        let n = k.normalise(&u);
        assert!((n - Vector2::new(p.x / p.z, p.y / p.z)).norm() < 1e-12);
    }
}
