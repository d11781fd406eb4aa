//! Loops that tracking has already joined. When the drift around a loop is small, tracking
//! matches the old place's points by projection as soon as the camera is back, so the new
//! keyframe is covisible with keyframes from the start of the loop and bag-of-words detection
//! (which skips covisible keyframes, as ORB-SLAM's) finds nothing. What marks the loop is
//! geometry: the two keyframes are close in space but far apart along the path travelled
//! between them (the keyframe chain in creation order, with the loops already closed as
//! shortcuts, so a place is not "revisited" again on every keyframe after its loop).

use std::collections::{HashMap, HashSet};

use nalgebra::Vector3;

use super::{fuse_and_link, se3_to_sim3, LoopCloser, LoopKind, LoopReport};
use crate::map::{KeyFrameId, Map, MapPointId};

impl LoopCloser {
    /// The covisible keyframe (strongest edge first) with which `kf` closes a revisit loop:
    /// the path travelled between them is at least `revisit_path_ratio` times the distance
    /// between their centres and `revisit_min_path_depths` times `kf`'s median scene depth.
    pub(super) fn detect_revisit(&self, map: &Map, kf: KeyFrameId) -> Option<KeyFrameId> {
        if !self.may_close(map, kf) {
            return None;
        }
        let k = map.keyframe(kf)?;
        let depth = median_depth(map, kf)?;
        let travelled = travelled_from(map, kf);
        let c0 = k.t_cw.center();
        let gap = self.config.min_keyframes_between_loops as u64;
        let mut best: Option<(u32, KeyFrameId)> = None;
        for &(c, w) in &k.covisibles {
            let Some(ck) = map.keyframe(c) else { continue };
            let Some(&path) = travelled.get(&c) else {
                continue;
            };
            let direct = (ck.t_cw.center() - c0).norm();
            let is_loop = ck.serial + gap <= k.serial
                && path >= self.config.revisit_min_path_depths * depth
                && path >= self.config.revisit_path_ratio * direct;
            if is_loop && best.is_none_or(|b| w > b.0) {
                best = Some((w, c));
            }
        }
        if let Some((w, c)) = best {
            tracing::debug!(
                keyframe = k.serial,
                old = map.keyframe(c).map_or(0, |x| x.serial),
                shared = w,
                "revisit"
            );
        }
        best.map(|b| b.1)
    }

    /// Closes a revisit: `kf`'s points already shared with the old side, plus the old side's
    /// points found by projection with `kf`'s own pose (at least `min_matches`), are fused and
    /// the loop edge added. Poses are not corrected here: tracking placed `kf` against the old
    /// side already; the full BA that follows a loop spreads the error around it.
    pub(super) fn close_revisit(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        c: KeyFrameId,
    ) -> Option<LoopReport> {
        let (k1, k2) = (map.keyframe(kf)?, map.keyframe(c)?);
        let gap = self.config.min_keyframes_between_loops as u64;
        // The old side: the loop keyframe and its covisible keyframes from before the loop.
        let old_side: HashSet<KeyFrameId> = std::iter::once(c)
            .chain(k2.covisibles.iter().map(|&(x, _)| x))
            .filter(|x| {
                map.keyframe(*x)
                    .is_some_and(|x| x.serial + gap <= k1.serial)
            })
            .collect();
        let mut matched: Vec<Option<MapPointId>> = vec![None; k1.keypoints.len()];
        for (i, p) in k1.observed() {
            let seen_before = map
                .point(p)
                .is_some_and(|mp| mp.observations.iter().any(|(o, _)| old_side.contains(o)));
            if seen_before {
                matched[i] = Some(p);
            }
        }
        let s_cw = se3_to_sim3(&k1.t_cw.0);
        let n_matches = self.match_loop_group(map, kf, c, &s_cw, &mut matched);
        if n_matches < self.config.min_matches {
            return None;
        }
        let fused = fuse_and_link(map, kf, c, &matched);
        Some(LoopReport {
            kind: LoopKind::Revisit,
            keyframe: kf,
            loop_keyframe: c,
            matches: n_matches,
            fused_points: fused,
        })
    }
}

