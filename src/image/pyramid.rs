//! The ORB scale pyramid, preallocated for one image size and rebuilt in place every frame.

use super::{gaussian_blur_7x7, PaddedImage};

/// Pyramid geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct PyramidConfig {
    pub levels: usize,
    pub scale_factor: f64,
    /// Border kept around every level (must cover the rotated BRIEF pattern).
    pub pad: usize,
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
    /// Per destination column: source index and weight (8-bit) for the horizontal resample.
    xmap: Vec<Vec<(u32, u16)>>,
    ymap: Vec<Vec<(u32, u16)>>,
    row_tmp: Vec<u16>,
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
        Pyramid {
            config,
            levels,
            blurred,
            scales,
            inv_scales,
            sigma2,
            inv_sigma2,
            tmp: Vec::with_capacity((width + 8) * (height + 8)),
            xmap,
            ymap,
            row_tmp: Vec::with_capacity(width * 2),
        }
    }

    pub fn n_levels(&self) -> usize {
        self.levels.len()
    }

    /// Rebuilds every level (and blurred level) from a tightly packed level-0 image.
    #[inline(always)]
    pub fn build(&mut self, gray: &[u8]) {
        self.levels[0].copy_from(gray);
        for l in 1..self.levels.len() {
            let (prev, cur) = self.levels.split_at_mut(l);
            resample(
                &prev[l - 1],
                &mut cur[0],
                &self.xmap[l],
                &self.ymap[l],
                &mut self.row_tmp,
            );
            cur[0].fill_border();
        }
    }

    /// Blurs every level (needed for descriptors only).
    pub fn blur(&mut self) {
        for l in 0..self.levels.len() {
            gaussian_blur_7x7(&self.levels[l], &mut self.blurred[l], &mut self.tmp);
        }
    }
}

/// Bilinear downsampling with precomputed maps: blend the two source rows (contiguous, SIMD),
/// then resample the blended row horizontally. `tmp` holds one blended row in 8.8 fixed point.
#[inline(always)]
fn resample(
    src: &PaddedImage,
    dst: &mut PaddedImage,
    xmap: &[(u32, u16)],
    ymap: &[(u32, u16)],
    tmp: &mut Vec<u16>,
) {
    let sw = src.width;
    // One spare entry: one-pixel-wide sources still read x0 + 1 (with weight 0).
    tmp.resize(sw + 1, 0);
    for (y, &(y0, wy)) in ymap.iter().enumerate() {
        let y0 = y0 as usize;
        let (a, b) = (src.row(y0), src.row((y0 + 1).min(src.height - 1)));
        let (wa, wb) = (256 - wy, wy);
        for ((t, &pa), &pb) in tmp.iter_mut().zip(a).zip(b) {
            *t = pa as u16 * wa + pb as u16 * wb;
        }
        let out = dst.row_mut(y);
        // The maps keep x0 + 1 inside the row (x0 <= max(width - 2, 0)).
        for (o, &(x0, wx)) in out.iter_mut().zip(xmap) {
            let pair = &tmp[x0 as usize..x0 as usize + 2];
            let v = pair[0] as u32 * (256 - wx as u32) + pair[1] as u32 * wx as u32;
            *o = ((v + (1 << 15)) >> 16) as u8;
        }
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
