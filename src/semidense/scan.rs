//! The inner loop of the epipolar search: walk the segment one pixel per step along its
//! major axis, keep the samples passing the three pixel conditions (section III-B) and
//! return the one with the smallest similarity error (eq. 3). Everything a sample needs is
//! in one word per pixel ([`GradientImage::packed`](super::GradientImage::packed)); with
//! AVX-512 sixteen samples at a time, with AVX2 eight, else one (portable fallback).

use super::epipolar::SearchParams;
use super::gradients::{unpack, MODULUS_SCALE};

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

/// Best sample: similarity error, its index, and its residuals r_I, r_G.
#[derive(Clone, Copy, Debug)]
pub(super) struct Best {
    pub e: f32,
    pub k: usize,
    pub ri: f32,
    pub rg: f32,
}

/// Scans `walk` over `t` (an image's packed words, or their transpose for steep lines).
/// Every sample must lie at least one pixel inside the image.
pub(super) fn scan(walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // SAFETY: AVX-512F is available (checked above); gathers read the in-image words of
        // live samples only (masked lanes read nothing).
        return unsafe { scan_avx512(walk, probe, params, t) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is available (checked above); loads and gathers read the in-image
        // words of live samples only (masked lanes read nothing).
        return unsafe { scan_avx2(walk, probe, params, t) };
    }
    scan_scalar(walk, probe, params, t)
}

/// Conditions 1-3 on a code: strong gradient, orientation within lambda_theta of the rotated
/// reference, within lambda_L of the line (either direction).
#[inline]
fn passes(code: u8, probe: &Probe, params: &SearchParams) -> bool {
    let o = code >> 1;
    let d3 = o.wrapping_sub(probe.a_ref) & 127;
    let d2 = o.wrapping_sub(probe.a_line) & 63;
    (code & 1 != 0)
        & (d3.min(128 - d3) < params.lambda_theta_steps)
        & (d2.min(64 - d2) < params.lambda_l_steps)
}

/// Sample k: its two words along the minor axis and the fraction between them (16 bits).
#[inline]
fn words(k: usize, walk: &Walk, t: &[u32]) -> (u32, u32, i32) {
    let major = (walk.major0 + walk.major_step * k as i32) as usize;
    let minor = walk.minor0 + walk.minor_step * k as i32;
    let i0 = major + (minor >> 16) as usize * walk.stride_n;
    (t[i0], t[i0 + walk.stride_n], minor & 0xffff)
}

/// Interpolated intensity and modulus between two words.
#[inline]
fn lerp(v0: u32, v1: u32, frac: i32) -> (f32, f32) {
    let f = frac as f32 * (1.0 / 65536.0);
    let (_, i0, g0) = unpack(v0);
    let (_, i1, g1) = unpack(v1);
    (i0 + (i1 - i0) * f, g0 + (g1 - g0) * f)
}

/// Residuals (r_I, r_G) and similarity error (eq. 3) of sample k.
#[inline]
pub(super) fn residuals(
    k: usize,
    walk: &Walk,
    probe: &Probe,
    params: &SearchParams,
    t: &[u32],
) -> (f32, f32, f32) {
    let (v0, v1, frac) = words(k, walk, t);
    let (i, g) = lerp(v0, v1, frac);
    let (ri, rg) = (probe.intensity - i, probe.modulus - g);
    (
        ri,
        rg,
        (ri * ri + rg * rg * params.inv_theta) * params.inv_sigma_i2,
    )
}

const NONE: Best = Best {
    e: f32::INFINITY,
    k: 0,
    ri: 0.0,
    rg: 0.0,
};

/// Across SIMD lanes (each holding its first minimum): the smallest error, and among equal
/// errors the first sample, as the scalar scan picks.
fn reduce_lanes(es: &[f32], ks: &[i32]) -> Best {
    let mut best = NONE;
    for (e, &k) in es.iter().zip(ks) {
        if *e < best.e || (*e == best.e && e.is_finite() && (k as usize) < best.k) {
            best.e = *e;
            best.k = k as usize;
        }
    }
    best
}

pub(super) fn scan_scalar(walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    let mut best = NONE;
    for k in 0..walk.n {
        let v = t[nearest(k, walk)];
        if passes((v & 255) as u8, probe, params) {
            let e = error(v, probe, params);
            if e < best.e {
                best.e = e;
                best.k = k;
            }
        }
    }
    finish(best, walk, probe, params, t)
}

/// Index of the pixel nearest to sample k.
#[inline]
fn nearest(k: usize, walk: &Walk) -> usize {
    let major = (walk.major0 + walk.major_step * k as i32) as usize;
    let minor = walk.minor0 + walk.minor_step * k as i32;
    major + ((minor + 32768) >> 16) as usize * walk.stride_n
}

