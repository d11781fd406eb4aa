//! ORB features (Rublee et al. 2011) as ORB-SLAM uses them: an 8-level pyramid, FAST-9 with a
//! per-cell threshold fallback, quadtree distribution, intensity-centroid orientation and steered
//! BRIEF on the blurred level. Extraction writes into preallocated buffers and does not allocate
//! once warmed up.

pub mod brief;
mod distribute;
mod extractor;
pub mod fast;
#[cfg(target_arch = "x86_64")]
mod fast_avx2;
pub mod harris;
mod helper;
pub mod orientation;
mod spread;

pub use brief::Descriptor;
pub use extractor::{features_per_level, OrbExtractor};

/// A keypoint in level-0 pixel coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KeyPoint {
    /// Distorted (raw image) position.
    pub x: f32,
    pub y: f32,
    /// Undistorted position (equals x, y for a distortion-free camera).
    pub ux: f32,
    pub uy: f32,
    /// Pyramid level it was detected on.
    pub octave: u8,
    /// Orientation in degrees [0, 360).
    pub angle: f32,
    /// FAST score.
    pub response: f32,
    /// Patch diameter in level-0 pixels (31 * scale).
    pub size: f32,
}

/// Keypoints and descriptors of one image, index-aligned.
#[derive(Clone, Debug, Default)]
pub struct Features {
    pub keypoints: Vec<KeyPoint>,
    pub descriptors: Vec<Descriptor>,
}

/// Keypoints and their descriptors (same length), borrowed: one side of a matching search,
/// from a frame's [`Features`] or a keyframe's stored arrays.
#[derive(Clone, Copy, Debug)]
pub struct FeatureView<'a> {
    pub keypoints: &'a [KeyPoint],
    pub descriptors: &'a [Descriptor],
}

impl<'a> FeatureView<'a> {
    pub fn new(keypoints: &'a [KeyPoint], descriptors: &'a [Descriptor]) -> Self {
        FeatureView {
            keypoints,
            descriptors,
        }
    }
}

impl Features {
    pub fn view(&self) -> FeatureView<'_> {
        FeatureView::new(&self.keypoints, &self.descriptors)
    }

    pub fn with_capacity(n: usize) -> Self {
        Features {
            keypoints: Vec::with_capacity(n),
            descriptors: Vec::with_capacity(n),
        }
    }
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }
    pub fn clear(&mut self) {
        self.keypoints.clear();
        self.descriptors.clear();
    }

    /// Copies `other` into these buffers (no allocation once the capacity suffices).
    pub fn copy_from(&mut self, other: &Features) {
        self.keypoints.clear();
        self.keypoints.extend_from_slice(&other.keypoints);
        self.descriptors.clear();
        self.descriptors.extend_from_slice(&other.descriptors);
    }
}
