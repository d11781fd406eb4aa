//! Kannala-Brandt fisheye model (the "equidistant" model of OpenCV's fisheye module and ROS,
//! `KannalaBrandt8` of ORB-SLAM3): the image radius grows with the angle θ from the optical
//! axis, `r = f · θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`, so it reaches 180° and beyond where a
//! pinhole cannot.
//!
//! Kannala & Brandt, "A generic camera model and calibration method for conventional,
//! wide-angle, and fish-eye lenses", TPAMI 2006.

use nalgebra::{Vector2, Vector3};

use super::PinholeRadtan;

/// Intrinsics and the four radial coefficients of a fisheye lens. Pixel coordinates have
/// (0, 0) at the centre of the top-left pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KannalaBrandt {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    pub k4: f64,
    pub width: u32,
    pub height: u32,
}

impl KannalaBrandt {
    /// `θ_d(θ)`: the normalised image radius of a ray at angle `θ` from the axis.
    #[inline]
    pub fn theta_d(&self, theta: f64) -> f64 {
        let t2 = theta * theta;
        theta * (1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4))))
    }

    /// `dθ_d/dθ`.
    #[inline]
    fn theta_d_slope(&self, theta: f64) -> f64 {
        let t2 = theta * theta;
        1.0 + t2
            * (3.0 * self.k1 + t2 * (5.0 * self.k2 + t2 * (7.0 * self.k3 + t2 * 9.0 * self.k4)))
    }

    /// The widest angle from the axis (≤ π) up to which `θ_d` keeps growing: beyond it the
    /// polynomial folds back and a radius no longer names one ray.
    pub fn theta_max(&self) -> f64 {
        let step = 1e-3;
        let mut t = step;
        while t < std::f64::consts::PI {
            if self.theta_d_slope(t) <= 0.0 {
                return t - step;
            }
            t += step;
        }
        std::f64::consts::PI
    }

    /// The angle `θ` whose image radius is `theta_d` (Newton from `θ = θ_d`, within [0, π];
    /// past the lens's monotonic range it stops where the radius stops growing).
    pub fn theta_of(&self, theta_d: f64) -> f64 {
        let max = std::f64::consts::PI;
        let mut t = theta_d.min(max);
        for _ in 0..20 {
            let e = self.theta_d(t) - theta_d;
            if e.abs() < 1e-13 {
                break;
            }
            let s = self.theta_d_slope(t);
            if s <= 1e-9 {
                break;
            }
            t = (t - e / s).clamp(0.0, max);
        }
        t
    }

    /// Raw image pixel of a camera-frame point; `None` at the centre of projection or beyond
    /// the lens's monotonic range (where the radius stops growing; a real lens's polynomial
    /// turns once, so the slope's sign there is the test).
    #[inline]
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        let r = (p_c.x * p_c.x + p_c.y * p_c.y).sqrt();
        let theta = r.atan2(p_c.z);
        if p_c.norm() < 1e-12 || self.theta_d_slope(theta) <= 0.0 {
            return None;
        }
        if r < 1e-12 {
            return Some(Vector2::new(self.cx, self.cy));
        }
        let s = self.theta_d(theta) / r;
        Some(Vector2::new(
            self.fx * p_c.x * s + self.cx,
            self.fy * p_c.y * s + self.cy,
        ))
    }

    /// Unit ray through a raw image pixel (its `z` is negative past 90° from the axis).
    #[inline]
    pub fn unproject(&self, u: f64, v: f64) -> Vector3<f64> {
        let (mx, my) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let theta_d = (mx * mx + my * my).sqrt();
        if theta_d < 1e-12 {
            return Vector3::new(0.0, 0.0, 1.0);
        }
        let theta = self.theta_of(theta_d);
        let s = theta.sin() / theta_d;
        Vector3::new(mx * s, my * s, theta.cos())
    }

    /// Horizontal field of view of the image, degrees (the wider side of the principal point
    /// doubled).
    pub fn horizontal_fov_deg(&self) -> f64 {
        let half = (self.cx.max(self.width as f64 - 1.0 - self.cx) + 0.5) / self.fx;
        2.0 * self.theta_of(half).to_degrees()
    }

    /// The pinhole view sdslam tracks and maps in: same size and principal point, the focal
    /// length that shows `hfov_deg` across the image's wider half (clamped to the lens's own
    /// field and to 150°, where a pinhole's edges stretch 15x). Frames are resampled into it
    /// once on arrival ([`super::FrameRectifier`]).
    pub fn pinhole_view(&self, hfov_deg: f64) -> PinholeRadtan {
        let half_deg = (hfov_deg.min(self.horizontal_fov_deg()).min(150.0) / 2.0).max(1.0);
        let half_px = self.cx.max(self.width as f64 - 1.0 - self.cx) + 0.5;
        let f = half_px / half_deg.to_radians().tan();
        let fy = f * self.fy / self.fx;
        PinholeRadtan::pinhole(f, fy, self.cx, self.cy, self.width, self.height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A 640x480 lens with a 170° horizontal field and mild higher-order terms.
    fn lens() -> KannalaBrandt {
        let mut k = KannalaBrandt {
            fx: 1.0,
            fy: 1.0,
            cx: 319.5,
            cy: 239.5,
            k1: -0.012,
            k2: 0.004,
            k3: -0.001,
            k4: 0.0001,
            width: 640,
            height: 480,
        };
        let f = 320.0 / k.theta_d(85f64.to_radians());
        (k.fx, k.fy) = (f, f);
        k
    }

    proptest! {
        #[test]
        fn unproject_then_project_is_the_pixel(u in 0.0f64..640.0, v in 0.0f64..480.0) {
            let k = lens();
            let ray = k.unproject(u, v);
            prop_assert!((ray.norm() - 1.0).abs() < 1e-12);
            let back = k.project(&(ray * 3.7)).unwrap();
            prop_assert!((back - Vector2::new(u, v)).norm() < 1e-7, "{u} {v} -> {back:?}");
        }

        #[test]
        fn project_then_unproject_is_the_ray(theta in 0.0f64..1.5, phi in -3.0f64..3.0) {
            let k = lens();
            let p = Vector3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
            let uv = k.project(&(p * 2.0)).unwrap();
            prop_assert!((k.unproject(uv.x, uv.y) - p).norm() < 1e-9);
        }
    }

    #[test]
    fn the_test_lens_sees_170_degrees_and_more_than_180_across_the_diagonal() {
        let k = lens();
        assert!(
            (k.horizontal_fov_deg() - 170.0).abs() < 0.1,
            "{}",
            k.horizontal_fov_deg()
        );
        assert!(
            k.unproject(0.0, 0.0).z < 0.0,
            "the corner ray looks backwards"
        );
    }

    #[test]
    fn equidistant_without_coefficients_is_f_theta() {
        let k = KannalaBrandt {
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
            fx: 200.0,
            fy: 200.0,
            ..lens()
        };
        let p = Vector3::new(1.0, 0.0, 1.0); // 45°
        let uv = k.project(&p).unwrap();
        assert!((uv.x - (319.5 + 200.0 * std::f64::consts::FRAC_PI_4)).abs() < 1e-9);
        assert!(
            k.project(&Vector3::new(0.0, 0.0, -1.0)).is_none()
                || k.theta_max() >= std::f64::consts::PI
        );
    }

    #[test]
    fn the_pinhole_view_shows_the_asked_field() {
        let k = lens();
        let p = k.pinhole_view(110.0);
        let half = (320.0 / p.fx).atan().to_degrees();
        assert!((half - 55.0).abs() < 1e-6, "{half}");
        // A ray at the pinhole view's edge lands inside the fisheye image.
        let uv = k.project(&p.unproject(639.0, 479.0)).unwrap();
        assert!(uv.x < 639.0 && uv.y < 479.0);
    }
}
