//! The atlas (ORB-SLAM3's idea, Campos et al. 2021): one arena holds several maps, each
//! keyframe tagged with its map's id. When tracking is lost where no map can relocalise it, a
//! new map starts at once so frames keep getting poses; when place recognition later joins a
//! keyframe of one map to a keyframe of another, the newer map is moved into the older one's
//! frame and takes its id (`loop_closing`). Maps never share a point or a covisibility edge
//! until merged, so tracking, local mapping and BA, which follow covisibility, stay inside one.

use super::*;

impl Map {
    /// The map new keyframes join.
    pub fn active_map(&self) -> u32 {
        self.active_map
    }

    /// Makes `id` the map new keyframes join (tracking relocalised into it).
    pub fn set_active_map(&mut self, id: u32) {
        self.active_map = id;
    }

    /// Starts a new, empty map (the old ones stay): later keyframes join it. Returns its id.
    pub fn start_new_map(&mut self) -> u32 {
        self.active_map = self.next_map_id;
        self.next_map_id += 1;
        self.active_map
    }

    /// Drops the map [`start_new_map`](Self::start_new_map) just started (its initialisation
    /// failed) and gives its id back: `previous` is active again.
    pub fn cancel_new_map(&mut self, previous: u32) {
        let id = self.active_map;
        self.erase_map(id);
        if id + 1 == self.next_map_id {
            self.next_map_id = id;
        }
        self.active_map = previous;
    }

    /// After a map file is restored with these keyframe map ids: the newest map is active
    /// and new maps get fresh ids.
    pub(super) fn restore_atlas(&mut self, ids: impl Iterator<Item = u32>) {
        let newest = ids.max().unwrap_or(0);
        self.active_map = newest;
        self.next_map_id = newest.saturating_add(1);
    }

    /// Maps started so far in this arena (since the last [`Map::reset`]), merged ones included.
    pub fn maps_started(&self) -> u32 {
        self.next_map_id
    }

    /// The map keyframe `kf` belongs to, also after it was culled (through the parents it was
    /// attached to, as [`Map::keyframe_pose_or_tombstone`]).
    pub fn map_of(&self, kf: KeyFrameId) -> Option<u32> {
        let mut at = kf;
        for _ in 0..=self.tombstones.len() {
            if let Some(k) = self.keyframes.get(at) {
                return Some(k.map_id);
            }
            at = self.tombstones.get(&at)?.0;
        }
        None
    }

    /// The ids of the maps that have keyframes now, ascending.
    pub fn map_ids(&self) -> Vec<u32> {
        let mut ids: Vec<u32> = self.keyframes.iter().map(|(_, k)| k.map_id).collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    /// The keyframes of map `id`.
    pub fn keyframes_of(&self, id: u32) -> Vec<KeyFrameId> {
        self.keyframes
            .iter()
            .filter(|(_, k)| k.map_id == id)
            .map(|(h, _)| h)
            .collect()
    }

    /// Removes map `id`: its keyframes (root included), their points and tombstones. The other
    /// maps are untouched (they share nothing with it).
    pub fn erase_map(&mut self, id: u32) {
        let kfs = self.keyframes_of(id);
        let mut pts: Vec<MapPointId> = Vec::new();
        for &k in &kfs {
            if let Some(kf) = self.keyframes.get(k) {
                pts.extend(kf.observed().map(|(_, p)| p));
            }
        }
        pts.sort_unstable();
        pts.dedup();
        for p in pts {
            if let Some(mut mp) = self.points.remove(p) {
                mp.clear();
                self.mp_pool.push(mp);
            }
        }
        let gone: std::collections::HashSet<KeyFrameId> = kfs.iter().copied().collect();
        // Tombstones whose chain ends in the erased map go too (walk each chain to its end).
        let dead: Vec<KeyFrameId> = self
            .tombstones
            .keys()
            .copied()
            .filter(|&t| {
                let mut at = t;
                for _ in 0..=self.tombstones.len() {
                    match self.tombstones.get(&at) {
                        Some(&(p, _)) => at = p,
                        None => break,
                    }
                }
                gone.contains(&at) || !self.keyframes.contains(at)
            })
            .collect();
        for t in dead {
            self.tombstones.remove(&t);
        }
        for k in kfs {
            if let Some(mut kf) = self.keyframes.remove(k) {
                kf.clear();
                self.kf_pool.push(kf);
            }
        }
    }

    /// Map `from` becomes part of map `into` (its keyframes already moved into `into`'s
    /// frame): the keyframes take `into`'s id, and `from`'s spanning tree is re-rooted at
    /// `joint` and hung under `into`'s keyframe `anchor`, so the merged map has one root (the
    /// gauge a full BA fixes).
    pub fn merge_maps(&mut self, from: u32, into: u32, joint: KeyFrameId, anchor: KeyFrameId) {
        for k in self.keyframes_of(from) {
            if let Some(kf) = self.keyframes.get_mut(k) {
                kf.map_id = into;
            }
        }
        self.reroot(joint);
        if let Some(j) = self.keyframes.get_mut(joint) {
            j.parent = Some(anchor);
        }
        if let Some(a) = self.keyframes.get_mut(anchor) {
            if !a.children.contains(&joint) {
                a.children.push(joint);
            }
        }
        if self.active_map == from {
            self.active_map = into;
        }
        self.merges += 1;
    }

    /// Maps merged into others over the run (not cleared by [`Map::reset`]).
    pub fn maps_merged(&self) -> u32 {
        self.merges
    }

    /// Keyframes of map `id` (counted without allocating: tracking asks every frame).
    pub fn n_keyframes_of(&self, id: u32) -> usize {
        self.keyframes
            .iter()
            .filter(|(_, k)| k.map_id == id)
            .count()
    }

    /// Makes `kf` the root of its spanning tree: the parent links on the path from it to the
    /// old root are reversed.
    fn reroot(&mut self, kf: KeyFrameId) {
        let mut path = vec![kf];
        let mut at = kf;
        while let Some(p) = self.keyframes.get(at).and_then(|k| k.parent) {
            if path.contains(&p) || path.len() > self.keyframes.capacity() {
                break; // a cycle would be a bug elsewhere; never loop on it
            }
            path.push(p);
            at = p;
        }
        for w in path.windows(2) {
            let (child, parent) = (w[0], w[1]);
            if let Some(pk) = self.keyframes.get_mut(parent) {
                pk.children.retain(|&c| c != child);
                pk.parent = Some(child);
            }
            if let Some(ck) = self.keyframes.get_mut(child) {
                ck.children.push(parent);
            }
        }
        if let Some(k) = self.keyframes.get_mut(kf) {
            k.parent = None;
        }
    }
}
