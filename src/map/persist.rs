//! The map as a file: keyframes (pose, features, spanning tree, loop edges), map points
//! (geometry, descriptor, observations) and what they were built with (camera, vocabulary).
//! Versioned binary: an 8-byte magic, format version, payload length and CRC-32, then the
//! payload in `postcard` (serde). Covisibility is rebuilt from the observations on load. Images
//! are not stored (semi-dense mapping does not run on loaded keyframes). Encoding and decoding
//! are pure; the file IO (atomic write) is in `crate::io`.

use std::collections::HashMap;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::{KeyFrameId, Map, MapPointId};
use crate::features::KeyPoint;
use crate::geometry::CameraFromWorld;

/// Identifies sdslam map files.
pub const MAGIC: &[u8; 8] = b"SDSLAMAP";
/// Bumped whenever the payload layout changes; older files are refused with a clear message.
pub const MAP_FORMAT_VERSION: u32 = 2;
const HEADER: usize = 8 + 4 + 8 + 4;

/// What a map was built with: loading it with another camera or vocabulary is refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapOrigin {
    /// fx, fy, cx, cy of the undistorted camera, and the image size.
    pub intrinsics: [f64; 4],
    pub width: u32,
    pub height: u32,
    pub vocabulary_words: u32,
    /// CRC-32 of the vocabulary's binary encoding.
    pub vocabulary_crc: u32,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct KeyFrameRec {
    frame_index: u64,
    timestamp: f64,
    /// T_cw as unit quaternion (w, x, y, z) and translation.
    rotation: [f64; 4],
    translation: [f64; 3],
    keypoints: Vec<KeyPoint>,
    descriptors: Vec<[u64; 4]>,
    parent: Option<u32>,
    loop_edges: Vec<u32>,
    /// The atlas map it belongs to (format 2).
    map_id: u32,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct MapPointRec {
    position: [f64; 3],
    normal: [f64; 3],
    descriptor: [u64; 4],
    min_distance: f64,
    max_distance: f64,
    /// (keyframe index in the file, keypoint index).
    observations: Vec<(u32, u32)>,
    reference: Option<u32>,
    visible: u32,
    found: u32,
}

/// A map, detached from the arenas: what goes into a file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MapSnapshot {
    pub origin: MapOrigin,
    keyframes: Vec<KeyFrameRec>,
    points: Vec<MapPointRec>,
}

/// Why a map file was refused.
#[derive(Debug, thiserror::Error)]
pub enum MapFileError {
    #[error("not an sdslam map file")]
    NotAMap,
    #[error(
        "map format version {found}; this sdslam reads version {expected} (re-create the map)"
    )]
    Version { found: u32, expected: u32 },
    #[error("truncated: {got} bytes of payload, {expected} expected")]
    Truncated { got: u64, expected: u64 },
    #[error("{got} bytes of payload where the header says {expected}: bytes were appended or the header is corrupt")]
    TooLong { got: u64, expected: u64 },
    #[error("checksum mismatch: the file is corrupt")]
    Checksum,
    #[error("payload does not decode: {0}")]
    Decode(String),
    #[error("inconsistent map: {0}")]
    Inconsistent(String),
    #[error("the map was built with {what}: {map} (this run: {run})")]
    Incompatible {
        what: &'static str,
        map: String,
        run: String,
    },
    #[error("the map has {need} {what} but this run holds at most {capacity} (raise {key})")]
    TooBig {
        what: &'static str,
        need: usize,
        capacity: usize,
        key: &'static str,
    },
}

