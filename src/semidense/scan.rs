//! The inner loop of the epipolar search: walk the segment one pixel per step along its
//! major axis, keep the samples passing the three pixel conditions (section III-B) and
//! return the one with the smallest similarity error (eq. 3). Everything a sample needs is
//! in one word per pixel ([`GradientImage::packed`](super::GradientImage::packed)); with
//! AVX-512 sixteen samples at a time, with AVX2 eight, else four ([`portable`]: SSE or
//! NEON, one source for both).

use super::epipolar::SearchParams;
use super::gradients::{unpack, MODULUS_SCALE};

mod portable;
use portable::scan_lanes;

/// A rasterised segment: sample k is at major coordinate `major0 + k * major_step` and minor
/// coordinate `(minor0 + k * minor_step) / 65536` (16.16 fixed point).
#[derive(Clone, Copy, Debug)]
pub(super) struct Walk {
    pub major0: i32,
    pub major_step: i32,
    pub minor0: i32,
    pub minor_step: i32,
    /// Index stride of the minor axis (the major axis has stride 1: steep lines walk the
    /// transposed image).
    pub stride_n: usize,
    pub n: usize,
}

/// The reference pixel as the scan needs it.
#[derive(Clone, Copy, Debug)]
pub(super) struct Probe {
    pub intensity: f32,
    pub modulus: f32,
    /// Reference orientation rotated into the neighbour, and the line direction, in steps.
    pub a_ref: u8,
    pub a_line: u8,
}

/// Best sample: similarity error, its index, and (when the error is at most the accepted
/// maximum) its residuals r_I, r_G and the derivatives g, q along the line (eq. 5, per step).
#[derive(Clone, Copy, Debug)]
pub(super) struct Best {
    pub e: f32,
    pub k: usize,
    pub ri: f32,
    pub rg: f32,
    pub g: f32,
    pub q: f32,
}

/// Scans `walk` over `t` (an image's packed words, or their transpose for steep lines).
/// Every sample must lie at least two pixels inside the image (the AVX2 path reads the eight
/// words of a step and the row on either side unmasked).
pub(super) fn scan(walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx512f() {
        // SAFETY: AVX-512F is available (checked above); gathers read the in-image words of
        // live samples only (masked lanes read nothing).
        return unsafe { scan_avx512(walk, probe, params, t) };
    }
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx2() {
        // SAFETY: AVX2 is available (checked above); loads and gathers read the in-image
        // words of live samples only (masked lanes read nothing).
        return unsafe { scan_avx2(walk, probe, params, t) };
    }
    scan_lanes(walk, probe, params, t)
}

/// Conditions 1-3 on a code: strong gradient, orientation within lambda_theta of the rotated
/// reference, within lambda_L of the line (either direction). The definition the vector
/// scans are tested against.
#[cfg(test)]
#[inline]
fn passes(code: u8, probe: &Probe, params: &SearchParams) -> bool {
    let o = code >> 1;
    let d3 = o.wrapping_sub(probe.a_ref) & 127;
    let d2 = o.wrapping_sub(probe.a_line) & 63;
    (code & 1 != 0)
        & (d3.min(128 - d3) < params.lambda_theta_steps)
        & (d2.min(64 - d2) < params.lambda_l_steps)
}

/// Offsets and bounds that turn a circular test `min(d, M - d) < t` on `d = (o - a) mod M`
/// into one subtraction, mask and comparison: `(o - (a + 1 - t)) mod M < 2 t - 1`.
#[inline]
fn circular_test(a: u8, t: u8, modulus: i32) -> (i32, i32) {
    let t = t as i32;
    ((a as i32 + 1 - t).rem_euclid(modulus), 2 * t - 1)
}

/// The similarity error (eq. 3) up to the factor 1 / sigma_I^2, from the intensity and
/// the modulus in fixed point (exact integers in f32), so the scan needs two products and a
/// sum per sample; [`finish`] applies the factor to the winner. The vector scans compute it
/// lane by lane with the same operations in the same order.
#[cfg(test)]
#[inline]
fn ranking_error(v: u32, pi: f32, pg_fixed: f32, k_g: f32) -> f32 {
    let ri = pi - ((v >> 8) & 255) as f32;
    let rg = pg_fixed - (v >> 16) as f32;
    ri * ri + rg * rg * k_g
}

