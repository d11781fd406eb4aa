//! Guided matching used by tracking and mapping: window search (initialisation), search by
//! projection (motion model and local map), and epipolar search (triangulation). Thresholds are
//! ORB-SLAM's (TH_LOW 50, TH_HIGH 100, ratio tests) and every search can apply the rotation-
//! consistency histogram.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::{hamming, FeatureGrid, RotationHistogram, TH_HIGH, TH_LOW};
use crate::features::{Descriptor, FeatureView, KeyPoint};

/// The window search of initialisation: pixels around each reference keypoint, the ratio
/// test, and the rotation-consistency histogram.
#[derive(Clone, Copy, Debug)]
pub struct WindowSearch {
    pub window: f32,
    pub ratio: f32,
    pub check_orientation: bool,
}

/// Search by projection: radius in pixels at level 0 (scaled by each level's factor) and the
/// ratio test.
#[derive(Clone, Copy, Debug)]
pub struct ProjectionSearch<'a> {
    pub scales: &'a [f64],
    pub radius: f32,
    pub ratio: f32,
}

/// Epipolar search between two keyframes: `f21` maps undistorted pixels of 1 to lines in 2,
/// the epipole in 2 (when in front of camera 1), sigma² per level, and the rotation check.
#[derive(Clone, Copy, Debug)]
pub struct EpipolarSearch<'a> {
    pub f21: &'a Matrix3<f64>,
    pub epipole2: Option<Vector2<f64>>,
    pub sigma2: &'a [f64],
    pub check_orientation: bool,
}

/// Matches keypoints of a reference frame to a new frame within a window around where each
/// reference keypoint was last matched (`centres`, one per reference keypoint: ORB-SLAM's
/// "previously matched" positions, so the window follows the features while the image moves
/// more than a window between the reference and the current frame, as on a turn), at the same
/// pyramid level (ORB-SLAM uses only the finest level and doubles the
/// feature count during initialisation instead; matching every level within its octave gives the
/// same density without a second extractor). Returns, per reference keypoint, the matched index
/// in the new frame.
pub fn search_for_initialization(
    reference: FeatureView,
    centres: &[[f32; 2]],
    current: FeatureView,
    cur_grid: &FeatureGrid,
    search: WindowSearch,
    out: &mut Vec<Option<u32>>,
) -> usize {
    let (ref_kps, ref_desc) = (reference.keypoints, reference.descriptors);
    let (cur_kps, cur_desc) = (current.keypoints, current.descriptors);
    let WindowSearch {
        window,
        ratio,
        check_orientation,
    } = search;
    out.clear();
    out.resize(ref_kps.len(), None);
    let mut best_of_cur: Vec<(u32, u32)> = vec![(u32::MAX, u32::MAX); cur_kps.len()]; // (dist, ref idx)
    let mut cand = Vec::new();
    let mut rot = RotationHistogram::default();
    for (i, k1) in ref_kps.iter().enumerate() {
        let [cx, cy] = centres.get(i).copied().unwrap_or([k1.ux, k1.uy]);
        cur_grid.in_area(cur_kps, cx, cy, window, k1.octave, k1.octave, &mut cand);
        let (mut best, mut second, mut best_j) = (u32::MAX, u32::MAX, u32::MAX);
        for &j in &cand {
            let d = hamming(&ref_desc[i], &cur_desc[j as usize]);
            if best_of_cur[j as usize].0 <= d {
                continue;
            }
            if d < best {
                second = best;
                best = d;
                best_j = j;
            } else if d < second {
                second = d;
            }
        }
        if best <= TH_LOW && (best as f32) < ratio * second as f32 {
            // A better claim on best_j replaces the previous one.
            let (_, prev) = best_of_cur[best_j as usize];
            if prev != u32::MAX {
                out[prev as usize] = None;
            }
            best_of_cur[best_j as usize] = (best, i as u32);
            out[i] = Some(best_j);
        }
    }
    if check_orientation {
        for (i, m) in out.iter().enumerate() {
            if let Some(j) = m {
                rot.add(ref_kps[i].angle, cur_kps[*j as usize].angle, i as u32);
            }
        }
        rot.for_each_rejected(|i| out[i as usize] = None);
    }
    out.iter().filter(|m| m.is_some()).count()
}

/// A map point prepared for projection into a frame.
#[derive(Clone, Copy, Debug)]
pub struct ProjectedPoint {
    /// Caller's identifier (index into its own list).
    pub id: u32,
    pub uv: Vector2<f32>,
    /// Predicted pyramid level.
    pub level: u8,
    pub descriptor: Descriptor,
    /// Search radius multiplier (ORB-SLAM widens it for points seen head-on).
    pub radius_factor: f32,
}

