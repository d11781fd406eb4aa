//! Tracking again shortly after a loss, before place recognition is asked. A frame or two of
//! weak texture or blur can drop the inliers just under `min_inliers` while the camera is
//! still where the map is. Relocalisation by bag of words then needs many descriptor matches
//! to one keyframe, which such scenes do not give (the outward loop's blank walls: 0-7), and
//! the next frames would start a new map instead. Within `recovery_frames` of the last
//! tracked frame, the usual path is tried first: the motion model carried over the lost
//! frames at the last velocity (the jump check anchored on that prediction), the reference
//! keyframe if it finds too few matches, then the local map. The pose is accepted on the
//! same bars as any tracked frame (`min_inliers`, then the quality checks).

use super::{TrackedFrame, Tracker, TrackingState};
use crate::geometry::{CameraFromWorld, Se3};
use crate::map::Map;

/// The last frame tracked (`Ok` or `Degraded`): where a frame shortly after a loss starts.
#[derive(Clone, Copy, Debug)]
pub(super) struct LastTracked {
    pub t_cw: CameraFromWorld,
    pub index: u64,
    pub velocity: Option<Se3>,
}

impl Tracker {
    /// Lost, within `recovery_frames` of the last tracked frame, with its reference keyframe
    /// still in the map: tracks `f` from the last tracked pose (see the module). Returns the
    /// new state: `Lost` when it did not recover (and `f`'s matches are reset for
    /// relocalisation).
    pub fn track_after_loss(&mut self, map: &mut Map, f: &mut TrackedFrame) -> TrackingState {
        if self.state != TrackingState::Lost {
            return self.state;
        }
        let Some(last) = self.last_tracked else {
            return TrackingState::Lost;
        };
        let gap = f.index.saturating_sub(last.index);
        let reference_known = self.reference_kf.is_some_and(|r| map.keyframe(r).is_some());
        if gap == 0 || gap > self.config.recovery_frames as u64 || !reference_known {
            return TrackingState::Lost;
        }
        // `track` predicts velocity * last: carry the last tracked pose over the gap - 1 lost
        // frames in between.
        let mut t_cw = last.t_cw.0;
        if let Some(v) = last.velocity {
            for _ in 1..gap {
                t_cw = v * t_cw;
            }
        }
        self.last.t_cw = CameraFromWorld(t_cw);
        self.velocity = last.velocity;
        f.reset_matches();
        let st = self.track(map, f);
        if st == TrackingState::Lost {
            f.reset_matches();
        } else {
            self.recoveries += 1;
            tracing::debug!(frame = f.index, gap, state = ?st, "tracked again after a loss");
        }
        st
    }
}
