//! FAST-9 detection and suppression in AVX2 intrinsics: the same results as the portable lanes
//! of [`super::fast`], about twice as fast. The portable code is left to LLVM, which keeps the
//! 32-byte lane arrays in memory and splits their loads and stores; here every value is one
//! `ymm` register.

use std::arch::x86_64::*;

use super::fast::{emit_kept, first_lanes, ring8, Corner, Region, CIRCLE, LANES};
use crate::image::PaddedImage;

/// Per lane: the best (over the 16 cyclic arcs of 9) of the smallest difference on the arc.
/// Same network as [`super::fast`]'s: 8-windows at even starts, each closing the two 9-arcs
/// that contain it (48 min/max instead of 80).
#[inline(always)]
unsafe fn best_arc_min(d: &[__m256i; 16]) -> __m256i {
    let mut m2 = [_mm256_setzero_si256(); 8];
    for j in 0..8 {
        m2[j] = _mm256_min_epu8(d[2 * j], d[2 * j + 1]);
    }
    let mut m4 = [_mm256_setzero_si256(); 8];
    for j in 0..8 {
        m4[j] = _mm256_min_epu8(m2[j], m2[(j + 1) & 7]);
    }
    let mut acc = _mm256_setzero_si256();
    for j in 0..8 {
        let k = 2 * j;
        let m8 = _mm256_min_epu8(m4[j], m4[(j + 2) & 7]);
        let ends = _mm256_max_epu8(d[(k + 15) & 15], d[(k + 8) & 15]);
        acc = _mm256_max_epu8(acc, _mm256_min_epu8(m8, ends));
    }
    acc
}

#[inline(always)]
unsafe fn load(p: *const u8) -> __m256i {
    _mm256_lddqu_si256(p as *const __m256i)
}

/// Largest per-lane value of "two adjacent compass points both beyond the centre".
#[inline(always)]
unsafe fn compass_pairs(m: [__m256i; 4]) -> __m256i {
    _mm256_max_epu8(
        _mm256_max_epu8(_mm256_min_epu8(m[0], m[1]), _mm256_min_epu8(m[1], m[2])),
        _mm256_max_epu8(_mm256_min_epu8(m[2], m[3]), _mm256_min_epu8(m[3], m[0])),
    )
}

/// `score + 1` per lane for the 32 pixels at `p`, 0 where not a corner above `t`.
///
/// # Safety
/// AVX2, and every circle offset from `p` readable for 32 bytes.
#[inline(always)]
unsafe fn chunk_scores(p: *const u8, offs: &[isize; 16], t: __m256i) -> __m256i {
    let c = load(p);
    let mut bright = [_mm256_setzero_si256(); 4];
    let mut dark = [_mm256_setzero_si256(); 4];
    for k in 0..4 {
        let r = load(p.offset(offs[4 * k]));
        bright[k] = _mm256_subs_epu8(r, c);
        dark[k] = _mm256_subs_epu8(c, r);
    }
    let over_b = _mm256_subs_epu8(compass_pairs(bright), t);
    let over_d = _mm256_subs_epu8(compass_pairs(dark), t);
    let over = _mm256_or_si256(over_b, over_d);
    if _mm256_testz_si256(over, over) != 0 {
        return _mm256_setzero_si256();
    }
    let mut d = [_mm256_setzero_si256(); 16];
    let both = _mm256_min_epu8(over_b, over_d);
    let s = if _mm256_testz_si256(both, both) != 0 {
        // No lane can be both a bright and a dark corner candidate, and a lane that fails
        // a polarity's compass test cannot be a corner of that polarity (its 9-arc would hold
        // two adjacent compass points): one arc network on per-lane polarity suffices.
        // Dark lanes use 255 - x on both sides, since (255 - r) - (255 - c) = c - r.
        let flip = _mm256_cmpeq_epi8(over_b, _mm256_setzero_si256());
        let cf = _mm256_xor_si256(c, flip);
        for k in 0..16 {
            d[k] = _mm256_subs_epu8(_mm256_xor_si256(load(p.offset(offs[k])), flip), cf);
        }
        best_arc_min(&d)
    } else {
        for k in 0..16 {
            d[k] = _mm256_subs_epu8(load(p.offset(offs[k])), c);
        }
        let sb = best_arc_min(&d);
        for k in 0..16 {
            d[k] = _mm256_subs_epu8(c, load(p.offset(offs[k])));
        }
        _mm256_max_epu8(sb, best_arc_min(&d))
    };
    // Keep s where s > t (unsigned): max(s, t + 1) == s.
    let t1 = _mm256_add_epi8(t, _mm256_set1_epi8(1));
    let keep = _mm256_cmpeq_epi8(_mm256_max_epu8(s, t1), s);
    _mm256_and_si256(s, keep)
}

