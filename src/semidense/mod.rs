//! Probabilistic semi-dense mapping (Mur-Artal & Tardós, RSS 2015, section III): every
//! keyframe is reconstructed from scratch by epipolar search of its high-gradient pixels in
//! its N best covisible keyframes, fusion of the inverse-depth hypotheses, intra-keyframe
//! checking/smoothing/growing, and inter-keyframe consistency with the neighbours' maps.
//!
//! [`KeyframeReconstructor`] and [`InterChecker`] are the algorithm on plain buffers (also used
//! by offline densification); [`SemiDenseMapper`] drives them from the SLAM map with the
//! keyframe delay, keeps the per-keyframe results and produces the cloud with current poses.

mod depth_stage;
mod epipolar;
mod fusion;
mod gradients;
mod inter;
mod intra;
mod mapper;
mod offline;
mod patch;
mod photometric;
mod prior;
mod reconstructor;
mod scan;

pub use epipolar::{Hypothesis, Intrinsics, SearchParams, StereoPair};
pub use fusion::{compatible, fuse, CHI2_1DOF_95, CHI2_2DOF_95};
pub use gradients::{GradientImage, PixelGradient};
pub use inter::InterChecker;
pub use intra::check_smooth_grow_row;
pub use mapper::{KeyframeDepth, PixelCounts, SemiDenseMapper, SemiDenseStats, STORED_PIXEL_BYTES};
pub use offline::Densifier;
pub use photometric::{photometric_gain, MIN_GAIN_MATCHES};
pub use prior::RegionalPrior;
pub use reconstructor::{KeyframeReconstructor, Seed, StageTimes, MAX_NEIGHBOURS};

/// One pixel's inverse-depth estimate N(rho, sigma^2); `idx` = y * width + x.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DepthPixel {
    pub idx: u32,
    pub rho: f32,
    pub sigma: f32,
}

/// Median in-plane rotation (radians) from ORB angle pairs (degrees, reference then
/// neighbour); `scratch` is reused. 0 when there are no pairs. The differences are angles:
/// they are unwrapped around their circular mean before the median, so a set straddling
/// +-180 deg (a camera rolled upside down) gives a median near 180, not one of its ends.
pub fn median_rotation(pairs: impl Iterator<Item = (f32, f32)>, scratch: &mut Vec<f32>) -> f64 {
    scratch.clear();
    let (mut sin, mut cos) = (0.0f64, 0.0f64);
    for (a, b) in pairs {
        let d = wrap_deg(b - a);
        let r = (d as f64).to_radians();
        (sin, cos) = (sin + r.sin(), cos + r.cos());
        scratch.push(d);
    }
    if scratch.is_empty() {
        return 0.0;
    }
    let mean = sin.atan2(cos).to_degrees() as f32;
    for d in scratch.iter_mut() {
        *d = wrap_deg(*d - mean);
    }
    let mid = scratch.len() / 2;
    let (_, m, _) = scratch.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    (wrap_deg(*m + mean) as f64).to_radians()
}

/// An angle in degrees wrapped into (-180, 180].
fn wrap_deg(mut d: f32) -> f32 {
    while d > 180.0 {
        d -= 360.0;
    }
    while d <= -180.0 {
        d += 360.0;
    }
    d
}

/// The inverse-depth prior N(rho_0, sigma_rho0^2) of a keyframe from its map points' inverse
/// depths (their mean and standard deviation), as the search range [rho_0 - 2 sigma_rho0,
/// rho_0 + 2 sigma_rho0] (section III-A; the lower bound is clamped at 0, the point at
/// infinity). `None` with fewer than 10 points.
pub fn prior_range(inverse_depths: &[f32]) -> Option<(f64, f64)> {
    if inverse_depths.len() < 10 {
        return None;
    }
    let n = inverse_depths.len() as f64;
    let mean = inverse_depths.iter().map(|&r| r as f64).sum::<f64>() / n;
    let var = inverse_depths
        .iter()
        .map(|&r| (r as f64 - mean).powi(2))
        .sum::<f64>()
        / (n - 1.0);
    let sigma = var.sqrt();
    (sigma > 0.0).then_some(((mean - 2.0 * sigma).max(0.0), mean + 2.0 * sigma))
}

#[cfg(test)]
mod tests;
