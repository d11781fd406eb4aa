//! The run's poses as the map has them now: every tracked frame through its reference
//! keyframe (so loop corrections, merges and BA move it), and the keyframes. With several
//! maps in the atlas, [`System::trajectory`] and [`System::keyframe_trajectory`] are those of
//! the primary map (the others are in their own frames: [`System::trajectory_of`]).

use super::atlas::{atlas_summary, keyframe_poses};
use super::*;

impl System {
    /// Poses (`T_wc`) of every tracked frame of the primary map, following their reference
    /// keyframe's correction.
    pub fn trajectory(&self) -> Vec<TimedPose> {
        let map = lock(&self.map);
        let maps = self.entry_maps_now(&map);
        let primary = atlas_summary(&map, &maps).primary;
        self.poses(&map, |i| maps[i].is_some() && maps[i] == primary)
    }

    /// Final keyframe poses of the primary map, by time.
    pub fn keyframe_trajectory(&self) -> Vec<TimedPose> {
        let map = lock(&self.map);
        let primary = atlas_summary(&map, &self.entry_maps_now(&map)).primary;
        keyframe_poses(&map, primary)
    }

    /// The map each trajectory entry is in now, through its reference keyframe (merges move
    /// entries with their keyframes; a culled reference is followed through its parents).
    pub(super) fn entry_maps_now(&self, map: &Map) -> Vec<Option<u32>> {
        self.trajectory
            .iter()
            .map(|e| e.reference.and_then(|r| map.map_of(r)))
            .collect()
    }

    /// The poses of the trajectory entries `keep` selects (by index), by time.
    pub(super) fn poses(&self, map: &Map, keep: impl Fn(usize) -> bool) -> Vec<TimedPose> {
        let mut v: Vec<TimedPose> = self
            .trajectory
            .iter()
            .enumerate()
            .filter(|(i, _)| keep(*i))
            .map(|(_, e)| {
                // A culled reference keyframe is followed through its parent.
                let t_cw = match e.reference.and_then(|r| map.keyframe_pose_or_tombstone(r)) {
                    Some(k) => CameraFromWorld(e.t_c_ref * k.0),
                    None => e.t_cw,
                };
                TimedPose {
                    timestamp: e.timestamp,
                    t_wc: t_cw.inverse(),
                }
            })
            .collect();
        // Backfilled frames were appended after initialisation: order by time.
        v.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        v
    }
}
