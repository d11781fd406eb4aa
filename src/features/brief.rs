//! Steered BRIEF: 256 intensity comparisons between point pairs of a 31 x 31 patch of the
//! blurred level, the pattern rotated by the keypoint angle.
//!
//! The pattern is sampled once, deterministically, from an isotropic Gaussian of standard
//! deviation 31/5 clipped to the patch (Calonder et al.'s G II, the best of their untrained
//! patterns); sdslam does not copy OpenCV's learned table.

use std::sync::OnceLock;

use crate::image::PaddedImage;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// The 256 pairs (x1, y1, x2, y2), integer offsets in [-15, 15].
pub fn pattern() -> &'static [[i8; 4]; 256] {
    static P: OnceLock<[[i8; 4]; 256]> = OnceLock::new();
    P.get_or_init(|| {
        let mut state = 0x5DEE_CE66_D1CE_4E5Bu64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let sigma = 31.0 / 5.0;
        let mut gauss = move || loop {
            // Box-Muller, rejecting samples outside the patch.
            let (u1, u2) = (uniform(), uniform());
            let g = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos() * sigma;
            let r = g.round();
            if r.abs() <= 15.0 {
                return r as i8;
            }
        };
        let mut p = [[0i8; 4]; 256];
        let mut i = 0;
        while i < 256 {
            let q = [gauss(), gauss(), gauss(), gauss()];
            if (q[0], q[1]) != (q[2], q[3]) {
                p[i] = q;
                i += 1;
            }
        }
        p
    })
}

/// The pattern as separate coordinate arrays (first points, then second points), so rotating
/// all 512 points runs as wide integer arithmetic.
pub struct PatternPoints {
    xs: [i32; 512],
    ys: [i32; 512],
}

impl PatternPoints {
    pub fn new() -> Self {
        let mut xs = [0i32; 512];
        let mut ys = [0i32; 512];
        for (i, q) in pattern().iter().enumerate() {
            (xs[i], ys[i]) = (q[0] as i32, q[1] as i32);
            (xs[256 + i], ys[256 + i]) = (q[2] as i32, q[3] as i32);
        }
        PatternPoints { xs, ys }
    }
}

impl Default for PatternPoints {
    fn default() -> Self {
        Self::new()
    }
}

/// sin and cos of the keypoint angle in 12-bit fixed point (the pattern's rotation).
#[inline(always)]
fn steer(angle_deg: f32) -> (i32, i32) {
    let (s, c) = angle_deg.to_radians().sin_cos();
    ((s * 4096.0).round() as i32, (c * 4096.0).round() as i32)
}

/// Computes the steered descriptor of the keypoint at level coordinates (x, y) with `angle` in
/// degrees, sampling `blurred`. The pattern is rotated in 12-bit fixed point (rounding half up),
/// all 512 offsets first, then the 256 comparisons.
#[inline(always)]
pub fn describe(
    blurred: &PaddedImage,
    points: &PatternPoints,
    x: isize,
    y: isize,
    angle_deg: f32,
) -> Descriptor {
    let (s, c) = steer(angle_deg);
    let st = blurred.stride as i32;
    // Offsets from the top-left of a 45 x 45 window centred on the keypoint: every rotated
    // point lies within 22 pixels of the centre, inside the padded image.
    let base = 22 * st + 22;
    let mut offs = [0i32; 512];
    for ((o, &px), &py) in offs.iter_mut().zip(&points.xs).zip(&points.ys) {
        let rx = (px * c - py * s + 2048) >> 12;
        let ry = (px * s + py * c + 2048) >> 12;
        *o = base + ry * st + rx;
    }
    let centre = blurred.idx(x, y);
    let win = &blurred.data[centre - 22 * blurred.stride - 22..centre + 22 * blurred.stride + 23];
    let (first, second) = offs.split_at(256);
    let mut desc = [0u64; 4];
    for (w, word) in desc.iter_mut().enumerate() {
        let mut bits = 0u64;
        for b in 0..64 {
            let i = w * 64 + b;
            let (a, bb) = (win[first[i] as usize], win[second[i] as usize]);
            bits |= ((a < bb) as u64) << b;
        }
        *word = bits;
    }
    desc
}

