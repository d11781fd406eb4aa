//! The map: keyframes and map points in fixed-capacity arenas addressed by generational
//! handles, their observations, the covisibility graph (edges of weight >= 15 shared points),
//! the spanning tree and the essential graph. Capacities come from the configuration; a full
//! arena is an error the caller answers by culling, never by growing. Slot buffers are recycled
//! through pools, so a steady-state map does not allocate.

mod arena;
mod atlas;
mod graph;
mod keyframe;
mod map_point;
pub mod persist;

pub use arena::{Arena, ArenaFull, Handle};
pub use keyframe::KeyFrame;
pub use map_point::MapPoint;

use nalgebra::Vector3;

use crate::matching::hamming;

/// The newest keyframes are never evicted (tracking and mapping work on them).
pub const RECENT_PROTECTED: usize = 10;

pub type KeyFrameId = Handle<KeyFrame>;
pub type MapPointId = Handle<MapPoint>;

/// Capacities and pyramid geometry the map needs.
#[derive(Clone, Debug)]
pub struct MapConfig {
    pub max_keyframes: usize,
    pub max_map_points: usize,
    pub max_features: usize,
    pub width: usize,
    pub height: usize,
    pub scale_factor: f64,
    pub n_levels: usize,
    /// Minimum shared points for a covisibility edge (ORB-SLAM: 15).
    pub covisibility_min_weight: u32,
    /// Minimum weight of covisibility edges kept in the essential graph (ORB-SLAM: 100).
    pub essential_min_weight: u32,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            max_keyframes: 500,
            max_map_points: 100_000,
            max_features: 2000,
            width: 640,
            height: 480,
            scale_factor: 1.2,
            n_levels: 8,
            covisibility_min_weight: 15,
            essential_min_weight: 100,
        }
    }
}

/// The map is at capacity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MapFull {
    #[error("keyframe capacity ({0}) reached")]
    KeyFrames(usize),
    #[error("map point capacity ({0}) reached")]
    MapPoints(usize),
}

pub struct Map {
    pub config: MapConfig,
    keyframes: Arena<KeyFrame>,
    points: Arena<MapPoint>,
    kf_pool: Vec<KeyFrame>,
    mp_pool: Vec<MapPoint>,
    next_serial: u64,
    /// Counts corrections that move the whole map (loop corrections, merged full BAs), so a
    /// local or full BA solved from a copy taken before one is not written over it.
    corrections: u64,
    /// Scratch for covisibility counting (indexed by keyframe slot).
    counts: Vec<u32>,
    touched: Vec<usize>,
    /// Culled keyframes: their spanning-tree parent and their pose relative to it when culled
    /// (ORB-SLAM's `Tcp`), so frames tracked against them keep following the map.
    tombstones: std::collections::HashMap<KeyFrameId, (KeyFrameId, crate::geometry::Se3)>,
    /// The atlas: the map new keyframes join, and the id the next new map gets.
    active_map: u32,
    next_map_id: u32,
    merges: u32,
}

impl Map {
    /// Bytes a map with `config` holds when full: (per keyframe slot, per map-point slot).
    /// Measured on one slot of each, so it follows the types.
    pub fn slot_bytes(config: &MapConfig) -> (usize, usize) {
        let kf = KeyFrame::with_capacity(config.max_features, config.width, config.height);
        (
            kf.reserved_bytes() + std::mem::size_of::<u32>(),
            MapPoint::with_capacity(8).reserved_bytes(),
        )
    }

    /// Allocates every keyframe and map-point buffer up front.
    pub fn new(config: MapConfig) -> Self {
        let kf_pool = (0..config.max_keyframes)
            .map(|_| KeyFrame::with_capacity(config.max_features, config.width, config.height))
            .collect();
        let mp_pool = (0..config.max_map_points)
            .map(|_| MapPoint::with_capacity(8))
            .collect();
        Map {
            keyframes: Arena::with_capacity(config.max_keyframes),
            points: Arena::with_capacity(config.max_map_points),
            kf_pool,
            mp_pool,
            next_serial: 0,
            corrections: 0,
            counts: vec![0; config.max_keyframes],
            touched: Vec::with_capacity(config.max_keyframes),
            tombstones: std::collections::HashMap::with_capacity(config.max_keyframes.min(4096)),
            active_map: 0,
            next_map_id: 1,
            merges: 0,
            config,
        }
    }