/// For each projected point, the best unmatched keypoint within `radius * scale(level) *
/// radius_factor` whose octave is within one level of the prediction, by Hamming distance
/// (<= TH_HIGH, ratio `ratio` against the second best on another level... as ORB-SLAM). Writes
/// the matched point id per keypoint into `matches` (only where `None`). Returns new matches.
pub fn search_by_projection(
    points: &[ProjectedPoint],
    frame: FeatureView,
    grid: &FeatureGrid,
    search: ProjectionSearch,
    matches: &mut [Option<u32>],
    scratch: &mut Vec<u32>,
) -> usize {
    let (kps, desc) = (frame.keypoints, frame.descriptors);
    let ProjectionSearch {
        scales,
        radius,
        ratio,
    } = search;
    let mut n = 0;
    let top = scales.len().saturating_sub(1) as u8;
    for p in points {
        let r = radius * scales[p.level as usize] as f32 * p.radius_factor;
        let (lo, hi) = (p.level.saturating_sub(1), (p.level + 1).min(top));
        grid.in_area(kps, p.uv.x, p.uv.y, r, lo, hi, scratch);
        let (mut best, mut second, mut best_j, mut best_level, mut second_level) =
            (u32::MAX, u32::MAX, usize::MAX, 0u8, 0u8);
        for &j in scratch.iter() {
            let j = j as usize;
            if matches[j].is_some() {
                continue;
            }
            let d = hamming(&p.descriptor, &desc[j]);
            if d < best {
                second = best;
                second_level = best_level;
                best = d;
                best_j = j;
                best_level = kps[j].octave;
            } else if d < second {
                second = d;
                second_level = kps[j].octave;
            }
        }
        if best <= TH_HIGH && best_j != usize::MAX {
            // Ratio test only between candidates of the same level (different levels of the same
            // corner look alike legitimately).
            if best_level == second_level && best as f32 > ratio * second as f32 {
                continue;
            }
            matches[best_j] = Some(p.id);
            n += 1;
        }
    }
    n
}

/// Whether `k2` may match a keypoint whose epipolar line in keyframe 2 is `l` (`ln` the norm
/// of its first two coordinates): within 3.84 sigma² of its level from the line, and not
/// within 10 sigma of the epipole (no parallax there).
#[inline]
fn on_epipolar_line(
    k2: &KeyPoint,
    l: &Vector3<f64>,
    ln: f64,
    epipole2: Option<Vector2<f64>>,
    sigma2: &[f64],
) -> bool {
    let s2 = sigma2[k2.octave as usize];
    if let Some(e) = epipole2 {
        let (dx, dy) = (k2.ux as f64 - e.x, k2.uy as f64 - e.y);
        if dx * dx + dy * dy < 100.0 * s2 {
            return false;
        }
    }
    let dist = (l.x * k2.ux as f64 + l.y * k2.uy as f64 + l.z) / ln;
    dist * dist < 3.84 * s2
}

/// Each keypoint of keyframe 2 goes to the keypoint of 1 that found it at the smallest
/// distance (the first of equals).
struct Claims {
    best: Vec<u32>,
    by: Vec<Option<u32>>,
}

impl Claims {
    fn new(n2: usize) -> Self {
        Claims {
            best: vec![u32::MAX; n2],
            by: vec![None; n2],
        }
    }

    /// Keypoint `i` of 1 found `j` of 2 (`usize::MAX`: none) at distance `d`.
    fn offer(&mut self, j: usize, d: u32, i: usize) {
        if j != usize::MAX && d < self.best[j] {
            self.best[j] = d;
            self.by[j] = Some(i as u32);
        }
    }

    /// The pairs (i1, i2) in the order of keyframe 2, appended to `out`.
    fn pairs_into(&self, out: &mut Vec<(u32, u32)>) {
        for (j, c) in self.by.iter().enumerate() {
            if let Some(i) = c {
                out.push((*i, j as u32));
            }
        }
    }
}