/// [`describe`] with AVX2 gathers: eight pairs per step, the same offsets (the same 12-bit
/// rotation and rounding) and therefore the same bits.
///
/// # Safety
/// The CPU supports AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub unsafe fn describe_avx2(
    blurred: &PaddedImage,
    points: &PatternPoints,
    x: isize,
    y: isize,
    angle_deg: f32,
) -> Descriptor {
    use std::arch::x86_64::*;
    let (s, c) = steer(angle_deg);
    let st = blurred.stride;
    let centre = blurred.idx(x, y);
    // Every rotated point lies within 22 pixels of the centre, and each gather reads 4 bytes
    // from a point: the 45 x 45 window plus 3 bytes stays inside the buffer.
    assert!(centre >= 22 * st + 22 && centre + 22 * st + 22 + 4 <= blurred.data.len());
    let base = blurred.data.as_ptr().add(centre) as *const i32;
    let (vc, vs) = (_mm256_set1_epi32(c), _mm256_set1_epi32(s));
    let (half, vst) = (_mm256_set1_epi32(2048), _mm256_set1_epi32(st as i32));
    let byte = _mm256_set1_epi32(0xff);
    let offset = |xs: *const i32, ys: *const i32| {
        let px = _mm256_loadu_si256(xs as *const __m256i);
        let py = _mm256_loadu_si256(ys as *const __m256i);
        let rx = _mm256_srai_epi32::<12>(_mm256_add_epi32(
            _mm256_sub_epi32(_mm256_mullo_epi32(px, vc), _mm256_mullo_epi32(py, vs)),
            half,
        ));
        let ry = _mm256_srai_epi32::<12>(_mm256_add_epi32(
            _mm256_add_epi32(_mm256_mullo_epi32(px, vs), _mm256_mullo_epi32(py, vc)),
            half,
        ));
        _mm256_add_epi32(_mm256_mullo_epi32(ry, vst), rx)
    };
    let mut desc = [0u64; 4];
    for g in 0..32 {
        let (xs, ys) = (points.xs.as_ptr().add(8 * g), points.ys.as_ptr().add(8 * g));
        let a = _mm256_i32gather_epi32::<1>(base, offset(xs, ys));
        let b = _mm256_i32gather_epi32::<1>(base, offset(xs.add(256), ys.add(256)));
        let lt = _mm256_cmpgt_epi32(_mm256_and_si256(b, byte), _mm256_and_si256(a, byte));
        let bits = _mm256_movemask_ps(_mm256_castsi256_ps(lt)) as u32 as u64;
        desc[g / 8] |= bits << (8 * (g % 8));
    }
    desc
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 gathers give the portable descriptor bit for bit.
    /// The descriptor bit by bit from the pattern: each point rotated alone and read through
    /// the image's own indexing (not `describe`'s window offsets).
    fn naive(img: &PaddedImage, x: isize, y: isize, a: f32) -> Descriptor {
        let (s, c) = steer(a);
        let rot = |q: [i8; 2]| {
            let (px, py) = (q[0] as i32, q[1] as i32);
            (
                ((px * c - py * s + 2048) >> 12) as isize,
                ((px * s + py * c + 2048) >> 12) as isize,
            )
        };
        let mut d = [0u64; 4];
        for (i, q) in pattern().iter().enumerate() {
            let (ax, ay) = rot([q[0], q[1]]);
            let (bx, by) = rot([q[2], q[3]]);
            let va = img.data[img.idx(x + ax, y + ay)];
            let vb = img.data[img.idx(x + bx, y + by)];
            d[i / 64] |= ((va < vb) as u64) << (i % 64);
        }
        d
    }

    #[test]
    fn portable_and_avx2_descriptors_equal_the_bitwise_definition() {
        let (w, h) = (90usize, 70usize);
        let mut s = 21u64;
        let data: Vec<u8> = (0..w * h)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
                (s >> 56) as u8
            })
            .collect();
        let mut img = PaddedImage::new(w, h, 24);
        img.copy_from(&data);
        let pts = PatternPoints::new();
        for k in 0..200 {
            let (x, y) = (3 + (k * 7) % (w - 6), 2 + (k * 13) % (h - 4));
            let a = (k as f32) * 7.3 % 360.0;
            let (x, y) = (x as isize, y as isize);
            let portable = describe(&img, &pts, x, y, a);
            assert_eq!(portable, naive(&img, x, y, a), "({x}, {y}) at {a}");
            #[cfg(target_arch = "x86_64")]
            if crate::simd::avx2() {
                // SAFETY: AVX2 checked above.
                let fast = unsafe { describe_avx2(&img, &pts, x, y, a) };
                assert_eq!(fast, portable, "AVX2 at ({x}, {y}) at {a}");
            }
        }
    }

    #[test]
    fn pattern_is_deterministic_within_patch_and_balanced() {
        let p = pattern();
        assert!(p.iter().flatten().all(|&v| (-15..=15).contains(&v)));
        let mean_x: f64 = p.iter().map(|q| q[0] as f64).sum::<f64>() / 256.0;
        assert!(mean_x.abs() < 1.5, "{mean_x}");
    }

    #[test]
    fn identical_patches_give_identical_descriptors() {
        let (w, h) = (130usize, 70usize);
        let mut data = vec![0u8; w * h];
        let mut s = 9u64;
        for v in data.iter_mut() {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            *v = (s >> 56) as u8;
        }
        // Copy the 45 x 45 window around (30, 35) to around (80, 35): the rotated pattern
        // reaches at most 15 * sqrt(2) < 22 pixels from the centre.
        for y in 13..58 {
            for x in 8..53 {
                data[y * w + x + 50] = data[y * w + x];
            }
        }
        let mut img = PaddedImage::new(w, h, 24);
        img.copy_from(&data);
        let pts = PatternPoints::new();
        for a in [0.0f32, 33.0, 90.0, 271.5] {
            assert_eq!(
                describe(&img, &pts, 30, 35, a),
                describe(&img, &pts, 80, 35, a),
                "angle {a}"
            );
        }
        assert_ne!(
            describe(&img, &pts, 30, 35, 0.0),
            describe(&img, &pts, 31, 35, 0.0)
        );
    }
}
