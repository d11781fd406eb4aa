//! The lens of the raw images: what turns rays into pixels of the frames a source delivers.
//! sdslam tracks and maps in an undistorted pinhole view ([`super::Calibration::camera`]);
//! the lens is used where raw pixels meet rays: resampling frames into that view
//! ([`super::RectifyMap`]), rendering, and projecting into ground-truth depth maps.

use nalgebra::{Vector2, Vector3};

use super::{KannalaBrandt, PinholeRadtan};

/// A camera model of raw images.
pub trait CameraModel {
    /// Raw pixel of a camera-frame point; `None` where the model does not image it.
    fn project_raw(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>>;
    /// A ray (any length) through a raw pixel.
    fn unproject_raw(&self, u: f64, v: f64) -> Vector3<f64>;
    /// Image width and height, pixels.
    fn size(&self) -> (u32, u32);
    /// Horizontal focal length, pixels (pixels per radian near the axis).
    fn focal_x(&self) -> f64;
}

impl CameraModel for PinholeRadtan {
    fn project_raw(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        let u = self.project(p_c)?;
        Some(self.distort_pixel(u.x, u.y))
    }
    fn unproject_raw(&self, u: f64, v: f64) -> Vector3<f64> {
        let p = self.undistort_pixel(u, v);
        self.unproject(p.x, p.y)
    }
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn focal_x(&self) -> f64 {
        self.fx
    }
}

impl CameraModel for KannalaBrandt {
    fn project_raw(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.project(p_c)
    }
    fn unproject_raw(&self, u: f64, v: f64) -> Vector3<f64> {
        self.unproject(u, v)
    }
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn focal_x(&self) -> f64 {
        self.fx
    }
}

/// Either lens, by value (cheap to copy into a renderer or a rectifier).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lens {
    /// Pinhole with radial-tangential distortion.
    Pinhole(PinholeRadtan),
    /// Kannala-Brandt fisheye.
    KannalaBrandt(KannalaBrandt),
}

impl CameraModel for Lens {
    #[inline]
    fn project_raw(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        match self {
            Lens::Pinhole(c) => c.project_raw(p_c),
            Lens::KannalaBrandt(c) => c.project_raw(p_c),
        }
    }
    #[inline]
    fn unproject_raw(&self, u: f64, v: f64) -> Vector3<f64> {
        match self {
            Lens::Pinhole(c) => c.unproject_raw(u, v),
            Lens::KannalaBrandt(c) => c.unproject_raw(u, v),
        }
    }
    fn size(&self) -> (u32, u32) {
        match self {
            Lens::Pinhole(c) => c.size(),
            Lens::KannalaBrandt(c) => c.size(),
        }
    }
    fn focal_x(&self) -> f64 {
        match self {
            Lens::Pinhole(c) => c.fx,
            Lens::KannalaBrandt(c) => c.fx,
        }
    }
}
