use super::*;
use crate::geometry::{Intrinsics, Se3};
use nalgebra::{Translation3, UnitQuaternion};

const W: usize = 64;
const H: usize = 48;
/// Focal length and baseline: a pixel at inverse depth rho moves fX * B * rho pixels left.
const FX: f64 = 100.0;
const B: f64 = 0.08;
const RHO_FG: f64 = 1.0; // 8 px of disparity
const RHO_BG: f64 = 0.25; // 2 px
/// The foreground square's columns in the reference image.
const FG: std::ops::Range<usize> = 20..40;

/// Deterministic pixel noise in 40..216: texture that decorrelates from pixel to pixel.
fn noise(x: usize, y: usize, seed: u32) -> u8 {
    let mut h = (x as u32).wrapping_mul(0x9E37_79B1) ^ (y as u32).wrapping_mul(0x85EB_CA6B) ^ seed;
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    40 + (h % 176) as u8
}

/// ZNCC of the 3 x 3 patch around (x, y) with its projection into `target` at `rho`; None
/// when it cannot be judged (border, flat patch, projection off the image).
fn patch_zncc(
    reference: &GradientImage,
    x: usize,
    y: usize,
    rho: f64,
    pair: &StereoPair,
    target: &GradientImage,
) -> Option<f32> {
    ReferencePatch::new(reference, x, y)?.zncc(rho, pair, target)
}

/// The worst correlation over the neighbours the check looks at.
fn worst_patch_zncc(
    reference: &GradientImage,
    x: usize,
    y: usize,
    rho: f64,
    pairs: &[StereoPair],
    neighbours: &[&GradientImage],
) -> Option<f32> {
    judged(reference, x, y, rho, pairs, neighbours).reduce(f32::min)
}

fn image(gray: &[u8]) -> GradientImage {
    let mut g = GradientImage::new(W, H);
    g.compute(gray, 8.0);
    g
}

/// A textured square at RHO_FG in front of a textured wall at RHO_BG, seen from the
/// reference and from a camera B to the right (the square occludes the wall there too).
fn scene() -> (GradientImage, GradientImage) {
    let (mut r, mut t) = (vec![0u8; W * H], vec![0u8; W * H]);
    let d_fg = (FX * B * RHO_FG).round() as usize;
    let d_bg = (FX * B * RHO_BG).round() as usize;
    for y in 0..H {
        for x in 0..W {
            r[y * W + x] = if FG.contains(&x) {
                noise(x, y, 1)
            } else {
                noise(x, y, 2)
            };
            // Target pixel u shows the square's column u + d_fg if that is on the square,
            // else the wall's column u + d_bg.
            t[y * W + x] = if FG.contains(&(x + d_fg)) {
                noise(x + d_fg, y, 1)
            } else {
                noise(x + d_bg, y, 2)
            };
        }
    }
    (image(&r), image(&t))
}

fn pair(baseline: f64) -> StereoPair {
    let k = Intrinsics::new(FX, FX, 32.0, 24.0);
    let t_ji = Se3::from_parts(
        Translation3::new(-baseline, 0.0, 0.0),
        UnitQuaternion::identity(),
    );
    StereoPair::new(&k, &t_ji, 0.0)
}

#[test]
fn true_depths_correlate_and_a_contour_pixel_at_the_foreground_depth_does_not() {
    let (r, t) = scene();
    let p = pair(B);
    let fg = patch_zncc(&r, 30, 24, RHO_FG, &p, &t).unwrap();
    let bg = patch_zncc(&r, 52, 24, RHO_BG, &p, &t).unwrap();
    assert!(fg > 0.95 && bg > 0.95, "fg {fg} bg {bg}");
    // Two pixels right of the square's edge: the wall, given the square's depth (what the
    // single-pixel search does when the pixel takes the contour's gradient).
    let fattened = patch_zncc(&r, 42, 24, RHO_FG, &p, &t).unwrap();
    assert!(fattened < 0.5, "{fattened}");
    // The same pixel at its true depth correlates.
    let right = patch_zncc(&r, 42, 24, RHO_BG, &p, &t).unwrap();
    assert!(right > 0.95, "{right}");
}

#[test]
fn the_worst_neighbour_decides_and_unjudgeable_patches_give_none() {
    let (r, t) = scene();
    // A neighbour with no baseline sees the reference image itself: every depth correlates.
    let same = pair(0.0);
    let wide = pair(B);
    let both = [same, wide];
    let images = [&r, &t];
    let worst = worst_patch_zncc(&r, 42, 24, RHO_FG, &both, &images).unwrap();
    assert!(worst < 0.5, "{worst}");
    assert!(fails_patch_check(&r, 42, 24, RHO_FG, &both, &images, 0.5));
    assert!(!fails_patch_check(&r, 42, 24, RHO_BG, &both, &images, 0.5));
    // One pixel per offset projected alone lands where the shared projection puts it.
    let mut uv = [(0.0f32, 0.0f32); 9];
    assert!(wide.project_offsets(42.0, 24.0, RHO_FG, &OFFSETS, &mut uv));
    for (&(dx, dy), &(u, v)) in OFFSETS.iter().zip(&uv) {
        let (pu, pv) = wide
            .project((42 + dx) as f64, (24 + dy) as f64, RHO_FG)
            .unwrap();
        assert!((u - pu).abs() < 1e-4 && (v - pv).abs() < 1e-4);
    }
    assert!(patch_zncc(&r, 42, 24, RHO_FG, &same, &r).unwrap() > 0.99);
    // Off the image (the patch needs its 3 x 3 neighbourhood and the target a margin).
    assert_eq!(patch_zncc(&r, 0, 24, RHO_BG, &wide, &t), None);
    assert_eq!(patch_zncc(&r, 3, 24, 10.0, &wide, &t), None);
    // A flat reference patch is not judged.
    let flat = image(&vec![128u8; W * H]);
    assert_eq!(patch_zncc(&flat, 30, 24, RHO_FG, &wide, &t), None);
    assert_eq!(
        worst_patch_zncc(&flat, 30, 24, RHO_FG, &both, &images),
        None
    );
}
