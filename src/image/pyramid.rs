//! The ORB scale pyramid, preallocated for one image size and rebuilt in place every frame.

use wide::{i16x8, u8x16};

use super::{gaussian_blur_7x7, PaddedImage};

/// Pyramid geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct PyramidConfig {
    pub levels: usize,
    pub scale_factor: f64,
    /// Border kept around every level (must cover the rotated BRIEF pattern).
    pub pad: usize,
    /// Pixels of that border filled by reflection each build (readers reaching further out
    /// only need the memory, not its values).
    pub filled: usize,
}

/// Levels (and their blurred copies) of one image, with per-level scale data.
pub struct Pyramid {
    pub config: PyramidConfig,
    pub levels: Vec<PaddedImage>,
    pub blurred: Vec<PaddedImage>,
    /// scale^l: multiply level coordinates by this to get level-0 coordinates.
    pub scales: Vec<f64>,
    pub inv_scales: Vec<f64>,
    /// sigma^2 of a level = scale^2 (measurement noise grows with the octave).
    pub sigma2: Vec<f64>,
    pub inv_sigma2: Vec<f64>,
    tmp: Vec<u16>,
    ymap: Vec<Vec<(u32, u16)>>,
    /// Per level: the horizontal resample as groups of 8 outputs (byte shuffle and weights).
    xgroups: Vec<Vec<XGroup>>,
    /// One vertically blended source row, with slack for 16-byte reads.
    row_tmp: Vec<u8>,
}

/// 8 horizontally resampled outputs: output j blends source bytes `base + a[2j + LOW]` and
/// `base + b[2j + LOW]` by `wa[j]` and `wb[j]` (7-bit fixed point, summing to 128). The
/// other byte of each pair is 0x80, which a byte shuffle turns into zero: shuffling the 16
/// source bytes by `a` gives the first bytes already widened to 16 bits (SSSE3 and NEON
/// alike).
#[derive(Clone, Copy, Debug)]
struct XGroup {
    base: u32,
    a: [u8; 16],
    b: [u8; 16],
    wa: [i16; 8],
    wb: [i16; 8],
}

/// The byte of a 16-bit lane that holds its low half.
const LOW: usize = if cfg!(target_endian = "little") { 0 } else { 1 };

/// Groups of 8 outputs for one horizontal map. A whole-pixel sample is written as the pixel
/// twice at half weight (the same sums as when the weights were signed bytes).
fn x_groups(xmap: &[(u32, u16)]) -> Vec<XGroup> {
    xmap.chunks(8)
        .map(|c| {
            let base = c[0].0;
            let mut g = XGroup {
                base,
                // Outputs past the map's end read byte 0 at weight 0.
                a: std::array::from_fn(|i| if i % 2 == LOW { 0 } else { 0x80 }),
                b: std::array::from_fn(|i| if i % 2 == LOW { 0 } else { 0x80 }),
                wa: [0; 8],
                wb: [0; 8],
            };
            for (j, &(x0, w8)) in c.iter().enumerate() {
                let w7 = (w8 as u32).div_ceil(2);
                let o = (x0 - base) as u8;
                let (a, b, wa, wb) = match w7 {
                    0 => (o, o, 64, 64),
                    128.. => (o + 1, o + 1, 64, 64),
                    w => (o, o + 1, 128 - w as i16, w as i16),
                };
                (g.a[2 * j + LOW], g.b[2 * j + LOW]) = (a, b);
                (g.wa[j], g.wb[j]) = (wa, wb);
            }
            g
        })
        .collect()
}

