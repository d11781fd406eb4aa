//! Full bundle adjustment as a job that does not stop tracking: the problem is copied out of
//! the map under a short lock, solved without it (on a background thread after a loop), and
//! merged back under a short lock. Keyframes made meanwhile follow their spanning-tree parent's
//! correction, points made meanwhile their reference keyframe's (as ORB-SLAM).

use std::collections::{HashMap, VecDeque};

use nalgebra::Vector2;

use crate::camera_model::PinholeRadtan;
use crate::geometry::CameraFromWorld;
use crate::map::{KeyFrameId, Map, MapPointId};
use crate::optimize::{BaObservation, BaOptions, BaProblem, BundleAdjuster};

pub struct GlobalBaJob {
    problem: BaProblem,
    keyframes: Vec<KeyFrameId>,
    points: Vec<MapPointId>,
    iterations: usize,
    /// The map's correction epoch when the problem was copied.
    epoch: u64,
}

impl GlobalBaJob {
    /// Copies every keyframe, point and observation (the first keyframe and keyframes without
    /// a parent fixed: the gauge). `None` with fewer than 3 keyframes.
    pub fn prepare(
        map: &Map,
        camera: &PinholeRadtan,
        scales: &[f64],
        iterations: usize,
    ) -> Option<Self> {
        if map.n_keyframes() < 3 {
            return None;
        }
        let keyframes: Vec<KeyFrameId> = map.keyframes().map(|(id, _)| id).collect();
        let points: Vec<MapPointId> = map.points().map(|(id, _)| id).collect();
        let index: HashMap<KeyFrameId, u32> = keyframes
            .iter()
            .enumerate()
            .map(|(i, &k)| (k, i as u32))
            .collect();
        let mut p = BaProblem {
            k: camera.intrinsics(),
            ..Default::default()
        };
        for (i, &k) in keyframes.iter().enumerate() {
            let kf = map.keyframe(k);
            p.poses
                .push(kf.map_or(CameraFromWorld::identity(), |k| k.t_cw));
            p.pose_fixed
                .push(i == 0 || kf.is_none_or(|k| k.parent.is_none()));
        }
        for (j, &mp) in points.iter().enumerate() {
            let position = map.point(mp).map(|m| m.position).unwrap_or_default();
            p.points.push(position);
            let Some(m) = map.point(mp) else { continue };
            for &(kf, i) in &m.observations {
                let (Some(&pi), Some(k)) = (index.get(&kf), map.keyframe(kf)) else {
                    continue;
                };
                let Some(kp) = k.keypoints.get(i as usize) else {
                    continue;
                };
                let s = scales.get(kp.octave as usize).copied().unwrap_or(1.0);
                p.observations.push(BaObservation {
                    pose: pi,
                    point: j as u32,
                    uv: Vector2::new(kp.ux as f64, kp.uy as f64),
                    inv_sigma2: 1.0 / (s * s),
                });
            }
        }
        Some(GlobalBaJob {
            problem: p,
            keyframes,
            points,
            iterations,
            epoch: map.correction_epoch(),
        })
    }

    /// Solves the copied problem (no map access).
    pub fn solve(&mut self) {
        BundleAdjuster::new().solve(
            &mut self.problem,
            &BaOptions {
                iterations: self.iterations,
                ..BaOptions::default()
            },
        );
    }

    /// Writes the solution back; keyframes and points made since [`prepare`](Self::prepare)
    /// move with their parent / reference keyframe. Returns false, writing nothing, when a
    /// loop correction has moved the map since the copy (its solution would undo it).
    pub fn merge(self, map: &mut Map) -> bool {
        if map.correction_epoch() != self.epoch {
            return false;
        }
        let mut new_pose: HashMap<KeyFrameId, CameraFromWorld> = HashMap::new();
        let mut old_pose: HashMap<KeyFrameId, CameraFromWorld> = HashMap::new();
        for (i, &k) in self.keyframes.iter().enumerate() {
            if let Some(kf) = map.keyframe(k) {
                old_pose.insert(k, kf.t_cw);
                new_pose.insert(k, self.problem.poses[i]);
            }
        }
        // Keyframes made meanwhile: breadth first down the spanning tree from solved ones.
        let mut queue: VecDeque<KeyFrameId> = new_pose.keys().copied().collect();
        while let Some(parent) = queue.pop_front() {
            let children = map
                .keyframe(parent)
                .map(|k| k.children.clone())
                .unwrap_or_default();
            for c in children {
                if new_pose.contains_key(&c) {
                    continue;
                }
                let (Some(ck), Some(pn), Some(po)) = (
                    map.keyframe(c),
                    new_pose.get(&parent).copied(),
                    old_pose.get(&parent).copied(),
                ) else {
                    continue;
                };
                let t_child_parent = ck.t_cw.0 * po.0.inverse();
                old_pose.insert(c, ck.t_cw);
                new_pose.insert(c, CameraFromWorld(t_child_parent * pn.0));
                queue.push_back(c);
            }
        }
        let solved: HashMap<MapPointId, usize> = self
            .points
            .iter()
            .enumerate()
            .map(|(j, &p)| (p, j))
            .collect();
        let all: Vec<(MapPointId, Option<KeyFrameId>)> =
            map.points().map(|(id, p)| (id, p.reference_kf)).collect();
        for (p, r) in all {
            let position = match solved.get(&p) {
                Some(&j) => Some(self.problem.points[j]),
                None => r.and_then(|r| {
                    let (o, n) = (old_pose.get(&r)?, new_pose.get(&r)?);
                    let pos = map.point(p)?.position;
                    Some(n.inverse().transform(&o.transform(&pos)))
                }),
            };
            if let (Some(pos), Some(m)) = (position, map.point_mut(p)) {
                m.position = pos;
            }
        }
        for (k, t) in &new_pose {
            if let Some(kf) = map.keyframe_mut(*k) {
                kf.t_cw = *t;
            }
        }
        let ids: Vec<MapPointId> = map.points().map(|(id, _)| id).collect();
        for p in ids {
            map.update_point_geometry(p);
        }
        map.note_correction();
        true
    }
}
