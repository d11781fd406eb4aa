//! Per-pixel intensity and Scharr gradient of a keyframe image, packed so that a sample along
//! an epipolar line touches one cache line.

/// A reference pixel as the epipolar search needs it: intensity, gradient modulus (Scharr
/// normalised by 1/32, i.e. intensity units per pixel: the units of `lambda_G` and of the
/// paper's `theta = 0.23`) and quantised gradient orientation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelGradient {
    pub intensity: f32,
    pub modulus: f32,
    /// Orientation in steps of 1/128 turn (see `ORIENTATION_STEPS`).
    pub orientation: u8,
}

/// A keyframe image's intensity and Scharr gradient packed one word per pixel, row-major and
/// transposed (so walks along steep epipolar lines also read consecutive words). Buffers are
/// allocated once for the image size; 2.4 MB at 640x480.
pub struct GradientImage {
    pub width: usize,
    pub height: usize,
    /// Per pixel: bits 0-7 the code (0 when the modulus is at most the threshold given to
    /// [`compute`](Self::compute), else the orientation in 128 steps per turn in bits 1-7
    /// and bit 0 set), bits 8-15 the intensity, bits 16-31 the modulus in 1/256 intensity
    /// units. Followed by one zero word of padding.
    pub packed: Vec<u32>,
    /// `packed` transposed (index x * height + y).
    pub packed_t: Vec<u32>,
}

/// Modulus fixed-point scale in [`GradientImage::packed`].
pub const MODULUS_SCALE: f32 = 256.0;

/// Decodes (code, intensity, modulus) from a packed word.
#[inline]
pub fn unpack(v: u32) -> (u8, f32, f32) {
    (
        (v & 255) as u8,
        ((v >> 8) & 255) as f32,
        (v >> 16) as f32 * (1.0 / MODULUS_SCALE),
    )
}

/// Orientation steps per turn in [`GradientImage::packed`] codes (2.8 degrees each).
pub const ORIENTATION_STEPS: f32 = 128.0;

/// Encodes a strong gradient's orientation (see [`GradientImage::packed`]).
#[inline]
pub fn orientation_code(gx: f32, gy: f32) -> u8 {
    (quantise_orientation(fast_atan2(gy, gx)) << 1) | 1
}

/// An angle (radians) in orientation steps, 0..128.
#[inline]
pub fn quantise_orientation(a: f32) -> u8 {
    ((a * (ORIENTATION_STEPS / std::f32::consts::TAU)).round() as i32 & 127) as u8
}

/// atan2 with < 0.0015 rad error (a 3rd-order minimax polynomial on [0, 1]).
#[inline]
pub fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (mn, mx) = if ax < ay { (ax, ay) } else { (ay, ax) };
    if mx == 0.0 {
        return 0.0;
    }
    let a = mn / mx;
    let s = a * a;
    let mut r = ((-0.046_496_473 * s + 0.159_314_22) * s - 0.327_622_77) * s * a + a;
    if ay > ax {
        r = FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 {
        -r
    } else {
        r
    }
}

impl GradientImage {
    pub fn new(width: usize, height: usize) -> Self {
        GradientImage {
            width,
            height,
            packed: vec![0; width * height + 1],
            packed_t: vec![0; width * height + 1],
        }
    }

    /// Recomputes from a grey image of this size (the 1-pixel border gets zero gradient);
    /// `strong` is the modulus threshold of the codes. Does not allocate.
    pub fn compute(&mut self, gray: &[u8], strong: f32) {
        let (w, h) = (self.width, self.height);
        debug_assert_eq!(gray.len(), w * h);
        for (p, &g) in self.packed.iter_mut().zip(gray) {
            *p = (g as u32) << 8;
        }
        if w < 3 || h < 3 {
            return;
        }
        const NORM: f32 = 1.0 / 32.0;
        for y in 1..h - 1 {
            let (r0, r1, r2) = (
                &gray[(y - 1) * w..y * w],
                &gray[y * w..(y + 1) * w],
                &gray[(y + 1) * w..(y + 2) * w],
            );
            for x in 1..w - 1 {
                let v = |r: &[u8], i: usize| r[i] as i32;
                let gx = 3 * (v(r0, x + 1) - v(r0, x - 1))
                    + 10 * (v(r1, x + 1) - v(r1, x - 1))
                    + 3 * (v(r2, x + 1) - v(r2, x - 1));
                let gy = 3 * (v(r2, x - 1) - v(r0, x - 1))
                    + 10 * (v(r2, x) - v(r0, x))
                    + 3 * (v(r2, x + 1) - v(r0, x + 1));
                let (gx, gy) = (gx as f32 * NORM, gy as f32 * NORM);
                let m = (gx * gx + gy * gy).sqrt();
                let code = if m > strong {
                    orientation_code(gx, gy) as u32
                } else {
                    0
                };
                let mq = (m * MODULUS_SCALE).round().min(65535.0) as u32;
                self.packed[y * w + x] = code | ((r1[x] as u32) << 8) | (mq << 16);
            }
        }
        // Blocked transpose (cache-friendly both ways).
        const B: usize = 32;
        for y0 in (0..h).step_by(B) {
            for x0 in (0..w).step_by(B) {
                for y in y0..(y0 + B).min(h) {
                    for x in x0..(x0 + B).min(w) {
                        self.packed_t[x * h + y] = self.packed[y * w + x];
                    }
                }
            }
        }
    }