/// Constants of [`ranking_error`]: the probe's modulus in the packed fixed point, and
/// 1 / theta in those units.
#[inline]
fn ranking_constants(probe: &Probe, params: &SearchParams) -> (f32, f32) {
    (
        probe.modulus * MODULUS_SCALE,
        params.inv_theta / (MODULUS_SCALE * MODULUS_SCALE),
    )
}

/// Interpolated intensity and modulus between two words.
#[inline]
fn lerp(v0: u32, v1: u32, frac: i32) -> (f32, f32) {
    let f = frac as f32 * (1.0 / 65536.0);
    let (_, i0, g0) = unpack(v0);
    let (_, i1, g1) = unpack(v1);
    (i0 + (i1 - i0) * f, g0 + (g1 - g0) * f)
}

/// Interpolated (intensity, modulus) at sample k; k may be one step outside the walk.
#[inline]
fn sample_at(k: isize, walk: &Walk, t: &[u32]) -> (f32, f32) {
    let major = (walk.major0 as isize + walk.major_step as isize * k) as usize;
    let minor = walk.minor0 as isize + walk.minor_step as isize * k;
    let i0 = major + (minor >> 16) as usize * walk.stride_n;
    lerp(t[i0], t[i0 + walk.stride_n], (minor & 0xffff) as i32)
}

const NONE: Best = Best {
    e: f32::INFINITY,
    k: 0,
    ri: 0.0,
    rg: 0.0,
    g: 0.0,
    q: 0.0,
};

/// The reference: one sample after the other, one running minimum (what every other scan is
/// tested equal to).
#[cfg(test)]
pub(super) fn scan_scalar(walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    let (pg_fixed, k_g) = ranking_constants(probe, params);
    let mut best = NONE;
    // Without branches on the sample (whether it passes is data and mispredicts): every
    // sample's error is computed and taken by selection.
    for k in 0..walk.n {
        let v = t[nearest(k, walk)];
        let e = ranking_error(v, probe.intensity, pg_fixed, k_g);
        let take = passes((v & 255) as u8, probe, params) & (e < best.e);
        best.e = if take { e } else { best.e };
        best.k = if take { k } else { best.k };
    }
    finish(best, walk, probe, params, t)
}

/// Index of the pixel nearest to sample k.
#[cfg(test)]
#[inline]
fn nearest(k: usize, walk: &Walk) -> usize {
    let major = (walk.major0 + walk.major_step * k as i32) as usize;
    let minor = walk.minor0 + walk.minor_step * k as i32;
    major + ((minor + 32768) >> 16) as usize * walk.stride_n
}

