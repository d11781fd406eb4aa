//! Separable 7x7 Gaussian blur (sigma 2) in fixed point: the smoothing ORB applies before
//! sampling BRIEF pairs, so descriptors are robust to noise.

use super::PaddedImage;

/// 7-tap Gaussian, sigma 2, scaled to sum 256.
const KERNEL: [u32; 7] = gaussian_kernel();

/// The kernel's distinct taps, outermost first, for the paired (symmetric) sums.
const K0: u16 = KERNEL[0] as u16;
const K1: u16 = KERNEL[1] as u16;
const K2: u16 = KERNEL[2] as u16;
const K3: u16 = KERNEL[3] as u16;
const _: () = assert!(KERNEL[0] == KERNEL[6] && KERNEL[1] == KERNEL[5] && KERNEL[2] == KERNEL[4]);

const fn gaussian_kernel() -> [u32; 7] {
    // exp(-x^2 / 8) for x = 0..3: 1, 0.8825, 0.6065, 0.3247; normalised, rounded, sum 256.
    [18, 33, 48, 58, 48, 33, 18]
}

/// Blurs the interior of `src` into `dst` (same size and pad), then fills `dst`'s border.
/// `tmp` holds the vertical pass (resized once). Both passes run in 16-bit lanes: the kernel sums
/// to 256, so `255 * 256` fits; the intermediate is rounded to 8 bits (error <= 1 grey level).
#[inline(always)]
pub fn gaussian_blur_7x7(
    src: &PaddedImage,
    dst: &mut PaddedImage,
    tmp: &mut Vec<u16>,
    filled: usize,
) {
    let (w, h) = (src.width, src.height);
    debug_assert!(src.pad >= 3 && dst.width == w && dst.height == h);
    // Vertical pass first, over interior rows and 3 border columns each side (contiguous rows
    // vectorise well).
    let tw = w + 6;
    tmp.resize(h * tw, 0);
    let st = src.stride;
    #[cfg(target_arch = "x86_64")]
    let avx2 = crate::simd::avx2();
    for y in 0..h {
        let base = src.idx(-3, y as isize);
        let out = &mut tmp[y * tw..(y + 1) * tw];
        let rows: [&[u8]; 7] = std::array::from_fn(|k| {
            let b = base + k * st - 3 * st;
            &src.data[b..b + tw]
        });
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: AVX2 checked above.
            unsafe { vertical_avx2(&rows, out) };
            continue;
        }
        vertical(&rows, out, 0);
    }
    // Horizontal pass.
    for y in 0..h {
        let t = &tmp[y * tw..(y + 1) * tw];
        let out = dst.row_mut(y);
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: AVX2 checked above.
            unsafe { horizontal_avx2(t, out) };
            continue;
        }
        horizontal(t, out, 0);
    }
    dst.fill_border_width(filled);
}

/// Vertical taps of columns `from..` of `out` (the 7 rows and `out` have the same length).
/// The kernel is symmetric: taps are paired first (4 multiplies instead of 7; the integer sums
/// are the same).
#[inline(always)]
fn vertical(rows: &[&[u8]; 7], out: &mut [u16], from: usize) {
    for x in from..out.len() {
        let tap = |a: usize, b: usize| rows[a][x] as u16 + rows[b][x] as u16;
        let acc = K0 * tap(0, 6) + K1 * tap(1, 5) + K2 * tap(2, 4) + K3 * rows[3][x] as u16;
        out[x] = (acc + 128) >> 8;
    }
}

/// Horizontal taps of outputs `from..` (`t` has 6 more values than `out`).
#[inline(always)]
fn horizontal(t: &[u16], out: &mut [u8], from: usize) {
    for x in from..out.len() {
        let tap = |a: usize, b: usize| t[x + a] + t[x + b];
        let acc = K0 * tap(0, 6) + K1 * tap(1, 5) + K2 * tap(2, 4) + K3 * t[x + 3];
        out[x] = ((acc + 128) >> 8) as u8;
    }
}

/// The rounded 7-tap sum of 16 lanes of 16-bit values (taps paired, as in [`vertical`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn taps_avx2(r: &[std::arch::x86_64::__m256i; 7]) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    let k = |v: u16| _mm256_set1_epi16(v as i16);
    let acc = _mm256_add_epi16(
        _mm256_add_epi16(
            _mm256_mullo_epi16(_mm256_add_epi16(r[0], r[6]), k(K0)),
            _mm256_mullo_epi16(_mm256_add_epi16(r[1], r[5]), k(K1)),
        ),
        _mm256_add_epi16(
            _mm256_mullo_epi16(_mm256_add_epi16(r[2], r[4]), k(K2)),
            _mm256_mullo_epi16(r[3], k(K3)),
        ),
    );
    _mm256_srli_epi16::<8>(_mm256_add_epi16(acc, _mm256_set1_epi16(128)))
}

