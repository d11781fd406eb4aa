//! The frame being tracked: its features, pose estimate and map-point matches, in buffers reused
//! from frame to frame.

use crate::features::Features;
use crate::geometry::CameraFromWorld;
use crate::map::MapPointId;
use crate::matching::FeatureGrid;

pub struct TrackedFrame {
    pub index: u64,
    pub timestamp: f64,
    pub features: Features,
    pub grid: FeatureGrid,
    pub t_cw: CameraFromWorld,
    /// Per keypoint: the matched map point.
    pub points: Vec<Option<MapPointId>>,
    /// Per keypoint: rejected by the last pose optimisation.
    pub outlier: Vec<bool>,
}

impl TrackedFrame {
    pub fn new(max_features: usize, width: usize, height: usize) -> Self {
        TrackedFrame {
            index: 0,
            timestamp: 0.0,
            features: Features::with_capacity(max_features),
            grid: FeatureGrid::new(
                (width / 10).max(1),
                (height / 10).max(1),
                (0.0, 0.0, width as f32, height as f32),
                max_features,
            ),
            t_cw: CameraFromWorld::identity(),
            points: Vec::with_capacity(max_features),
            outlier: Vec::with_capacity(max_features),
        }
    }

    /// Resets matches after new features were extracted.
    pub fn reset_matches(&mut self) {
        self.points.clear();
        self.points.resize(self.features.len(), None);
        self.outlier.clear();
        self.outlier.resize(self.features.len(), false);
        self.grid.assign(&self.features.keypoints);
    }

    /// Copies `other` into this frame's buffers (no allocation once capacities suffice).
    pub fn copy_from(&mut self, other: &TrackedFrame) {
        self.index = other.index;
        self.timestamp = other.timestamp;
        self.t_cw = other.t_cw;
        self.features.copy_from(&other.features);
        self.points.clear();
        self.points.extend_from_slice(&other.points);
        self.outlier.clear();
        self.outlier.extend_from_slice(&other.outlier);
    }

    /// Matched map points that survived the last optimisation.
    pub fn inlier_points(&self) -> impl Iterator<Item = (usize, MapPointId)> + '_ {
        self.points
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.filter(|_| !self.outlier[i]).map(|p| (i, p)))
    }

    pub fn n_inliers(&self) -> usize {
        self.inlier_points().count()
    }
}

/// A frame's grey (and colour) image kept beyond the frame, in reused buffers: the
/// initialisation reference and the frame of an attempt in flight become keyframes later.
#[derive(Clone, Default)]
pub struct KeptImages {
    pub gray: Vec<u8>,
    rgb: Vec<u8>,
    has_color: bool,
}

impl KeptImages {
    pub fn with_capacity(pixels: usize) -> Self {
        KeptImages {
            gray: Vec::with_capacity(pixels),
            rgb: Vec::with_capacity(pixels * 3),
            has_color: false,
        }
    }

    /// Copies `gray` and `rgb` in (no allocation once the buffers have the frame's size).
    pub fn set(&mut self, gray: &[u8], rgb: Option<&[u8]>) {
        self.gray.clear();
        self.gray.extend_from_slice(gray);
        self.rgb.clear();
        if let Some(c) = rgb {
            self.rgb.extend_from_slice(c);
        }
        self.has_color = rgb.is_some();
    }

    pub fn rgb(&self) -> Option<&[u8]> {
        self.has_color.then_some(&self.rgb[..])
    }
}
