//! Relocalisation of a lost frame against every map of the atlas: the place-recognition
//! database's candidates, tried in an order that lets a real-time frame cut by its budget
//! hand the untried ones to the next frame.

use super::*;

/// Which relocalisation candidates a lost episode has tried, so frames cut by the budget
/// go on with the others; reused buffers.
#[derive(Default)]
pub(super) struct RelocCandidates {
    candidates: Vec<KeyFrameId>,
    tried: Vec<KeyFrameId>,
}

impl RelocCandidates {
    pub(super) fn with_capacity(n: usize) -> Self {
        RelocCandidates {
            candidates: Vec::with_capacity(n),
            tried: Vec::with_capacity(2 * n),
        }
    }

    /// The first `n` of `candidates` were tried with outcome `state`: remembered while the
    /// episode goes on, forgotten once relocalised or once every candidate had its turn
    /// (the frames change: a candidate may match a later one).
    pub(super) fn attempted(&mut self, candidates: &[KeyFrameId], n: usize, state: TrackingState) {
        let n = n.min(candidates.len());
        if state == TrackingState::Ok || n == candidates.len() {
            self.tried.clear();
            return;
        }
        for c in &candidates[..n] {
            if !self.tried.contains(c) && self.tried.len() < self.tried.capacity() {
                self.tried.push(*c);
            }
        }
        if self.tried.len() == self.tried.capacity() {
            self.tried.clear();
        }
    }
}

impl System {
    /// Keyframes to try relocalising against: the database's best matches for the frame's
    /// bag of words (stale entries of culled keyframes are dropped on the way).
    pub(super) fn relocalise(&mut self, map: &mut Map) -> TrackingState {
        let Some(v) = self.vocabulary.clone() else {
            return TrackingState::Lost;
        };
        let (bow, _) = v.transform(&self.frame.features.descriptors, 2);
        let mut candidates = std::mem::take(&mut self.reloc.candidates);
        candidates.clear();
        {
            let mut places = self.places.lock().unwrap_or_else(|e| e.into_inner());
            let n = self.limits.relocalisation_candidates;
            let hits = places.database.query(&bow, 0.0, n, |_| false);
            for (key, _) in hits {
                match places.keys.get(&key) {
                    Some(&kf) if map.keyframe(kf).is_some() => candidates.push(kf),
                    _ => {
                        places.database.remove(key);
                        places.keys.remove(&key);
                    }
                }
            }
        }
        // Real time: the candidates not tried in this lost episode first, within the budget.
        let budget = self
            .limits
            .relocalisation_budget
            .filter(|_| self.bounds_frame_time());
        let tried = &self.reloc.tried;
        candidates.sort_by_key(|c| tried.contains(c));
        let st = self
            .tracker
            .relocalise(map, &mut self.frame, &candidates, budget);
        self.reloc.attempted(
            &candidates,
            self.tracker.relocalisation_candidates_tried(),
            st,
        );
        self.reloc.candidates = candidates;
        st
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cut_episode_goes_on_with_the_candidates_not_yet_tried() {
        let mut map = Map::new(MapConfig {
            max_keyframes: 8,
            max_map_points: 8,
            max_features: 10,
            ..MapConfig::default()
        });
        let k: Vec<KeyFrameId> = (0..4)
            .filter_map(|_| map.insert_keyframe(|_| {}).ok())
            .collect();
        let mut r = RelocCandidates::with_capacity(4);
        // Frame 1 tried two of four: they go to the back of frame 2's list.
        r.attempted(&k, 2, TrackingState::Lost);
        let mut next = vec![k[0], k[2], k[1], k[3]];
        next.sort_by_key(|c| r.tried.contains(c));
        assert_eq!(next, vec![k[2], k[3], k[0], k[1]]);
        // Frame 2 tried its whole list: the episode starts over with the best first.
        r.attempted(&next, 4, TrackingState::Lost);
        assert!(r.tried.is_empty());
        // Relocalised: forgotten as well.
        r.attempted(&k, 1, TrackingState::Lost);
        r.attempted(&k, 1, TrackingState::Ok);
        assert!(r.tried.is_empty());
    }
}