impl MapSnapshot {
    /// Copies `map` out (keyframes in creation order).
    pub fn capture(map: &Map, origin: MapOrigin) -> Self {
        let mut kfs: Vec<(KeyFrameId, &super::KeyFrame)> = map.keyframes().collect();
        kfs.sort_by_key(|(_, k)| k.serial);
        let kf_index: HashMap<KeyFrameId, u32> = kfs
            .iter()
            .enumerate()
            .map(|(i, (id, _))| (*id, i as u32))
            .collect();
        let pts: Vec<(MapPointId, &super::MapPoint)> = map.points().collect();
        let keyframes = kfs
            .iter()
            .map(|(_, k)| {
                let q = k.t_cw.0.rotation.quaternion();
                let t = k.t_cw.0.translation.vector;
                KeyFrameRec {
                    frame_index: k.frame_index,
                    timestamp: k.timestamp,
                    rotation: [q.w, q.i, q.j, q.k],
                    translation: [t.x, t.y, t.z],
                    keypoints: k.keypoints.clone(),
                    descriptors: k.descriptors.clone(),
                    parent: k.parent.and_then(|p| kf_index.get(&p).copied()),
                    map_id: k.map_id,
                    loop_edges: k
                        .loop_edges
                        .iter()
                        .filter_map(|e| kf_index.get(e).copied())
                        .collect(),
                }
            })
            .collect();
        let points = pts
            .iter()
            .map(|(_, p)| MapPointRec {
                position: [p.position.x, p.position.y, p.position.z],
                normal: [p.normal.x, p.normal.y, p.normal.z],
                descriptor: p.descriptor,
                min_distance: p.min_distance,
                max_distance: p.max_distance,
                observations: p
                    .observations
                    .iter()
                    .filter_map(|(kf, i)| kf_index.get(kf).map(|k| (*k, *i)))
                    .collect(),
                reference: p.reference_kf.and_then(|r| kf_index.get(&r).copied()),
                visible: p.visible,
                found: p.found,
            })
            .filter(|r| !r.observations.is_empty())
            .collect();
        MapSnapshot {
            origin,
            keyframes,
            points,
        }
    }

    pub fn n_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    pub fn n_points(&self) -> usize {
        self.points.len()
    }

    /// Checks every index and number before anything is built from the snapshot.
    fn validate(&self) -> Result<(), MapFileError> {
        let bad = |m: String| Err(MapFileError::Inconsistent(m));
        let nk = self.keyframes.len() as u32;
        for (i, k) in self.keyframes.iter().enumerate() {
            let finite = k
                .rotation
                .iter()
                .chain(&k.translation)
                .all(|v| v.is_finite())
                && k.timestamp.is_finite();
            let qn: f64 = k.rotation.iter().map(|v| v * v).sum::<f64>();
            if !finite || (qn - 1.0).abs() > 1e-3 {
                return bad(format!("keyframe {i} has an invalid pose"));
            }
            if k.keypoints.len() != k.descriptors.len() {
                return bad(format!(
                    "keyframe {i}: {} keypoints, {} descriptors",
                    k.keypoints.len(),
                    k.descriptors.len()
                ));
            }
            if k.parent.is_some_and(|p| p >= nk) || k.loop_edges.iter().any(|&e| e >= nk) {
                return bad(format!(
                    "keyframe {i} links to a keyframe that does not exist"
                ));
            }
            if k.parent
                .is_some_and(|p| self.keyframes[p as usize].map_id != k.map_id)
            {
                return bad(format!(
                    "keyframe {i} of map {} has its spanning-tree parent in another map",
                    k.map_id
                ));
            }
            if k.keypoints.iter().any(|p| {
                !(p.x.is_finite() && p.y.is_finite() && p.ux.is_finite() && p.uy.is_finite())
            }) {
                return bad(format!("keyframe {i} has a non-finite keypoint"));
            }
        }
        for (j, p) in self.points.iter().enumerate() {
            if !p.position.iter().chain(&p.normal).all(|v| v.is_finite()) {
                return bad(format!("map point {j} has a non-finite position"));
            }
            for &(k, i) in &p.observations {
                let Some(kf) = self.keyframes.get(k as usize) else {
                    return bad(format!(
                        "map point {j} is observed by keyframe {k}, which does not exist"
                    ));
                };
                if i as usize >= kf.keypoints.len() {
                    return bad(format!(
                        "map point {j} is observed by keypoint {i} of keyframe {k}, which has {}",
                        kf.keypoints.len()
                    ));
                }
            }
            if p.reference.is_some_and(|r| r >= nk) {
                return bad(format!(
                    "map point {j} refers to a keyframe that does not exist"
                ));
            }
        }
        Ok(())
    }

