//! Keyframes: a pose, the frame's features, their map-point associations, the grey image for
//! semi-dense mapping, and the keyframe's place in the covisibility graph and spanning tree.
//! Buffers are reserved once and reused when the slot is recycled.

use super::{KeyFrameId, MapPointId};
use crate::features::{Descriptor, KeyPoint};
use crate::geometry::CameraFromWorld;
use crate::matching::FeatureGrid;

pub struct KeyFrame {
    /// Creation order (monotonic over the whole run; never reused).
    pub serial: u64,
    /// The map of the atlas it belongs to (a new map starts when tracking is lost in
    /// unmapped space; merged maps take the older map's id). Set by [`super::Map`].
    pub map_id: u32,
    /// Index of the frame it was made from.
    pub frame_index: u64,
    pub timestamp: f64,
    pub t_cw: CameraFromWorld,
    pub keypoints: Vec<KeyPoint>,
    pub descriptors: Vec<Descriptor>,
    /// Per keypoint: the map point it observes.
    pub points: Vec<Option<MapPointId>>,
    pub grid: FeatureGrid,
    /// Undistorted grey image (semi-dense mapping, relocalisation checks).
    pub gray: Vec<u8>,
    /// Colour when the source has it (colours the semi-dense cloud), as half-resolution
    /// residuals against `gray` ([`crate::image::colour`]): 0.75 bytes per pixel, not 3.
    pub colour: Vec<u8>,
    /// Image width (for reading `gray` and `colour`).
    pub width: usize,
    pub has_color: bool,
    /// Covisible keyframes with shared-point counts, strongest first.
    pub covisibles: Vec<(KeyFrameId, u32)>,
    /// Spanning tree.
    pub parent: Option<KeyFrameId>,
    pub children: Vec<KeyFrameId>,
    /// Loop-closure edges (part of the essential graph).
    pub loop_edges: Vec<KeyFrameId>,
}

impl KeyFrame {
    /// Reserves buffers for `max_features` keypoints and `width` x `height` images.
    pub fn with_capacity(max_features: usize, width: usize, height: usize) -> Self {
        let grid_cols = (width / 10).max(1);
        let grid_rows = (height / 10).max(1);
        KeyFrame {
            serial: 0,
            map_id: 0,
            frame_index: 0,
            timestamp: 0.0,
            t_cw: CameraFromWorld::identity(),
            keypoints: Vec::with_capacity(max_features),
            descriptors: Vec::with_capacity(max_features),
            points: Vec::with_capacity(max_features),
            grid: FeatureGrid::new(
                grid_cols,
                grid_rows,
                (0.0, 0.0, width as f32, height as f32),
                max_features,
            ),
            gray: Vec::with_capacity(width * height),
            colour: Vec::with_capacity(crate::image::colour::residual_len(width, height)),
            width,
            has_color: false,
            covisibles: Vec::with_capacity(64),
            parent: None,
            children: Vec::with_capacity(8),
            loop_edges: Vec::new(),
        }
    }

    /// Bytes this keyframe holds once its reserved buffers are filled (the slot's cost).
    pub fn reserved_bytes(&self) -> usize {
        fn cap<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        std::mem::size_of::<Self>()
            + cap(&self.keypoints)
            + cap(&self.descriptors)
            + cap(&self.points)
            // The grid stores one index per keypoint.
            + self.keypoints.capacity() * std::mem::size_of::<u32>()
            + cap(&self.gray)
            + cap(&self.colour)
            + cap(&self.covisibles)
            + cap(&self.children)
    }

    /// Clears the contents, keeping every buffer's capacity.
    pub fn clear(&mut self) {
        // A recycled slot must not keep the pose of the keyframe it held (a new map's first
        // keyframe is the identity only if nothing sets it).
        self.t_cw = CameraFromWorld::identity();
        self.map_id = 0;
        self.keypoints.clear();
        self.descriptors.clear();
        self.points.clear();
        self.gray.clear();
        self.colour.clear();
        self.has_color = false;
        self.covisibles.clear();
        self.parent = None;
        self.children.clear();
        self.loop_edges.clear();
    }

    /// Stores the keyframe's undistorted grey image and, when given, its colour (tightly
    /// packed RGB of the same size) as residuals. Reuses the reserved buffers.
    pub fn set_images(&mut self, gray: &[u8], rgb: Option<&[u8]>) {
        self.gray.clear();
        self.gray.extend_from_slice(gray);
        self.colour.clear();
        self.has_color = false;
        if let Some(c) = rgb {
            let h = gray.len() / self.width.max(1);
            crate::image::colour::encode_residual(c, gray, self.width, h, &mut self.colour);
            self.has_color = !self.colour.is_empty();
        }
    }

    /// Map points observed, with their keypoint index.
    pub fn observed(&self) -> impl Iterator<Item = (usize, MapPointId)> + '_ {
        self.points
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.map(|p| (i, p)))
    }

    /// The `n` strongest covisible keyframes.
    pub fn best_covisibles(&self, n: usize) -> impl Iterator<Item = KeyFrameId> + '_ {
        self.covisibles.iter().take(n).map(|&(k, _)| k)
    }

    /// Covisibility weight with `other` (0 when not connected).
    pub fn weight_with(&self, other: KeyFrameId) -> u32 {
        self.covisibles
            .iter()
            .find(|(k, _)| *k == other)
            .map_or(0, |&(_, w)| w)
    }
}
