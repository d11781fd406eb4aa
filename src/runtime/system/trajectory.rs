//! The run's poses as the map has them now: every tracked frame through its reference
//! keyframe (so loop corrections and BA move it), and the keyframes.

use super::*;

impl System {
    /// Poses (`T_wc`) of every tracked frame, following their reference keyframe's correction.
    pub fn trajectory(&self) -> Vec<TimedPose> {
        let map = lock(&self.map);
        let mut v: Vec<TimedPose> = self
            .trajectory
            .iter()
            .map(|e| {
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

    /// Final keyframe poses, by time.
    pub fn keyframe_trajectory(&self) -> Vec<TimedPose> {
        let map = lock(&self.map);
        let mut v: Vec<TimedPose> = map
            .keyframes()
            .map(|(_, k)| TimedPose {
                timestamp: k.timestamp,
                t_wc: k.t_cw.inverse(),
            })
            .collect();
        v.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        v
    }
}