/// Median depth of `kf`'s map points in its camera (the scale of its scene).
fn median_depth(map: &Map, kf: KeyFrameId) -> Option<f64> {
    let k = map.keyframe(kf)?;
    let mut z: Vec<f64> = k
        .observed()
        .filter_map(|(_, p)| map.point(p))
        .map(|p| k.t_cw.transform(&p.position).z)
        .filter(|z| z.is_finite() && *z > 0.0)
        .collect();
    if z.is_empty() {
        return None;
    }
    let mid = z.len() / 2;
    z.select_nth_unstable_by(mid, f64::total_cmp);
    Some(z[mid])
}

/// Shortest travelled distance from `kf` to every keyframe: along consecutive keyframes in
/// creation order (the path the camera took) and across loop edges (places already joined),
/// each step weighted by the distance between camera centres (Dijkstra; maps hold at most a
/// few hundred keyframes, so the quadratic scan is cheap).
fn travelled_from(map: &Map, kf: KeyFrameId) -> HashMap<KeyFrameId, f64> {
    let mut order: Vec<(u64, KeyFrameId)> = map.keyframes().map(|(id, k)| (k.serial, id)).collect();
    order.sort_unstable();
    let n = order.len();
    let slot: HashMap<KeyFrameId, usize> = order
        .iter()
        .enumerate()
        .map(|(i, &(_, id))| (id, i))
        .collect();
    let centres: Vec<Vector3<f64>> = order
        .iter()
        .map(|&(_, id)| {
            map.keyframe(id)
                .map_or(Vector3::zeros(), |k| k.t_cw.center())
        })
        .collect();
    let mut links: Vec<Vec<usize>> = vec![Vec::new(); n];
    for i in 1..n {
        links[i].push(i - 1);
        links[i - 1].push(i);
    }
    for (i, &(_, id)) in order.iter().enumerate() {
        for l in map
            .keyframe(id)
            .map(|k| k.loop_edges.as_slice())
            .unwrap_or(&[])
        {
            if let Some(&j) = slot.get(l) {
                links[i].push(j);
                links[j].push(i);
            }
        }
    }
    let mut dist = vec![f64::INFINITY; n];
    let mut done = vec![false; n];
    if let Some(&s) = slot.get(&kf) {
        dist[s] = 0.0;
    }
    while let Some(u) = (0..n)
        .filter(|&i| !done[i] && dist[i].is_finite())
        .min_by(|&a, &b| dist[a].total_cmp(&dist[b]))
    {
        done[u] = true;
        for &v in &links[u] {
            let d = dist[u] + (centres[u] - centres[v]).norm();
            if d < dist[v] {
                dist[v] = d;
            }
        }
    }
    order
        .iter()
        .zip(dist)
        .filter(|(_, d)| d.is_finite())
        .map(|(&(_, id), d)| (id, d))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera_model::PinholeRadtan;
    use crate::features::KeyPoint;
    use crate::geometry::WorldFromCamera;
    use crate::map::MapConfig;
    use nalgebra::UnitQuaternion;

    const RADIUS: f64 = 2.0;
    const N: usize = 20;

    /// Keyframes on a circle of radius 2 (looking along +z at points 3 away), each sharing 20
    /// points with the next.
    fn ring(n: usize) -> (Map, Vec<KeyFrameId>) {
        let mut map = Map::new(MapConfig {
            max_keyframes: 32,
            max_map_points: 2000,
            max_features: 100,
            width: 640,
            height: 480,
            ..MapConfig::default()
        });
        let mut kfs = Vec::new();
        for i in 0..n {
            let a = i as f64 / N as f64 * std::f64::consts::TAU;
            let centre = Vector3::new(RADIUS * a.cos(), RADIUS * a.sin(), 0.0);
            let kf = map
                .insert_keyframe(|k| {
                    for j in 0..100 {
                        let u = (j % 10) as f32 * 60.0 + 20.0;
                        let v = (j / 10) as f32 * 45.0 + 20.0;
                        k.keypoints.push(KeyPoint {
                            x: u,
                            y: v,
                            ux: u,
                            uy: v,
                            ..Default::default()
                        });
                        k.descriptors.push([j as u64, i as u64, 0, 0]);
                    }
                    k.t_cw =
                        WorldFromCamera::from_parts(centre, UnitQuaternion::identity()).inverse();
                })
                .unwrap();
            kfs.push(kf);
            if i > 0 {
                share(&mut map, kfs[i - 1], kf);
            }
        }
        (map, kfs)
    }

    /// 20 new points near `a`'s view, seen by `a` at keypoints `ka..ka+20` and by `b` at
    /// `kb..kb+20`.
    fn share_points(map: &mut Map, a: KeyFrameId, b: KeyFrameId, ka: usize, kb: usize) {
        let c = map.keyframe(a).unwrap().t_cw.center();
        for i in 0..20 {
            let p = map
                .insert_point(c + Vector3::new(i as f64 * 0.01, ka as f64 * 1e-3, 3.0), a)
                .unwrap();
            map.add_observation(p, a, ka + i);
            map.add_observation(p, b, kb + i);
        }
        map.update_connections(a);
        map.update_connections(b);
    }

    /// Consecutive keyframes of the ring: keypoints 0..20 of the first, 20..40 of the second.
    fn share(map: &mut Map, a: KeyFrameId, b: KeyFrameId) {
        share_points(map, a, b, 0, 20);
    }

    /// `later` sees 20 new points of `old` (keypoints 40..60 of `old`, 60..80 of `later`), as
    /// when tracking re-associates a place mapped before.
    fn reobserve(map: &mut Map, old: KeyFrameId, later: KeyFrameId) {
        share_points(map, old, later, 40, 60);
    }

    fn closer() -> LoopCloser {
        let cam = PinholeRadtan::pinhole(520.0, 520.0, 320.0, 240.0, 640, 480);
        LoopCloser::new(cam, &[1.0, 1.2, 1.44])
    }

    #[test]
    fn the_end_of_a_ring_joined_to_its_start_is_a_revisit() {
        let (mut map, kfs) = ring(N);
        let last = kfs[N - 1];
        assert_eq!(
            closer().detect_revisit(&map, last),
            None,
            "open ring: no loop"
        );
        // Tracking re-associates the start's points: the last keyframe sees 20 of keyframe 0.
        let first = kfs[0];
        reobserve(&mut map, first, last);
        assert_eq!(closer().detect_revisit(&map, last), Some(first));
        // Once that loop is an edge, a later keyframe near the start is no new loop.
        map.keyframe_mut(last).unwrap().loop_edges.push(first);
        map.keyframe_mut(first).unwrap().loop_edges.push(last);
        let d = travelled_from(&map, kfs[N - 2]);
        let centre = |k: KeyFrameId| map.keyframe(k).unwrap().t_cw.center();
        // One step to the last keyframe, then across the loop edge, not 18 steps back.
        let via_loop =
            (centre(last) - centre(kfs[N - 2])).norm() + (centre(first) - centre(last)).norm();
        assert!(
            (d[&first] - via_loop).abs() < 1e-9,
            "the loop edge is a shortcut"
        );
        assert!(d[&first] < 0.1 * RADIUS * std::f64::consts::TAU);
    }

    #[test]
    fn a_keyframe_seeing_across_the_circle_is_no_loop() {
        // Keyframe 10 sees keyframe 0's points from the far side (like a camera circling over
        // a floor): travelled half the circle, pi r, against a distance of 2 r.
        let (mut map, kfs) = ring(N / 2 + 1);
        let (first, opposite) = (kfs[0], kfs[N / 2]);
        reobserve(&mut map, first, opposite);
        assert!(map
            .keyframe(opposite)
            .unwrap()
            .covisibles
            .iter()
            .any(|&(k, _)| k == first));
        assert_eq!(closer().detect_revisit(&map, opposite), None);
    }
}
