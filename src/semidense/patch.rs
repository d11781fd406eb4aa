//! Patch check (not in the paper, `[semidense] min_patch_zncc`): the paper matches single
//! pixels by intensity and gradient modulus (eq. 2-3). A background pixel beside an occluding
//! contour takes the contour's gradient, matches where the contour moved and so gets the
//! foreground's depth while it sees the background: on desk 55% of the outliers lie within 4
//! pixels of a depth step, on fast-blur 86% (94% of them in front of the truth). Its 3 x 3
//! neighbourhood, carried into the neighbours at that depth, lands on other background, so
//! it does not correlate there. Each estimate's patch is compared (zero-mean normalised
//! cross-correlation) with its projections at that inverse depth into the first neighbours
//! where it fits; the worst must reach the threshold. The widest view is the one that
//! exposes a contour pixel, hence the minimum and not the best.

use super::epipolar::StereoPair;
use super::gradients::GradientImage;

/// Neighbours (in search order) a patch is compared in.
pub const PATCH_NEIGHBOURS: usize = 3;

/// Reference patches with a smaller intensity deviation (grey levels) are not judged: the
/// correlation of a flat patch is noise. Pixels with G > lambda_G rarely come near it.
const MIN_PATCH_DEVIATION: f32 = 2.0;

const OFFSETS: [(isize, isize); 9] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (0, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// A reference pixel's 3 x 3 intensities less their mean, and their sum of squares: computed
/// once per pixel, correlated with each neighbour.
struct ReferencePatch {
    x: f64,
    y: f64,
    a: [f32; 9],
    saa: f32,
}

impl ReferencePatch {
    /// None at the image border or for a flat patch.
    fn new(reference: &GradientImage, x: usize, y: usize) -> Option<Self> {
        if x == 0 || y == 0 || x + 1 >= reference.width || y + 1 >= reference.height {
            return None;
        }
        let mut a = [0.0f32; 9];
        for (v, &(dx, dy)) in a.iter_mut().zip(&OFFSETS) {
            *v = reference
                .at((x as isize + dx) as usize, (y as isize + dy) as usize)
                .intensity;
        }
        let mean = a.iter().sum::<f32>() / 9.0;
        a.iter_mut().for_each(|v| *v -= mean);
        let saa = a.iter().map(|v| v * v).sum::<f32>();
        (saa >= 9.0 * MIN_PATCH_DEVIATION * MIN_PATCH_DEVIATION).then_some(ReferencePatch {
            x: x as f64,
            y: y as f64,
            a,
            saa,
        })
    }

    /// The correlation with the patch's projection into `target` at inverse depth `rho`;
    /// None when it leaves the image (or lands behind the camera).
    fn zncc(&self, rho: f64, pair: &StereoPair, target: &GradientImage) -> Option<f32> {
        let mut uv = [(0.0f32, 0.0f32); 9];
        if !pair.project_offsets(self.x, self.y, rho, &OFFSETS, &mut uv) {
            return None;
        }
        let (u_max, v_max) = (
            target.width.saturating_sub(2) as f32,
            target.height.saturating_sub(2) as f32,
        );
        // With a zero-mean reference, sum a (b - mean b) = sum a b.
        let (mut sab, mut sb, mut sbb) = (0.0f32, 0.0f32, 0.0f32);
        for (&a, &(u, v)) in self.a.iter().zip(&uv) {
            if !(u >= 1.0 && v >= 1.0 && u < u_max && v < v_max) {
                return None;
            }
            let b = target.intensity_at(u, v);
            sab += a * b;
            sb += b;
            sbb += b * b;
        }
        let var_b = (sbb - sb * sb / 9.0).max(0.0);
        Some(sab / (self.saa * var_b).sqrt().max(1e-6))
    }
}

/// The patch correlations of reference pixel (x, y) at `rho` in the first
/// [`PATCH_NEIGHBOURS`] neighbours where it can be judged, in search order.
fn judged<'a>(
    reference: &'a GradientImage,
    x: usize,
    y: usize,
    rho: f64,
    pairs: &'a [StereoPair],
    neighbours: &'a [&'a GradientImage],
) -> impl Iterator<Item = f32> + 'a {
    let patch = ReferencePatch::new(reference, x, y);
    patch
        .into_iter()
        .flat_map(move |p| {
            pairs
                .iter()
                .zip(neighbours)
                .filter_map(move |(pair, img)| p.zncc(rho, pair, img))
        })
        .take(PATCH_NEIGHBOURS)
}

/// Whether the estimate fails the check: its worst correlation over the first
/// [`PATCH_NEIGHBOURS`] neighbours where it can be judged is below `min_zncc` (stopping at the
/// first one below). An estimate judged nowhere passes.
pub fn fails_patch_check(
    reference: &GradientImage,
    x: usize,
    y: usize,
    rho: f64,
    pairs: &[StereoPair],
    neighbours: &[&GradientImage],
    min_zncc: f32,
) -> bool {
    judged(reference, x, y, rho, pairs, neighbours).any(|z| z < min_zncc)
}

#[cfg(test)]
mod tests;
