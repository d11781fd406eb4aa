//! The ORB extractor: owns the pyramid and every scratch buffer for one image size.

use super::brief::{describe, PatternPoints};
use super::distribute::{distribute, QuadtreeScratch};
use super::fast::{detect, Corner};
use super::orientation::{circle_umax, ic_angle, MomentWeights};
use super::{Features, KeyPoint};
use crate::camera_model::PinholeRadtan;
use crate::config::OrbConfig;
use crate::image::{Pyramid, PyramidConfig};

/// Keypoints stay this far (level pixels) from the level's edge; the padded border covers the
/// orientation patch and the rotated BRIEF pattern beyond it.
const MIN_BORDER: usize = 16;
/// FAST threshold cells, level pixels (ORB-SLAM's 30 x 30).
const CELL: usize = 30;
/// Padding of pyramid levels: FAST's wide loads (3 + LANES) and the rotated pattern (< 22 px).
const PAD: usize = 3 + super::fast::LANES;

/// Features wanted per level: a geometric series over levels summing to `n` (ORB-SLAM's rule).
pub fn features_per_level(n: usize, scale_factor: f64, levels: usize) -> Vec<usize> {
    let f = 1.0 / scale_factor;
    let mut desired = n as f64 * (1.0 - f) / (1.0 - f.powi(levels as i32));
    let mut out = Vec::with_capacity(levels);
    let mut sum = 0;
    for _ in 0..levels.saturating_sub(1) {
        let k = desired.round() as usize;
        out.push(k);
        sum += k;
        desired *= f;
    }
    out.push(n.saturating_sub(sum));
    out
}

/// ORB extraction for images of one size.
pub struct OrbExtractor {
    config: OrbConfig,
    pyramid: Pyramid,
    per_level: Vec<usize>,
    moments: Box<MomentWeights>,
    pattern: Box<PatternPoints>,
    corners: Vec<Corner>,
    score_map: Vec<u8>,
    cell_counts: Vec<u32>,
    scratch: QuadtreeScratch,
    selected: Vec<u32>,
    /// Per level: level -> level-0 coordinate scale (x, y), from the actual level sizes.
    to_level0: Vec<(f64, f64)>,
}

impl OrbExtractor {
    /// Allocates everything for `width` x `height` images.
    pub fn new(width: usize, height: usize, config: &OrbConfig) -> Self {
        let pyramid = Pyramid::new(
            width,
            height,
            PyramidConfig {
                levels: config.n_levels,
                scale_factor: config.scale_factor,
                pad: PAD,
            },
        );
        let to_level0 = pyramid
            .levels
            .iter()
            .map(|l| {
                (
                    width as f64 / l.width as f64,
                    height as f64 / l.height as f64,
                )
            })
            .collect();
        let cells = (width / CELL + 2) * (height / CELL + 2);
        OrbExtractor {
            per_level: features_per_level(config.n_features, config.scale_factor, config.n_levels),
            config: config.clone(),
            moments: Box::new(MomentWeights::new(&circle_umax())),
            pattern: Box::new(PatternPoints::new()),
            // Bounded by construction: at most one corner per pixel of level 0.
            corners: Vec::with_capacity(width * height),
            score_map: vec![0; width * height],
            cell_counts: vec![0; cells],
            scratch: QuadtreeScratch::with_capacity(width * height, config.n_features),
            selected: Vec::with_capacity(config.n_features * 2),
            pyramid,
            to_level0,
        }
    }

    pub fn pyramid(&self) -> &Pyramid {
        &self.pyramid
    }

    pub fn config(&self) -> &OrbConfig {
        &self.config
    }