/// The winner's similarity error (eq. 3); if acceptable, its residuals and the derivatives
/// along the line (eq. 5) from the samples on either side, interpolated on the line itself.
fn finish(mut best: Best, walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    best.e *= params.inv_sigma_i2;
    if best.e <= params.max_error {
        let k = best.k as isize;
        let (i, g) = sample_at(k, walk, t);
        let (ip, gp) = sample_at(k + 1, walk, t);
        let (im, gm) = sample_at(k - 1, walk, t);
        best.ri = probe.intensity - i;
        best.rg = probe.modulus - g;
        best.g = 0.5 * (ip - im);
        best.q = 0.5 * (gp - gm);
    }
    best
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn scan_avx2(walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    // Eight samples of a shallow walk (less than one row over seven steps) lie on at most
    // two rows: two loads and a blend; steeper walks gather.
    if 7 * walk.minor_step.unsigned_abs() < 65536 {
        scan_avx2_with::<true>(walk, probe, params, t)
    } else {
        scan_avx2_with::<false>(walk, probe, params, t)
    }
}

/// Eight samples per step. Lane l holds the samples at memory position `pos + l` along the
/// major axis (backward walks: sample indices descend across the lanes), so contiguous
/// loads need no lane reversal. The eight words of a step, and of the row on either side,
/// lie inside `t` because every sample is at least two pixels inside the image; lanes past
/// the end of the walk are masked out of the result only.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn scan_avx2_with<const SHALLOW: bool>(
    walk: &Walk,
    probe: &Probe,
    params: &SearchParams,
    t: &[u32],
) -> Best {
    use std::arch::x86_64::*;
    let forward = walk.major_step > 0;
    // Sample index of each lane in the first step.
    let k_first = if forward {
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7)
    } else {
        _mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0)
    };
    let (k3, b3) = circular_test(probe.a_ref, params.lambda_theta_steps, 128);
    let (k2, b2) = circular_test(probe.a_line, params.lambda_l_steps, 64);
    let (k3, b3) = (_mm256_set1_epi32(k3), _mm256_set1_epi32(b3));
    let (k2, b2) = (_mm256_set1_epi32(k2), _mm256_set1_epi32(b2));
    let m127 = _mm256_set1_epi32(127);
    let m63 = _mm256_set1_epi32(63);
    let (pg_fixed, k_g) = ranking_constants(probe, params);
    let pi = _mm256_set1_ps(probe.intensity);
    let pg = _mm256_set1_ps(pg_fixed);
    let k_g = _mm256_set1_ps(k_g);
    // Byte 1 of each word (the intensity) to the low byte, zero-extended.
    let intensity_bytes = _mm256_setr_epi8(
        1, -1, -1, -1, 5, -1, -1, -1, 9, -1, -1, -1, 13, -1, -1, -1, 1, -1, -1, -1, 5, -1, -1, -1,
        9, -1, -1, -1, 13, -1, -1, -1,
    );
    let base = t.as_ptr() as *const i32;
    let stride = walk.stride_n as isize;
    let mut best_e = _mm256_set1_ps(f32::INFINITY);
    let mut best_k = _mm256_setzero_si256();
    let mut kv = k_first;
    let k_step = _mm256_set1_epi32(8);
    // Rounded minor coordinate of each lane (16.16 fixed point, + 0.5 for rounding).
    let mut minor = _mm256_add_epi32(
        _mm256_set1_epi32(walk.minor0 + 32768),
        _mm256_mullo_epi32(k_first, _mm256_set1_epi32(walk.minor_step)),
    );
    let minor_8 = _mm256_set1_epi32(8 * walk.minor_step);
    // Memory position (major coordinate) of lane 0, and its rounded minor coordinate.
    let back = if forward { 0 } else { 7 };
    let mut pos = walk.major0 as isize - back;
    let pos_8: isize = if forward { 8 } else { -8 };
    let mut minor_lane0 = walk.minor0 + 32768 + walk.minor_step * back as i32;
    let minor_lane0_8 = 8 * walk.minor_step;
    // The other row a shallow step may touch, relative to lane 0's.
    let next_row = (walk.minor_step.signum() * if forward { 1 } else { -1 }) as isize * stride;
    let stride_v = _mm256_set1_epi32(walk.stride_n as i32);
    let pos_lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let n_v = _mm256_set1_epi32(walk.n as i32);
    let mut k0 = 0usize;
    while k0 < walk.n {
        let row = _mm256_srai_epi32::<16>(minor);
        let live = _mm256_cmpgt_epi32(n_v, kv);
        let near = if SHALLOW {
            let r0 = minor_lane0 >> 16;
            let p = base.wrapping_offset(pos + r0 as isize * stride);
            let a = _mm256_loadu_si256(p as *const __m256i);
            let b = _mm256_loadu_si256(p.wrapping_offset(next_row) as *const __m256i);
            _mm256_blendv_epi8(b, a, _mm256_cmpeq_epi32(row, _mm256_set1_epi32(r0)))
        } else {
            let idx = _mm256_add_epi32(
                _mm256_add_epi32(_mm256_set1_epi32(pos as i32), pos_lanes),
                _mm256_mullo_epi32(row, stride_v),
            );
            // Masked: past the end of the walk a steep line soon leaves the image.
            _mm256_mask_i32gather_epi32::<4>(_mm256_setzero_si256(), base, idx, live)
        };
        let o = _mm256_srli_epi32::<1>(_mm256_and_si256(near, _mm256_set1_epi32(0xff)));
        let c3 = _mm256_cmpgt_epi32(b3, _mm256_and_si256(_mm256_sub_epi32(o, k3), m127));
        let c2 = _mm256_cmpgt_epi32(b2, _mm256_and_si256(_mm256_sub_epi32(o, k2), m63));
        // Bit 0 (strong gradient) to the sign bit, which is all the blends below read.
        let ok = _mm256_and_si256(_mm256_and_si256(c3, c2), _mm256_slli_epi32::<31>(near));
        let ri = _mm256_sub_ps(
            pi,
            _mm256_cvtepi32_ps(_mm256_shuffle_epi8(near, intensity_bytes)),
        );
        let rg = _mm256_sub_ps(pg, _mm256_cvtepi32_ps(_mm256_srli_epi32::<16>(near)));
        let e = _mm256_add_ps(
            _mm256_mul_ps(ri, ri),
            _mm256_mul_ps(_mm256_mul_ps(rg, rg), k_g),
        );
        // Per lane, keep the first minimum (strictly smaller replaces); lanes past the end
        // of the walk are dropped.
        let better = _mm256_castsi256_ps(_mm256_and_si256(
            _mm256_and_si256(
                _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(e, best_e)),
                ok,
            ),
            live,
        ));
        best_e = _mm256_blendv_ps(best_e, e, better);
        best_k = _mm256_castps_si256(_mm256_blendv_ps(
            _mm256_castsi256_ps(best_k),
            _mm256_castsi256_ps(kv),
            better,
        ));
        kv = _mm256_add_epi32(kv, k_step);
        minor = _mm256_add_epi32(minor, minor_8);
        pos += pos_8;
        minor_lane0 += minor_lane0_8;
        k0 += 8;
    }
    finish(reduce_avx2(best_e, best_k), walk, probe, params, t)
}

