//! Two-view initialisation (ORB-SLAM's monocular bootstrap): a homography (normalised DLT) and a
//! fundamental matrix (normalised 8-point) estimated in parallel by RANSAC on shared minimal
//! sets, scored by symmetric transfer errors with chi² gates; the model is chosen by
//! `S_H / (S_H + S_F) > 0.45`; the motion is recovered from Faugeras' 8 hypotheses for H or the
//! 4 of `E = K^T F K`, keeping the one that triangulates clearly most points with parallax.
//! Ambiguous and degenerate (no translation) cases are reported, never guessed.

mod models;
mod reconstruct;
mod refine;

use nalgebra::{Matrix3, Vector2, Vector3};

use super::ransac::SeededRng;
use super::Se3;
use models::{normalize, ransac_model, refit, NormalizedMatches};
use reconstruct::{reconstruct_f, reconstruct_h};

pub use models::{fundamental_8point, homography_dlt};

/// Parameters (ORB-SLAM's defaults).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwoViewConfig {
    pub ransac_iterations: usize,
    /// Standard deviation of keypoint positions, pixels.
    pub sigma: f64,
    /// Minimum parallax of the initial map, degrees.
    pub min_parallax_deg: f64,
    /// Minimum triangulated points.
    pub min_triangulated: usize,
    /// Choose H when `S_H / (S_H + S_F)` exceeds this.
    pub h_selection_ratio: f64,
    pub seed: u64,
    /// Map points the initial map must keep after its two-view BA, or it is refused
    /// (ORB-SLAM monocular: 100).
    pub min_initial_map_points: usize,
}

impl Default for TwoViewConfig {
    fn default() -> Self {
        TwoViewConfig {
            ransac_iterations: 200,
            sigma: 1.0,
            min_parallax_deg: 1.0,
            min_triangulated: 50,
            h_selection_ratio: 0.45,
            seed: 0,
            min_initial_map_points: 100,
        }
    }
}

/// Which model explained the matches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TwoViewModel {
    Homography,
    Fundamental,
}

/// A recovered two-view motion and structure (translation of unit norm).
#[derive(Clone, Debug)]
pub struct TwoViewMotion {
    pub model: TwoViewModel,
    /// Camera 2 from camera 1.
    pub t_21: Se3,
    /// Per match: the triangulated point in camera-1 coordinates, when it passed every check.
    pub points: Vec<Option<Vector3<f64>>>,
    pub parallax_deg: f64,
    /// `S_H / (S_H + S_F)`.
    pub score_ratio: f64,
    /// Matches consistent with the chosen model.
    pub inliers: usize,
}

/// Why no motion was returned.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TwoViewError {
    #[error("too few matches ({0}) for two-view initialisation")]
    TooFewMatches(usize),
    #[error("no model explains the matches")]
    NoModel,
    /// Too little translation for the scene depth (pure rotation, or too short a baseline).
    #[error("degenerate motion: parallax {parallax_deg:.3} deg")]
    Degenerate { parallax_deg: f64 },
    /// Several motion hypotheses explain the data about equally well.
    #[error("ambiguous motion: best hypothesis {best} points, runner-up {second}")]
    Ambiguous { best: usize, second: usize },
    #[error("only {good} points triangulated, {needed} needed")]
    TooFewTriangulated { good: usize, needed: usize },
}

/// Both models fitted by RANSAC, and the selection ratio `S_H / (S_H + S_F)`.
pub struct ModelEstimates {
    pub h21: Matrix3<f64>,
    pub h_inliers: Vec<bool>,
    pub f21: Matrix3<f64>,
    pub f_inliers: Vec<bool>,
    pub ratio: f64,
}

impl ModelEstimates {
    /// The model `initialize` reconstructs from.
    pub fn selected(&self, cfg: &TwoViewConfig) -> TwoViewModel {
        if self.ratio > cfg.h_selection_ratio {
            TwoViewModel::Homography
        } else {
            TwoViewModel::Fundamental
        }
    }
}

/// Fits H and F in parallel on shared minimal sets (the model-selection half of [`initialize`]).
pub fn estimate_models(
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    cfg: &TwoViewConfig,
) -> Result<ModelEstimates, TwoViewError> {
    let n = x1.len().min(x2.len());
    if n < 8 {
        return Err(TwoViewError::TooFewMatches(n));
    }
    let (x1, x2) = (&x1[..n], &x2[..n]);
    let (n1, t1) = normalize(x1);
    let (n2, t2) = normalize(x2);
    let nm = NormalizedMatches {
        x1,
        x2,
        n1,
        n2,
        t1,
        t2,
    };
    let mut rng = SeededRng::new(cfg.seed);
    let sets: Vec<[usize; 8]> = (0..cfg.ransac_iterations.max(1))
        .map(|_| {
            let mut s = [0usize; 8];
            rng.sample_distinct(n, &mut s);
            s
        })
        .collect();
    let inv_s2 = 1.0 / (cfg.sigma * cfg.sigma);
    let (h, f) = rayon::join(
        || ransac_model(&nm, &sets, inv_s2, true),
        || ransac_model(&nm, &sets, inv_s2, false),
    );
    let total = h.score + f.score;
    if total <= 0.0 {
        return Err(TwoViewError::NoModel);
    }
    Ok(ModelEstimates {
        h21: h.m,
        h_inliers: h.inliers,
        f21: f.m,
        f_inliers: f.inliers,
        ratio: h.score / total,
    })
}

/// Recovers the relative motion of two views from matched undistorted pixels `x1[i] <-> x2[i]`
/// of a pinhole camera `k`.
pub fn initialize(
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    k: &Matrix3<f64>,
    cfg: &TwoViewConfig,
) -> Result<TwoViewMotion, TwoViewError> {
    let mut est = estimate_models(x1, x2, cfg)?;
    let n = x1.len().min(x2.len());
    let (x1, x2) = (&x1[..n], &x2[..n]);
    let th2 = 4.0 * cfg.sigma * cfg.sigma;
    let inv_s2 = 1.0 / (cfg.sigma * cfg.sigma);
    let model = est.selected(cfg);
    let mut r = match model {
        TwoViewModel::Homography => {
            refit(model, &mut est.h21, &mut est.h_inliers, x1, x2, inv_s2);
            reconstruct_h(&est.h21, x1, x2, &est.h_inliers, k, th2, cfg)?
        }
        TwoViewModel::Fundamental => {
            refit(model, &mut est.f21, &mut est.f_inliers, x1, x2, inv_s2);
            reconstruct_f(&est.f21, x1, x2, &est.f_inliers, k, th2, cfg)?
        }
    };
    r.score_ratio = est.ratio;
    Ok(r)
}