    /// Extracts ORB features of a tightly packed grey image into `out` (cleared first). With a
    /// camera, keypoints also get undistorted coordinates.
    pub fn extract(&mut self, gray: &[u8], camera: Option<&PinholeRadtan>, out: &mut Features) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above); the function is otherwise safe.
            unsafe { self.extract_avx2(gray, camera, out) };
            return;
        }
        self.extract_portable(gray, camera, out)
    }

    /// The whole extraction compiled for AVX2: the pyramid, blur, FAST, orientation and
    /// descriptor loops inline into it and vectorise 32 bytes wide.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn extract_avx2(&mut self, gray: &[u8], camera: Option<&PinholeRadtan>, out: &mut Features) {
        self.extract_portable(gray, camera, out)
    }

    #[inline(always)]
    fn extract_portable(
        &mut self,
        gray: &[u8],
        camera: Option<&PinholeRadtan>,
        out: &mut Features,
    ) {
        out.clear();
        self.pyramid.build(gray);
        for l in 0..self.pyramid.n_levels() {
            self.extract_level(l, out);
        }
        if let Some(cam) = camera.filter(|c| !c.is_distortion_free()) {
            for k in &mut out.keypoints {
                let u = cam.undistort_pixel(k.x as f64, k.y as f64);
                k.ux = u.x as f32;
                k.uy = u.y as f32;
            }
        }
    }

    #[inline(always)]
    fn extract_level(&mut self, l: usize, out: &mut Features) {
        let level = &self.pyramid.levels[l];
        let (w, h) = (level.width, level.height);
        if w <= 2 * MIN_BORDER + 8 || h <= 2 * MIN_BORDER + 8 {
            return;
        }
        let (x0, y0, x1, y1) = (MIN_BORDER, MIN_BORDER, w - MIN_BORDER, h - MIN_BORDER);
        let score_map = &mut self.score_map[..w * h];
        score_map.fill(0);
        self.corners.clear();
        // FAST (with non-maximum suppression) at the initial threshold everywhere, then the low
        // threshold in cells left empty.
        detect(
            level,
            self.config.ini_th_fast,
            (x0, y0, x1, y1),
            &mut self.corners,
            score_map,
        );
        let (cols, rows) = ((x1 - x0).div_ceil(CELL), (y1 - y0).div_ceil(CELL));
        let counts = &mut self.cell_counts[..cols * rows];
        counts.fill(0);
        for c in &self.corners {
            counts[(c.y as usize - y0) / CELL * cols + (c.x as usize - x0) / CELL] += 1;
        }
        if self.config.min_th_fast < self.config.ini_th_fast {
            for cy in 0..rows {
                for cx in 0..cols {
                    if counts[cy * cols + cx] == 0 {
                        let r = (
                            x0 + cx * CELL,
                            y0 + cy * CELL,
                            (x0 + (cx + 1) * CELL).min(x1),
                            (y0 + (cy + 1) * CELL).min(y1),
                        );
                        detect(
                            level,
                            self.config.min_th_fast,
                            r,
                            &mut self.corners,
                            score_map,
                        );
                    }
                }
            }
        }
        let wanted = self.per_level[l];
        // More nodes than wanted, then the strongest node winners: spread like ORB-SLAM's
        // quadtree, but strong (repeatable) corners survive node boundaries moving.
        let nodes = (wanted as f64 * self.config.quadtree_oversampling).round() as usize;
        distribute(
            &self.corners,
            (x0 as f32, y0 as f32, x1 as f32, y1 as f32),
            nodes,
            &mut self.scratch,
            &mut self.selected,
        );
        if self.selected.len() > wanted {
            let corners = &self.corners;
            self.selected
                .sort_unstable_by_key(|&i| std::cmp::Reverse(corners[i as usize].score));
            self.selected.truncate(wanted);
        }
        if self.selected.is_empty() {
            return;
        }
        self.pyramid.blur_level(l);
        let level = &self.pyramid.levels[l];
        let blurred = &self.pyramid.blurred[l];
        let (sx, sy) = self.to_level0[l];
        let scale = self.pyramid.scales[l] as f32;
        for &i in &self.selected {
            let c = self.corners[i as usize];
            let (x, y) = (c.x as isize, c.y as isize);
            let angle = ic_angle(level, x, y, &self.moments);
            out.descriptors
                .push(describe(blurred, &self.pattern, x, y, angle));
            // Level pixel centres map to level-0 positions through the resampling geometry.
            let px = ((c.x as f64 + 0.5) * sx - 0.5) as f32;
            let py = ((c.y as f64 + 0.5) * sy - 0.5) as f32;
            out.keypoints.push(KeyPoint {
                x: px,
                y: py,
                ux: px,
                uy: py,
                octave: l as u8,
                angle,
                response: c.score as f32,
                size: 31.0 * scale,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_level_counts_follow_orbslam() {
        let v = features_per_level(1000, 1.2, 8);
        assert_eq!(v.iter().sum::<usize>(), 1000);
        assert_eq!(v[0], 217);
        assert!(v.windows(2).take(6).all(|w| w[0] > w[1]));
    }
}
