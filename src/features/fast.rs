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
/// threshold t exactly when the result exceeds t.
#[inline(always)]
fn best_arc_min(d: &[Lanes; 16]) -> Lanes {
    let mut m2 = [[0u8; LANES]; 16];
    for k in 0..16 {
        m2[k] = min(&d[k], &d[(k + 1) & 15]);
    }
    let mut m4 = [[0u8; LANES]; 16];
    for k in 0..16 {
        m4[k] = min(&m2[k], &m2[(k + 2) & 15]);
    }
    let mut acc = [0u8; LANES];
    for k in 0..16 {
        let m8 = min(&m4[k], &m4[(k + 4) & 15]);
        acc = max(&acc, &min(&m8, &d[(k + 8) & 15]));
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

/// Detects every FAST-9 corner with score >= `threshold` inside `region` of `img`, appending to
/// `out` with their exact scores, and writes scores into `score_map` (level-sized, zeroed by
/// the caller) for non-maximum suppression. Uses AVX2 when the CPU has it.
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
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
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
    detect_lanes(img, threshold, region, out, score_map)
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
    let t = threshold;
    for y in y0..y1 {
        let row = img.idx(0, y as isize);
        let mut x = x0;
        while x < x1 {
            let at = row + x;
            let c = load(&img.data, at);
            let ring = |k: usize| load(&img.data, (at as isize + offs[k]) as usize);
            // Compass test: an arc of 9 always covers two adjacent compass points, each beyond
            // the threshold in the same direction. Rejects most chunks of flat image.
            let mut bright = [[0u8; LANES]; 16];
            let mut dark = [[0u8; LANES]; 16];
            for k in [0usize, 4, 8, 12] {
                let r = ring(k);
                for i in 0..LANES {
                    bright[k][i] = r[i].saturating_sub(c[i]);
                    dark[k][i] = c[i].saturating_sub(r[i]);
                }
            }
            let pair = |m: &[Lanes; 16]| {
                max(
                    &max(&min(&m[0], &m[4]), &min(&m[4], &m[8])),
                    &max(&min(&m[8], &m[12]), &min(&m[12], &m[0])),
                )
            };
            let cand = max(&pair(&bright), &pair(&dark));
            if cand.iter().any(|&v| v > t) {
                for k in 0..16 {
                    if k % 4 == 0 {
                        continue;
                    }
                    let r = ring(k);
                    for i in 0..LANES {
                        bright[k][i] = r[i].saturating_sub(c[i]);
                        dark[k][i] = c[i].saturating_sub(r[i]);
                    }
                }
                let score = max(&best_arc_min(&bright), &best_arc_min(&dark));
                let lim = (x1 - x).min(LANES);
                for (i, &s) in score.iter().enumerate().take(lim) {
                    if s > t {
                        let (cx, cy) = (x + i, y);
                        let s = s - 1;
                        score_map[cy * img.width + cx] = s;
                        out.push(Corner {
                            x: cx as u16,
                            y: cy as u16,
                            score: s,
                        });
                    }
                }
            }
            x += LANES;
        }
    }
}

/// Keeps corners whose score beats all 8 neighbours strictly (as OpenCV's FAST), in place.
pub fn non_max_suppression(
    corners: &mut Vec<Corner>,
    score_map: &[u8],
    width: usize,
    height: usize,
) {
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
                assert!(
                    !is_corner(&img, k.x as isize, k.y as isize, s.saturating_add(1)) || s == 255
                );
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
        let mut img = PaddedImage::new(64, 64, 40);
        img.copy_from(&data);
        let mut out = Vec::new();
        let mut map = vec![0u8; 64 * 64];
        detect(&img, 20, (3, 3, 61, 61), &mut out, &mut map);
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

    #[test]
    fn non_max_suppression_keeps_strict_local_maxima() {
        let (w, h) = (10, 10);
        let mut map = vec![0u8; w * h];
        let mut cs = vec![
            Corner {
                x: 3,
                y: 3,
                score: 50,
            },
            Corner {
                x: 4,
                y: 3,
                score: 40,
            },
            Corner {
                x: 7,
                y: 7,
                score: 30,
            },
            Corner {
                x: 7,
                y: 8,
                score: 30,
            },
            Corner {
                x: 1,
                y: 6,
                score: 10,
            },
        ];
        for c in &cs {
            map[c.y as usize * w + c.x as usize] = c.score;
        }
        non_max_suppression(&mut cs, &map, w, h);
        assert_eq!(
            cs,
            vec![
                Corner {
                    x: 3,
                    y: 3,
                    score: 50
                },
                Corner {
                    x: 1,
                    y: 6,
                    score: 10
                }
            ]
        );
    }
}
