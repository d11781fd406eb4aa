//! The vocabulary tree and the bag-of-words transform.

use crate::features::Descriptor;
use crate::matching::hamming;

/// A tree node; node 0 is the root. Leaves are the words.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    pub parent: u32,
    pub children: Vec<u32>,
    pub descriptor: Descriptor,
    /// idf weight (leaves only).
    pub weight: f32,
    /// Word id (leaves only).
    pub word: Option<u32>,
}

/// Sparse, L1-normalised word histogram, sorted by word id.
pub type BowVector = Vec<(u32, f32)>;

/// Feature indices grouped by a node some levels above the leaves (for BoW-guided matching):
/// sorted by node id.
pub type FeatureVector = Vec<(u32, Vec<u32>)>;

#[derive(Clone, Debug, PartialEq)]
pub struct Vocabulary {
    /// Branching factor and depth it was built with.
    pub k: usize,
    pub levels: usize,
    pub nodes: Vec<Node>,
    /// Word id -> node index.
    pub words: Vec<u32>,
}

impl Vocabulary {
    pub fn n_words(&self) -> usize {
        self.words.len()
    }

    /// Descends from the root to a leaf, choosing the closest child at each level. Returns the
    /// word id, its weight, and the node passed `levels_up` levels above the leaf.
    pub fn lookup(&self, d: &Descriptor, levels_up: usize) -> Option<(u32, f32, u32)> {
        let mut path = [0u32; 32];
        let mut depth: usize = 0;
        let mut n = 0u32;
        loop {
            let node = self.nodes.get(n as usize)?;
            if node.children.is_empty() {
                let word = node.word?;
                let anchor = path[depth.saturating_sub(levels_up)];
                return Some((word, node.weight, anchor));
            }
            let best = node.children.iter().copied().min_by_key(|&c| {
                self.nodes
                    .get(c as usize)
                    .map_or(u32::MAX, |cn| hamming(d, &cn.descriptor))
            })?;
            depth += 1;
            if depth >= path.len() {
                return None;
            }
            path[depth] = best;
            n = best;
        }
    }

    /// Bag-of-words vector (tf-idf, L1-normalised) and feature vector grouped `levels_up` levels
    /// above the leaves.
    pub fn transform(
        &self,
        descriptors: &[Descriptor],
        levels_up: usize,
    ) -> (BowVector, FeatureVector) {
        let mut bow: Vec<(u32, f32)> = Vec::with_capacity(descriptors.len());
        let mut fv: Vec<(u32, u32)> = Vec::with_capacity(descriptors.len());
        for (i, d) in descriptors.iter().enumerate() {
            if let Some((w, weight, anchor)) = self.lookup(d, levels_up) {
                if weight > 0.0 {
                    bow.push((w, weight));
                }
                fv.push((anchor, i as u32));
            }
        }
        bow.sort_by_key(|&(w, _)| w);
        let mut merged: BowVector = Vec::with_capacity(bow.len());
        for (w, v) in bow {
            match merged.last_mut() {
                Some((lw, lv)) if *lw == w => *lv += v,
                _ => merged.push((w, v)),
            }
        }
        let sum: f32 = merged.iter().map(|(_, v)| v.abs()).sum();
        if sum > 0.0 {
            for (_, v) in &mut merged {
                *v /= sum;
            }
        }
        fv.sort_unstable();
        let mut groups: FeatureVector = Vec::new();
        for (node, i) in fv {
            match groups.last_mut() {
                Some((n, list)) if *n == node => list.push(i),
                _ => groups.push((node, vec![i])),
            }
        }
        (merged, groups)
    }
}

/// DBoW2's L1 score of two L1-normalised vectors: `1 - |a - b|_1 / 2`, in [0, 1].
pub fn l1_score(a: &BowVector, b: &BowVector) -> f32 {
    let (mut i, mut j) = (0, 0);
    let mut s = 0.0f32;
    while i < a.len() && j < b.len() {
        match a[i].0.cmp(&b[j].0) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                let (x, y) = (a[i].1, b[j].1);
                s += x.abs() + y.abs() - (x - y).abs();
                i += 1;
                j += 1;
            }
        }
    }
    0.5 * s
}
