//! Keyframe colour stored as grey plus half-resolution colour residuals: per 2 x 2 block and
//! channel, the mean of (channel - grey), halved into a byte. Colour is read back as grey +
//! residual, so edges (where semi-dense points lie) keep their full-resolution brightness while
//! the colour costs 0.75 bytes per pixel instead of 3 (as 4:2:0 chroma subsampling does).

/// Bytes of the residual image of a `width` x `height` frame.
pub fn residual_len(width: usize, height: usize) -> usize {
    3 * width.div_ceil(2) * height.div_ceil(2)
}

/// Encodes tightly packed `rgb` against `gray` (both `width` x `height`) into `out` (cleared
/// first; allocates nothing when `out` has [`residual_len`] capacity).
pub fn encode_residual(rgb: &[u8], gray: &[u8], width: usize, height: usize, out: &mut Vec<u8>) {
    out.clear();
    if rgb.len() < 3 * width * height || gray.len() < width * height {
        return;
    }
    for by in 0..height.div_ceil(2) {
        let (y0, full_rows) = (2 * by, 2 * by + 1 < height);
        let mut bx = 0;
        if full_rows {
            // Interior 2 x 2 blocks: fixed size, no bounds juggling (this runs on the tracking
            // thread at every keyframe insertion).
            let (g0, g1) = (
                &gray[y0 * width..][..width],
                &gray[(y0 + 1) * width..][..width],
            );
            let (c0, c1) = (
                &rgb[3 * y0 * width..][..3 * width],
                &rgb[3 * (y0 + 1) * width..][..3 * width],
            );
            for ((ga, gb), (ca, cb)) in g0
                .chunks_exact(2)
                .zip(g1.chunks_exact(2))
                .zip(c0.chunks_exact(6).zip(c1.chunks_exact(6)))
            {
                let g = ga[0] as i32 + ga[1] as i32 + gb[0] as i32 + gb[1] as i32;
                for c in 0..3 {
                    let s = ca[c] as i32 + ca[3 + c] as i32 + cb[c] as i32 + cb[3 + c] as i32;
                    out.push(halved_mean(s - g, 4));
                }
            }
            bx = width / 2;
        }
        for bx in bx..width.div_ceil(2) {
            let mut sum = [0i32; 3];
            let mut n = 0i32;
            for y in y0..(y0 + 2).min(height) {
                for x in 2 * bx..(2 * bx + 2).min(width) {
                    let i = y * width + x;
                    let g = gray[i] as i32;
                    for (c, s) in sum.iter_mut().enumerate() {
                        *s += rgb[3 * i + c] as i32 - g;
                    }
                    n += 1;
                }
            }
            for s in sum {
                out.push(halved_mean(s, n));
            }
        }
    }
}

/// The mean residual `sum / n` in [-255, 255], halved (rounded away from zero) into a byte
/// offset by 128.
#[inline(always)]
fn halved_mean(sum: i32, n: i32) -> u8 {
    let half = (sum + n * sum.signum()) / (2 * n);
    (half.clamp(-128, 127) + 128) as u8
}

/// Colour of pixel (x, y) from its grey value and the residual image (grey when `residual` is
/// empty).
#[inline]
pub fn colour_at(gray: &[u8], residual: &[u8], width: usize, x: usize, y: usize) -> [u8; 3] {
    let g = gray[y * width + x] as i32;
    let b = 3 * ((y / 2) * width.div_ceil(2) + x / 2);
    match residual.get(b..b + 3) {
        Some(r) => std::array::from_fn(|c| (g + 2 * (r[c] as i32 - 128)).clamp(0, 255) as u8),
        None => [g as u8; 3],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_survives_within_two_levels_on_smooth_colour_and_sharp_grey_edges() {
        let (w, h) = (7usize, 5usize);
        let mut rgb = vec![0u8; 3 * w * h];
        let mut gray = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                // A grey edge at x = 3 with a constant tint.
                let l: u8 = if x < 3 { 40 } else { 200 };
                let px = [l + 30, l - 10, l - 25];
                rgb[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&px);
                gray[y * w + x] = l;
            }
        }
        let mut res = Vec::with_capacity(residual_len(w, h));
        encode_residual(&rgb, &gray, w, h, &mut res);
        assert_eq!(res.len(), residual_len(w, h));
        for y in 0..h {
            for x in 0..w {
                let c = colour_at(&gray, &res, w, x, y);
                for k in 0..3 {
                    let want = rgb[3 * (y * w + x) + k] as i32;
                    assert!((c[k] as i32 - want).abs() <= 2, "({x},{y}) {c:?}");
                }
            }
        }
        assert_eq!(colour_at(&gray, &[], w, 4, 2), [200; 3]);
    }

    #[test]
    fn extreme_residuals_clamp_instead_of_wrapping() {
        let rgb = [255u8, 0, 255, 255, 0, 255];
        let gray = [0u8, 0];
        let mut res = Vec::new();
        encode_residual(&rgb, &gray, 2, 1, &mut res);
        let c = colour_at(&gray, &res, 2, 1, 0);
        assert!(c[0] >= 253 && c[1] == 0 && c[2] >= 253, "{c:?}");
    }

    #[test]
    fn interior_fast_path_equals_the_per_block_mean_on_every_size_parity() {
        for (w, h) in [(8usize, 6usize), (9, 6), (8, 7), (9, 7)] {
            // Pseudo-random colour and grey (an LCG), so residuals of every sign occur.
            let mut state = 12345u32;
            let mut next = || {
                state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
                (state >> 16) as u8
            };
            let rgb: Vec<u8> = (0..3 * w * h).map(|_| next()).collect();
            let gray: Vec<u8> = (0..w * h).map(|_| next()).collect();
            let mut res = Vec::new();
            encode_residual(&rgb, &gray, w, h, &mut res);
            let bw = w.div_ceil(2);
            for by in 0..h.div_ceil(2) {
                for bx in 0..bw {
                    for c in 0..3 {
                        let (mut s, mut n) = (0i32, 0i32);
                        for y in 2 * by..(2 * by + 2).min(h) {
                            for x in 2 * bx..(2 * bx + 2).min(w) {
                                s += rgb[3 * (y * w + x) + c] as i32 - gray[y * w + x] as i32;
                                n += 1;
                            }
                        }
                        let want = halved_mean(s, n);
                        assert_eq!(res[3 * (by * bw + bx) + c], want, "{w}x{h} ({bx},{by}) {c}");
                    }
                }
            }
        }
    }
}