    /// Pixel (x, y) as a reference pixel.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> PixelGradient {
        let (code, intensity, modulus) = unpack(self.packed[y * self.width + x]);
        PixelGradient {
            intensity,
            modulus,
            orientation: code >> 1,
        }
    }

    /// Gradient modulus of pixel `i` (= y * width + x).
    #[inline]
    pub fn modulus(&self, i: usize) -> f32 {
        (self.packed[i] >> 16) as f32 * (1.0 / MODULUS_SCALE)
    }

    /// Bilinear intensity at a sub-pixel position at least one pixel inside.
    #[inline]
    pub fn intensity_at(&self, x: f32, y: f32) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (ax, ay) = (x - x0, y - y0);
        let i = y0 as usize * self.width + x0 as usize;
        let p = &self.packed;
        let g = |j: usize| ((p[j] >> 8) & 255) as f32;
        let top = g(i) + ax * (g(i + 1) - g(i));
        let bottom = g(i + self.width) + ax * (g(i + self.width + 1) - g(i + self.width));
        top + ay * (bottom - top)
    }

    /// Bilinear (intensity, modulus) at a sub-pixel position at least one pixel inside.
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> (f32, f32) {
        let (x0, y0) = (x.floor(), y.floor());
        let (ax, ay) = (x - x0, y - y0);
        let i = y0 as usize * self.width + x0 as usize;
        let p = &self.packed;
        let (a, b, c, d) = (
            unpack(p[i]),
            unpack(p[i + 1]),
            unpack(p[i + self.width]),
            unpack(p[i + self.width + 1]),
        );
        let w00 = (1.0 - ax) * (1.0 - ay);
        let w01 = ax * (1.0 - ay);
        let w10 = (1.0 - ax) * ay;
        let w11 = ax * ay;
        (
            w00 * a.1 + w01 * b.1 + w10 * c.1 + w11 * d.1,
            w00 * a.2 + w01 * b.2 + w10 * c.2 + w11 * d.2,
        )
    }
}

/// An image's contrast against `reference` grey levels of spread (5th to 95th percentile),
/// clamped to [1/8, 1]; 1 when `reference` is 0 (off).
pub fn contrast_scale(gray: &[u8], reference: f64) -> f32 {
    if reference <= 0.0 || gray.is_empty() {
        return 1.0;
    }
    let mut hist = [0u32; 256];
    for &v in gray {
        hist[v as usize] += 1;
    }
    let n = gray.len() as u64;
    let at = |q: u64| {
        let want = (n * q).div_ceil(100).max(1);
        let mut seen = 0u64;
        hist.iter()
            .position(|&c| {
                seen += c as u64;
                seen >= want
            })
            .unwrap_or(255)
    };
    let spread = at(95).saturating_sub(at(5)) as f64;
    (spread / reference).clamp(0.125, 1.0) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contrast_is_the_spread_against_the_reference_clamped() {
        // A ramp 0..=255: 5th to 95th percentile about 230 grey levels apart.
        let ramp: Vec<u8> = (0..256 * 40).map(|i| (i / 40) as u8).collect();
        assert_eq!(contrast_scale(&ramp, 100.0), 1.0);
        assert_eq!(contrast_scale(&ramp, 0.0), 1.0);
        // A quarter of the light: the spread is a quarter.
        let dim: Vec<u8> = ramp.iter().map(|&v| v / 4).collect();
        let c = contrast_scale(&dim, 100.0);
        assert!((c - 0.57).abs() < 0.02, "{c}");
        let flat = vec![40u8; 1000];
        assert_eq!(contrast_scale(&flat, 100.0), 0.125);
    }

    #[test]
    fn ramp_has_its_slope_in_intensity_units_per_pixel() {
        let (w, h) = (8, 6);
        let gray: Vec<u8> = (0..w * h)
            .map(|i| ((i % w) * 7 + (i / w) * 3) as u8)
            .collect();
        let mut g = GradientImage::new(w, h);
        g.compute(&gray, 5.0);
        let p = g.at(3, 2);
        assert!(
            (p.modulus - (49.0f32 + 9.0).sqrt()).abs() < 1.0 / 256.0,
            "{p:?}"
        );
        assert_eq!(p.orientation, orientation_code(7.0, 3.0) >> 1);
        assert_eq!(g.at(0, 0).modulus, 0.0);
        assert_eq!(g.packed[0] & 255, 0);
        let (code, i, m) = unpack(g.packed[2 * w + 3]);
        assert_eq!(code, orientation_code(7.0, 3.0));
        assert_eq!(i, gray[2 * w + 3] as f32);
        assert!((m - p.modulus).abs() < 1.0 / 256.0);
        let (i, m) = g.sample(3.5, 2.0);
        assert!((i - (3.5 * 7.0 + 6.0)).abs() < 1e-4 && (m - p.modulus).abs() < 1e-3);
    }

    #[test]
    fn fast_atan2_matches_std() {
        for i in 0..3600 {
            let a = (i as f32 / 10.0 - 180.0).to_radians();
            let (y, x) = (a.sin() * 3.0, a.cos() * 3.0);
            let d = (fast_atan2(y, x) - y.atan2(x)).abs();
            assert!(
                d < 0.0015 || (d - std::f32::consts::TAU).abs() < 0.0015,
                "{a} {d}"
            );
        }
    }

    #[test]
    fn scharr_noise_variance_ratio_is_theta() {
        // theta = var(G-component) / var(I) for white noise: (2*(9+100+9))/32^2 = 0.2305.
        let ratio = 2.0 * (9.0 + 100.0 + 9.0) / (32.0f64 * 32.0);
        assert!((ratio - 0.23).abs() < 0.001);
    }
}