/// Across the lanes (each holding its first minimum), without branches: the smallest error,
/// then the smallest sample index among the lanes holding it, as the scalar scan picks.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn reduce_avx2(e: std::arch::x86_64::__m256, k: std::arch::x86_64::__m256i) -> Best {
    use std::arch::x86_64::*;
    let m = _mm256_min_ps(e, _mm256_permute2f128_ps::<1>(e, e));
    let m = _mm256_min_ps(m, _mm256_shuffle_ps::<0b01_00_11_10>(m, m));
    let m = _mm256_min_ps(m, _mm256_shuffle_ps::<0b10_11_00_01>(m, m));
    let min = _mm256_cvtss_f32(m);
    if min == f32::INFINITY {
        return NONE;
    }
    let at_min = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_EQ_OQ>(e, m));
    let ks = _mm256_blendv_epi8(_mm256_set1_epi32(i32::MAX), k, at_min);
    let ks = _mm256_min_epi32(ks, _mm256_permute2x128_si256::<1>(ks, ks));
    let ks = _mm256_min_epi32(ks, _mm256_shuffle_epi32::<0b01_00_11_10>(ks));
    let ks = _mm256_min_epi32(ks, _mm256_shuffle_epi32::<0b10_11_00_01>(ks));
    Best {
        e: min,
        k: _mm256_cvtsi256_si32(ks) as usize,
        ..NONE
    }
}

