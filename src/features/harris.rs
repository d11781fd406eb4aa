//! Harris corner response (Harris & Stephens 1988) of single keypoints, used to rank FAST
//! corners: it varies smoothly with the image, so the ranking survives small warps better than
//! FAST's threshold score does.

use wide::{i16x8, i32x4};

use crate::image::PaddedImage;

/// Window of the structure tensor (pixels per side), as in ORB (Rublee et al. 2011).
pub const HARRIS_BLOCK: usize = 7;
/// The Harris sensitivity `k` of `det - k trace²`.
pub const HARRIS_K: f32 = 0.04;

/// Lanes per row: the 7 window columns and one unused.
const L: usize = 8;
/// Pixels read on each side of the keypoint: the window's half-width plus the Sobel tap.
const REACH: isize = HARRIS_BLOCK as isize / 2 + 1;
/// Bytes read per row (L + 2 taps).
const ROW_BYTES: usize = L + 2;

/// `det(M) - k trace(M)²` of the structure tensor `M` of 3x3 Sobel gradients summed over the
/// 7x7 window centred on (x, y). Needs 4 pixels of image or border around (x, y).
///
/// One source for every CPU on `wide`'s 8 x i16 vectors (SSE on x86-64, NEON on aarch64):
/// each window row is a vector (lane 7 masked out), and the squares are summed in pairs
/// into i32 (`pmaddwd`, NEON's widening multiply and pairwise add). Integer sums, so the
/// result does not depend on the CPU.
#[inline]
pub fn harris_response(img: &PaddedImage, x: isize, y: isize) -> f32 {
    let first = img.idx(x - REACH, y - REACH);
    let row = |j: usize| {
        let at = first + j * img.stride;
        let p = &img.data[at..at + ROW_BYTES];
        // Eight bytes in one load (the slice's length is known, so the fallback is dead).
        let lanes = |o: usize| {
            let bytes = <[u8; 8]>::try_from(&p[o..o + 8]).map_or(0, u64::from_ne_bytes);
            i16x8::from_u8x16_low(bytemuck::cast([bytes, 0u64]))
        };
        let (a, b, c) = (lanes(0), lanes(1), lanes(2));
        // Horizontal difference and vertical-smoothing sum of the Sobel taps.
        (c - a, a + c + b + b)
    };
    // Lane 7 lies outside the window.
    let mask = i16x8::new([-1, -1, -1, -1, -1, -1, -1, 0]);
    let (mut sxx, mut syy, mut sxy) = (i32x4::ZERO, i32x4::ZERO, i32x4::ZERO);
    let (mut h0, mut v0) = row(0);
    let (mut h1, mut v1) = row(1);
    for j in 1..=HARRIS_BLOCK {
        let (h2, v2) = row(j + 1);
        let gx = (h0 + h2 + h1 + h1) & mask;
        let gy = (v2 - v0) & mask;
        sxx += gx.dot(gx);
        syy += gy.dot(gy);
        sxy += gx.dot(gy);
        (h0, v0, h1, v1) = (h1, v1, h2, v2);
    }
    let (a, b, c) = (
        sxx.reduce_add() as f32,
        syy.reduce_add() as f32,
        sxy.reduce_add() as f32,
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
        // Integer sums: exactly the definition's up to the final products.
        for y in 4..36 {
            for x in 4..36 {
                let (got, want) = (harris_response(&noise, x, y), reference(&noise, x, y));
                assert!(
                    (got - want).abs() <= 1e-6 * want.abs().max(1.0),
                    "{got} {want}"
                );
            }
        }
        let at_corner = harris_response(&corner, 20, 20);
        let on_edge = harris_response(&corner, 30, 20);
        let flat = harris_response(&corner, 8, 8);
        assert!(at_corner > 0.0 && on_edge < 0.0 && flat == 0.0);
    }
}