/// Similarity error (eq. 3) of a pixel's word.
#[inline]
fn error(v: u32, probe: &Probe, params: &SearchParams) -> f32 {
    let (_, i, g) = unpack(v);
    let (ri, rg) = (probe.intensity - i, probe.modulus - g);
    (ri * ri + rg * rg * params.inv_theta) * params.inv_sigma_i2
}

/// The best sample's residuals on the line itself (interpolated), for the sub-pixel step.
fn finish(mut best: Best, walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    if best.e.is_finite() {
        let (ri, rg, _) = residuals(best.k, walk, probe, params, t);
        best.ri = ri;
        best.rg = rg;
    }
    best
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn scan_avx2(walk: &Walk, probe: &Probe, params: &SearchParams, t: &[u32]) -> Best {
    use std::arch::x86_64::*;
    let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let major_step = _mm256_set1_epi32(walk.major_step);
    let minor_step = _mm256_set1_epi32(walk.minor_step);
    let stride_n = _mm256_set1_epi32(walk.stride_n as i32);
    let half_px = _mm256_set1_epi32(32768);
    let byte = _mm256_set1_epi32(0xff);
    let one = _mm256_set1_epi32(1);
    let m127 = _mm256_set1_epi32(127);
    let m63 = _mm256_set1_epi32(63);
    let c128 = _mm256_set1_epi32(128);
    let c64 = _mm256_set1_epi32(64);
    let a_ref = _mm256_set1_epi32(probe.a_ref as i32);
    let a_line = _mm256_set1_epi32(probe.a_line as i32);
    let t3 = _mm256_set1_epi32(params.lambda_theta_steps as i32);
    let t2 = _mm256_set1_epi32(params.lambda_l_steps as i32);
    let inv_mod = _mm256_set1_ps(1.0 / MODULUS_SCALE);
    let pi = _mm256_set1_ps(probe.intensity);
    let pg = _mm256_set1_ps(probe.modulus);
    let inv_theta = _mm256_set1_ps(params.inv_theta);
    let inv_s2 = _mm256_set1_ps(params.inv_sigma_i2);
    let inf = _mm256_set1_ps(f32::INFINITY);
    let base = t.as_ptr() as *const i32;
    let mut best_e = inf;
    let mut best_k = _mm256_setzero_si256();
    // Lane state, advanced by 8 samples per iteration.
    let mut kv = lanes;
    let mut major = _mm256_add_epi32(
        _mm256_set1_epi32(walk.major0),
        _mm256_mullo_epi32(lanes, major_step),
    );
    let mut minor = _mm256_add_epi32(
        _mm256_set1_epi32(walk.minor0),
        _mm256_mullo_epi32(lanes, minor_step),
    );
    let eight = _mm256_set1_epi32(8);
    let major_8 = _mm256_set1_epi32(8 * walk.major_step);
    let minor_8 = _mm256_set1_epi32(8 * walk.minor_step);
    let n = _mm256_set1_epi32(walk.n as i32);
    let mut k0 = 0usize;
    while k0 < walk.n {
        let live = _mm256_cmpgt_epi32(n, kv);
        // The conditions and the error are evaluated on the pixel nearest to each sample
        // (one gather); the winner's residuals are interpolated on the line afterwards.
        let row = _mm256_srai_epi32::<16>(_mm256_add_epi32(minor, half_px));
        let idx = _mm256_add_epi32(major, _mm256_mullo_epi32(row, stride_n));
        // Few rows crossed by the eight samples: masked contiguous loads, one per row
        // (cheaper than a gather; masked-out lanes read nothing).
        let minor_first = walk.minor0 + walk.minor_step * k0 as i32;
        let r_a = (minor_first + 32768) >> 16;
        let r_b = (minor_first + 7 * walk.minor_step + 32768) >> 16;
        let (r_lo, r_hi) = (r_a.min(r_b), r_a.max(r_b));
        let major_first = walk.major0 as isize + walk.major_step as isize * k0 as isize;
        let near = if r_hi - r_lo < LOAD_ROWS_MAX / 2 {
            let forward = walk.major_step > 0;
            let rev = _mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0);
            // Backward walks: lane l reads major_first - l; load the 8 words ending there
            // in reversed lane order and reverse them afterwards.
            let (row_o, live_o, start) = if forward {
                (row, live, major_first)
            } else {
                (
                    _mm256_permutevar8x32_epi32(row, rev),
                    _mm256_permutevar8x32_epi32(live, rev),
                    major_first - 7,
                )
            };
            let mut near = _mm256_setzero_si256();
            for r in r_lo..=r_hi {
                let m = _mm256_and_si256(live_o, _mm256_cmpeq_epi32(row_o, _mm256_set1_epi32(r)));
                let p = base.wrapping_offset(start + r as isize * walk.stride_n as isize);
                near = _mm256_or_si256(near, _mm256_maskload_epi32(p, m));
            }
            if forward {
                near
            } else {
                _mm256_permutevar8x32_epi32(near, rev)
            }
        } else {
            _mm256_mask_i32gather_epi32::<4>(_mm256_setzero_si256(), base, idx, live)
        };
        let code = _mm256_and_si256(near, byte);
        let o = _mm256_srli_epi32::<1>(code);
        let d3 = _mm256_and_si256(_mm256_sub_epi32(o, a_ref), m127);
        let d3 = _mm256_min_epi32(d3, _mm256_sub_epi32(c128, d3));
        let d2 = _mm256_and_si256(_mm256_sub_epi32(o, a_line), m63);
        let d2 = _mm256_min_epi32(d2, _mm256_sub_epi32(c64, d2));
        let strong = _mm256_cmpeq_epi32(_mm256_and_si256(code, one), one);
        let ok = _mm256_and_si256(
            _mm256_and_si256(strong, live),
            _mm256_and_si256(_mm256_cmpgt_epi32(t3, d3), _mm256_cmpgt_epi32(t2, d2)),
        );
        // Same arithmetic as `error`, eight lanes at a time (no branch on `ok`: it is
        // data-dependent and mispredicts).
        let i = _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<8>(near), byte));
        let g = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32::<16>(near)), inv_mod);
        let ri = _mm256_sub_ps(pi, i);
        let rg = _mm256_sub_ps(pg, g);
        let e = _mm256_mul_ps(
            _mm256_add_ps(
                _mm256_mul_ps(ri, ri),
                _mm256_mul_ps(_mm256_mul_ps(rg, rg), inv_theta),
            ),
            inv_s2,
        );
        let e = _mm256_blendv_ps(inf, e, _mm256_castsi256_ps(ok));
        // Per lane, keep the first minimum (strictly smaller replaces).
        let better = _mm256_cmp_ps::<_CMP_LT_OQ>(e, best_e);
        best_e = _mm256_blendv_ps(best_e, e, better);
        best_k = _mm256_blendv_epi8(best_k, kv, _mm256_castps_si256(better));
        kv = _mm256_add_epi32(kv, eight);
        major = _mm256_add_epi32(major, major_8);
        minor = _mm256_add_epi32(minor, minor_8);
        k0 += 8;
    }
    let mut es = [0.0f32; 8];
    let mut ks = [0i32; 8];
    _mm256_storeu_ps(es.as_mut_ptr(), best_e);
    _mm256_storeu_si256(ks.as_mut_ptr() as *mut __m256i, best_k);
    finish(reduce_lanes(&es, &ks), walk, probe, params, t)
}

