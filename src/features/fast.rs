//! FAST-9 corner detection (Rosten & Drummond) with exact corner scores.
//!
//! The segment test runs on 16 pixels at once over fixed-size lane arrays, which LLVM turns
//! into SIMD (SSE2/NEON) without `unsafe`; a 4-point compass test rejects flat chunks first.
//! The score of a corner is the largest threshold at which it is still a corner, so one pass at
//! the lowest threshold serves every per-cell threshold of ORB's fallback rule.

use crate::image::PaddedImage;

/// Bresenham circle of radius 3, clockwise from the top.
pub const CIRCLE: [(isize, isize); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Pixels processed together: 32 lanes fill an AVX2 register (or two SSE/NEON registers).
pub const LANES: usize = 32;

type Lanes = [u8; LANES];

#[inline(always)]
fn load(data: &[u8], at: usize) -> Lanes {
    let mut l = [0u8; LANES];
    l.copy_from_slice(&data[at..at + LANES]);
    l
}

#[inline(always)]
fn min(a: &Lanes, b: &Lanes) -> Lanes {
    let mut o = [0u8; LANES];
    for i in 0..LANES {
        o[i] = a[i].min(b[i]);
    }
    o
}

#[inline(always)]
fn max(a: &Lanes, b: &Lanes) -> Lanes {
    let mut o = [0u8; LANES];
    for i in 0..LANES {
        o[i] = a[i].max(b[i]);
    }
    o
}

/// Per lane: the best (over the 16 cyclic arcs of 9) of the smallest difference on the arc.
/// With `d[k]` the saturated difference of circle pixel k from the centre, a lane is a corner at
/// threshold t exactly when the result exceeds t. The 9-arcs starting at k - 1 and k share the
/// 8-window starting at k, so 8-windows at even k, each closed by the larger of its two end
/// pixels, cover all 16 arcs: 48 min/max instead of 80.
#[inline(always)]
fn best_arc_min(d: &[Lanes; 16]) -> Lanes {
    let mut m2 = [[0u8; LANES]; 8];
    for j in 0..8 {
        m2[j] = min(&d[2 * j], &d[2 * j + 1]);
    }
    let mut m4 = [[0u8; LANES]; 8];
    for j in 0..8 {
        m4[j] = min(&m2[j], &m2[(j + 1) & 7]);
    }
    let mut acc = [0u8; LANES];
    for j in 0..8 {
        let k = 2 * j;
        let m8 = min(&m4[j], &m4[(j + 2) & 7]);
        let ends = max(&d[(k + 15) & 15], &d[(k + 8) & 15]);
        acc = max(&acc, &min(&m8, &ends));
    }
    acc
}

/// Exact FAST score: the largest `t` for which the pixel is a corner (all 9 contiguous circle
/// pixels brighter than `p + t` or darker than `p - t`, strictly); 0 if none. Scalar reference
/// of what [`detect`] computes 16 pixels at a time.
#[inline]
pub fn corner_score(img: &PaddedImage, x: isize, y: isize) -> u8 {
    let p = img.at(x, y) as i16;
    let mut d = [0i16; 16];
    for (k, &(dx, dy)) in CIRCLE.iter().enumerate() {
        d[k] = img.at(x + dx, y + dy) as i16 - p;
    }
    let mut best_b = i16::MIN;
    let mut best_d = i16::MIN;
    for s in 0..16 {
        let mut mn = i16::MAX;
        let mut mx = i16::MIN;
        for j in 0..9 {
            let v = d[(s + j) & 15];
            mn = mn.min(v);
            mx = mx.max(v);
        }
        best_b = best_b.max(mn);
        best_d = best_d.max(-mx);
    }
    (best_b.max(best_d) - 1).clamp(0, 255) as u8
}

/// A detected corner in level coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Corner {
    pub x: u16,
    pub y: u16,
    pub score: u8,
}

/// Region of a level: `(x0, y0, x1, y1)`, end-exclusive.
pub type Region = (usize, usize, usize, usize);

