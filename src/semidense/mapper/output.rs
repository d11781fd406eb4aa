//! The mapper's results in today's map: a keyframe's depths follow its pose and its depth
//! scale as the map has them now (loop corrections, BA), read from its anchor points; a
//! keyframe culled since takes its pose from the Sim3 of those anchors.

use super::*;

/// An anchor: a map point the keyframe observed at reconstruction, by id and by the
/// keyframe's keypoint index (fusion replaces a duplicate point with another id, which the
/// keypoint then holds), with its camera-frame position in the reconstruction's scale.
#[derive(Clone, Copy, Debug)]
pub(super) struct Anchor {
    pub point: MapPointId,
    pub keypoint: u32,
    pub x_then: [f32; 3],
}

/// The anchor's point now: the one its keypoint holds in the live keyframe `kf` (it
/// follows fusion), else the stored id (a culled keyframe, or a keypoint left empty).
fn anchor_point<'m>(
    map: &'m Map,
    kf: Option<&KeyFrame>,
    a: &Anchor,
) -> Option<&'m crate::map::MapPoint> {
    kf.and_then(|k| k.points.get(a.keypoint as usize).copied().flatten())
        .and_then(|mp| map.point(mp))
        .or_else(|| map.point(a.point))
}

/// Depth scale of a keyframe at pose `t_cw` now relative to its reconstruction (depth_now
/// = depth_then x scale): the median ratio over its anchor points still in the map; `None`
/// when none is left (the caller keeps the last scale it had).
pub(super) fn anchor_scale(
    map: &Map,
    e: &KeyframeDepth,
    t_cw: &CameraFromWorld,
    scratch: &mut Vec<f32>,
) -> Option<f32> {
    let kf = map.keyframe(e.keyframe);
    scratch.clear();
    for a in &e.anchors {
        if let Some(p) = anchor_point(map, kf, a) {
            let z = t_cw.transform(&p.position).z;
            if z > 0.0 && scratch.len() < scratch.capacity() {
                scratch.push((z / a.x_then[2] as f64) as f32);
            }
        }
    }
    if scratch.is_empty() {
        return None;
    }
    let mid = scratch.len() / 2;
    let (_, m, _) = scratch.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    (m.is_finite() && *m > 0.0).then_some(*m)
}

/// Anchors still usable: below this share of [`MAX_ANCHORS`] a live keyframe is re-anchored
/// on the points it observes now, so it still has anchors when a loop correction comes or
/// it is culled.
const REANCHOR_BELOW: usize = MAX_ANCHORS / 2;

/// Re-anchors a live keyframe (pose `t_cw`, depth scale `scale` now) on the map points it
/// observes now when fewer than [`REANCHOR_BELOW`] of its anchors are left (points culled
/// or fused by local mapping and loop fusion): their positions now, brought back to the
/// reconstruction's scale.
pub(super) fn reanchor(map: &Map, e: &mut KeyframeDepth, t_cw: &CameraFromWorld, scale: f32) {
    let Some(k) = map.keyframe(e.keyframe) else {
        return;
    };
    let alive = e
        .anchors
        .iter()
        .filter(|a| anchor_point(map, Some(k), a).is_some())
        .count();
    if alive >= REANCHOR_BELOW || !(scale.is_finite() && scale > 0.0) {
        return;
    }
    let anchors = sample_anchors(map, k, t_cw, scale);
    // Only when it gives more than what is left.
    if anchors.len() > alive {
        e.anchors = anchors;
    }
}

/// Up to [`MAX_ANCHORS`] of the points `k` observes, spread over them (every few), with
/// their camera-frame positions at pose `t_cw` divided by the depth scale `scale` (1 at
/// reconstruction).
pub(super) fn sample_anchors(
    map: &Map,
    k: &KeyFrame,
    t_cw: &CameraFromWorld,
    scale: f32,
) -> heapless::Vec<Anchor, MAX_ANCHORS> {
    let stride = k.observed().count().div_ceil(MAX_ANCHORS).max(1);
    let mut anchors = heapless::Vec::new();
    for (i, mp) in k.observed().step_by(stride) {
        let Some(p) = map.point(mp) else { continue };
        let x = t_cw.transform(&p.position) / scale as f64;
        if x.z > 0.0 {
            let _ = anchors.push(Anchor {
                point: mp,
                keypoint: i as u32,
                x_then: [x.x as f32, x.y as f32, x.z as f32],
            });
        }
    }
    anchors
}

