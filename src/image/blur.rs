//! Separable 7x7 Gaussian blur (sigma 2) in fixed point: the smoothing ORB applies before
//! sampling BRIEF pairs, so descriptors are robust to noise.

use super::PaddedImage;

/// 7-tap Gaussian, sigma 2, scaled to sum 256.
const KERNEL: [u32; 7] = gaussian_kernel();

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
    for y in 0..h {
        let base = src.idx(-3, y as isize);
        let out = &mut tmp[y * tw..(y + 1) * tw];
        let rows: [&[u8]; 7] = std::array::from_fn(|k| {
            let b = base + k * st - 3 * st;
            &src.data[b..b + tw]
        });
        for (x, o) in out.iter_mut().enumerate() {
            let mut acc = 0u16;
            for k in 0..7 {
                acc += KERNEL[k] as u16 * rows[k][x] as u16;
            }
            *o = (acc + 128) >> 8;
        }
    }
    // Horizontal pass.
    for y in 0..h {
        let t = &tmp[y * tw..(y + 1) * tw];
        let out = dst.row_mut(y);
        for (x, o) in out.iter_mut().enumerate() {
            let mut acc = 0u16;
            for k in 0..7 {
                acc += KERNEL[k] as u16 * t[x + k];
            }
            *o = ((acc + 128) >> 8) as u8;
        }
    }
    dst.fill_border_width(filled);
}

#[cfg(test)]
mod tests {
    use super::*;

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