/// Detects the FAST-9 corners with score >= `threshold` inside `region` of `img` that are strict
/// local maxima of the score over their 8 neighbours (as OpenCV's FAST with suppression), and
/// appends them to `out` with their exact scores.
///
/// `score_map` is level-sized and zeroed by the caller once per level; it keeps `score + 1` of
/// every corner (0 = none) of this and earlier calls, over the region and a one-pixel frame
/// around it, so regions detected later (ORB's low-threshold cells) are suppressed against their
/// neighbours too. Suppression runs one row behind detection, so only surviving corners are
/// ever emitted. The region must stay 4 pixels inside the level. Uses AVX2 when the CPU has it.
pub fn detect(
    img: &PaddedImage,
    threshold: u8,
    region: Region,
    out: &mut Vec<Corner>,
    score_map: &mut [u8],
) {
    assert!(
        img.pad >= 3 + LANES,
        "FAST needs a border of 3 + LANES pixels for its wide loads"
    );
    let (x0, y0, x1, y1) = region;
    if x0 >= x1 || y0 >= y1 {
        return;
    }
    assert!(
        x0 >= 4 && y0 >= 4 && x1 + 4 <= img.width && y1 + 4 <= img.height,
        "FAST region must stay 4 pixels inside the level"
    );
    assert!(score_map.len() >= img.width * img.height);
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx2() {
        // SAFETY: the CPU supports AVX2 (checked just above); the function is otherwise safe.
        unsafe { detect_avx2(img, threshold, region, out, score_map) };
        return;
    }
    detect_lanes(img, threshold, region, out, score_map)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn detect_avx2(
    img: &PaddedImage,
    threshold: u8,
    region: Region,
    out: &mut Vec<Corner>,
    score_map: &mut [u8],
) {
    // SAFETY: AVX2 is enabled here; `detect` checked the pad, the region and the map size.
    unsafe { super::fast_avx2::detect(img, threshold, region, out, score_map) }
}

/// Bit i set when lane i is non-zero.
#[inline(always)]
fn nonzero_mask(v: &Lanes) -> u32 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{
            __m128i, _mm_cmpeq_epi8, _mm_loadu_si128, _mm_movemask_epi8, _mm_setzero_si128,
        };
        // SAFETY: SSE2 is part of the x86_64 baseline; both loads read inside the 32-byte array.
        unsafe {
            let z = _mm_setzero_si128();
            let a = _mm_loadu_si128(v.as_ptr() as *const __m128i);
            let b = _mm_loadu_si128(v.as_ptr().add(16) as *const __m128i);
            let za = _mm_movemask_epi8(_mm_cmpeq_epi8(a, z)) as u32;
            let zb = _mm_movemask_epi8(_mm_cmpeq_epi8(b, z)) as u32;
            !(za | (zb << 16))
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let mut m = 0u32;
        for (i, &x) in v.iter().enumerate() {
            m |= ((x != 0) as u32) << i;
        }
        m
    }
}

/// Appends the corners of the lanes set in `keep`: row `y`, columns from `x`, with `scores`
/// holding `score + 1` per lane (the score map's encoding).
#[inline(always)]
pub(super) fn emit_kept(mut keep: u32, scores: &Lanes, x: usize, y: usize, out: &mut Vec<Corner>) {
    while keep != 0 {
        let i = keep.trailing_zeros() as usize;
        keep &= keep - 1;
        out.push(Corner {
            x: (x + i) as u16,
            y: y as u16,
            score: scores[i] - 1,
        });
    }
}

/// Indices of the 8 neighbours of index `at` in a map of row length `w` (suppression).
#[inline(always)]
pub(super) fn ring8(at: usize, w: usize) -> [usize; 8] {
    [
        at - w - 1,
        at - w,
        at - w + 1,
        at - 1,
        at + 1,
        at + w - 1,
        at + w,
        at + w + 1,
    ]
}

