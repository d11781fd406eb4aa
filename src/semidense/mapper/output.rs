//! The mapper's results in today's map: a keyframe's depths follow its pose and its depth
//! scale as the map has them now (loop corrections, BA), read from its anchor points; a
//! keyframe culled since takes its pose from the Sim3 of those anchors.

use super::*;

/// Depth scale of a keyframe now relative to its reconstruction (depth_now = depth_then x
/// scale): the median ratio over its anchor points still in the map, 1 when none is left.
pub(super) fn anchor_scale(map: &Map, e: &KeyframeDepth, scratch: &mut Vec<f32>) -> f32 {
    scratch.clear();
    for (mp, x_then) in &e.anchors {
        if let Some(p) = map.point(*mp) {
            let z = e.t_cw.transform(&p.position).z;
            if z > 0.0 && scratch.len() < scratch.capacity() {
                scratch.push((z / x_then[2] as f64) as f32);
            }
        }
    }
    if scratch.is_empty() {
        return 1.0;
    }
    let mid = scratch.len() / 2;
    let (_, m, _) = scratch.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    if m.is_finite() && *m > 0.0 {
        *m
    } else {
        1.0
    }
}

/// Pose and depth scale of a keyframe that has left the map (culled after reconstruction):
/// the similarity taking its anchors from its camera frame then to where the map has them now
/// (so its cloud follows loop corrections and BA). `None` with fewer than 3 anchors left.
pub(super) fn pose_from_anchors(map: &Map, e: &KeyframeDepth) -> Option<(CameraFromWorld, f32)> {
    let mut then = [nalgebra::Vector3::zeros(); MAX_ANCHORS];
    let mut now = [nalgebra::Vector3::zeros(); MAX_ANCHORS];
    let mut n = 0;
    for (mp, x) in &e.anchors {
        if let Some(p) = map.point(*mp) {
            then[n] = nalgebra::Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
            now[n] = p.position;
            n += 1;
        }
    }
    // x_w = s R x_c + t: the camera pose is [R | t], its depths are scaled by s.
    let s = crate::geometry::umeyama(&then[..n], &now[..n], true)?;
    if !(s.scale.is_finite() && s.scale > 0.0) {
        return None;
    }
    let t_wc = crate::geometry::Se3::from_parts(s.translation.into(), s.rotation);
    Some((CameraFromWorld(t_wc.inverse()), s.scale as f32))
}

impl SemiDenseMapper {
    /// The cloud in world coordinates with the keyframe poses in `map` now (stored poses for
    /// keyframes culled since). Appends to `out`.
    pub fn cloud(&self, map: &Map, out: &mut Vec<CloudPoint>) {
        self.cloud_of(map, None, out);
    }

    /// [`cloud`](Self::cloud) of the keyframes of atlas map `map_id` only (`None`: all; a
    /// keyframe of a discarded map belongs to none). Maps are in different frames until
    /// merged: one cloud must not mix them.
    pub fn cloud_of(&self, map: &Map, map_id: Option<u32>, out: &mut Vec<CloudPoint>) {
        let k = self.reconstructor.k;
        let w = self.reconstructor.width;
        let mut scratch = Vec::with_capacity(MAX_ANCHORS);
        let in_map =
            |e: &&KeyframeDepth| map_id.is_none_or(|id| map.map_of(e.keyframe) == Some(id));
        for e in self.entries.iter().filter(|e| e.checked).filter(in_map) {
            let (t_cw, scale) = match map.keyframe(e.keyframe) {
                Some(kf) => {
                    let now = KeyframeDepth {
                        t_cw: kf.t_cw,
                        ..e.clone()
                    };
                    (kf.t_cw, anchor_scale(map, &now, &mut scratch) as f64)
                }
                None => pose_from_anchors(map, e)
                    .map_or((e.t_cw, e.scale as f64), |(t, s)| (t, s as f64)),
            };
            let t_wc = t_cw.inverse();
            for p in self.pixels(e).filter(|p| p.rho > 0.0) {
                let i = p.raw.idx as usize;
                let x_c = k.ray((i % w) as f64, (i / w) as f64) * (scale / p.rho as f64);
                let x_w = t_wc.transform(&x_c);
                out.push(CloudPoint {
                    position: [x_w.x as f32, x_w.y as f32, x_w.z as f32],
                    rgb: p.rgb,
                    sigma: p.raw.sigma,
                    timestamp: e.timestamp,
                });
            }
        }
    }

    /// Depth (z, metres of the map) of entry `e`'s accepted pixels into `out` (0 elsewhere).
    pub fn depth_map(&self, e: usize, out: &mut [f32]) {
        out.fill(0.0);
        if let Some(d) = self.entries.get(e) {
            for p in self.pixels(d).filter(|p| p.rho > 0.0) {
                if let Some(o) = out.get_mut(p.raw.idx as usize) {
                    *o = d.scale / p.rho;
                }
            }
        }
    }
}