/// Pose and depth scale of a keyframe that has left the map (culled after reconstruction):
/// the similarity taking its anchors from its camera frame then to where the map has them now
/// (so its cloud follows loop corrections and BA). `None` with fewer than 3 anchors left.
fn pose_from_anchors(map: &Map, e: &KeyframeDepth) -> Option<(CameraFromWorld, f32)> {
    let mut then = [nalgebra::Vector3::zeros(); MAX_ANCHORS];
    let mut now = [nalgebra::Vector3::zeros(); MAX_ANCHORS];
    let mut n = 0;
    for a in &e.anchors {
        if let Some(p) = anchor_point(map, None, a) {
            let x = a.x_then;
            then[n] = nalgebra::Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
            now[n] = p.position;
            n += 1;
        }
    }
    if n < 3 {
        return None;
    }
    // x_w = s R x_c + t: the camera pose is [R | t], its depths are scaled by s.
    let s = crate::geometry::umeyama(&then[..n], &now[..n], true)?;
    if !(s.scale.is_finite() && s.scale > 0.0) {
        return None;
    }
    let t_wc = crate::geometry::Se3::from_parts(s.translation.into(), s.rotation);
    Some((CameraFromWorld(t_wc.inverse()), s.scale as f32))
}

/// A culled keyframe's pose and scale through a live neighbour
/// ([`KeyframeDepth::relative_to`]): the pose relative to it when both were last read, its
/// translation and the keyframe's depths scaled by how the neighbour's depth scale changed
/// since (a Sim3 correction moves both alike).
fn pose_via_neighbour(
    map: &Map,
    e: &KeyframeDepth,
    entries: &[KeyframeDepth],
    scratch: &mut Vec<f32>,
) -> Option<(CameraFromWorld, f32)> {
    let (j, t_ej, scale_then) = e.relative_to?;
    let k = map.keyframe(j)?;
    let d = entries.iter().find(|d| d.keyframe == j)?;
    let scale_now = anchor_scale(map, d, &k.t_cw, scratch)?;
    let ratio = scale_now / scale_then;
    if !(ratio.is_finite() && ratio > 0.0) {
        return None;
    }
    let mut t = t_ej;
    t.translation.vector *= ratio as f64;
    Some((CameraFromWorld(t * k.t_cw.0), e.scale * ratio))
}

/// Current pose and depth scale of a reconstructed keyframe. A live keyframe: its pose and
/// its anchors' scale. A culled one: the Sim3 of its anchors; with fewer than 3 of them
/// (fused or culled since) through a live neighbour; else through the spanning tree it was
/// culled from ([`Map::keyframe_pose_or_tombstone`]: the rotation follows corrections, the
/// relative translation keeps the scale of the cull) with its last scale; else as stored.
pub(super) fn pose_and_scale_now(
    map: &Map,
    e: &KeyframeDepth,
    entries: &[KeyframeDepth],
    scratch: &mut Vec<f32>,
) -> (CameraFromWorld, f32) {
    if let Some(k) = map.keyframe(e.keyframe) {
        let scale = anchor_scale(map, e, &k.t_cw, scratch).unwrap_or(e.scale);
        return (k.t_cw, scale);
    }
    pose_from_anchors(map, e)
        .or_else(|| pose_via_neighbour(map, e, entries, scratch))
        .or_else(|| {
            map.keyframe_pose_or_tombstone(e.keyframe)
                .map(|t| (t, e.scale))
        })
        .unwrap_or((e.t_cw, e.scale))
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
        let k = self.ws.reconstructor.k;
        let w = self.ws.reconstructor.width;
        let mut scratch = Vec::with_capacity(MAX_ANCHORS);
        let in_map =
            |e: &&KeyframeDepth| map_id.is_none_or(|id| map.map_of(e.keyframe) == Some(id));
        for e in self.entries.iter().filter(|e| e.checked).filter(in_map) {
            let (t_cw, scale) = pose_and_scale_now(map, e, &self.entries, &mut scratch);
            let scale = scale as f64;
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