impl Pyramid {
    /// Allocates every level for `width` x `height` input.
    pub fn new(width: usize, height: usize, config: PyramidConfig) -> Self {
        let n = config.levels.max(1);
        let mut scales = Vec::with_capacity(n);
        let mut s = 1.0;
        for _ in 0..n {
            scales.push(s);
            s *= config.scale_factor;
        }
        let inv_scales: Vec<f64> = scales.iter().map(|s| 1.0 / s).collect();
        let sigma2: Vec<f64> = scales.iter().map(|s| s * s).collect();
        let inv_sigma2 = sigma2.iter().map(|s| 1.0 / s).collect();
        let sizes: Vec<(usize, usize)> = inv_scales
            .iter()
            .map(|is| {
                (
                    ((width as f64 * is).round() as usize).max(1),
                    ((height as f64 * is).round() as usize).max(1),
                )
            })
            .collect();
        let levels: Vec<PaddedImage> = sizes
            .iter()
            .map(|&(w, h)| PaddedImage::new(w, h, config.pad))
            .collect();
        let blurred = levels.clone();
        // Bilinear resample maps from level l-1 to level l (as cv::resize INTER_LINEAR).
        let map = |src: usize, dst: usize| -> Vec<(u32, u16)> {
            let r = src as f64 / dst as f64;
            (0..dst)
                .map(|i| {
                    let f = ((i as f64 + 0.5) * r - 0.5).clamp(0.0, (src - 1) as f64);
                    let i0 = (f.floor() as usize).min(src.saturating_sub(2));
                    let w = ((f - i0 as f64) * 256.0).round().min(256.0) as u16;
                    (i0 as u32, w)
                })
                .collect()
        };
        let mut xmap = vec![Vec::new()];
        let mut ymap = vec![Vec::new()];
        for l in 1..n {
            xmap.push(map(sizes[l - 1].0, sizes[l].0));
            ymap.push(map(sizes[l - 1].1, sizes[l].1));
        }
        let xgroups = xmap.iter().map(|m| x_groups(m)).collect();
        Pyramid {
            config,
            levels,
            blurred,
            scales,
            inv_scales,
            sigma2,
            inv_sigma2,
            tmp: Vec::with_capacity((width + 8) * (height + 8)),
            ymap,
            xgroups,
            row_tmp: Vec::with_capacity(width + 32),
        }
    }

    pub fn n_levels(&self) -> usize {
        self.levels.len()
    }

    /// Rebuilds every level (and blurred level) from a tightly packed level-0 image.
    #[inline(always)]
    pub fn build(&mut self, gray: &[u8]) {
        let filled = self.config.filled;
        self.levels[0].copy_interior_from(gray);
        self.levels[0].fill_border_width(filled);
        for l in 1..self.levels.len() {
            let (prev, cur) = self.levels.split_at_mut(l);
            resample(
                &prev[l - 1],
                &mut cur[0],
                &self.xgroups[l],
                &self.ymap[l],
                &mut self.row_tmp,
            );
            cur[0].fill_border_width(filled);
        }
    }

    /// Blurs every level (needed for descriptors only).
    pub fn blur(&mut self) {
        for l in 0..self.levels.len() {
            let filled = self.config.filled;
            gaussian_blur_7x7(&self.levels[l], &mut self.blurred[l], &mut self.tmp, filled);
        }
    }
}

/// Bilinear downsampling with precomputed maps: blend the two source rows (contiguous, SIMD),
/// then resample the blended row horizontally, 8 outputs per byte shuffle (SSSE3 or NEON,
/// one source for both).
#[inline(always)]
fn resample(
    src: &PaddedImage,
    dst: &mut PaddedImage,
    groups: &[XGroup],
    ymap: &[(u32, u16)],
    tmp: &mut Vec<u8>,
) {
    let sw = src.width;
    // Slack: each group reads 16 bytes from its base (<= sw - 1).
    tmp.resize(sw + 16, 0);
    let (dw, dpad, dstride) = (dst.width, dst.pad, dst.stride);
    for (y, &(y0, wy)) in ymap.iter().enumerate() {
        let y0 = y0 as usize;
        let (a, b) = (src.row(y0), src.row((y0 + 1).min(src.height - 1)));
        let (wa, wb) = (256 - wy, wy);
        for ((t, &pa), &pb) in tmp.iter_mut().zip(a).zip(b) {
            *t = ((pa as u16 * wa + pb as u16 * wb + 128) >> 8) as u8;
        }
        // The row and up to 7 bytes of its right border (refilled after the build).
        let start = (y + dpad) * dstride + dpad;
        let out = &mut dst.data[start..start + dw + dpad.min(8)];
        horizontal(tmp, groups, out, dw);
    }
}

/// One row of the horizontal resample: `out[..n]` from the groups (`out` may have up to 7
/// bytes of slack past `n`, which are overwritten).
#[inline(always)]
fn horizontal(tmp: &[u8], groups: &[XGroup], out: &mut [u8], n: usize) {
    if out.len() >= groups.len() * 8 && tmp.len() >= 16 {
        horizontal_lanes(tmp, groups, out);
    } else {
        horizontal_scalar(tmp, groups, out, n)
    }
}