/// Most rows sixteen samples may span for the contiguous-load path (beyond it, one gather).
#[cfg(target_arch = "x86_64")]
const LOAD_ROWS_MAX: i32 = 8;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn scan_avx512(walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    use std::arch::x86_64::*;
    let lanes = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    let stride_n = _mm512_set1_epi32(walk.stride_n as i32);
    let half_px = _mm512_set1_epi32(32768);
    let byte = _mm512_set1_epi32(0xff);
    let one = _mm512_set1_epi32(1);
    let m127 = _mm512_set1_epi32(127);
    let m63 = _mm512_set1_epi32(63);
    let c128 = _mm512_set1_epi32(128);
    let c64 = _mm512_set1_epi32(64);
    let a_ref = _mm512_set1_epi32(probe.a_ref as i32);
    let a_line = _mm512_set1_epi32(probe.a_line as i32);
    let t3 = _mm512_set1_epi32(params.lambda_theta_steps as i32);
    let t2 = _mm512_set1_epi32(params.lambda_l_steps as i32);
    let (pg_fixed, k_g) = ranking_constants(probe, params);
    let pi = _mm512_set1_ps(probe.intensity);
    let pg = _mm512_set1_ps(pg_fixed);
    let k_g = _mm512_set1_ps(k_g);
    let inf = _mm512_set1_ps(f32::INFINITY);
    let mut best_e = inf;
    let mut best_k = _mm512_setzero_si512();
    let mut kv = lanes;
    let mut major = _mm512_add_epi32(
        _mm512_set1_epi32(walk.major0),
        _mm512_mullo_epi32(lanes, _mm512_set1_epi32(walk.major_step)),
    );
    let mut minor = _mm512_add_epi32(
        _mm512_set1_epi32(walk.minor0),
        _mm512_mullo_epi32(lanes, _mm512_set1_epi32(walk.minor_step)),
    );
    let sixteen = _mm512_set1_epi32(16);
    let major_16 = _mm512_set1_epi32(16 * walk.major_step);
    let minor_16 = _mm512_set1_epi32(16 * walk.minor_step);
    let n = _mm512_set1_epi32(walk.n as i32);
    let mut k0 = 0usize;
    while k0 < walk.n {
        let live = _mm512_cmpgt_epi32_mask(n, kv);
        let row = _mm512_srai_epi32::<16>(_mm512_add_epi32(minor, half_px));
        // The sixteen samples' rows (of the walked image) span r_lo..=r_hi; a shallow line
        // crosses few rows, and one masked contiguous load per row is much cheaper than a
        // gather (masked-out lanes read nothing).
        let minor_first = walk.minor0 + walk.minor_step * k0 as i32;
        let r_a = (minor_first + 32768) >> 16;
        let r_b = (minor_first + 15 * walk.minor_step + 32768) >> 16;
        let (r_lo, r_hi) = (r_a.min(r_b), r_a.max(r_b));
        let major_first = walk.major0 as isize + walk.major_step as isize * k0 as isize;
        let near = if r_hi - r_lo < LOAD_ROWS_MAX {
            let base = t.as_ptr() as *const i32;
            if walk.major_step > 0 {
                let load = |near, r: i32| {
                    let m = live & _mm512_cmpeq_epi32_mask(row, _mm512_set1_epi32(r));
                    let p = base.wrapping_offset(major_first + r as isize * walk.stride_n as isize);
                    _mm512_mask_loadu_epi32(near, m, p)
                };
                rows_fold(r_lo, r_hi, _mm512_setzero_si512(), load)
            } else {
                // Lane l reads the word at major_first - l: load the 16 words ending there
                // and reverse them.
                let rev = _mm512_setr_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
                let row_r = _mm512_permutexvar_epi32(rev, row);
                let live_r = live.reverse_bits();
                let load = |near, r: i32| {
                    let m = live_r & _mm512_cmpeq_epi32_mask(row_r, _mm512_set1_epi32(r));
                    let p = base
                        .wrapping_offset(major_first - 15 + r as isize * walk.stride_n as isize);
                    _mm512_mask_loadu_epi32(near, m, p)
                };
                _mm512_permutexvar_epi32(rev, rows_fold(r_lo, r_hi, _mm512_setzero_si512(), load))
            }
        } else {
            let idx = _mm512_add_epi32(major, _mm512_mullo_epi32(row, stride_n));
            _mm512_mask_i32gather_epi32::<4>(
                _mm512_setzero_si512(),
                live,
                idx,
                t.as_ptr() as *const i32,
            )
        };
        let code = _mm512_and_si512(near, byte);
        let o = _mm512_srli_epi32::<1>(code);
        let d3 = _mm512_and_si512(_mm512_sub_epi32(o, a_ref), m127);
        let d3 = _mm512_min_epi32(d3, _mm512_sub_epi32(c128, d3));
        let d2 = _mm512_and_si512(_mm512_sub_epi32(o, a_line), m63);
        let d2 = _mm512_min_epi32(d2, _mm512_sub_epi32(c64, d2));
        let ok = live
            & _mm512_cmpeq_epi32_mask(_mm512_and_si512(code, one), one)
            & _mm512_cmpgt_epi32_mask(t3, d3)
            & _mm512_cmpgt_epi32_mask(t2, d2);
        // Same arithmetic as `error`, sixteen lanes at a time; no branch on `ok` (it is
        // data-dependent and mispredicts, exposing the gather latency every time).
        // `ranking_error`, sixteen lanes at a time.
        let i = _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32::<8>(near), byte));
        let g = _mm512_cvtepi32_ps(_mm512_srli_epi32::<16>(near));
        let ri = _mm512_sub_ps(pi, i);
        let rg = _mm512_sub_ps(pg, g);
        let e = _mm512_add_ps(
            _mm512_mul_ps(ri, ri),
            _mm512_mul_ps(_mm512_mul_ps(rg, rg), k_g),
        );
        // Per lane, keep the first minimum (strictly smaller replaces).
        let better = ok & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(e, best_e);
        best_e = _mm512_mask_blend_ps(better, best_e, e);
        best_k = _mm512_mask_blend_epi32(better, best_k, kv);
        kv = _mm512_add_epi32(kv, sixteen);
        major = _mm512_add_epi32(major, major_16);
        minor = _mm512_add_epi32(minor, minor_16);
        k0 += 16;
    }
    finish(reduce_avx512(best_e, best_k), walk, probe, params, t)
}

