//! Detector and descriptor quality under a known homography (Mikolajczyk-style repeatability and
//! matching score), used by tests and by `sdslam features --warp`.

use nalgebra::Matrix3;

use crate::features::{Features, KeyPoint};
use crate::image::warp::apply_homography;
use crate::matching::hamming;

/// Quality of features of image A against image B = A warped by `H`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WarpQuality {
    /// Keypoints of A whose mapping lands inside B (away from the border).
    pub comparable: usize,
    /// Share of comparable A keypoints with a B keypoint within `eps` pixels.
    pub repeatability: f64,
    /// Share of comparable A keypoints whose nearest descriptor in B lies within `eps` of the
    /// mapped position (a correct match).
    pub matching_score: f64,
}

/// Measures A -> B with `h_ba` mapping A pixels to B pixels, B of size `w` x `h`; points within
/// `border` of B's edge are not compared (detectors keep away from edges).
pub fn warp_quality(
    a: &Features,
    b: &Features,
    h_ba: &Matrix3<f64>,
    w: f64,
    h: f64,
    border: f64,
    eps: f64,
) -> WarpQuality {
    let inside = |x: f64, y: f64| {
        x >= border && y >= border && x <= w - 1.0 - border && y <= h - 1.0 - border
    };
    let near = |k: &KeyPoint, x: f64, y: f64| {
        ((k.x as f64 - x).powi(2) + (k.y as f64 - y).powi(2)).sqrt() <= eps
    };
    let (mut comparable, mut repeated, mut matched) = (0usize, 0usize, 0usize);
    for (ka, da) in a.keypoints.iter().zip(&a.descriptors) {
        let Some((x, y)) = apply_homography(h_ba, ka.x as f64, ka.y as f64) else {
            continue;
        };
        if !inside(x, y) {
            continue;
        }
        comparable += 1;
        if b.keypoints.iter().any(|kb| near(kb, x, y)) {
            repeated += 1;
        }
        let best = b
            .descriptors
            .iter()
            .enumerate()
            .min_by_key(|(_, db)| hamming(da, db))
            .map(|(i, _)| i);
        if best.is_some_and(|i| near(&b.keypoints[i], x, y)) {
            matched += 1;
        }
    }
    let n = comparable.max(1) as f64;
    WarpQuality {
        comparable,
        repeatability: repeated as f64 / n,
        matching_score: matched as f64 / n,
    }
}