/// Epipolar search between two keyframes for triangulation: for each keypoint of keyframe 1
/// without a map point, the best keypoint of keyframe 2 (also free) whose distance to the
/// epipolar line is below 3.84 sigma² of its level and that is not too close to the epipole.
/// `f21` maps undistorted pixels of 1 to lines in 2. Returns pairs (i1, i2).
///
/// Each line is first measured against every free keypoint of 2 at once (a loop the compiler
/// vectorises), and descriptors are compared only within the band of the widest level: about
/// 5% of the keypoints instead of all of them. The exact tests then run on those, in index
/// order, so the pairs are those of a full scan.
pub fn search_for_triangulation(
    one: FeatureView,
    free1: &[bool],
    two: FeatureView,
    free2: &[bool],
    search: &EpipolarSearch,
    out: &mut Vec<(u32, u32)>,
) {
    let (kps1, desc1) = (one.keypoints, one.descriptors);
    let (kps2, desc2) = (two.keypoints, two.descriptors);
    let EpipolarSearch {
        f21,
        epipole2,
        sigma2,
        check_orientation,
    } = *search;
    out.clear();
    let mut claims = Claims::new(kps2.len());
    // The free keypoints of 2, their positions apart (structure of arrays).
    let free: Vec<u32> = (0..kps2.len() as u32)
        .filter(|&j| free2[j as usize])
        .collect();
    let xs: Vec<f32> = free.iter().map(|&j| kps2[j as usize].ux).collect();
    let ys: Vec<f32> = free.iter().map(|&j| kps2[j as usize].uy).collect();
    // Per free keypoint, 1 when inside the band; padded to whole 8-byte words of zeros.
    let mut near = vec![0u8; free.len().div_ceil(8) * 8];
    // Every accepted candidate is inside this band (with a margin for the f32 prefilter).
    let max_sigma2 = sigma2.iter().copied().fold(1.0f64, f64::max);
    let band = ((3.84 * max_sigma2).sqrt() + 0.01) as f32;
    for (i, k1) in kps1.iter().enumerate() {
        if !free1[i] {
            continue;
        }
        let l = f21 * Vector3::new(k1.ux as f64, k1.uy as f64, 1.0);
        let ln = (l.x * l.x + l.y * l.y).sqrt();
        if ln < 1e-12 {
            continue;
        }
        let (la, lb, lc) = ((l.x / ln) as f32, (l.y / ln) as f32, (l.z / ln) as f32);
        for ((n, x), y) in near.iter_mut().zip(&xs).zip(&ys) {
            *n = ((la * x + lb * y + lc).abs() < band) as u8;
        }
        let (mut best, mut best_j) = (TH_LOW, usize::MAX);
        // Eight flags per word, visited in index order.
        for (w, c) in near.chunks_exact(8).enumerate() {
            let mut bits = u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]);
            while bits != 0 {
                let k = 8 * w + (bits.trailing_zeros() / 8) as usize;
                bits &= bits - 1;
                let j = free[k] as usize;
                let d = hamming(&desc1[i], &desc2[j]);
                if d <= best && on_epipolar_line(&kps2[j], &l, ln, epipole2, sigma2) {
                    best = d;
                    best_j = j;
                }
            }
        }
        claims.offer(best_j, best, i);
    }
    claims.pairs_into(out);
    if check_orientation && !out.is_empty() {
        let mut rot = RotationHistogram::default();
        for (k, &(i, j)) in out.iter().enumerate() {
            rot.add(kps1[i as usize].angle, kps2[j as usize].angle, k as u32);
        }
        let mut reject = vec![false; out.len()];
        rot.for_each_rejected(|k| reject[k as usize] = true);
        let mut k = 0;
        out.retain(|_| {
            let keep = !reject[k];
            k += 1;
            keep
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pairs of [`search_for_triangulation`] from a scan of all of keyframe 2 (the
    /// definition the band prefilter must reproduce).
    #[allow(clippy::too_many_arguments)]
    fn brute_force(
        kps1: &[KeyPoint],
        desc1: &[Descriptor],
        kps2: &[KeyPoint],
        desc2: &[Descriptor],
        free2: &[bool],
        f21: &Matrix3<f64>,
        epipole2: Option<Vector2<f64>>,
        sigma2: &[f64],
    ) -> Vec<(u32, u32)> {
        let mut claims = Claims::new(kps2.len());
        for (i, k1) in kps1.iter().enumerate() {
            let l = f21 * Vector3::new(k1.ux as f64, k1.uy as f64, 1.0);
            let ln = (l.x * l.x + l.y * l.y).sqrt();
            let (mut best, mut best_j) = (TH_LOW, usize::MAX);
            for (j, k2) in kps2.iter().enumerate() {
                let d = hamming(&desc1[i], &desc2[j]);
                if free2[j] && d <= best && on_epipolar_line(k2, &l, ln, epipole2, sigma2) {
                    best = d;
                    best_j = j;
                }
            }
            claims.offer(best_j, best, i);
        }
        let mut out = Vec::new();
        claims.pairs_into(&mut out);
        out
    }

    /// On a turn the image moves more than a window between the reference and the current
    /// frame: a window at the reference position finds nothing, one at the position where each
    /// feature was last matched finds every feature again.
    #[test]
    fn initialisation_window_follows_the_last_matched_position() {
        let shift = 250.0f32;
        let kp = |x: f32, y: f32| KeyPoint {
            x,
            y,
            ux: x,
            uy: y,
            ..Default::default()
        };
        let reference: Vec<KeyPoint> = (0..40)
            .map(|i| kp(20.0 + 10.0 * (i % 10) as f32, 40.0 + 30.0 * (i / 10) as f32))
            .collect();
        let current: Vec<KeyPoint> = reference.iter().map(|k| kp(k.ux + shift, k.uy)).collect();
        let desc: Vec<Descriptor> = (0..40u64)
            .map(|i| {
                [
                    i.wrapping_mul(0x9E37_79B9_7F4A_7C15),
                    !i,
                    i << 7,
                    i ^ 0xFF00,
                ]
            })
            .collect();
        let mut grid = FeatureGrid::new(64, 48, (0.0, 0.0, 640.0, 480.0), 64);
        grid.assign(&current);
        let search = WindowSearch {
            window: 100.0,
            ratio: 0.9,
            check_orientation: true,
        };
        let mut out = Vec::new();
        let at_reference: Vec<[f32; 2]> = reference.iter().map(|k| [k.ux, k.uy]).collect();
        let last_seen: Vec<[f32; 2]> = current.iter().map(|k| [k.ux - 5.0, k.uy + 3.0]).collect();
        let view_r = FeatureView::new(&reference, &desc);
        let view_c = FeatureView::new(&current, &desc);
        let n = search_for_initialization(view_r, &at_reference, view_c, &grid, search, &mut out);
        assert_eq!(n, 0);
        let n = search_for_initialization(view_r, &last_seen, view_c, &grid, search, &mut out);
        assert_eq!(n, 40);
        assert!(out.iter().enumerate().all(|(i, m)| *m == Some(i as u32)));
    }

    #[test]
    fn band_prefilter_finds_the_pairs_of_a_full_scan() {
        let mut s = 3u64;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            s >> 11
        };
        let kp = |next: &mut dyn FnMut() -> u64| {
            let x = (next() % 62000) as f32 / 100.0 + 10.0;
            let y = (next() % 46000) as f32 / 100.0 + 10.0;
            KeyPoint {
                x,
                y,
                ux: x,
                uy: y,
                octave: (next() % 8) as u8,
                ..Default::default()
            }
        };
        let kps1: Vec<KeyPoint> = (0..300).map(|_| kp(&mut next)).collect();
        let kps2: Vec<KeyPoint> = (0..600).map(|_| kp(&mut next)).collect();
        // Few distinct descriptors (few bits set), so distances tie often.
        let desc = |next: &mut dyn FnMut() -> u64| -> Descriptor {
            [1u64 << (next() % 8), 1u64 << (next() % 4), 0, 0]
        };
        let desc1: Vec<Descriptor> = (0..300).map(|_| desc(&mut next)).collect();
        let desc2: Vec<Descriptor> = (0..600).map(|_| desc(&mut next)).collect();
        let free1 = vec![true; 300];
        let free2: Vec<bool> = (0..600).map(|j| j % 7 != 0).collect();
        let sigma2: Vec<f64> = (0..8).map(|l| 1.2f64.powi(2 * l)).collect();
        // A sideways motion (near-horizontal lines) and a forward one (lines through the
        // epipole in the image).
        let skew = |t: Vector3<f64>| Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
        let k = Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0);
        let kinv = k.try_inverse().unwrap();
        for (t, epipole) in [
            (Vector3::new(1.0, 0.1, 0.0), None),
            (
                Vector3::new(0.1, 0.05, 1.0),
                Some(Vector2::new(370.0, 265.0)),
            ),
        ] {
            let r = nalgebra::Rotation3::from_euler_angles(0.02, -0.03, 0.01);
            let f21 = kinv.transpose() * skew(t) * r.matrix() * kinv;
            let mut out = Vec::new();
            let search = EpipolarSearch {
                f21: &f21,
                epipole2: epipole,
                sigma2: &sigma2,
                check_orientation: false,
            };
            search_for_triangulation(
                FeatureView::new(&kps1, &desc1),
                &free1,
                FeatureView::new(&kps2, &desc2),
                &free2,
                &search,
                &mut out,
            );
            let expect = brute_force(&kps1, &desc1, &kps2, &desc2, &free2, &f21, epipole, &sigma2);
            assert!(expect.len() > 20, "{}", expect.len());
            assert_eq!(out, expect);
        }
    }
}
