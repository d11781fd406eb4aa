//! Harris corner response (Harris & Stephens 1988) of single keypoints, used to rank FAST
//! corners: it varies smoothly with the image, so the ranking survives small warps better than
//! FAST's threshold score does.

use crate::image::PaddedImage;

/// Window of the structure tensor (pixels per side), as in ORB (Rublee et al. 2011).
pub const HARRIS_BLOCK: usize = 7;
/// The Harris sensitivity `k` of `det - k trace²`.
pub const HARRIS_K: f32 = 0.04;

/// Lanes per row: the 7 window columns and one unused.
const L: usize = 8;
/// Pixels read on each side of the keypoint: the window's half-width plus the Sobel tap.
const REACH: isize = HARRIS_BLOCK as isize / 2 + 1;
/// Rows read (window plus a Sobel row above and below), and bytes read per row (L + 2 taps).
const ROWS: usize = 2 * REACH as usize + 1;
const ROW_BYTES: usize = L + 2;

/// `det(M) - k trace(M)²` of the structure tensor `M` of 3x3 Sobel gradients summed over the
/// 7x7 window centred on (x, y). Needs 4 pixels of image or border around (x, y).
#[inline]
pub fn harris_response(img: &PaddedImage, x: isize, y: isize) -> f32 {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
    {
        let at = img.idx(x - REACH, y - REACH);
        let last = img.idx(x - REACH, y + REACH) + ROW_BYTES;
        assert!(
            last <= img.data.len(),
            "Harris window outside the padded image"
        );
        // SAFETY: SSE4.1 is enabled at compile time, and the ROWS rows' reads of ROW_BYTES
        // bytes each stay inside the buffer (the last row's end is checked just above).
        return unsafe { harris_sse41(img.data.as_ptr().add(at), img.stride) };
    }
    #[allow(unreachable_code)]
    harris_lanes(img, x, y)
}

/// [`harris_response`] on 8 i16 lanes per row with `pmaddwd` sums: the same integer sums.
///
/// # Safety
/// SSE4.1; ROWS rows of ROW_BYTES bytes readable from `p` with row pitch `stride`.
#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
#[inline]
unsafe fn harris_sse41(p: *const u8, stride: usize) -> f32 {
    use std::arch::x86_64::*;
    let row = |j: usize| {
        let q = p.add(j * stride);
        let a = _mm_cvtepu8_epi16(_mm_loadl_epi64(q as *const __m128i));
        let b = _mm_cvtepu8_epi16(_mm_loadl_epi64(q.add(1) as *const __m128i));
        let c = _mm_cvtepu8_epi16(_mm_loadl_epi64(q.add(2) as *const __m128i));
        let hd = _mm_sub_epi16(c, a);
        let vs = _mm_add_epi16(_mm_add_epi16(a, c), _mm_add_epi16(b, b));
        (hd, vs)
    };
    // Lane 7 lies outside the window.
    let mask = _mm_set_epi16(0, -1, -1, -1, -1, -1, -1, -1);
    let (mut sxx, mut syy, mut sxy) = (
        _mm_setzero_si128(),
        _mm_setzero_si128(),
        _mm_setzero_si128(),
    );
    let (mut h0, mut v0) = row(0);
    let (mut h1, mut v1) = row(1);
    for j in 1..=HARRIS_BLOCK {
        let (h2, v2) = row(j + 1);
        let gx = _mm_and_si128(
            _mm_add_epi16(_mm_add_epi16(h0, h2), _mm_add_epi16(h1, h1)),
            mask,
        );
        let gy = _mm_and_si128(_mm_sub_epi16(v2, v0), mask);
        sxx = _mm_add_epi32(sxx, _mm_madd_epi16(gx, gx));
        syy = _mm_add_epi32(syy, _mm_madd_epi16(gy, gy));
        sxy = _mm_add_epi32(sxy, _mm_madd_epi16(gx, gy));
        (h0, v0, h1, v1) = (h1, v1, h2, v2);
    }
    let hsum = |v: __m128i| {
        let v = _mm_add_epi32(v, _mm_shuffle_epi32(v, 0b01_00_11_10));
        let v = _mm_add_epi32(v, _mm_shuffle_epi32(v, 0b10_11_00_01));
        _mm_cvtsi128_si32(v) as f32
    };
    let (a, b, c) = (hsum(sxx), hsum(syy), hsum(sxy));
    a * b - c * c - HARRIS_K * (a + b) * (a + b)
}