/// Folds `load` over rows `r_lo..=r_hi`. Shallow lines cross one or two rows per sixteen
/// samples, unpredictably: both are loaded without a loop (a load whose mask is empty reads
/// nothing), so the loop's exit no longer mispredicts.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn rows_fold<V>(r_lo: i32, r_hi: i32, init: V, mut load: impl FnMut(V, i32) -> V) -> V {
    if r_hi - r_lo <= 1 {
        let v = load(init, r_lo);
        return load(v, r_lo + 1);
    }
    (r_lo..=r_hi).fold(init, load)
}

/// [`reduce_avx2`] on sixteen lanes (a scalar loop over them mispredicted once per search).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn reduce_avx512(e: std::arch::x86_64::__m512, k: std::arch::x86_64::__m512i) -> Best {
    use std::arch::x86_64::*;
    let min = _mm512_reduce_min_ps(e);
    if min == f32::INFINITY {
        return NONE;
    }
    let at_min = _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(e, _mm512_set1_ps(min));
    Best {
        e: min,
        k: _mm512_mask_reduce_min_epi32(at_min, k) as usize,
        ..NONE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The SIMD (AVX2, AVX-512) and scalar scans give identical results on random words
    /// and lines.
    #[test]
    fn simd_and_scalar_scans_agree() {
        let (w, h) = (64usize, 48usize);
        let mut t = vec![0u32; w * h + 1];
        let mut s = 12345u64;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        for v in t.iter_mut().take(w * h) {
            *v = (rnd() & 0xffff_ffff) as u32;
        }
        let params = SearchParams::from_config(&crate::config::SemiDenseConfig::default());
        #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
        let mut simd_checked = 0;
        for trial in 0..2000 {
            // Walks along rows of the image, or of its transpose (stride h).
            let horizontal = trial % 2 == 0;
            let (len_m, len_n) = if horizontal { (w, h) } else { (h, w) };
            // Shallow and steep slopes (up to 1: the walk follows the major axis), forward
            // and backward walks, all samples inside the image.
            let minor_step = if trial % 4 < 2 {
                (rnd() % 2000) as i32 - 1000
            } else {
                (rnd() % 131_073) as i32 - 65_536
            };
            let minor_start = 2 + rnd() as usize % (len_n - 6);
            let room = if minor_step >= 0 {
                len_n - 3 - minor_start
            } else {
                minor_start - 1
            };
            let by_minor = match minor_step.unsigned_abs() as usize {
                0 => len_m,
                s => room * 65_536 / s,
            };
            let n = 1 + rnd() as usize % (len_m - 6).min(by_minor).max(1);
            let forward = rnd() % 2 == 0;
            let start = 2 + rnd() as usize % (len_m - 4 - n);
            let walk = Walk {
                major0: if forward { start } else { start + n - 1 } as i32,
                major_step: if forward { 1 } else { -1 },
                minor0: (minor_start << 16) as i32,
                minor_step,
                stride_n: len_m,
                n,
            };
            let probe = Probe {
                intensity: (rnd() % 256) as f32,
                modulus: (rnd() % 40) as f32,
                a_ref: (rnd() % 128) as u8,
                a_line: (rnd() % 128) as u8,
            };
            let a = scan_scalar(&walk, &probe, &params, &t);
            let key = |b: Best| (b.e.to_bits(), b.k, b.ri.to_bits(), b.rg.to_bits());
            let b = scan_lanes(&walk, &probe, &params, &t);
            assert_eq!(key(a), key(b), "portable lanes, trial {trial}");
            #[cfg(target_arch = "x86_64")]
            {
                if crate::simd::avx2() {
                    // SAFETY: AVX2 checked; the walk stays inside `t`.
                    let b = unsafe { scan_avx2(&walk, &probe, &params, &t) };
                    assert_eq!(key(a), key(b), "AVX2, trial {trial}");
                    simd_checked += 1;
                }
                if crate::simd::avx512f() {
                    // SAFETY: AVX-512F checked; the walk stays inside `t`.
                    let b = unsafe { scan_avx512(&walk, &probe, &params, &t) };
                    assert_eq!(key(a), key(b), "AVX-512, trial {trial}");
                }
            }
            let b = scan(&walk, &probe, &params, &t);
            assert_eq!(key(a), key(b), "dispatch, trial {trial}");
        }
        // On x86-64 build machines the SIMD paths must have been compared.
        if cfg!(target_arch = "x86_64") {
            assert!(
                simd_checked > 0,
                "no AVX2 on this machine: SIMD scan untested"
            );
        }
    }
}
