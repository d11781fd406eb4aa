//! Offline densification from given poses (a refined trajectory or ground truth), as the
//! paper suggests after full BA: every given keyframe gets ORB features; map points are
//! triangulated between each keyframe and the previous N with the known poses, then matched
//! by projection into every keyframe that sees them (so a keyframe revisiting a place shares
//! points with the earlier ones): shared points measure viewing overlap (the covisibility
//! that picks neighbours), give the depth prior and the in-plane rotations; then the same
//! [`SemiDenseMapper`] reconstructs them.

use std::sync::Mutex;

use crate::camera_model::PinholeRadtan;
use crate::config::Config;
use crate::features::{Features, OrbExtractor};
use crate::geometry::CloudPoint;
use crate::geometry::WorldFromCamera;
use crate::local_mapping::{fuse_into, LocalMapper};
use crate::map::{KeyFrameId, Map, MapConfig, MapPointId};

use super::SemiDenseMapper;

pub struct Densifier {
    extractor: OrbExtractor,
    features: Features,
    triangulator: LocalMapper,
    map: Mutex<Map>,
    keyframes: Vec<KeyFrameId>,
    mapper: SemiDenseMapper,
    n_neighbours: usize,
    camera: PinholeRadtan,
    scales: Vec<f64>,
}

impl Densifier {
    /// For undistorted images of `camera`'s size and at most `max_keyframes` keyframes.
    pub fn new(camera: &PinholeRadtan, config: &Config, max_keyframes: usize) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let extractor = OrbExtractor::new(w, h, &config.orb);
        let scales = extractor.pyramid().scales.clone();
        let max_features = config.orb.n_features * 2;
        let map = Map::new(MapConfig {
            max_features,
            width: w,
            height: h,
            scale_factor: config.orb.scale_factor,
            n_levels: config.orb.n_levels,
            max_keyframes: max_keyframes.max(2),
            max_map_points: config.map.max_map_points,
            ..MapConfig::default()
        });
        let k = camera.intrinsics();
        Densifier {
            features: Features::with_capacity(max_features),
            extractor,
            triangulator: LocalMapper::new(*camera, &scales),
            map: Mutex::new(map),
            keyframes: Vec::with_capacity(max_keyframes),
            mapper: SemiDenseMapper::new(
                k,
                w,
                h,
                &config.semidense,
                max_keyframes.max(2),
                max_features,
            ),
            n_neighbours: config.semidense.n_neighbours,
            camera: *camera,
            scales,
        }
    }

    /// Adds a keyframe (undistorted grey, optional RGB) with its pose. False when the map is
    /// full.
    pub fn add_keyframe(
        &mut self,
        gray: &[u8],
        rgb: Option<&[u8]>,
        timestamp: f64,
        index: u64,
        t_wc: &WorldFromCamera,
    ) -> bool {
        self.extractor.extract(gray, None, &mut self.features);
        let map = self.map.get_mut().unwrap_or_else(|e| e.into_inner());
        let f = &self.features;
        let Ok(kf) = map.insert_keyframe(|k| {
            k.keypoints.extend_from_slice(&f.keypoints);
            k.descriptors.extend_from_slice(&f.descriptors);
            k.frame_index = index;
            k.timestamp = timestamp;
            k.t_cw = t_wc.inverse();
            k.set_images(gray, rgb);
        }) else {
            return false;
        };
        let start = self.keyframes.len().saturating_sub(self.n_neighbours);
        let previous: Vec<KeyFrameId> = self.keyframes[start..].iter().rev().copied().collect();
        self.triangulator.triangulate_with(map, kf, &previous);
        for &p in &previous {
            map.update_connections(p);
        }
        self.keyframes.push(kf);
        true
    }

    /// Updates every keyframe's covisibility from the points triangulated so far (each
    /// keyframe with the previous N: neighbours near in time).
    pub fn connect(&mut self) {
        let map = self.map.get_mut().unwrap_or_else(|e| e.into_inner());
        for &k in &self.keyframes {
            map.update_connections(k);
        }
    }

    /// Matches every point into every keyframe that sees it (projection, descriptor; ORB-
    /// SLAM's duplicate fusion over all keyframes, not only those near in time), then
    /// [`connect`](Self::connect)s: a keyframe revisiting a place becomes a neighbour of the
    /// earlier ones.
    pub fn connect_by_covisibility(&mut self) {
        let map = self.map.get_mut().unwrap_or_else(|e| e.into_inner());
        let points: Vec<MapPointId> = map.points().map(|(id, _)| id).collect();
        for &k in &self.keyframes {
            fuse_into(map, &self.camera, &self.scales, k, &points, 3.0);
        }
        self.connect();
    }

    /// The keyframe map built from the given poses.
    pub fn map(&self) -> &Mutex<Map> {
        &self.map
    }

    pub fn keyframes(&self) -> &[KeyFrameId] {
        &self.keyframes
    }

    /// Reconstructs every keyframe (neighbours by covisibility over all of them).
    pub fn finish(&mut self) -> &SemiDenseMapper {
        self.connect_by_covisibility();
        for &k in &self.keyframes {
            self.mapper.on_keyframe(&self.map, k);
        }
        self.mapper.flush(&self.map);
        &self.mapper
    }

    pub fn mapper(&self) -> &SemiDenseMapper {
        &self.mapper
    }

    pub fn cloud(&self, out: &mut Vec<CloudPoint>) {
        let map = self.map.lock().unwrap_or_else(|e| e.into_inner());
        self.mapper.cloud(&map, out);
    }
}