/// [`vertical`], 16 columns per step (LLVM kept the 7 zero-extended rows in 128-bit halves).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn vertical_avx2(rows: &[&[u8]; 7], out: &mut [u16]) {
    use std::arch::x86_64::*;
    let n = out.len();
    assert!(rows.iter().all(|r| r.len() == n));
    let mut x = 0;
    while x + 16 <= n {
        let r: [__m256i; 7] = std::array::from_fn(|i| {
            _mm256_cvtepu8_epi16(_mm_loadu_si128(rows[i].as_ptr().add(x) as *const __m128i))
        });
        let v = taps_avx2(&r);
        _mm256_storeu_si256(out.as_mut_ptr().add(x) as *mut __m256i, v);
        x += 16;
    }
    vertical(rows, out, x);
}

/// [`horizontal`], 16 outputs per step.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn horizontal_avx2(t: &[u16], out: &mut [u8]) {
    use std::arch::x86_64::*;
    let n = out.len();
    assert!(t.len() >= n + 6);
    let mut x = 0;
    while x + 16 <= n {
        let r: [__m256i; 7] =
            std::array::from_fn(|i| _mm256_loadu_si256(t.as_ptr().add(x + i) as *const __m256i));
        let v = taps_avx2(&r);
        // Values are <= 255: pack the two 128-bit halves' words to 16 bytes.
        let packed = _mm256_packus_epi16(v, v);
        let bytes = _mm256_permute4x64_epi64::<0b1000>(packed);
        _mm_storeu_si128(
            out.as_mut_ptr().add(x) as *mut __m128i,
            _mm256_castsi256_si128(bytes),
        );
        x += 16;
    }
    horizontal(t, out, x);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 passes equal the scalar ones on random rows of awkward lengths.
    #[test]
    fn avx2_passes_equal_scalar() {
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2() {
            let mut s = 3u64;
            let mut rnd = || {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
                (s >> 56) as u8
            };
            for n in [1usize, 15, 16, 17, 40, 77] {
                let rows: Vec<Vec<u8>> = (0..7).map(|_| (0..n).map(|_| rnd()).collect()).collect();
                let rows: [&[u8]; 7] = std::array::from_fn(|i| &rows[i][..]);
                let (mut a, mut b) = (vec![0u16; n], vec![0u16; n]);
                vertical(&rows, &mut a, 0);
                // SAFETY: AVX2 checked above.
                unsafe { vertical_avx2(&rows, &mut b) };
                assert_eq!(a, b, "vertical, {n}");
                let t: Vec<u16> = (0..n + 6).map(|_| rnd() as u16).collect();
                let (mut c, mut d) = (vec![0u8; n], vec![0u8; n]);
                horizontal(&t, &mut c, 0);
                // SAFETY: AVX2 checked above.
                unsafe { horizontal_avx2(&t, &mut d) };
                assert_eq!(c, d, "horizontal, {n}");
            }
        }
    }

    #[test]
    fn kernel_sums_to_256_and_flat_stays_flat() {
        assert_eq!(KERNEL.iter().sum::<u32>(), 256);
        let mut a = PaddedImage::new(20, 10, 4);
        a.copy_from(&[100; 200]);
        let mut b = PaddedImage::new(20, 10, 4);
        let mut t = Vec::new();
        gaussian_blur_7x7(&a, &mut b, &mut t, 3);
        assert!(b.row(5).iter().all(|&v| v == 100));
    }

    #[test]
    fn impulse_spreads_symmetrically() {
        let mut img = vec![0u8; 21 * 21];
        img[10 * 21 + 10] = 255;
        let mut a = PaddedImage::new(21, 21, 4);
        a.copy_from(&img);
        let mut b = PaddedImage::new(21, 21, 4);
        gaussian_blur_7x7(&a, &mut b, &mut Vec::new(), 3);
        assert_eq!(b.at(9, 10), b.at(11, 10));
        assert_eq!(b.at(10, 8), b.at(10, 12));
        assert!(b.at(10, 10) > b.at(11, 10) && b.at(11, 10) > b.at(12, 10));
        assert_eq!(b.at(14, 10), 0);
    }
}
