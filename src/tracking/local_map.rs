//! Local-map tracking: the keyframes sharing points with the frame plus their best covisible
//! neighbours, children and parents; their points are projected (frustum, scale range and
//! viewing angle < 60 deg), matched, and the pose optimised again.

use super::{TrackedFrame, Tracker};
use crate::map::{KeyFrameId, Map, MapPointId};
use crate::matching::search::{search_by_projection, ProjectedPoint, ProjectionSearch};

#[derive(Default)]
pub struct LocalMap {
    keyframes: Vec<KeyFrameId>,
    points: Vec<MapPointId>,
    projected: Vec<ProjectedPoint>,
    ids: Vec<MapPointId>,
    /// Per keyframe / point slot: the frame that last marked it (dedup without hashing).
    kf_stamp: Vec<u64>,
    pt_stamp: Vec<u64>,
    counts: Vec<(KeyFrameId, u32)>,
    scratch: Vec<u32>,
    matches: Vec<Option<u32>>,
}

/// Grows `v`'s capacity to at least `n` (a no-op once it has).
fn reserve_total<T>(v: &mut Vec<T>, n: usize) {
    if v.capacity() < n {
        v.reserve(n - v.len());
    }
}

impl LocalMap {
    pub fn with_capacity(points: usize) -> Self {
        LocalMap {
            points: Vec::with_capacity(points),
            projected: Vec::with_capacity(points),
            ids: Vec::with_capacity(points),
            ..Default::default()
        }
    }

    fn collect(&mut self, t: &mut Tracker, map: &Map, f: &TrackedFrame) {
        let stamp = f.index + 1;
        self.kf_stamp.resize(map.config.max_keyframes, 0);
        self.pt_stamp.resize(map.config.max_map_points, 0);
        // Sized once for the map's bounds, so a frame seeing more keyframes than any before
        // does not allocate.
        reserve_total(&mut self.keyframes, map.config.max_keyframes);
        reserve_total(&mut self.counts, map.config.max_keyframes);
        reserve_total(&mut self.points, map.config.max_map_points);
        self.keyframes.clear();
        self.counts.clear();
        // Keyframes observing the frame's points, with how many they share.
        for (_, mp) in f.inlier_points() {
            let Some(p) = map.point(mp) else { continue };
            for &(kf, _) in &p.observations {
                match self.counts.iter_mut().find(|(k, _)| *k == kf) {
                    Some(c) => c.1 += 1,
                    None => self.counts.push((kf, 1)),
                }
            }
        }
        self.counts.sort_by_key(|c| std::cmp::Reverse(c.1));
        if let Some(&(best, _)) = self.counts.first() {
            t.reference_kf = Some(best);
        }
        for &(kf, _) in &self.counts {
            if self.kf_stamp[kf.index()] != stamp {
                self.kf_stamp[kf.index()] = stamp;
                self.keyframes.push(kf);
            }
        }
        // Neighbours: best covisibles, children, parent.
        let direct = self.keyframes.len();
        for i in 0..direct {
            if self.keyframes.len() >= t.config.max_local_keyframes {
                break;
            }
            let Some(k) = map.keyframe(self.keyframes[i]) else {
                continue;
            };
            let more = k
                .best_covisibles(10)
                .chain(k.children.iter().copied())
                .chain(k.parent);
            for n in more {
                if map.keyframe(n).is_some() && self.kf_stamp[n.index()] != stamp {
                    self.kf_stamp[n.index()] = stamp;
                    self.keyframes.push(n);
                    if self.keyframes.len() >= t.config.max_local_keyframes {
                        break;
                    }
                }
            }
        }
        // Their points, once each, skipping those already matched.
        self.points.clear();
        for (_, mp) in f.inlier_points() {
            self.pt_stamp[mp.index()] = stamp;
        }
        for &kf in &self.keyframes {
            let Some(k) = map.keyframe(kf) else { continue };
            for (_, mp) in k.observed() {
                if self.pt_stamp[mp.index()] != stamp {
                    self.pt_stamp[mp.index()] = stamp;
                    self.points.push(mp);
                }
            }
        }
    }

    /// Matches local-map points into `f` and re-optimises; returns inliers.
    pub fn track(&mut self, t: &mut Tracker, map: &mut Map, f: &mut TrackedFrame) -> usize {
        self.collect(t, map, f);
        let centre = f.t_cw.center();
        let (sf, nl) = (map.config.scale_factor, map.config.n_levels);
        reserve_total(&mut self.projected, map.config.max_map_points);
        reserve_total(&mut self.ids, map.config.max_map_points);
        self.projected.clear();
        self.ids.clear();
        for &mp in &self.points {
            let Some(p) = map.point_mut(mp) else { continue };
            let pc = f.t_cw.transform(&p.position);
            let Some(uv) = t.camera.project(&pc) else {
                continue;
            };
            if !t.camera.in_image(uv.x, uv.y, 0.0) {
                continue;
            }
            let ray = p.position - centre;
            let dist = ray.norm();
            if dist < 0.8 * p.min_distance || dist > 1.2 * p.max_distance {
                continue;
            }
            let view_cos = ray.dot(&p.normal) / dist;
            if view_cos < t.config.min_view_cos {
                continue;
            }
            p.visible += 1;
            let level = p.predict_level(dist, sf, nl) as u8;
            let radius_factor = if view_cos > 0.998 { 2.5 } else { 4.0 };
            self.projected.push(ProjectedPoint {
                id: self.ids.len() as u32,
                uv: uv.cast(),
                level,
                descriptor: p.descriptor,
                radius_factor,
            });
            self.ids.push(mp);
        }
        // Matches only into free keypoints.
        self.matches.clear();
        self.matches
            .extend(f.points.iter().map(|p| p.map(|_| u32::MAX)));
        // ORB-SLAM's local-map search: radius 1 (times the level's scale and the viewing
        // angle's factor), ratio 0.8.
        let search = ProjectionSearch {
            scales: &t.scales,
            radius: 1.0,
            ratio: 0.8,
        };
        search_by_projection(
            &self.projected,
            f.features.view(),
            &f.grid,
            search,
            &mut self.matches,
            &mut self.scratch,
        );
        for (j, m) in self.matches.iter().enumerate() {
            if let Some(id) = m {
                if *id != u32::MAX {
                    f.points[j] = Some(self.ids[*id as usize]);
                    f.outlier[j] = false;
                }
            }
        }
        // Counted only for the trace line (a pass over the keypoints every frame otherwise).
        let matched = tracing::enabled!(tracing::Level::TRACE)
            .then(|| f.points.iter().filter(|p| p.is_some()).count());
        let n = t.optimize_pose(map, f);
        tracing::trace!(
            frame = f.index,
            features = f.points.len(),
            local_keyframes = self.keyframes.len(),
            local_points = self.points.len(),
            projected = self.projected.len(),
            matched = matched.unwrap_or(0),
            inliers = n,
            "local map tracked"
        );
        for (_, mp) in f.inlier_points() {
            if let Some(p) = map.point_mut(mp) {
                p.found += 1;
            }
        }
        n
    }
}
