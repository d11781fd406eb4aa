//! Map points: a 3D position with its observations, mean viewing direction, representative
//! descriptor and scale-invariance distance range.

use nalgebra::Vector3;

use super::KeyFrameId;
use crate::features::Descriptor;

pub struct MapPoint {
    pub position: Vector3<f64>,
    /// Mean viewing direction (unit), from the observing cameras to the point.
    pub normal: Vector3<f64>,
    /// The observation descriptor with the least median distance to the others.
    pub descriptor: Descriptor,
    /// Distances within which the point is expected to be detected (scale invariance).
    pub min_distance: f64,
    pub max_distance: f64,
    /// (keyframe, keypoint index).
    pub observations: Vec<(KeyFrameId, u32)>,
    pub reference_kf: Option<KeyFrameId>,
    /// Serial of the keyframe that created it (recent-point culling).
    pub first_kf_serial: u64,
    /// Frames in which the point was predicted visible / actually matched (culling ratio).
    pub visible: u32,
    pub found: u32,
}

impl MapPoint {
    pub fn with_capacity(observations: usize) -> Self {
        MapPoint {
            position: Vector3::zeros(),
            normal: Vector3::zeros(),
            descriptor: [0; 4],
            min_distance: 0.0,
            max_distance: f64::INFINITY,
            observations: Vec::with_capacity(observations),
            reference_kf: None,
            first_kf_serial: 0,
            visible: 1,
            found: 1,
        }
    }

    /// Bytes this point's slot holds with its reserved observations.
    pub fn reserved_bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + self.observations.capacity() * std::mem::size_of::<(KeyFrameId, u32)>()
    }

    pub fn clear(&mut self) {
        self.observations.clear();
        self.reference_kf = None;
        self.visible = 1;
        self.found = 1;
        self.min_distance = 0.0;
        self.max_distance = f64::INFINITY;
    }

    pub fn found_ratio(&self) -> f64 {
        self.found as f64 / self.visible.max(1) as f64
    }

    /// Predicted pyramid level for a point at `distance`, given the level scale factor.
    pub fn predict_level(&self, distance: f64, scale_factor: f64, n_levels: usize) -> usize {
        let ratio = self.max_distance / distance.max(1e-12);
        let l = (ratio.ln() / scale_factor.ln()).ceil();
        l.clamp(0.0, (n_levels - 1) as f64) as usize
    }
}