/// Lanes kept by the first `n` of `LANES` (n <= LANES).
#[inline(always)]
pub(super) fn first_lanes(n: usize) -> u32 {
    if n >= 32 {
        u32::MAX
    } else {
        (1u32 << n) - 1
    }
}

#[inline(always)]
fn sub_sat(a: &Lanes, b: &Lanes) -> Lanes {
    let mut o = [0u8; LANES];
    for i in 0..LANES {
        o[i] = a[i].saturating_sub(b[i]);
    }
    o
}

/// Largest per-lane value of "two adjacent compass points both beyond the centre".
#[inline(always)]
fn compass_pairs(m: &[Lanes; 4]) -> Lanes {
    max(
        &max(&min(&m[0], &m[1]), &min(&m[1], &m[2])),
        &max(&min(&m[2], &m[3]), &min(&m[3], &m[0])),
    )
}

/// `score + 1` per lane for the 32 pixels starting at `at`, 0 where not a corner above `t`.
#[inline(always)]
fn chunk_scores(data: &[u8], at: usize, offs: &[isize; 16], t: u8) -> Lanes {
    let c = load(data, at);
    // Compass test: an arc of 9 always covers two adjacent compass points, each beyond the
    // threshold in the same direction. Rejects most chunks of flat image.
    let mut compass = [[0u8; LANES]; 4];
    for (k, r) in compass.iter_mut().enumerate() {
        *r = load(data, (at as isize + offs[4 * k]) as usize);
    }
    let mut bright = [[0u8; LANES]; 4];
    let mut dark = [[0u8; LANES]; 4];
    for k in 0..4 {
        bright[k] = sub_sat(&compass[k], &c);
        dark[k] = sub_sat(&c, &compass[k]);
    }
    let mut tl = [0u8; LANES];
    tl.fill(t);
    let over_b = sub_sat(&compass_pairs(&bright), &tl);
    let over_d = sub_sat(&compass_pairs(&dark), &tl);
    if nonzero_mask(&max(&over_b, &over_d)) == 0 {
        return [0; LANES];
    }
    let s = if nonzero_mask(&min(&over_b, &over_d)) == 0 {
        // No lane is a candidate of both polarities, and a lane failing a polarity's compass
        // test cannot be a corner of that polarity: one arc network on per-lane polarity
        // (dark lanes as 255 - x on both sides, since (255 - r) - (255 - c) = c - r).
        let mut flip = [0u8; LANES];
        for i in 0..LANES {
            flip[i] = if over_b[i] == 0 { 255 } else { 0 };
        }
        let mut cf = c;
        for i in 0..LANES {
            cf[i] ^= flip[i];
        }
        let mut d = [[0u8; LANES]; 16];
        for (k, dk) in d.iter_mut().enumerate() {
            let mut r = load(data, (at as isize + offs[k]) as usize);
            for i in 0..LANES {
                r[i] ^= flip[i];
            }
            *dk = sub_sat(&r, &cf);
        }
        best_arc_min(&d)
    } else {
        let mut bright = [[0u8; LANES]; 16];
        let mut dark = [[0u8; LANES]; 16];
        for k in 0..16 {
            let r = load(data, (at as isize + offs[k]) as usize);
            bright[k] = sub_sat(&r, &c);
            dark[k] = sub_sat(&c, &r);
        }
        max(&best_arc_min(&bright), &best_arc_min(&dark))
    };
    let mut o = [0u8; LANES];
    for i in 0..LANES {
        o[i] = if s[i] > t { s[i] } else { 0 };
    }
    o
}

