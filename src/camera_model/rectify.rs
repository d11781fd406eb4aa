//! Rectification map: built once per calibration, then remaps every raw image into the
//! undistorted pinhole view (the same K for a pinhole lens, the chosen view for a fisheye)
//! with bilinear interpolation, into a caller buffer.

use super::{Calibration, CameraModel, PinholeRadtan};

/// Resamples whole frames into the pinhole view, into one reused buffer; a distortion-free
/// pinhole camera's frames pass through untouched. The one rectification step of every frame consumer
/// ([`crate::runtime::System::process_frame`], `sdslam densify`).
pub struct FrameRectifier {
    map: Option<RectifyMap>,
    out: sdslam_camera::Frame,
}

impl FrameRectifier {
    pub fn new(calib: &Calibration) -> Self {
        let camera = &calib.camera;
        let map = match &calib.fisheye {
            Some(lens) => Some(RectifyMap::between(camera, lens)),
            None => (!camera.is_distortion_free()).then(|| RectifyMap::new(camera)),
        };
        FrameRectifier {
            map,
            out: sdslam_camera::Frame::new(camera.width, camera.height),
        }
    }

    /// `frame` in the undistorted geometry (grey, and colour when it has it).
    pub fn apply<'a>(&'a mut self, frame: &'a sdslam_camera::Frame) -> &'a sdslam_camera::Frame {
        let Some(map) = &self.map else {
            return frame;
        };
        map.remap_gray(&frame.gray, &mut self.out.gray);
        if frame.has_color {
            map.remap_rgb(&frame.rgb, &mut self.out.rgb);
        }
        self.out.timestamp = frame.timestamp;
        self.out.index = frame.index;
        self.out.has_color = frame.has_color;
        self.out.arrival = frame.arrival;
        &self.out
    }
}

/// For each output pixel, the top-left source pixel and bilinear weights, precomputed.
pub struct RectifyMap {
    width: u32,
    height: u32,
    /// Per output pixel: index of the top-left source pixel, or `u32::MAX` when outside.
    index: Vec<u32>,
    /// Per output pixel: bilinear weights (w00, w10, w01, w11) in 1/65536 units.
    weights: Vec<[u32; 4]>,
}

impl RectifyMap {
    /// Builds the map of `camera` (the output uses the same K without distortion).
    pub fn new(camera: &PinholeRadtan) -> Self {
        Self::between(&camera.undistorted(), camera)
    }

    /// Builds the map from raw images of `lens` into the pinhole `view` (same size): each
    /// view pixel's ray, projected through the lens.
    pub fn between(view: &PinholeRadtan, lens: &impl CameraModel) -> Self {
        let (w, h) = (view.width, view.height);
        let n = w as usize * h as usize;
        let mut index = vec![u32::MAX; n];
        let mut weights = vec![[0u32; 4]; n];
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let Some(d) = lens.project_raw(&view.unproject(x as f64, y as f64)) else {
                    continue;
                };
                if d.x < 0.0 || d.y < 0.0 || d.x > (w - 1) as f64 || d.y > (h - 1) as f64 {
                    continue;
                }
                let (x0, y0) = (
                    d.x.floor().min((w.max(2) - 2) as f64),
                    d.y.floor().min((h.max(2) - 2) as f64),
                );
                let (fx, fy) = (d.x - x0, d.y - y0);
                // 8-bit fractions per axis; the four products sum to exactly 65536.
                let (wx, wy) = ((fx * 256.0).round() as u32, (fy * 256.0).round() as u32);
                index[i] = y0 as u32 * w + x0 as u32;
                weights[i] = [
                    (256 - wx) * (256 - wy),
                    wx * (256 - wy),
                    (256 - wx) * wy,
                    wx * wy,
                ];
            }
        }
        RectifyMap {
            width: w,
            height: h,
            index,
            weights,
        }
    }

    /// Remaps a grey image; pixels with no source become 0. `src` and `dst` are `w * h`.
    pub fn remap_gray(&self, src: &[u8], dst: &mut [u8]) {
        let w = self.width as usize;
        debug_assert_eq!(src.len(), w * self.height as usize);
        for ((d, &i), wt) in dst.iter_mut().zip(&self.index).zip(&self.weights) {
            if i == u32::MAX {
                *d = 0;
                continue;
            }
            let i = i as usize;
            let v = wt[0] * src[i] as u32
                + wt[1] * src[i + 1] as u32
                + wt[2] * src[i + w] as u32
                + wt[3] * src[i + w + 1] as u32;
            *d = ((v + 32768) >> 16) as u8;
        }
    }

    /// Remaps an interleaved RGB image (one branch and one pair of row slices per pixel,
    /// not per channel).
    pub fn remap_rgb(&self, src: &[u8], dst: &mut [u8]) {
        let w = self.width as usize;
        for ((d, &i), wt) in dst.chunks_exact_mut(3).zip(&self.index).zip(&self.weights) {
            if i == u32::MAX {
                d.fill(0);
                continue;
            }
            let i = 3 * i as usize;
            let (a, b) = (&src[i..i + 6], &src[i + 3 * w..i + 3 * w + 6]);
            for c in 0..3 {
                let v = wt[0] * a[c] as u32
                    + wt[1] * a[3 + c] as u32
                    + wt[2] * b[c] as u32
                    + wt[3] * b[3 + c] as u32;
                d[c] = ((v + 32768) >> 16) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_for_distortion_free_camera() {
        let c = PinholeRadtan::pinhole(100.0, 100.0, 15.5, 11.5, 32, 24);
        let src: Vec<u8> = (0..32 * 24).map(|i| (i % 251) as u8).collect();
        let mut dst = vec![0; src.len()];
        RectifyMap::new(&c).remap_gray(&src, &mut dst);
        assert_eq!(src, dst);
    }

    #[test]
    fn rectified_image_puts_straight_lines_back() {
        // Render a distorted image of a vertical bright line at undistorted x = 200, then check
        // that rectification brings it back to column 200 on every row.
        let c = PinholeRadtan {
            k1: -0.28,
            k2: 0.07,
            ..PinholeRadtan::pinhole(458.0, 457.0, 367.0, 248.0, 752, 480)
        };
        let (w, h) = (752usize, 480usize);
        let mut src = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let u = c.undistort_pixel(x as f64, y as f64);
                let d = (u.x - 200.0).abs();
                src[y * w + x] = (255.0 * (1.0 - d / 3.0).max(0.0)) as u8;
            }
        }
        let mut dst = vec![0; w * h];
        RectifyMap::new(&c).remap_gray(&src, &mut dst);
        for y in (60..420).step_by(40) {
            let row = &dst[y * w..(y + 1) * w];
            let best = (0..w).max_by_key(|&x| row[x]).unwrap();
            assert!((best as i64 - 200).abs() <= 1, "row {y}: peak at {best}");
        }
    }
}
