//! Guided matching used by tracking and mapping: window search (initialisation), search by
//! projection (motion model and local map), and epipolar search (triangulation). Thresholds are
//! ORB-SLAM's (TH_LOW 50, TH_HIGH 100, ratio tests) and every search can apply the rotation-
//! consistency histogram.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::{hamming, FeatureGrid, RotationHistogram, TH_HIGH, TH_LOW};
use crate::features::{Descriptor, KeyPoint};

/// Matches keypoints of a reference frame to a new frame within a window around each reference
/// keypoint, at the same pyramid level (ORB-SLAM uses only the finest level and doubles the
/// feature count during initialisation instead; matching every level within its octave gives the
/// same density without a second extractor). Returns, per reference keypoint, the matched index
/// in the new frame.
#[allow(clippy::too_many_arguments)]
pub fn search_for_initialization(
    ref_kps: &[KeyPoint],
    ref_desc: &[Descriptor],
    cur_kps: &[KeyPoint],
    cur_desc: &[Descriptor],
    cur_grid: &FeatureGrid,
    window: f32,
    ratio: f32,
    check_orientation: bool,
    out: &mut Vec<Option<u32>>,
) -> usize {
    out.clear();
    out.resize(ref_kps.len(), None);
    let mut best_of_cur: Vec<(u32, u32)> = vec![(u32::MAX, u32::MAX); cur_kps.len()]; // (dist, ref idx)
    let mut cand = Vec::new();
    let mut rot = RotationHistogram::default();
    for (i, k1) in ref_kps.iter().enumerate() {
        cur_grid.in_area(
            cur_kps, k1.ux, k1.uy, window, k1.octave, k1.octave, &mut cand,
        );
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
#[allow(clippy::too_many_arguments)]
pub fn search_by_projection(
    points: &[ProjectedPoint],
    kps: &[KeyPoint],
    desc: &[Descriptor],
    grid: &FeatureGrid,
    scales: &[f64],
    radius: f32,
    ratio: f32,
    matches: &mut [Option<u32>],
    scratch: &mut Vec<u32>,
) -> usize {
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

/// Epipolar search between two keyframes for triangulation: for each keypoint of keyframe 1
/// without a map point, the best keypoint of keyframe 2 (also free) whose distance to the
/// epipolar line is below 3.84 sigma² of its level and that is not too close to the epipole.
/// `f21` maps undistorted pixels of 1 to lines in 2. Returns pairs (i1, i2).
#[allow(clippy::too_many_arguments)]
pub fn search_for_triangulation(
    kps1: &[KeyPoint],
    desc1: &[Descriptor],
    free1: &[bool],
    kps2: &[KeyPoint],
    desc2: &[Descriptor],
    free2: &[bool],
    f21: &Matrix3<f64>,
    epipole2: Option<Vector2<f64>>,
    sigma2: &[f64],
    check_orientation: bool,
    out: &mut Vec<(u32, u32)>,
) {
    out.clear();
    let mut taken = vec![u32::MAX; kps2.len()]; // best distance claiming each keypoint of 2
    let mut claim: Vec<Option<u32>> = vec![None; kps2.len()];
    for (i, k1) in kps1.iter().enumerate() {
        if !free1[i] {
            continue;
        }
        let l = f21 * Vector3::new(k1.ux as f64, k1.uy as f64, 1.0);
        let ln = (l.x * l.x + l.y * l.y).sqrt();
        if ln < 1e-12 {
            continue;
        }
        let (mut best, mut best_j) = (TH_LOW, usize::MAX);
        for (j, k2) in kps2.iter().enumerate() {
            if !free2[j] {
                continue;
            }
            let d = hamming(&desc1[i], &desc2[j]);
            if d > best {
                continue;
            }
            if let Some(e) = epipole2 {
                let (dx, dy) = (k2.ux as f64 - e.x, k2.uy as f64 - e.y);
                if dx * dx + dy * dy < 100.0 * sigma2[k2.octave as usize] {
                    continue;
                }
            }
            let dist = (l.x * k2.ux as f64 + l.y * k2.uy as f64 + l.z) / ln;
            if dist * dist < 3.84 * sigma2[k2.octave as usize] {
                best = d;
                best_j = j;
            }
        }
        if best_j != usize::MAX && best < taken[best_j] {
            taken[best_j] = best;
            claim[best_j] = Some(i as u32);
        }
    }
    for (j, c) in claim.iter().enumerate() {
        if let Some(i) = c {
            out.push((*i, j as u32));
        }
    }
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
