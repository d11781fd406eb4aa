//! Descriptor matching tools: Hamming distance, rotation-consistency histogram, ratio test,
//! and a grid for radius searches of keypoints.

mod grid;
mod hamming;
mod rotation;
pub mod search;

pub use grid::FeatureGrid;
pub use hamming::{hamming, passes_ratio, TH_HIGH, TH_LOW};
pub use rotation::RotationHistogram;