/// Portable [`harris_response`]: fixed-size lanes that LLVM vectorises.
#[inline]
fn harris_lanes(img: &PaddedImage, x: isize, y: isize) -> f32 {
    // Rows y-4 ..= y+4, columns x-4 ..= x+4 (read 10 wide so each row is one 8+2 slice).
    let mut hdiff = [[0i16; L]; ROWS];
    let mut vsum = [[0i16; L]; ROWS];
    for (j, (hd, vs)) in hdiff.iter_mut().zip(vsum.iter_mut()).enumerate() {
        let at = img.idx(x - REACH, y - REACH + j as isize);
        let p = &img.data[at..at + ROW_BYTES];
        for i in 0..L {
            let (a, b, c) = (p[i] as i16, p[i + 1] as i16, p[i + 2] as i16);
            hd[i] = c - a;
            vs[i] = a + 2 * b + c;
        }
    }
    let (mut sxx, mut syy, mut sxy) = ([0i32; L], [0i32; L], [0i32; L]);
    for j in 1..=HARRIS_BLOCK {
        for i in 0..L {
            let gx = (hdiff[j - 1][i] + 2 * hdiff[j][i] + hdiff[j + 1][i]) as i32;
            let gy = (vsum[j + 1][i] - vsum[j - 1][i]) as i32;
            // Lane 7 lies outside the window.
            let m = (i < HARRIS_BLOCK) as i32;
            sxx[i] += m * gx * gx;
            syy[i] += m * gy * gy;
            sxy[i] += m * gx * gy;
        }
    }
    let (a, b, c) = (
        sxx.iter().sum::<i32>() as f32,
        syy.iter().sum::<i32>() as f32,
        sxy.iter().sum::<i32>() as f32,
    );
    a * b - c * c - HARRIS_K * (a + b) * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(f: impl Fn(usize, usize) -> u8) -> PaddedImage {
        let (w, h) = (40, 40);
        let data: Vec<u8> = (0..w * h).map(|i| f(i % w, i / w)).collect();
        let mut img = PaddedImage::new(w, h, 8);
        img.copy_from(&data);
        img
    }

    /// Straight scalar definition.
    fn reference(img: &PaddedImage, x: isize, y: isize) -> f32 {
        let p = |dx: isize, dy: isize| img.at(x + dx, y + dy) as f64;
        let (mut a, mut b, mut c) = (0.0, 0.0, 0.0);
        for v in -3..=3 {
            for u in -3..=3 {
                let gx = (p(u + 1, v - 1) - p(u - 1, v - 1))
                    + 2.0 * (p(u + 1, v) - p(u - 1, v))
                    + (p(u + 1, v + 1) - p(u - 1, v + 1));
                let gy = (p(u - 1, v + 1) - p(u - 1, v - 1))
                    + 2.0 * (p(u, v + 1) - p(u, v - 1))
                    + (p(u + 1, v + 1) - p(u + 1, v - 1));
                a += gx * gx;
                b += gy * gy;
                c += gx * gy;
            }
        }
        (a * b - c * c - HARRIS_K as f64 * (a + b) * (a + b)) as f32
    }

    #[test]
    fn matches_the_definition_and_ranks_corners_over_edges_and_flat() {
        let corner = image(|x, y| if x >= 20 && y >= 20 { 200 } else { 30 });
        let noise = image(|x, y| ((x * 7919 + y * 104729) % 251) as u8);
        for (img, x, y) in [(&corner, 20, 20), (&noise, 13, 27), (&noise, 4, 4)] {
            let (got, want) = (harris_response(img, x, y), reference(img, x, y));
            assert!(
                (got - want).abs() <= 1e-4 * want.abs().max(1.0),
                "{got} {want}"
            );
        }
        for y in 4..36 {
            for x in 4..36 {
                assert_eq!(harris_response(&noise, x, y), harris_lanes(&noise, x, y));
            }
        }
        let at_corner = harris_response(&corner, 20, 20);
        let on_edge = harris_response(&corner, 30, 20);
        let flat = harris_response(&corner, 8, 8);
        assert!(at_corner > 0.0 && on_edge < 0.0 && flat == 0.0);
    }
}