#[inline(always)]
fn detect_lanes(
    img: &PaddedImage,
    threshold: u8,
    (x0, y0, x1, y1): Region,
    out: &mut Vec<Corner>,
    score_map: &mut [u8],
) {
    let offs: [isize; 16] = CIRCLE.map(|(dx, dy)| dy * img.stride as isize + dx);
    let w = img.width;
    // Scores over the region and a one-pixel frame (the suppression neighbourhood).
    let (sx0, sx1) = (x0 - 1, x1 + 1);
    for y in y0 - 1..=y1 {
        let row = img.idx(0, y as isize);
        let mut x = sx0;
        while x < sx1 {
            let s = chunk_scores(&img.data, row + x, &offs, threshold);
            let n = (sx1 - x).min(LANES);
            let dst = &mut score_map[y * w + x..y * w + x + n];
            // Never lower a score an earlier (higher-threshold) call wrote.
            for (d, &v) in dst.iter_mut().zip(&s[..n]) {
                *d = (*d).max(v);
            }
            x += LANES;
        }
        if y > y0 {
            suppress_row(score_map, w, y - 1, x0, x1, out);
        }
    }
}

/// Emits the corners of row `y` in `[x0, x1)` whose score beats all 8 neighbours strictly.
#[inline(always)]
fn suppress_row(map: &[u8], w: usize, y: usize, x0: usize, x1: usize, out: &mut Vec<Corner>) {
    let mut x = x0;
    while x < x1 {
        let at = y * w + x;
        let s = load(map, at);
        let mut keep = nonzero_mask(&s) & first_lanes(x1 - x);
        if keep != 0 {
            let mut margin = [u8::MAX; LANES];
            for off in ring8(at, w) {
                let n = load(map, off);
                for i in 0..LANES {
                    margin[i] = margin[i].min(s[i].saturating_sub(n[i]));
                }
            }
            keep &= nonzero_mask(&margin);
            emit_kept(keep, &s, x, y, out);
        }
        x += LANES;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scalar reference of the segment test.
    fn is_corner(img: &PaddedImage, x: isize, y: isize, t: u8) -> bool {
        let p = img.at(x, y) as i16;
        let t = t as i16;
        let v: Vec<i16> = CIRCLE
            .iter()
            .map(|&(dx, dy)| img.at(x + dx, y + dy) as i16)
            .collect();
        (0..16).any(|s| (0..9).all(|j| v[(s + j) % 16] > p + t))
            || (0..16).any(|s| (0..9).all(|j| v[(s + j) % 16] < p - t))
    }

    fn noise_image(w: usize, h: usize, seed: u64) -> PaddedImage {
        let mut s = seed;
        let data: Vec<u8> = (0..w * h)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect();
        let mut img = PaddedImage::new(w, h, 40);
        img.copy_from(&data);
        img
    }

    /// Scalar reference: corners at `t` in the region that beat their 8 neighbours' scores.
    fn reference(img: &PaddedImage, t: u8, (x0, y0, x1, y1): Region) -> Vec<Corner> {
        let score = |x: isize, y: isize| -> i16 {
            if is_corner(img, x, y, t) {
                corner_score(img, x, y) as i16
            } else {
                -1
            }
        };
        let mut out = Vec::new();
        for y in y0 as isize..y1 as isize {
            for x in x0 as isize..x1 as isize {
                let s = score(x, y);
                let beats = (-1..=1)
                    .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
                    .filter(|&d| d != (0, 0))
                    .all(|(dx, dy)| s > score(x + dx, y + dy));
                if s >= 0 && beats {
                    out.push(Corner {
                        x: x as u16,
                        y: y as u16,
                        score: s as u8,
                    });
                }
            }
        }
        out
    }

    #[test]
    fn lane_detector_matches_scalar_segment_test_suppression_and_exact_scores() {
        let img = noise_image(90, 40, 3);
        for t in [7u8, 20, 40] {
            let mut out = Vec::new();
            let mut map = vec![0u8; 90 * 40];
            detect(&img, t, (4, 4, 86, 36), &mut out, &mut map);
            let expect = reference(&img, t, (4, 4, 86, 36));
            assert!(!expect.is_empty());
            assert_eq!(out, expect, "t {t}");
            for k in &out {
                let s = k.score;
                assert!(is_corner(&img, k.x as isize, k.y as isize, s));
                assert!(
                    !is_corner(&img, k.x as isize, k.y as isize, s.saturating_add(1)) || s == 255
                );
            }
        }
        // The portable lanes give the same corners as the AVX2 build.
        let mut out = Vec::new();
        let mut map = vec![0u8; 90 * 40];
        detect_lanes(&img, 20, (4, 4, 86, 36), &mut out, &mut map);
        assert_eq!(out, reference(&img, 20, (4, 4, 86, 36)));
    }

    /// On smooth texture (box-blurred noise) most chunks hold corners of one polarity only,
    /// the single-network path (AVX2 and portable); its corners and scores are still exact.
    #[test]
    fn smooth_texture_corners_are_exact() {
        let (w, h) = (120usize, 60usize);
        let noise = noise_image(w, h, 9);
        let mut data = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut sum = 0u32;
                for dy in -2isize..=2 {
                    for dx in -2isize..=2 {
                        let xx = (x as isize + dx).clamp(0, w as isize - 1);
                        let yy = (y as isize + dy).clamp(0, h as isize - 1);
                        sum += noise.at(xx, yy) as u32;
                    }
                }
                // Stretch the blurred values back over most of the byte range.
                data[y * w + x] = ((sum as i32 / 25 - 128) * 5 + 128).clamp(0, 255) as u8;
            }
        }
        let mut img = PaddedImage::new(w, h, 40);
        img.copy_from(&data);
        for t in [7u8, 20] {
            let mut out = Vec::new();
            let mut map = vec![0u8; w * h];
            detect(&img, t, (4, 4, w - 4, h - 4), &mut out, &mut map);
            let expect = reference(&img, t, (4, 4, w - 4, h - 4));
            assert!(expect.len() > 20, "t {t}: {}", expect.len());
            assert_eq!(out, expect, "t {t}");
            // The portable lanes (other CPUs) take the same one-network path.
            let (mut lanes, mut map) = (Vec::new(), vec![0u8; w * h]);
            detect_lanes(&img, t, (4, 4, w - 4, h - 4), &mut lanes, &mut map);
            assert_eq!(lanes, expect, "portable, t {t}");
        }
    }

    #[test]
    fn later_low_threshold_regions_are_suppressed_against_earlier_corners() {
        let img = noise_image(90, 40, 5);
        let mut map = vec![0u8; 90 * 40];
        let mut high = Vec::new();
        detect(&img, 30, (4, 4, 86, 36), &mut high, &mut map);
        let mut low = Vec::new();
        detect(&img, 7, (40, 10, 60, 30), &mut low, &mut map);
        // Every low corner beats its neighbours at the low threshold, and no high corner
        // next to it outscores it.
        let full = reference(&img, 7, (40, 10, 60, 30));
        assert!(low.iter().all(|c| full.contains(c)), "{low:?}");
        assert_eq!(low.len(), full.len());
    }
    #[test]
    fn a_bright_square_corner_is_found() {
        // A bright square whose brightness falls away from its corner, so the corner pixel has
        // a unique best score (strict suppression removes tied plateaus, as OpenCV's does).
        let mut data = vec![20u8; 64 * 64];
        for y in 32..64 {
            for x in 32..64 {
                data[y * 64 + x] = (200 - (x - 32) - (y - 32)) as u8;
            }
        }
        let mut img = PaddedImage::new(64, 64, 40);
        img.copy_from(&data);
        let mut out = Vec::new();
        let mut map = vec![0u8; 64 * 64];
        detect(&img, 20, (4, 4, 60, 60), &mut out, &mut map);
        let best = out.iter().map(|c| c.score).max().unwrap();
        assert!(
            out.contains(&Corner {
                x: 32,
                y: 32,
                score: best
            }),
            "{out:?}"
        );
        // Straight edges are not corners.
        assert!(
            out.iter()
                .all(|c| (c.x as i32 - 32).abs() <= 3 && (c.y as i32 - 32).abs() <= 3),
            "{out:?}"
        );
    }
}
