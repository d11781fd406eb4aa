//! Intra-keyframe depth checking, smoothing and growing (paper section III-D, after Engel et
//! al. 2013): a pixel keeps its estimate only if at least 2 of its 8 neighbours are compatible
//! (eq. 10); kept pixels are averaged with their compatible neighbours (eq. 11) with the
//! standard deviation fixed to the smallest; high-gradient pixels without an estimate but with
//! at least 2 mutually compatible neighbours get their average (growing).

use super::fusion::compatible;

/// Minimum number of compatible neighbours to keep or grow a pixel.
pub const MIN_SUPPORT: usize = 2;

const NEIGHBOURS: [(isize, isize); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// Processes row `y` of the inverse-depth map (`rho`, `s2`: sigma^2, 0 = no estimate) of a
/// `width`-wide image into `out_rho` / `out_s2` (that row). `grad_ok(x)` says whether pixel
/// (x, y) is a high-gradient pixel (may be grown).
#[allow(clippy::too_many_arguments)]
pub fn check_smooth_grow_row(
    y: usize,
    width: usize,
    height: usize,
    rho: &[f32],
    s2: &[f32],
    grad_ok: impl Fn(usize) -> bool,
    out_rho: &mut [f32],
    out_s2: &mut [f32],
) {
    out_rho.fill(0.0);
    out_s2.fill(0.0);
    if y == 0 || y + 1 >= height {
        return;
    }
    for x in 1..width - 1 {
        let i = y * width + x;
        let mut nb = [(0.0f32, 0.0f32); 8];
        let mut n = 0;
        for (ox, oy) in NEIGHBOURS {
            let j = (i as isize + oy * width as isize + ox) as usize;
            if s2[j] > 0.0 {
                nb[n] = (rho[j], s2[j]);
                n += 1;
            }
        }
        if n < MIN_SUPPORT {
            continue;
        }
        let nb = &nb[..n];
        if s2[i] > 0.0 {
            let (r0, v0) = (rho[i], s2[i]);
            let (mut cnt, mut info, mut sum, mut vmin) = (0, 1.0 / v0, r0 / v0, v0);
            for &(r, v) in nb {
                if compatible(r0, v0, r, v) {
                    cnt += 1;
                    info += 1.0 / v;
                    sum += r / v;
                    vmin = vmin.min(v);
                }
            }
            if cnt >= MIN_SUPPORT {
                out_rho[x] = sum / info;
                out_s2[x] = vmin;
            }
        } else if grad_ok(x) {
            // The largest set of neighbours compatible with one of them.
            let mut best = (0usize, 0.0f32, 0.0f32, 0.0f32);
            for &(ra, va) in nb {
                let (mut cnt, mut info, mut sum, mut vmin) = (0, 0.0f32, 0.0f32, f32::MAX);
                for &(r, v) in nb {
                    if compatible(ra, va, r, v) {
                        cnt += 1;
                        info += 1.0 / v;
                        sum += r / v;
                        vmin = vmin.min(v);
                    }
                }
                if cnt > best.0 {
                    best = (cnt, info, sum, vmin);
                }
            }
            if best.0 >= MIN_SUPPORT {
                out_rho[x] = best.2 / best.1;
                out_s2[x] = best.3;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(rho: &[f32], s2: &[f32], w: usize, h: usize, grow: bool) -> (Vec<f32>, Vec<f32>) {
        let (mut orho, mut os2) = (vec![0.0; w * h], vec![0.0; w * h]);
        for y in 0..h {
            check_smooth_grow_row(
                y,
                w,
                h,
                rho,
                s2,
                |_| grow,
                &mut orho[y * w..(y + 1) * w],
                &mut os2[y * w..(y + 1) * w],
            );
        }
        (orho, os2)
    }

    #[test]
    fn isolated_outlier_is_removed_and_surface_smoothed() {
        let (w, h) = (7, 7);
        let mut rho = vec![1.0f32; w * h];
        let s2 = vec![0.01f32; w * h];
        rho[3 * w + 3] = 3.0; // planted outlier
        rho[2 * w + 2] = 1.05; // noisy but compatible
        let (o, os2) = run(&rho, &s2, w, h, false);
        assert_eq!(os2[3 * w + 3], 0.0, "outlier kept");
        assert!(o[2 * w + 2] < 1.05 && o[2 * w + 2] > 1.0);
        assert!(os2[2 * w + 2] > 0.0);
    }

    #[test]
    fn gaps_between_compatible_pixels_are_grown_only_on_gradient() {
        let (w, h) = (5, 5);
        let mut rho = vec![0.0f32; w * h];
        let mut s2 = vec![0.0f32; w * h];
        for x in 0..w {
            rho[w + x] = 0.5;
            s2[w + x] = 0.01;
            rho[3 * w + x] = 0.5;
            s2[3 * w + x] = 0.01;
        }
        let (o, os2) = run(&rho, &s2, w, h, true);
        assert!(os2[2 * w + 2] > 0.0 && (o[2 * w + 2] - 0.5).abs() < 1e-6);
        let (_, os2) = run(&rho, &s2, w, h, false);
        assert_eq!(os2[2 * w + 2], 0.0);
    }
}
