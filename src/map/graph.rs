//! The map's graphs: covisibility (keyframes sharing at least `covisibility_min_weight`
//! points), the spanning tree (repaired when a keyframe is erased) and the essential graph.

use super::*;
use crate::geometry::CameraFromWorld;

impl Map {
    /// Recomputes `kf`'s covisibility edges (weight = shared points; edges of weight >= the
    /// configured minimum, or the single strongest if none reaches it), updates the neighbours'
    /// lists, and on first connection sets the spanning-tree parent (the strongest neighbour).
    pub fn update_connections(&mut self, kf: KeyFrameId) {
        let Some(k) = self.keyframes.get(kf) else {
            return;
        };
        self.touched.clear();
        for (_, mp) in k.observed() {
            let Some(p) = self.points.get(mp) else {
                continue;
            };
            for &(other, _) in &p.observations {
                if other == kf || !self.keyframes.contains(other) {
                    continue;
                }
                let s = other.index();
                if self.counts[s] == 0 {
                    self.touched.push(s);
                }
                self.counts[s] += 1;
            }
        }
        let handles: Vec<(KeyFrameId, u32)> = self
            .touched
            .iter()
            .filter_map(|&s| {
                self.keyframes
                    .handles()
                    .find(|h| h.index() == s)
                    .map(|h| (h, self.counts[s]))
            })
            .collect();
        for &s in &self.touched {
            self.counts[s] = 0;
        }
        let min_w = self.config.covisibility_min_weight;
        let mut edges: Vec<(KeyFrameId, u32)> = handles
            .iter()
            .copied()
            .filter(|&(_, w)| w >= min_w)
            .collect();
        if edges.is_empty() {
            if let Some(&best) = handles.iter().max_by_key(|&&(_, w)| w) {
                edges.push(best);
            }
        }
        edges.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        for &(other, w) in &edges {
            if let Some(o) = self.keyframes.get_mut(other) {
                o.covisibles.retain(|&(f, _)| f != kf);
                o.covisibles.push((kf, w));
                o.covisibles
                    .sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
            }
        }
        // A keyframe joins the spanning tree the first time it gets an older neighbour (the root,
        // the first keyframe, has none and stays the root).
        let first_connection = self.keyframes.get(kf).is_some_and(|k| k.parent.is_none());
        if let Some(k) = self.keyframes.get_mut(kf) {
            k.covisibles.clear();
            k.covisibles.extend_from_slice(&edges);
        }
        if first_connection {
            // The parent must be older (the tree is rooted at the first keyframe).
            let serial = self.keyframes.get(kf).map_or(0, |k| k.serial);
            let parent = edges
                .iter()
                .map(|&(f, _)| f)
                .find(|&f| self.keyframes.get(f).is_some_and(|o| o.serial < serial));
            if let Some(p) = parent {
                if let Some(k) = self.keyframes.get_mut(kf) {
                    k.parent = Some(p);
                }
                if let Some(pk) = self.keyframes.get_mut(p) {
                    pk.children.push(kf);
                }
            }
        }
    }

    /// Erases a keyframe: its observations go (points left with < 2 observations are erased),
    /// neighbours drop it, and its children are re-parented to the most covisible keyframe
    /// already in the tree (ORB-SLAM's spanning-tree repair). The first keyframe (the root) is
    /// never erased. A keyframe that local mapping has not connected yet (no parent, no
    /// children, no covisibility links) can be: a roll-back under a running mapping thread
    /// erases keyframes still in its queue, and once left behind such a keyframe would be
    /// connected later with its collapsed pose.
    pub fn erase_keyframe(&mut self, kf: KeyFrameId) -> bool {
        let Some(k) = self.keyframes.get(kf) else {
            return false;
        };
        let unconnected = k.children.is_empty() && k.covisibles.is_empty();
        if k.parent.is_none() && !unconnected {
            return false; // root
        }
        let observed: Vec<MapPointId> = k.observed().map(|(_, p)| p).collect();
        let neighbours: Vec<KeyFrameId> = k.covisibles.iter().map(|&(f, _)| f).collect();
        let mut children = k.children.clone();
        let parent = k.parent;
        if let Some(pk) = parent.and_then(|p| self.keyframes.get(p)) {
            let t_child_parent = k.t_cw.0 * pk.t_cw.0.inverse();
            if let Some(p) = parent {
                self.tombstones.insert(kf, (p, t_child_parent));
            }
        }
        for mp in observed {
            self.erase_observation(mp, kf);
        }
        for n in neighbours {
            if let Some(o) = self.keyframes.get_mut(n) {
                o.covisibles.retain(|&(f, _)| f != kf);
            }
        }
        // Re-parent children: repeatedly attach the child with the strongest link to a keyframe
        // already in the tree (the erased one's parent seeds the set).
        let mut in_tree: Vec<KeyFrameId> = parent.into_iter().collect();
        while !children.is_empty() {
            let mut best: Option<(usize, KeyFrameId, u32)> = None;
            for (ci, &c) in children.iter().enumerate() {
                let Some(ck) = self.keyframes.get(c) else {
                    continue;
                };
                for &(f, w) in &ck.covisibles {
                    if in_tree.contains(&f) && best.is_none_or(|(_, _, bw)| w > bw) {
                        best = Some((ci, f, w));
                    }
                }
            }
            let (ci, new_parent) = match best {
                Some((ci, f, _)) => (ci, f),
                // No link to the tree: attach to the erased keyframe's parent.
                None => match parent {
                    Some(p) => (0, p),
                    None => break,
                },
            };
            let c = children.swap_remove(ci);
            if let Some(ck) = self.keyframes.get_mut(c) {
                ck.parent = Some(new_parent);
            }
            if let Some(pk) = self.keyframes.get_mut(new_parent) {
                pk.children.push(c);
            }
            in_tree.push(c);
        }
        if let Some(p) = parent.and_then(|p| self.keyframes.get_mut(p)) {
            p.children.retain(|&c| c != kf);
        }
        if let Some(mut k) = self.keyframes.remove(kf) {
            k.clear();
            self.kf_pool.push(k);
        }
        true
    }

    /// The current pose of keyframe `kf`, also after it was culled: through the parents it
    /// was attached to (each culled keyframe keeps its pose relative to its parent).
    pub fn keyframe_pose_or_tombstone(&self, kf: KeyFrameId) -> Option<CameraFromWorld> {
        let mut rel = crate::geometry::Se3::identity();
        let mut at = kf;
        // A chain is at most as long as the keyframes culled; bounded against cycles.
        for _ in 0..=self.tombstones.len() {
            if let Some(k) = self.keyframes.get(at) {
                return Some(CameraFromWorld(rel * k.t_cw.0));
            }
            let (parent, t_child_parent) = self.tombstones.get(&at)?;
            rel *= t_child_parent;
            at = *parent;
        }
        None
    }

    /// Essential-graph edges (each once): spanning tree, covisibility >= `essential_min_weight`,
    /// and loop edges.
    pub fn essential_edges(&self) -> Vec<(KeyFrameId, KeyFrameId)> {
        let mut out = Vec::new();
        for (id, k) in self.keyframes.iter() {
            if let Some(p) = k.parent {
                out.push((p.min(id), p.max(id)));
            }
            for &(f, w) in &k.covisibles {
                if w >= self.config.essential_min_weight {
                    out.push((f.min(id), f.max(id)));
                }
            }
            for &l in &k.loop_edges {
                out.push((l.min(id), l.max(id)));
            }
        }
        out.sort();
        out.dedup();
        out
    }
}