    /// How many map-wide corrections have been applied (see [`Map::note_correction`]).
    pub fn correction_epoch(&self) -> u64 {
        self.corrections
    }

    /// Records a map-wide correction: BA results copied out before it are stale.
    pub fn note_correction(&mut self) {
        self.corrections += 1;
    }

    /// The serial the next keyframe will get (one past the newest's).
    pub fn next_serial(&self) -> u64 {
        self.next_serial
    }

    pub fn keyframe(&self, id: KeyFrameId) -> Option<&KeyFrame> {
        self.keyframes.get(id)
    }
    pub fn keyframe_mut(&mut self, id: KeyFrameId) -> Option<&mut KeyFrame> {
        self.keyframes.get_mut(id)
    }
    pub fn point(&self, id: MapPointId) -> Option<&MapPoint> {
        self.points.get(id)
    }
    pub fn point_mut(&mut self, id: MapPointId) -> Option<&mut MapPoint> {
        self.points.get_mut(id)
    }
    pub fn keyframes(&self) -> impl Iterator<Item = (KeyFrameId, &KeyFrame)> {
        self.keyframes.iter()
    }
    pub fn points(&self) -> impl Iterator<Item = (MapPointId, &MapPoint)> {
        self.points.iter()
    }
    pub fn n_keyframes(&self) -> usize {
        self.keyframes.len()
    }
    pub fn n_points(&self) -> usize {
        self.points.len()
    }
    /// (keyframes, map points) the map can hold.
    pub fn capacity(&self) -> (usize, usize) {
        (self.keyframes.capacity(), self.points.capacity())
    }

    /// Frees a keyframe slot: erases the least useful keyframe, i.e. the one (neither the root
    /// nor among the [`RECENT_PROTECTED`] newest) with the fewest points no other keyframe sees.
    /// Returns whether one was erased.
    pub fn evict_keyframe(&mut self) -> bool {
        let mut serials: Vec<u64> = self.keyframes.iter().map(|(_, k)| k.serial).collect();
        serials.sort_unstable();
        let cutoff = serials
            .len()
            .checked_sub(RECENT_PROTECTED)
            .map(|i| serials[i])
            .unwrap_or(0);
        let victim = self
            .keyframes
            .iter()
            .filter(|(_, k)| k.parent.is_some() && k.serial < cutoff)
            .min_by_key(|(_, k)| {
                k.observed()
                    .filter(|&(_, p)| {
                        self.points
                            .get(p)
                            .is_some_and(|m| m.observations.len() <= 1)
                    })
                    .count()
            })
            .map(|(id, _)| id);
        victim.is_some_and(|v| self.erase_keyframe(v))
    }

    /// Frees point slots: erases up to `n` points with the lowest found/visible ratio (then the
    /// fewest observations). Returns how many were erased.
    pub fn evict_points(&mut self, n: usize) -> usize {
        let mut scored: Vec<(f64, usize, MapPointId)> = self
            .points
            .iter()
            .map(|(id, p)| (p.found_ratio(), p.observations.len(), id))
            .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let k = n.min(scored.len());
        for &(_, _, id) in &scored[..k] {
            self.erase_point(id);
        }
        k
    }

    /// Takes a recycled keyframe buffer, lets `fill` set it up, and stores it. `fill` must set
    /// `points` to one entry per keypoint (the map resizes it if not). A full map first evicts
    /// its least useful keyframe ([`Map::evict_keyframe`]); it never grows.
    pub fn insert_keyframe(
        &mut self,
        fill: impl FnOnce(&mut KeyFrame),
    ) -> Result<KeyFrameId, MapFull> {
        if self.kf_pool.is_empty() {
            self.evict_keyframe();
        }
        let cap = self.keyframes.capacity();
        let mut kf = self.kf_pool.pop().ok_or(MapFull::KeyFrames(cap))?;
        kf.clear();
        fill(&mut kf);
        kf.points.resize(kf.keypoints.len(), None);
        kf.grid.assign(&kf.keypoints);
        kf.serial = self.next_serial;
        kf.map_id = self.active_map;
        self.next_serial += 1;
        self.keyframes.insert(kf).map_err(|(_, kf)| {
            self.kf_pool.push(kf);
            MapFull::KeyFrames(cap)
        })
    }