    /// Replaces the contents of `map` with the snapshot. `map` must be empty-able: it is reset.
    pub fn restore(&self, map: &mut Map) -> Result<Vec<KeyFrameId>, MapFileError> {
        self.validate()?;
        let (kcap, pcap) = map.capacity();
        if self.keyframes.len() > kcap {
            return Err(MapFileError::TooBig {
                what: "keyframes",
                need: self.keyframes.len(),
                capacity: kcap,
                key: "[map] max_keyframes",
            });
        }
        if self.points.len() > pcap {
            return Err(MapFileError::TooBig {
                what: "map points",
                need: self.points.len(),
                capacity: pcap,
                key: "[map] max_map_points",
            });
        }
        let (max_features, levels) = (map.config.max_features, map.config.n_levels);
        for (i, k) in self.keyframes.iter().enumerate() {
            if k.keypoints.len() > max_features {
                return Err(MapFileError::TooBig {
                    what: "features in a keyframe",
                    need: k.keypoints.len(),
                    capacity: max_features,
                    key: "[orb] n_features",
                });
            }
            // Octaves index the pyramid's scale tables: out of range would be out of bounds.
            if k.keypoints.iter().any(|p| p.octave as usize >= levels) {
                return Err(MapFileError::Inconsistent(format!(
                    "keyframe {i} has keypoints beyond the {levels} pyramid levels of this run"
                )));
            }
        }
        map.reset();
        let mut ids = Vec::with_capacity(self.keyframes.len());
        for k in &self.keyframes {
            let q = UnitQuaternion::from_quaternion(Quaternion::new(
                k.rotation[0],
                k.rotation[1],
                k.rotation[2],
                k.rotation[3],
            ));
            let t = Translation3::new(k.translation[0], k.translation[1], k.translation[2]);
            let id = map
                .insert_keyframe(|kf| {
                    kf.frame_index = k.frame_index;
                    kf.timestamp = k.timestamp;
                    kf.t_cw = CameraFromWorld(Isometry3::from_parts(t, q));
                    kf.keypoints.extend_from_slice(&k.keypoints);
                    kf.descriptors.extend_from_slice(&k.descriptors);
                })
                .map_err(|e| MapFileError::Inconsistent(format!("{e:?}")))?;
            ids.push(id);
        }
        for (k, rec) in ids.iter().zip(&self.keyframes) {
            let parent = rec.parent.map(|p| ids[p as usize]);
            let loops: Vec<KeyFrameId> = rec.loop_edges.iter().map(|&e| ids[e as usize]).collect();
            if let Some(kf) = map.keyframe_mut(*k) {
                kf.parent = parent;
                kf.loop_edges = loops;
                kf.map_id = rec.map_id;
            }
            if let Some(p) = parent {
                if let Some(pk) = map.keyframe_mut(p) {
                    pk.children.push(*k);
                }
            }
        }
        for p in &self.points {
            let reference = p
                .reference
                .map(|r| ids[r as usize])
                .unwrap_or(ids[p.observations[0].0 as usize]);
            let id = map
                .insert_point(Vector3::from(p.position), reference)
                .map_err(|e| MapFileError::Inconsistent(format!("{e:?}")))?;
            for &(k, i) in &p.observations {
                map.add_observation(id, ids[k as usize], i as usize);
            }
            if let Some(mp) = map.point_mut(id) {
                mp.normal = Vector3::from(p.normal);
                mp.descriptor = p.descriptor;
                mp.min_distance = p.min_distance;
                mp.max_distance = p.max_distance;
                mp.visible = p.visible;
                mp.found = p.found;
                mp.first_kf_serial = 0;
            }
        }
        for k in &ids {
            map.update_connections(*k);
        }
        map.restore_atlas(self.keyframes.iter().map(|k| k.map_id));
        Ok(ids)
    }

    /// The file bytes: header (magic, version, payload length, CRC-32) and payload.
    pub fn encode(&self) -> Result<Vec<u8>, MapFileError> {
        let payload = postcard::to_stdvec(self).map_err(|e| MapFileError::Decode(e.to_string()))?;
        let mut out = Vec::with_capacity(HEADER + payload.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&MAP_FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// Parses file bytes, checking magic, version, length and checksum first.
    pub fn decode(bytes: &[u8]) -> Result<Self, MapFileError> {
        if bytes.len() < HEADER || &bytes[..8] != MAGIC {
            return Err(MapFileError::NotAMap);
        }
        let u32_at =
            |i: usize| u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
        let version = u32_at(8);
        if version != MAP_FORMAT_VERSION {
            return Err(MapFileError::Version {
                found: version,
                expected: MAP_FORMAT_VERSION,
            });
        }
        let mut len8 = [0u8; 8];
        len8.copy_from_slice(&bytes[12..20]);
        let len = u64::from_le_bytes(len8);
        let payload = &bytes[HEADER..];
        let got = payload.len() as u64;
        if got < len {
            return Err(MapFileError::Truncated { got, expected: len });
        }
        if got > len {
            return Err(MapFileError::TooLong { got, expected: len });
        }
        if crc32fast::hash(payload) != u32_at(20) {
            return Err(MapFileError::Checksum);
        }
        let snap: MapSnapshot =
            postcard::from_bytes(payload).map_err(|e| MapFileError::Decode(e.to_string()))?;
        snap.validate()?;
        Ok(snap)
    }
}
