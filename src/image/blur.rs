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
/// `tmp` holds the horizontal pass (resized once).
pub fn gaussian_blur_7x7(src: &PaddedImage, dst: &mut PaddedImage, tmp: &mut Vec<u16>) {
    let (w, h) = (src.width, src.height);
    debug_assert!(src.pad >= 3 && dst.width == w && dst.height == h);
    // Horizontal pass over interior rows plus 3 border rows above and below.
    let rows = h + 6;
    tmp.resize(rows * w, 0);
    for r in 0..rows {
        let y = r as isize - 3;
        let base = src.idx(0, y);
        let s = &src.data[base - 3..base + w + 3];
        let out = &mut tmp[r * w..(r + 1) * w];
        for (x, o) in out.iter_mut().enumerate() {
            let mut acc = 0u32;
            for (k, &kv) in KERNEL.iter().enumerate() {
                acc += kv * s[x + k] as u32;
            }
            *o = ((acc + 4) >> 3) as u16; // keep 5 fractional bits (values < 8192)
        }
    }
    // Vertical pass.
    for y in 0..h {
        let out = dst.row_mut(y);
        for (x, o) in out.iter_mut().enumerate() {
            let mut acc = 0u32;
            for (k, &kv) in KERNEL.iter().enumerate() {
                acc += kv * tmp[(y + k) * w + x] as u32;
            }
            *o = ((acc + (1 << 12)) >> 13) as u8;
        }
    }
    dst.fill_border();
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
        gaussian_blur_7x7(&a, &mut b, &mut t);
        assert!(b.row(5).iter().all(|&v| v == 100));
    }

    #[test]
    fn impulse_spreads_symmetrically() {
        let mut img = vec![0u8; 21 * 21];
        img[10 * 21 + 10] = 255;
        let mut a = PaddedImage::new(21, 21, 4);
        a.copy_from(&img);
        let mut b = PaddedImage::new(21, 21, 4);
        gaussian_blur_7x7(&a, &mut b, &mut Vec::new());
        assert_eq!(b.at(9, 10), b.at(11, 10));
        assert_eq!(b.at(10, 8), b.at(10, 12));
        assert!(b.at(10, 10) > b.at(11, 10) && b.at(11, 10) > b.at(12, 10));
        assert_eq!(b.at(14, 10), 0);
    }
}
