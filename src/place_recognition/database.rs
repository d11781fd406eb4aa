//! Keyframe database: an inverted index word -> keyframes, for relocalisation and loop
//! candidates. A query counts shared words, keeps candidates sharing at least 80% of the best
//! count (ORB-SLAM's pre-filter), scores them with the L1 score, and returns the best first.

use std::collections::HashMap;

use super::vocabulary::{l1_score, BowVector};

#[derive(Default)]
pub struct KeyFrameDatabase {
    /// Per word: keyframe keys containing it.
    inverted: Vec<Vec<u32>>,
    bows: HashMap<u32, BowVector>,
}

impl KeyFrameDatabase {
    pub fn new(n_words: usize) -> Self {
        KeyFrameDatabase {
            inverted: vec![Vec::new(); n_words],
            bows: HashMap::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.bows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.bows.is_empty()
    }

    /// Adds (or replaces) keyframe `key` with its bag of words.
    pub fn add(&mut self, key: u32, bow: &BowVector) {
        self.remove(key);
        for &(w, _) in bow {
            if let Some(list) = self.inverted.get_mut(w as usize) {
                list.push(key);
            }
        }
        self.bows.insert(key, bow.clone());
    }

    /// The bag of words stored for `key`.
    pub fn bow(&self, key: u32) -> Option<&BowVector> {
        self.bows.get(&key)
    }

    pub fn remove(&mut self, key: u32) {
        if let Some(old) = self.bows.remove(&key) {
            for (w, _) in old {
                if let Some(list) = self.inverted.get_mut(w as usize) {
                    list.retain(|&k| k != key);
                }
            }
        }
    }

    /// Keyframes similar to `bow` with score >= `min_score`, skipping those `exclude` rejects;
    /// at most `max` results, best first.
    pub fn query(
        &self,
        bow: &BowVector,
        min_score: f32,
        max: usize,
        exclude: impl Fn(u32) -> bool,
    ) -> Vec<(u32, f32)> {
        let mut common: HashMap<u32, u32> = HashMap::new();
        for &(w, _) in bow {
            for &k in self
                .inverted
                .get(w as usize)
                .map(|v| v.as_slice())
                .unwrap_or(&[])
            {
                if !exclude(k) {
                    *common.entry(k).or_insert(0) += 1;
                }
            }
        }
        let best_common = common.values().copied().max().unwrap_or(0);
        let min_common = (0.8 * best_common as f32) as u32;
        let mut out: Vec<(u32, f32)> = common
            .into_iter()
            .filter(|&(_, c)| c >= min_common.max(1))
            .filter_map(|(k, _)| self.bows.get(&k).map(|b| (k, l1_score(bow, b))))
            .filter(|&(_, s)| s >= min_score)
            .collect();
        out.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        out.truncate(max);
        out
    }
}
