//! Exposure between two keyframes. The paper compares a reference pixel's intensity and
//! gradient modulus with the neighbour's as they are (eq. 2), which assumes both images were
//! taken with the same exposure. A camera with auto exposure or auto gain (most USB and CSI
//! cameras) changes it from frame to frame; a 20% change moves every intensity residual of a
//! bright pixel by tens of grey levels, beyond sigma_I, and the pair gives no matches. The
//! ratio of the two images' brightness at the ORB points they share measures the change.
//! A gain, not an offset: exposure time and analogue gain scale the light, and a power-law
//! (gamma) response keeps a scale a scale.

/// Half side of the patch averaged around a keypoint (5x5): the mean of a patch, not the
/// keypoint's own pixel, which sits on a corner and changes with sub-pixel position.
const HALF: usize = 2;
/// Matches needed for a measured gain (fewer: 1).
pub const MIN_GAIN_MATCHES: usize = 20;
/// Patch means outside (MIN_MEAN, MAX_MEAN) are left out: dark patches give noisy ratios and
/// saturated ones clip.
const MIN_MEAN: f32 = 16.0;
const MAX_MEAN: f32 = 240.0;
/// The gain is kept within this factor either way (beyond it the images are not a pair).
const MAX_GAIN: f32 = 4.0;

/// Mean of the 5x5 patch of `gray` (`w` x `h`) around (x, y); `None` too near the border.
fn patch_mean(gray: &[u8], w: usize, h: usize, x: f32, y: f32) -> Option<f32> {
    if !(x.is_finite() && y.is_finite()) || x < 0.0 || y < 0.0 {
        return None;
    }
    let (cx, cy) = (x.round() as usize, y.round() as usize);
    if cx < HALF || cy < HALF || cx + HALF >= w || cy + HALF >= h {
        return None;
    }
    let mut s = 0u32;
    for row in gray
        .get((cy - HALF) * w..(cy + HALF + 1) * w)?
        .chunks_exact(w)
    {
        s += row[cx - HALF..=cx + HALF]
            .iter()
            .map(|&v| v as u32)
            .sum::<u32>();
    }
    Some(s as f32 / ((2 * HALF + 1) * (2 * HALF + 1)) as f32)
}

/// Intensity of image j over image i (`gray_*`: `w` x `h`, row-major) from the median ratio
/// of their 5x5 patch means at matched points (`pairs`: pixel in i, pixel in j); `scratch`
/// is reused (up to its capacity when it has one). 1 with fewer than [`MIN_GAIN_MATCHES`] usable matches.
pub fn photometric_gain(
    gray_i: &[u8],
    gray_j: &[u8],
    w: usize,
    h: usize,
    pairs: impl Iterator<Item = ((f32, f32), (f32, f32))>,
    scratch: &mut Vec<f32>,
) -> f32 {
    scratch.clear();
    if gray_i.len() < w * h || gray_j.len() < w * h {
        return 1.0;
    }
    // Per-keyframe code does not allocate: at most the scratch's capacity of matches count
    // (any capacity is taken as given, so a first call may size it).
    let cap = if scratch.capacity() > 0 {
        scratch.capacity()
    } else {
        usize::MAX
    };
    for ((xi, yi), (xj, yj)) in pairs {
        if scratch.len() == cap {
            break;
        }
        let (Some(a), Some(b)) = (
            patch_mean(gray_i, w, h, xi, yi),
            patch_mean(gray_j, w, h, xj, yj),
        ) else {
            continue;
        };
        if a > MIN_MEAN && a < MAX_MEAN && b > MIN_MEAN && b < MAX_MEAN {
            scratch.push(b / a);
        }
    }
    if scratch.len() < MIN_GAIN_MATCHES {
        return 1.0;
    }
    let mid = scratch.len() / 2;
    let (_, m, _) = scratch.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    m.clamp(1.0 / MAX_GAIN, MAX_GAIN)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured image and the same image brighter by `gain` (clipped at 255).
    fn images(gain: f32) -> (Vec<u8>, Vec<u8>, usize, usize) {
        let (w, h) = (64, 48);
        let a: Vec<u8> = (0..w * h)
            .map(|i| (40 + ((i % w) * 7 + (i / w) * 13) % 120) as u8)
            .collect();
        let b = a
            .iter()
            .map(|&v| (v as f32 * gain).round().min(255.0) as u8)
            .collect();
        (a, b, w, h)
    }

    fn grid() -> impl Iterator<Item = ((f32, f32), (f32, f32))> {
        (0..40).map(|k| {
            let p = (5.0 + (k % 8) as f32 * 7.0, 5.0 + (k / 8) as f32 * 8.0);
            (p, p)
        })
    }

    #[test]
    fn the_gain_of_a_brighter_copy_is_its_factor() {
        let mut s = Vec::with_capacity(64);
        for g in [0.7f32, 1.0, 1.3] {
            let (a, b, w, h) = images(g);
            let m = photometric_gain(&a, &b, w, h, grid(), &mut s);
            assert!((m - g).abs() < 0.02, "gain {m}, want {g}");
        }
    }

    #[test]
    fn too_few_matches_or_wrong_sizes_give_one() {
        let mut s = Vec::with_capacity(64);
        let (a, b, w, h) = images(1.3);
        assert_eq!(photometric_gain(&a, &b, w, h, grid().take(10), &mut s), 1.0);
        assert_eq!(photometric_gain(&a[..10], &b, w, h, grid(), &mut s), 1.0);
        // Points at the border or not finite are left out, not read out of bounds.
        let odd = (0..40).map(|_| ((f32::NAN, 0.0), (1e9, -3.0)));
        assert_eq!(photometric_gain(&a, &b, w, h, odd, &mut s), 1.0);
    }

    #[test]
    fn a_minority_of_wrong_matches_does_not_move_the_median() {
        let mut s = Vec::with_capacity(64);
        let (a, b, w, h) = images(1.2);
        // A third of the pairs point at unrelated places in j.
        let pairs = grid().enumerate().map(|(k, (p, q))| {
            if k % 3 == 0 {
                (p, (60.0 - q.0, 45.0 - q.1))
            } else {
                (p, q)
            }
        });
        let m = photometric_gain(&a, &b, w, h, pairs, &mut s);
        assert!((m - 1.2).abs() < 0.05, "gain {m}");
    }
}