/// Bit i set when byte i is non-zero.
#[inline(always)]
unsafe fn nonzero_mask(v: __m256i) -> u32 {
    !(_mm256_movemask_epi8(_mm256_cmpeq_epi8(v, _mm256_setzero_si256())) as u32)
}

/// [`super::fast::detect`] on AVX2 (the caller has checked the CPU, the region and the sizes).
///
/// # Safety
/// The CPU supports AVX2; `img.pad >= 3 + LANES`; the region is non-empty and 4 pixels inside
/// the level; `score_map.len() >= width * height`.
#[target_feature(enable = "avx2")]
pub unsafe fn detect(
    img: &PaddedImage,
    threshold: u8,
    (x0, y0, x1, y1): Region,
    out: &mut Vec<Corner>,
    score_map: &mut [u8],
) {
    let offs: [isize; 16] = CIRCLE.map(|(dx, dy)| dy * img.stride as isize + dx);
    let w = img.width;
    let t = _mm256_set1_epi8(threshold as i8);
    let (sx0, sx1) = (x0 - 1, x1 + 1);
    // Every wide read of a row stays inside the padded buffer: rows y - 3 ..= y + 3 and
    // columns x - 3 .. x + 3 + LANES with x < sx1 <= width - 3 and a pad of 3 + LANES.
    let data = img.data.as_ptr();
    for y in y0 - 1..=y1 {
        let row = img.idx(0, y as isize);
        let mut x = sx0;
        while x < sx1 {
            let s = chunk_scores(data.add(row + x), &offs, t);
            let n = (sx1 - x).min(LANES);
            let at = y * w + x;
            // Never lower a score an earlier (higher-threshold) call wrote.
            if n == LANES {
                let dst = score_map[at..at + LANES].as_mut_ptr() as *mut __m256i;
                _mm256_storeu_si256(dst, _mm256_max_epu8(_mm256_loadu_si256(dst), s));
            } else {
                let mut lanes = [0u8; LANES];
                _mm256_storeu_si256(lanes.as_mut_ptr() as *mut __m256i, s);
                for (d, &v) in score_map[at..at + n].iter_mut().zip(&lanes[..n]) {
                    *d = (*d).max(v);
                }
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
unsafe fn suppress_row(
    map: &[u8],
    w: usize,
    y: usize,
    x0: usize,
    x1: usize,
    out: &mut Vec<Corner>,
) {
    // The 32-byte reads of rows y - 1 ..= y + 1 starting before x1 + 1 stay in the map.
    assert!(y >= 1 && x0 >= 1 && (y + 1) * w + x1 + LANES <= map.len());
    let mut x = x0;
    while x < x1 {
        let at = y * w + x;
        let s = load(map.as_ptr().add(at));
        let mut keep = nonzero_mask(s) & first_lanes(x1 - x);
        if keep != 0 {
            let mut margin = _mm256_set1_epi8(-1);
            for off in ring8(at, w) {
                let n = load(map.as_ptr().add(off));
                margin = _mm256_min_epu8(margin, _mm256_subs_epu8(s, n));
            }
            keep &= nonzero_mask(margin);
            let mut lanes = [0u8; LANES];
            _mm256_storeu_si256(lanes.as_mut_ptr() as *mut __m256i, s);
            emit_kept(keep, &lanes, x, y, out);
        }
        x += LANES;
    }
}
