//! Pinhole camera with radial-tangential (Brown-Conrady: k1 k2 p1 p2 k3) distortion.

use nalgebra::{Matrix3, Vector2, Vector3};

/// Intrinsics and distortion of one camera. Pixel coordinates have (0, 0) at the centre of
/// the top-left pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PinholeRadtan {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
    pub width: u32,
    pub height: u32,
}

impl PinholeRadtan {
    /// The pinhole part (what the solvers use on rectified images).
    pub fn intrinsics(&self) -> crate::geometry::Intrinsics {
        crate::geometry::Intrinsics::new(self.fx, self.fy, self.cx, self.cy)
    }

    /// A distortion-free pinhole camera.
    pub fn pinhole(fx: f64, fy: f64, cx: f64, cy: f64, width: u32, height: u32) -> Self {
        PinholeRadtan {
            fx,
            fy,
            cx,
            cy,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            width,
            height,
        }
    }

    /// True when every distortion coefficient is zero (undistortion is the identity).
    pub fn is_distortion_free(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
            .iter()
            .all(|c| *c == 0.0)
    }

    /// The same intrinsics without distortion: the geometry of undistorted images and points.
    pub fn undistorted(&self) -> Self {
        Self::pinhole(self.fx, self.fy, self.cx, self.cy, self.width, self.height)
    }

    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Applies the distortion to normalised coordinates.
    #[inline]
    pub fn distort_normalized(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Inverts the distortion by Newton iterations on the 2x2 Jacobian (converges in a few
    /// steps for real lenses; far more accurate than OpenCV's fixed-point default).
    pub fn undistort_normalized(&self, xd: f64, yd: f64) -> (f64, f64) {
        if self.is_distortion_free() {
            return (xd, yd);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let (fx, fy) = self.distort_normalized(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex * ex + ey * ey < 1e-24 {
                break;
            }
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2); // d radial / d r2
            let j00 = radial + 2.0 * x * x * dradial + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
            let j01 = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
            let j10 = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
            let j11 = radial + 2.0 * y * y * dradial + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
            let det = j00 * j11 - j01 * j10;
            if det.abs() < 1e-12 || !det.is_finite() {
                break;
            }
            x -= (j11 * ex - j01 * ey) / det;
            y -= (-j10 * ex + j00 * ey) / det;
        }
        (x, y)
    }

    /// Distorted pixel -> undistorted pixel (same K).
    pub fn undistort_pixel(&self, u: f64, v: f64) -> Vector2<f64> {
        let (x, y) = self.undistort_normalized((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        Vector2::new(self.fx * x + self.cx, self.fy * y + self.cy)
    }

    /// Undistorted pixel -> distorted pixel (same K).
    pub fn distort_pixel(&self, u: f64, v: f64) -> Vector2<f64> {
        let (x, y) = self.distort_normalized((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        Vector2::new(self.fx * x + self.cx, self.fy * y + self.cy)
    }

    /// Projects a camera-frame point to an undistorted pixel; `None` behind the camera.
    #[inline]
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        if p_c.z <= 1e-9 {
            return None;
        }
        let iz = 1.0 / p_c.z;
        Some(Vector2::new(
            self.fx * p_c.x * iz + self.cx,
            self.fy * p_c.y * iz + self.cy,
        ))
    }

    /// Ray (z = 1) through an undistorted pixel.
    #[inline]
    pub fn unproject(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// True when an undistorted pixel lies inside the image (with `border` pixels margin).
    #[inline]
    pub fn in_image(&self, u: f64, v: f64, border: f64) -> bool {
        u >= border
            && v >= border
            && u <= self.width as f64 - 1.0 - border
            && v <= self.height as f64 - 1.0 - border
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn euroc() -> PinholeRadtan {
        PinholeRadtan {
            k1: -0.28340811,
            k2: 0.07395907,
            p1: 0.00019359,
            p2: 1.76187114e-05,
            ..PinholeRadtan::pinhole(458.654, 457.296, 367.215, 248.375, 752, 480)
        }
    }

    fn tum_fr1() -> PinholeRadtan {
        PinholeRadtan {
            k1: 0.262383,
            k2: -0.953104,
            p1: -0.005358,
            p2: 0.002628,
            k3: 1.163314,
            ..PinholeRadtan::pinhole(517.306408, 516.469215, 318.643040, 255.313989, 640, 480)
        }
    }

    proptest! {
        #[test]
        fn undistort_inverts_distort_over_the_image(u in 0.0f64..752.0, v in 0.0f64..480.0) {
            let c = euroc();
            let d = c.distort_pixel(u, v);
            let back = c.undistort_pixel(d.x, d.y);
            prop_assert!((back.x - u).abs() < 1e-6 && (back.y - v).abs() < 1e-6, "{u} {v} -> {back:?}");
        }

        #[test]
        fn undistort_inverts_distort_tum_fr1(u in 0.0f64..640.0, v in 0.0f64..480.0) {
            let c = tum_fr1();
            let d = c.distort_pixel(u, v);
            let back = c.undistort_pixel(d.x, d.y);
            prop_assert!((back - Vector2::new(u, v)).norm() < 1e-6);
        }

        #[test]
        fn project_unproject_round_trip(u in 0.0f64..640.0, v in 0.0f64..480.0, z in 0.1f64..50.0) {
            let c = tum_fr1().undistorted();
            let p = c.unproject(u, v) * z;
            let q = c.project(&p).unwrap();
            prop_assert!((q - Vector2::new(u, v)).norm() < 1e-9);
        }
    }

    #[test]
    fn behind_camera_does_not_project() {
        let c = euroc();
        assert!(c.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn distortion_free_is_identity() {
        let c = PinholeRadtan::pinhole(500.0, 500.0, 320.0, 240.0, 640, 480);
        assert!(c.is_distortion_free());
        assert_eq!(c.undistort_pixel(10.0, 20.0), Vector2::new(10.0, 20.0));
    }
}
