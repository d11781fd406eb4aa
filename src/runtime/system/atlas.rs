//! The atlas on the tracking side: lost in an established map, relocalise in every map and
//! meanwhile initialise a new one, so frames keep getting poses (loop closing merges the maps
//! when a place of an older one comes back); a map found wrong is discarded alone (or rolled
//! back, see `rollback`).

use super::*;

/// What the atlas holds at the end of a run (for `report.json`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct AtlasSummary {
    /// The map whose poses go to `trajectory.txt`: the one holding the most tracked frames.
    pub primary: Option<u32>,
    /// Every map with tracked frames or keyframes: (id, tracked frames, keyframes), by id.
    pub maps: Vec<(u32, usize, usize)>,
}

impl System {
    /// A lost frame: shortly after the loss, track it from the last tracked pose; then
    /// relocalise against every map; failing that, once the active map is established (or
    /// was discarded), try to initialise a new map on this frame.
    pub(super) fn relocalise_or_start_map(
        &mut self,
        map: &mut Map,
        gray: &[u8],
        rgb: Option<&[u8]>,
    ) -> TrackingState {
        // Shortly after the loss: tracked as usual from the last tracked pose first.
        let st = self.tracker.track_after_loss(map, &mut self.frame);
        if st != TrackingState::Lost {
            self.forget_initialisation();
            return st;
        }
        let st = self.relocalise(map);
        if st == TrackingState::Ok {
            if let Some(m) = self.tracker.reference_kf().and_then(|r| map.map_of(r)) {
                map.set_active_map(m);
            }
            self.forget_initialisation();
            return st;
        }
        if !self.limits.new_map_when_lost || self.localize_only {
            return TrackingState::Lost;
        }
        // Lost in a young map: it gets `young_map_patience_frames` to relocalise (a short
        // blackout, a covered lens), but a map lost a few frames after it began is more often
        // a poor start; a new map started meanwhile replaces it at once, so the frames of the
        // patience window get poses instead of waiting for the reset.
        let young = self.active_map_is_young(map).then(|| map.active_map());
        if self.initialize(map, gray, rgb) != TrackingState::Ok {
            return TrackingState::Lost;
        }
        if let Some(id) = young.filter(|&id| id != map.active_map()) {
            tracing::warn!(
                frame = self.frame.index,
                map = id,
                "lost right after initialisation: map replaced by the new one"
            );
            self.discard_map(map, id);
        }
        TrackingState::Ok
    }

    /// The active map has keyframes, but no more than `[tracking] young_map_keyframes`.
    pub(super) fn active_map_is_young(&self, map: &Map) -> bool {
        let n = map.n_keyframes_of(map.active_map());
        n > 0 && n <= self.limits.young_map_keyframes
    }

    /// Initialisation starts from scratch (new reference, attempts in flight dropped).
    pub(super) fn forget_initialisation(&mut self) {
        self.init.reset();
        if let Some(s) = self.init_solver.as_mut() {
            s.generation += 1;
        }
    }

    /// Discards the active map (lost while young, or diverging). With no other map this is
    /// the full [`reset`](Self::reset); otherwise only its keyframes, points and poses go and
    /// tracking is lost: it relocalises in the other maps or starts a new one.
    pub(super) fn discard_active_map(&mut self, map: &mut Map) {
        let id = map.active_map();
        if map.map_ids().iter().all(|&m| m == id) {
            self.reset(map);
            return;
        }
        self.discard_map(map, id);
        if let Some(&newest) = map.map_ids().last() {
            map.set_active_map(newest);
        }
        self.lost_after_map_edit();
    }

    /// The active map lost what tracking stood on (discarded or rolled back): lost, with the
    /// backfill, initialisation attempts and the collapse window started over.
    pub(super) fn lost_after_map_edit(&mut self) {
        self.backfill = Backfill::default();
        self.tracker.reset(TrackingState::Lost);
        self.forget_initialisation();
        self.collapse.reset();
    }

    /// Erases map `id` with the poses of the frames tracked in it (counted as a reset).
    /// Tracking, the backfill and the active map are the caller's.
    fn discard_map(&mut self, map: &mut Map, id: u32) {
        self.drop_poses_in_map(map, id, |_| true);
        map.erase_map(id);
        self.stats.resets += 1;
    }

    /// Drops the trajectory entries of map `id` that `drop` selects (by timestamp), before
    /// the map's keyframes go (an entry's map is found through its reference keyframe);
    /// returns how many went.
    pub(super) fn drop_poses_in_map(
        &mut self,
        map: &Map,
        id: u32,
        drop: impl Fn(f64) -> bool,
    ) -> usize {
        let before = self.trajectory.len();
        self.trajectory
            .retain(|e| !drop(e.timestamp) || e.reference.and_then(|r| map.map_of(r)) != Some(id));
        let dropped = before - self.trajectory.len();
        self.stats.tracked_frames = self.stats.tracked_frames.saturating_sub(dropped);
        self.stats.poses_discarded_by_reset += dropped;
        dropped
    }

    /// The maps of the run and which is primary.
    pub fn atlas(&self) -> AtlasSummary {
        let map = lock(&self.map);
        atlas_summary(&map, &self.entry_maps_now(&map))
    }

    /// Poses (`T_wc`) of the tracked frames in map `id` (see [`System::trajectory`]).
    pub fn trajectory_of(&self, id: u32) -> Vec<TimedPose> {
        let map = lock(&self.map);
        let maps = self.entry_maps_now(&map);
        self.poses(&map, |i| maps[i] == Some(id))
    }

    /// Final keyframe poses of map `id`, by time.
    pub fn keyframe_trajectory_of(&self, id: u32) -> Vec<TimedPose> {
        let map = lock(&self.map);
        keyframe_poses(&map, Some(id))
    }
}

/// Frames and keyframes per map; the primary map holds the most frames (then keyframes, then
/// the lower id).
pub(super) fn atlas_summary(map: &Map, entry_maps: &[Option<u32>]) -> AtlasSummary {
    let mut ids = map.map_ids();
    ids.extend(entry_maps.iter().flatten());
    ids.sort_unstable();
    ids.dedup();
    let maps: Vec<(u32, usize, usize)> = ids
        .iter()
        .map(|&id| {
            let frames = entry_maps.iter().filter(|&&m| m == Some(id)).count();
            (id, frames, map.n_keyframes_of(id))
        })
        .collect();
    let primary = maps
        .iter()
        .max_by(|a, b| (a.1, a.2).cmp(&(b.1, b.2)).then(b.0.cmp(&a.0)))
        .map(|m| m.0);
    AtlasSummary { primary, maps }
}

/// Keyframe poses by time, of one map or all.
pub(super) fn keyframe_poses(map: &Map, id: Option<u32>) -> Vec<TimedPose> {
    let mut v: Vec<TimedPose> = map
        .keyframes()
        .filter(|(_, k)| id.is_none_or(|id| k.map_id == id))
        .map(|(_, k)| TimedPose {
            timestamp: k.timestamp,
            t_wc: k.t_cw.inverse(),
        })
        .collect();
    v.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    v
}