    /// Stores a new point at `position` (world), created by keyframe `reference`. A full map
    /// first evicts its least reliable 1% of points ([`Map::evict_points`]); it never grows.
    pub fn insert_point(
        &mut self,
        position: Vector3<f64>,
        reference: KeyFrameId,
    ) -> Result<MapPointId, MapFull> {
        if self.mp_pool.is_empty() {
            self.evict_points((self.points.capacity() / 100).max(1));
        }
        let cap = self.points.capacity();
        let mut mp = self.mp_pool.pop().ok_or(MapFull::MapPoints(cap))?;
        mp.clear();
        mp.position = position;
        mp.reference_kf = Some(reference);
        mp.first_kf_serial = self.keyframes.get(reference).map_or(0, |k| k.serial);
        self.points.insert(mp).map_err(|(_, mp)| {
            self.mp_pool.push(mp);
            MapFull::MapPoints(cap)
        })
    }

    /// A new point triangulated from two views: inserted with `a` as its reference keyframe,
    /// observed by keypoint `i` of `a` and `j` of `b`, its normal and descriptor updated.
    pub fn insert_two_view_point(
        &mut self,
        position: Vector3<f64>,
        (a, i): (KeyFrameId, usize),
        (b, j): (KeyFrameId, usize),
    ) -> Result<MapPointId, MapFull> {
        let p = self.insert_point(position, a)?;
        self.add_observation(p, a, i);
        self.add_observation(p, b, j);
        self.update_point_geometry(p);
        Ok(p)
    }

    /// Records that keypoint `idx` of `kf` observes `mp`.
    pub fn add_observation(&mut self, mp: MapPointId, kf: KeyFrameId, idx: usize) -> bool {
        let Some(k) = self.keyframes.get_mut(kf) else {
            return false;
        };
        if idx >= k.points.len() || !self.points.contains(mp) {
            return false;
        }
        if let Some(old) = k.points[idx] {
            if old == mp {
                return true;
            }
            if let Some(o) = self.points.get_mut(old) {
                o.observations.retain(|&(f, _)| f != kf);
            }
        }
        k.points[idx] = Some(mp);
        let Some(p) = self.points.get_mut(mp) else {
            return false;
        };
        // One observation per keyframe: a keypoint that held this point before lets go of it
        // (left pointing at it, it would dangle once the point is erased or replaced).
        for &(_, i) in p
            .observations
            .iter()
            .filter(|&&(f, i)| f == kf && i as usize != idx)
        {
            if let Some(slot) = k.points.get_mut(i as usize) {
                *slot = None;
            }
        }
        p.observations.retain(|&(f, _)| f != kf);
        p.observations.push((kf, idx as u32));
        true
    }

    /// Removes the observation of `mp` by `kf`; a point left with fewer than 2 observations is
    /// erased (it can no longer be triangulated).
    pub fn erase_observation(&mut self, mp: MapPointId, kf: KeyFrameId) {
        let Some(p) = self.points.get_mut(mp) else {
            return;
        };
        let mut idx = None;
        p.observations.retain(|&(f, i)| {
            if f == kf {
                idx = Some(i as usize);
                false
            } else {
                true
            }
        });
        let remaining = p.observations.len();
        if p.reference_kf == Some(kf) {
            p.reference_kf = p.observations.first().map(|&(f, _)| f);
        }
        if let (Some(i), Some(k)) = (idx, self.keyframes.get_mut(kf)) {
            if k.points.get(i).copied().flatten() == Some(mp) {
                k.points[i] = None;
            }
        }
        if remaining < 2 {
            self.erase_point(mp);
        }
    }

    /// Erases a point and every association to it; its buffer returns to the pool.
    pub fn erase_point(&mut self, mp: MapPointId) {
        let Some(mut p) = self.points.remove(mp) else {
            return;
        };
        for &(kf, i) in &p.observations {
            if let Some(k) = self.keyframes.get_mut(kf) {
                if k.points.get(i as usize).copied().flatten() == Some(mp) {
                    k.points[i as usize] = None;
                }
            }
        }
        p.clear();
        self.mp_pool.push(p);
    }