fn horizontal_scalar(tmp: &[u8], groups: &[XGroup], out: &mut [u8], n: usize) {
    for (g, grp) in groups.iter().enumerate() {
        let src = &tmp[grp.base as usize..grp.base as usize + 16];
        for j in 0..8.min(n - 8 * g) {
            let a = src[grp.a[2 * j + LOW] as usize] as i32 * grp.wa[j] as i32;
            let b = src[grp.b[2 * j + LOW] as usize] as i32 * grp.wb[j] as i32;
            out[8 * g + j] = ((a + b + 64) >> 7) as u8;
        }
    }
}

/// [`horizontal_scalar`] on `wide`'s 128-bit vectors (SSE on x86-64, NEON on aarch64): two
/// byte shuffles gather each output's two source bytes, widened to 16 bits, and the blend
/// runs in 16-bit lanes (at most 255 x 128 + 64). Every group writes 8 bytes (`out` has the
/// slack).
fn horizontal_lanes(tmp: &[u8], groups: &[XGroup], out: &mut [u8]) {
    let round = i16x8::splat(64);
    for (g, grp) in groups.iter().enumerate() {
        let base = grp.base as usize;
        let Ok(src) = <[u8; 16]>::try_from(&tmp[base..base + 16]) else {
            continue;
        };
        let src = u8x16::new(src);
        let wide = |idx: &[u8; 16]| -> i16x8 { bytemuck::cast(src.shuffle(u8x16::new(*idx))) };
        let (a, b) = (wide(&grp.a), wide(&grp.b));
        let sum = a * i16x8::new(grp.wa) + b * i16x8::new(grp.wb) + round;
        let px = u8x16::narrow_i16x8(sum >> 7u32, i16x8::ZERO).to_array();
        out[8 * g..8 * g + 8].copy_from_slice(&px[..8]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> PyramidConfig {
        PyramidConfig {
            levels: 8,
            scale_factor: 1.2,
            pad: 24,
            filled: 24,
        }
    }

    #[test]
    fn level_sizes_follow_the_scale_factor() {
        let p = Pyramid::new(640, 480, cfg());
        let sizes: Vec<_> = p.levels.iter().map(|l| (l.width, l.height)).collect();
        assert_eq!(sizes[0], (640, 480));
        assert_eq!(sizes[1], (533, 400));
        assert_eq!(sizes[7], (179, 134));
        assert!((p.sigma2[1] - 1.44).abs() < 1e-12);
    }

    #[test]
    fn flat_image_stays_flat_and_ramp_is_preserved() {
        let mut p = Pyramid::new(64, 48, cfg());
        p.build(&[77; 64 * 48]);
        assert!(p
            .levels
            .iter()
            .all(|l| (0..l.height).all(|y| l.row(y).iter().all(|&v| v == 77))));
        let ramp: Vec<u8> = (0..64 * 48).map(|i| (i % 64 * 3) as u8).collect();
        p.build(&ramp);
        let l1 = &p.levels[1];
        // Level-1 pixel x maps to level-0 position (x + 0.5) * 1.2 - 0.5.
        let x = 20usize;
        let expect = ((x as f64 + 0.5) * 64.0 / l1.width as f64 - 0.5) * 3.0;
        assert!(
            (l1.at(x as isize, 10) as f64 - expect).abs() <= 1.0,
            "{} vs {expect}",
            l1.at(x as isize, 10)
        );
    }

    #[test]
    fn byte_shuffle_resample_equals_the_scalar_one() {
        let p = Pyramid::new(640, 480, cfg());
        let tmp: Vec<u8> = (0..640 + 16).map(|i| (i * 37 % 251) as u8).collect();
        for g in &p.xgroups[1..] {
            let n = (g.len() * 8).saturating_sub(3);
            let (mut a, mut b) = (vec![0u8; g.len() * 8], vec![0u8; g.len() * 8]);
            horizontal(&tmp, g, &mut a, n);
            horizontal_scalar(&tmp, g, &mut b, n);
            assert_eq!(a[..n], b[..n]);
        }
    }

    #[test]
    fn rebuild_does_not_reallocate() {
        let mut p = Pyramid::new(320, 240, cfg());
        let img: Vec<u8> = (0..320 * 240).map(|i| (i * 7 % 256) as u8).collect();
        p.build(&img);
        p.blur();
        let ptrs: Vec<_> = p.levels.iter().map(|l| l.data.as_ptr()).collect();
        p.build(&img);
        p.blur();
        assert_eq!(
            ptrs,
            p.levels.iter().map(|l| l.data.as_ptr()).collect::<Vec<_>>()
        );
    }
}
