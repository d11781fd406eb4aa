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

type Lanes = [u8; 16];

#[inline(always)]
fn load(data: &[u8], at: usize) -> Lanes {
    let mut l = [0u8; 16];
    l.copy_from_slice(&data[at..at + 16]);
    l
}

#[inline(always)]
fn and(a: &Lanes, b: &Lanes) -> Lanes {
    let mut o = [0u8; 16];
    for i in 0..16 {
        o[i] = a[i] & b[i];
    }
    o
}

#[inline(always)]
fn or(a: &Lanes, b: &Lanes) -> Lanes {
    let mut o = [0u8; 16];
    for i in 0..16 {
        o[i] = a[i] | b[i];
    }
    o
}

#[inline(always)]
fn any(a: &Lanes) -> bool {
    u128::from_ne_bytes(*a) != 0
}

/// Lanes where 9 contiguous circle masks (cyclically) are all set.
#[inline(always)]
fn arc9(m: &[Lanes; 16]) -> Lanes {
    let mut a2 = [[0u8; 16]; 16];
    for k in 0..16 {
        a2[k] = and(&m[k], &m[(k + 1) & 15]);
    }
    let mut a4 = [[0u8; 16]; 16];
    for k in 0..16 {
        a4[k] = and(&a2[k], &a2[(k + 2) & 15]);
    }
    let mut acc = [0u8; 16];
    for k in 0..16 {
        let a8 = and(&a4[k], &a4[(k + 4) & 15]);
        acc = or(&acc, &and(&a8, &m[(k + 8) & 15]));
    }
    acc
}

/// Exact FAST score: the largest `t` for which the pixel is a corner (all 9 contiguous circle
/// pixels brighter than `p + t` or darker than `p - t`, strictly); 0 if none.
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

/// Detects every FAST-9 corner with score >= `threshold` inside `[x0, x1) x [y0, y1)` of `img`,
/// appending to `out` with their scores, and writes scores into `score_map` (level-sized, zeroed
/// by the caller) for non-maximum suppression.
pub fn detect(
    img: &PaddedImage,
    threshold: u8,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    out: &mut Vec<Corner>,
    score_map: &mut [u8],
) {
    assert!(img.pad >= 3 + 16, "FAST needs a border of 19 pixels for 16-lane loads");
    let offs: [isize; 16] = CIRCLE.map(|(dx, dy)| dy * img.stride as isize + dx);
    let t = threshold;
    for y in y0..y1 {
        let row = img.idx(0, y as isize);
        let mut x = x0;
        while x < x1 {
            let at = row + x;
            let c = load(&img.data, at);
            let mut hi = [0u8; 16];
            let mut lo = [0u8; 16];
            for i in 0..16 {
                hi[i] = c[i].saturating_add(t);
                lo[i] = c[i].saturating_sub(t);
            }
            let ring = |k: usize| load(&img.data, (at as isize + offs[k]) as usize);
            let mut b = [[0u8; 16]; 16];
            let mut d = [[0u8; 16]; 16];
            // Compass points first: an arc of 9 always covers two adjacent compass points.
            for k in [0usize, 4, 8, 12] {
                let r = ring(k);
                for i in 0..16 {
                    b[k][i] = if r[i] > hi[i] { 0xFF } else { 0 };
                    d[k][i] = if r[i] < lo[i] { 0xFF } else { 0 };
                }
            }
            let pair = |m: &[Lanes; 16]| {
                or(&or(&and(&m[0], &m[4]), &and(&m[4], &m[8])), &or(&and(&m[8], &m[12]), &and(&m[12], &m[0])))
            };
            let cand = or(&pair(&b), &pair(&d));
            if any(&cand) {
                for k in 0..16 {
                    if k % 4 == 0 {
                        continue;
                    }
                    let r = ring(k);
                    for i in 0..16 {
                        b[k][i] = if r[i] > hi[i] { 0xFF } else { 0 };
                        d[k][i] = if r[i] < lo[i] { 0xFF } else { 0 };
                    }
                }
                let corners = or(&arc9(&b), &arc9(&d));
                if any(&corners) {
                    let lim = (x1 - x).min(16);
                    for (i, &cv) in corners.iter().enumerate().take(lim) {
                        if cv != 0 {
                            let (cx, cy) = (x + i, y);
                            let s = corner_score(img, cx as isize, cy as isize).max(t);
                            score_map[cy * img.width + cx] = s;
                            out.push(Corner {
                                x: cx as u16,
                                y: cy as u16,
                                score: s,
                            });
                        }
                    }
                }
            }
            x += 16;
        }
    }
}

