//! Duplicate fusion (ORB-SLAM's "search in neighbours"): the new keyframe's points are
//! projected into its neighbours (and theirs into it); a point landing on a keypoint with a
//! matching descriptor either adds that observation or, when the keypoint already has a point,
//! the two are merged (the one with more observations survives).

use nalgebra::Vector2;

use crate::camera_model::PinholeRadtan;
use crate::map::{KeyFrameId, Map, MapPointId};
use crate::matching::{hamming, TH_LOW};

/// What fusing one set of points into one keyframe should do.
enum Action {
    Observe(MapPointId, usize),
    Merge { keep: MapPointId, drop: MapPointId },
}

/// Projects `points` into keyframe `target` and fuses them; returns (observations added,
/// points merged). `radius` is in pixels at level 0 (ORB-SLAM: 3), scaled by the level.
pub fn fuse_into(
    map: &mut Map,
    camera: &PinholeRadtan,
    scales: &[f64],
    target: KeyFrameId,
    points: &[MapPointId],
    radius: f32,
) -> (usize, usize) {
    let Some(kf) = map.keyframe(target) else {
        return (0, 0);
    };
    let centre = kf.t_cw.center();
    let (sf, nl) = (map.config.scale_factor, map.config.n_levels);
    let mut actions = Vec::new();
    let mut cand = Vec::new();
    for &mp in points {
        let Some(p) = map.point(mp) else { continue };
        if p.observations.iter().any(|&(f, _)| f == target) {
            continue;
        }
        let pc = kf.t_cw.transform(&p.position);
        let Some(uv) = camera.project(&pc) else {
            continue;
        };
        if !camera.in_image(uv.x, uv.y, 0.0) {
            continue;
        }
        let ray = p.position - centre;
        let dist = ray.norm();
        if dist < 0.8 * p.min_distance
            || dist > 1.2 * p.max_distance
            || ray.dot(&p.normal) < 0.5 * dist
        {
            continue;
        }
        let level = p.predict_level(dist, sf, nl);
        let r = radius * scales[level] as f32;
        kf.grid.in_area(
            &kf.keypoints,
            uv.x as f32,
            uv.y as f32,
            r,
            level.saturating_sub(1) as u8,
            (level + 1).min(nl - 1) as u8,
            &mut cand,
        );
        let (mut best, mut best_j) = (TH_LOW + 1, usize::MAX);
        for &j in &cand {
            let k = &kf.keypoints[j as usize];
            let e2 = (Vector2::new(k.ux as f64, k.uy as f64) - uv).norm_squared();
            if e2 > 5.991 * scales[k.octave as usize].powi(2) {
                continue;
            }
            let d = hamming(&p.descriptor, &kf.descriptors[j as usize]);
            if d < best {
                best = d;
                best_j = j as usize;
            }
        }
        if best_j == usize::MAX {
            continue;
        }
        match kf.points[best_j] {
            Some(other) if other != mp => {
                let n_other = map.point(other).map_or(0, |o| o.observations.len());
                let (keep, drop) = if n_other > p.observations.len() {
                    (other, mp)
                } else {
                    (mp, other)
                };
                actions.push(Action::Merge { keep, drop });
            }
            Some(_) => {}
            None => actions.push(Action::Observe(mp, best_j)),
        }
    }
    let (mut added, mut merged) = (0, 0);
    for a in actions {
        match a {
            Action::Observe(mp, j) => {
                let free = map.keyframe(target).is_some_and(|k| k.points[j].is_none());
                if free && map.point(mp).is_some() && map.add_observation(mp, target, j) {
                    map.update_point_geometry(mp);
                    added += 1;
                }
            }
            Action::Merge { keep, drop } => {
                if map.point(keep).is_some() && map.point(drop).is_some() {
                    map.replace_point(drop, keep);
                    merged += 1;
                }
            }
        }
    }
    (added, merged)
}

/// The keyframes to fuse with (best covisibles and their 5 best covisibles) and the new
/// keyframe's points; `None` if it is gone.
pub fn fusion_targets(
    map: &Map,
    kf: KeyFrameId,
    n_neighbours: usize,
) -> Option<(Vec<KeyFrameId>, Vec<MapPointId>)> {
    let k = map.keyframe(kf)?;
    let mut targets: Vec<KeyFrameId> = k.best_covisibles(n_neighbours).collect();
    let first = targets.clone();
    for t in first {
        if let Some(tk) = map.keyframe(t) {
            for n in tk.best_covisibles(5) {
                if n != kf && !targets.contains(&n) {
                    targets.push(n);
                }
            }
        }
    }
    let own: Vec<MapPointId> = k.observed().map(|(_, p)| p).collect();
    Some((targets, own))
}

/// The targets' points into the new keyframe, then its connections updated.
pub fn fuse_neighbours_into(
    map: &mut Map,
    camera: &PinholeRadtan,
    scales: &[f64],
    kf: KeyFrameId,
    targets: &[KeyFrameId],
) -> (usize, usize) {
    let mut theirs: Vec<MapPointId> = Vec::new();
    for &t in targets {
        if let Some(tk) = map.keyframe(t) {
            theirs.extend(tk.observed().map(|(_, p)| p));
        }
    }
    theirs.sort();
    theirs.dedup();
    let r = fuse_into(map, camera, scales, kf, &theirs, 3.0);
    map.update_connections(kf);
    r
}