    /// Merges `old` into `new` (duplicate fusion): observations move to `new` unless that
    /// keyframe already sees `new`; `old` is erased.
    pub fn replace_point(&mut self, old: MapPointId, new: MapPointId) {
        if old == new || !self.points.contains(new) {
            return;
        }
        let Some(p) = self.points.get(old) else {
            return;
        };
        let obs: Vec<(KeyFrameId, u32)> = p.observations.clone();
        let (visible, found) = (p.visible, p.found);
        for (kf, i) in obs {
            let already = self
                .points
                .get(new)
                .is_some_and(|n| n.observations.iter().any(|&(f, _)| f == kf));
            if let Some(k) = self.keyframes.get_mut(kf) {
                k.points[i as usize] = None;
            }
            if !already {
                self.add_observation(new, kf, i as usize);
            }
        }
        if let Some(n) = self.points.get_mut(new) {
            n.visible += visible;
            n.found += found;
        }
        if let Some(mut p) = self.points.remove(old) {
            p.clear();
            self.mp_pool.push(p);
        }
        self.update_point_geometry(new);
    }

    /// Recomputes a point's mean viewing direction, distance range and representative
    /// descriptor from its observations.
    pub fn update_point_geometry(&mut self, mp: MapPointId) {
        let Some(p) = self.points.get(mp) else { return };
        let pos = p.position;
        let mut normal = Vector3::zeros();
        let mut n = 0;
        let mut best_desc = None;
        let mut best_median = u32::MAX;
        let descs: Vec<crate::features::Descriptor> = p
            .observations
            .iter()
            .filter_map(|&(kf, i)| {
                self.keyframes
                    .get(kf)
                    .and_then(|k| k.descriptors.get(i as usize).copied())
            })
            .collect();
        for &(kf, _) in &p.observations {
            if let Some(k) = self.keyframes.get(kf) {
                let c = k.t_cw.center();
                normal += (pos - c).normalize();
                n += 1;
            }
        }
        for d in &descs {
            let mut dist: Vec<u32> = descs.iter().map(|e| hamming(d, e)).collect();
            dist.sort_unstable();
            let m = dist[(dist.len() - 1) / 2];
            if m < best_median {
                best_median = m;
                best_desc = Some(*d);
            }
        }
        let reference = p.reference_kf.and_then(|r| {
            self.keyframes.get(r).map(|k| {
                (
                    k,
                    p.observations
                        .iter()
                        .find(|&&(f, _)| f == r)
                        .map(|&(_, i)| i),
                )
            })
        });
        let (sf, nl) = (self.config.scale_factor, self.config.n_levels);
        let range = reference.and_then(|(k, i)| {
            let kp = k.keypoints.get(i? as usize)?;
            let dist = (pos - k.t_cw.center()).norm();
            let max = dist * sf.powi(kp.octave as i32);
            Some((max / sf.powi(nl as i32 - 1), max))
        });
        let Some(p) = self.points.get_mut(mp) else {
            return;
        };
        if n > 0 {
            p.normal = (normal / n as f64).normalize();
        }
        if let Some(d) = best_desc {
            p.descriptor = d;
        }
        if let Some((lo, hi)) = range {
            p.min_distance = lo;
            p.max_distance = hi;
        }
    }

    /// Frees every keyframe's grey and colour image, live or pooled (the run is over; only
    /// semi-dense mapping and relocalisation checks read them).
    pub fn release_images(&mut self) {
        let kfs: Vec<KeyFrameId> = self.keyframes.handles().collect();
        for k in kfs {
            if let Some(kf) = self.keyframes.get_mut(k) {
                kf.gray = Vec::new();
                kf.colour = Vec::new();
                kf.has_color = false;
            }
        }
        for kf in &mut self.kf_pool {
            kf.gray = Vec::new();
            kf.colour = Vec::new();
        }
    }

    /// Removes every keyframe and point (buffers return to the pools): a fresh map.
    pub fn reset(&mut self) {
        self.tombstones.clear();
        self.active_map = 0;
        self.next_map_id = 1;
        let kfs: Vec<KeyFrameId> = self.keyframes.handles().collect();
        for k in kfs {
            if let Some(mut kf) = self.keyframes.remove(k) {
                kf.clear();
                self.kf_pool.push(kf);
            }
        }
        let pts: Vec<MapPointId> = self.points.handles().collect();
        for p in pts {
            if let Some(mut mp) = self.points.remove(p) {
                mp.clear();
                self.mp_pool.push(mp);
            }
        }
    }
}

#[cfg(test)]
mod tests;