/// Keeps corners whose score beats all 8 neighbours strictly (as OpenCV's FAST), in place.
pub fn non_max_suppression(corners: &mut Vec<Corner>, score_map: &[u8], width: usize, height: usize) {
    corners.retain(|c| {
        let (x, y, s) = (c.x as usize, c.y as usize, c.score);
        if x == 0 || y == 0 || x + 1 >= width || y + 1 >= height {
            return false;
        }
        let r0 = (y - 1) * width + x;
        let r1 = y * width + x;
        let r2 = (y + 1) * width + x;
        s > score_map[r0 - 1]
            && s > score_map[r0]
            && s > score_map[r0 + 1]
            && s > score_map[r1 - 1]
            && s > score_map[r1 + 1]
            && s > score_map[r2 - 1]
            && s > score_map[r2]
            && s > score_map[r2 + 1]
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scalar reference of the segment test.
    fn is_corner(img: &PaddedImage, x: isize, y: isize, t: u8) -> bool {
        let p = img.at(x, y) as i16;
        let t = t as i16;
        let v: Vec<i16> = CIRCLE.iter().map(|&(dx, dy)| img.at(x + dx, y + dy) as i16).collect();
        (0..16).any(|s| (0..9).all(|j| v[(s + j) % 16] > p + t)) || (0..16).any(|s| (0..9).all(|j| v[(s + j) % 16] < p - t))
    }

    fn noise_image(w: usize, h: usize, seed: u64) -> PaddedImage {
        let mut s = seed;
        let data: Vec<u8> = (0..w * h)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect();
        let mut img = PaddedImage::new(w, h, 24);
        img.copy_from(&data);
        img
    }

    #[test]
    fn lane_detector_matches_scalar_segment_test_and_scores_are_exact() {
        let img = noise_image(90, 40, 3);
        for t in [7u8, 20, 40] {
            let mut out = Vec::new();
            let mut map = vec![0u8; 90 * 40];
            detect(&img, t, (3, 3, 87, 37), &mut out, &mut map);
            let mut expect = 0;
            for y in 3..37 {
                for x in 3..87 {
                    let c = is_corner(&img, x, y, t);
                    expect += c as usize;
                    let found = out.iter().any(|k| k.x as isize == x && k.y as isize == y);
                    assert_eq!(c, found, "t {t} at ({x},{y})");
                }
            }
            assert_eq!(out.len(), expect);
            for k in &out {
                let s = corner_score(&img, k.x as isize, k.y as isize);
                assert!(is_corner(&img, k.x as isize, k.y as isize, s));
                assert!(!is_corner(&img, k.x as isize, k.y as isize, s.saturating_add(1)) || s == 255);
            }
        }
    }

    #[test]
    fn a_bright_square_corner_is_found() {
        let mut data = vec![20u8; 64 * 64];
        for y in 32..64 {
            for x in 32..64 {
                data[y * 64 + x] = 200;
            }
        }
        // Blurred like a real image (a hard-edged synthetic corner ties every score).
        let mut sharp = PaddedImage::new(64, 64, 24);
        sharp.copy_from(&data);
        let mut img = PaddedImage::new(64, 64, 24);
        crate::image::gaussian_blur_7x7(&sharp, &mut img, &mut Vec::new());
        let mut out = Vec::new();
        let mut map = vec![0u8; 64 * 64];
        detect(&img, 20, (3, 3, 61, 61), &mut out, &mut map);
        non_max_suppression(&mut out, &map, 64, 64);
        assert!(out.iter().any(|c| (c.x as i32 - 32).abs() <= 2 && (c.y as i32 - 32).abs() <= 2), "{out:?}");
        assert!(out.len() <= 3, "{out:?}");
    }
}