/// Most rows sixteen samples may span for the contiguous-load path (beyond it, one gather).
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
    let inv_mod = _mm512_set1_ps(1.0 / MODULUS_SCALE);
    let pi = _mm512_set1_ps(probe.intensity);
    let pg = _mm512_set1_ps(probe.modulus);
    let inv_theta = _mm512_set1_ps(params.inv_theta);
    let inv_s2 = _mm512_set1_ps(params.inv_sigma_i2);
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
                let mut near = _mm512_setzero_si512();
                for r in r_lo..=r_hi {
                    let m = live & _mm512_cmpeq_epi32_mask(row, _mm512_set1_epi32(r));
                    let p = base.wrapping_offset(major_first + r as isize * walk.stride_n as isize);
                    near = _mm512_mask_loadu_epi32(near, m, p);
                }
                near
            } else {
                // Lane l reads the word at major_first - l: load the 16 words ending there
                // and reverse them.
                let rev = _mm512_setr_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
                let row_r = _mm512_permutexvar_epi32(rev, row);
                let live_r = live.reverse_bits();
                let mut near = _mm512_setzero_si512();
                for r in r_lo..=r_hi {
                    let m = live_r & _mm512_cmpeq_epi32_mask(row_r, _mm512_set1_epi32(r));
                    let p = base
                        .wrapping_offset(major_first - 15 + r as isize * walk.stride_n as isize);
                    near = _mm512_mask_loadu_epi32(near, m, p);
                }
                _mm512_permutexvar_epi32(rev, near)
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
        let i = _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32::<8>(near), byte));
        let g = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_srli_epi32::<16>(near)), inv_mod);
        let ri = _mm512_sub_ps(pi, i);
        let rg = _mm512_sub_ps(pg, g);
        let e = _mm512_mul_ps(
            _mm512_add_ps(
                _mm512_mul_ps(ri, ri),
                _mm512_mul_ps(_mm512_mul_ps(rg, rg), inv_theta),
            ),
            inv_s2,
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
    let mut es = [0.0f32; 16];
    let mut ks = [0i32; 16];
    _mm512_storeu_ps(es.as_mut_ptr(), best_e);
    _mm512_storeu_si512(ks.as_mut_ptr() as *mut __m512i, best_k);
    finish(reduce_lanes(&es, &ks), walk, probe, params, t)
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
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: AVX2 checked; the walk stays inside `t`.
                    let b = unsafe { scan_avx2(&walk, &probe, &params, &t) };
                    assert_eq!(key(a), key(b), "AVX2, trial {trial}");
                    simd_checked += 1;
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
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
