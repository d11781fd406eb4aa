//! Correcting a detected loop: the Sim3 propagated to the current keyframe's neighbourhood,
//! the loop's map points fused into it, the essential-graph pose graph over the whole map.

use super::*;

impl LoopCloser {
    /// Corrects the current keyframe's neighbourhood with `s_cw`, fuses the loop matches, adds
    /// the loop edge and optimises the essential graph. When the loop keyframe is in another
    /// map of the atlas, every keyframe of the current keyframe's map is corrected (the whole
    /// map moves into the loop keyframe's frame) and the two maps are merged.
    pub(super) fn correct(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        loop_kf: KeyFrameId,
        s_cw: &Sim3,
        matched: &[Option<MapPointId>],
        n_matches: usize,
    ) -> LoopReport {
        let before: HashMap<KeyFrameId, Sim3> = map
            .keyframes()
            .map(|(id, k)| (id, se3_to_sim3(&k.t_cw.0)))
            .collect();
        let edges_before: HashSet<(KeyFrameId, KeyFrameId)> =
            map.essential_edges().into_iter().collect();
        let t_wc = before[&kf].inverse();
        // Corrected S_iw for the current keyframe and its neighbours.
        let mut corrected: HashMap<KeyFrameId, Sim3> = HashMap::new();
        let mut neighbours: Vec<KeyFrameId> = map
            .keyframe(kf)
            .map(|k| k.covisibles.iter().map(|&(x, _)| x).collect())
            .unwrap_or_default();
        let (from, into) = (map.map_of(kf), map.map_of(loop_kf));
        let merge = from != into;
        if let (true, Some(from)) = (merge, from) {
            // The rest of the map after the neighbours, in arena order (reproducible).
            let rest: Vec<KeyFrameId> = map
                .keyframes_of(from)
                .into_iter()
                .filter(|k| *k != kf && !neighbours.contains(k))
                .collect();
            neighbours.extend(rest);
        }
        // In a fixed order (the keyframe, then its neighbours by covisibility): a point seen
        // by several of them moves with the first, so runs are reproducible.
        let mut order = vec![kf];
        corrected.insert(kf, *s_cw);
        for &n in &neighbours {
            if let Some(s_iw) = before.get(&n) {
                let s_ic = sim3_compose(s_iw, &t_wc);
                corrected.insert(n, sim3_compose(&s_ic, s_cw));
                order.push(n);
            }
        }
        // Points seen by the corrected keyframes move with them (and later with that keyframe
        // in the pose graph step).
        let mut moved: HashMap<MapPointId, KeyFrameId> = HashMap::new();
        for id in &order {
            let (id, s_new) = (*id, &corrected[id]);
            let pts: Vec<MapPointId> = map
                .keyframe(id)
                .map(|k| k.observed().map(|(_, p)| p).collect())
                .unwrap_or_default();
            let s_old = before[&id];
            for p in pts {
                if moved.contains_key(&p) {
                    continue;
                }
                moved.insert(p, id);
                if let Some(mp) = map.point_mut(p) {
                    mp.position = s_new.inverse().transform(&s_old.transform(&mp.position));
                }
            }
        }
        for (&id, s_new) in &corrected {
            if let Some(k) = map.keyframe_mut(id) {
                k.t_cw = sim3_to_camera(s_new);
            }
        }
        for &p in moved.keys() {
            map.update_point_geometry(p);
        }
        let fused = fuse_and_link(map, kf, loop_kf, matched);
        if let (true, Some(from), Some(into)) = (merge, from, into) {
            map.merge_maps(from, into, kf, loop_kf);
            tracing::info!(from, into, scale = 1.0 / s_cw.scale, "maps merged");
        }
        self.optimize_essential_graph(map, &before, &edges_before, &corrected, &moved, loop_kf);
        map.note_correction();
        LoopReport {
            kind: if merge {
                LoopKind::Merge
            } else {
                LoopKind::Place
            },
            keyframe: kf,
            loop_keyframe: loop_kf,
            matches: n_matches,
            fused_points: fused,
        }
    }

    /// Sim3 pose graph over the essential graph: an edge that was there before the correction
    /// keeps the relative pose it had then; an edge the loop made (loop fusion's links, the
    /// loop edge, a merged map's re-rooted spanning tree) is measured after the correction,
    /// when both its keyframes are in one frame (ORB-SLAM's loop connections). The loop
    /// keyframe is fixed. Keyframes and points are then moved with their keyframe's
    /// (reference keyframe's) correction.
    pub(super) fn optimize_essential_graph(
        &mut self,
        map: &mut Map,
        before: &HashMap<KeyFrameId, Sim3>,
        edges_before: &HashSet<(KeyFrameId, KeyFrameId)>,
        corrected: &HashMap<KeyFrameId, Sim3>,
        moved_by: &HashMap<MapPointId, KeyFrameId>,
        fixed: KeyFrameId,
    ) {
        let ids: Vec<KeyFrameId> = map.keyframes().map(|(id, _)| id).collect();
        let index: HashMap<KeyFrameId, u32> = ids
            .iter()
            .enumerate()
            .map(|(i, &id)| (id, i as u32))
            .collect();
        let now = |id: &KeyFrameId| corrected.get(id).or_else(|| before.get(id)).copied();
        let poses: Vec<Sim3> = ids
            .iter()
            .map(|id| now(id).unwrap_or(Sim3::identity()))
            .collect();
        let fixed_flags: Vec<bool> = ids.iter().map(|&id| id == fixed).collect();
        let mut edges = Vec::new();
        for (a, b) in map.essential_edges() {
            let (Some(&ia), Some(&ib)) = (index.get(&a), index.get(&b)) else {
                continue;
            };
            let (sa, sb) = if !edges_before.contains(&(a, b)) {
                (Some(&poses[ia as usize]), Some(&poses[ib as usize]))
            } else {
                (before.get(&a), before.get(&b))
            };
            let (Some(sa), Some(sb)) = (sa, sb) else {
                continue;
            };
            edges.push(PoseGraphEdge {
                i: ia,
                j: ib,
                s_ji: sim3_compose(sb, &sa.inverse()),
                weight: 1.0,
            });
        }
        let mut g = PoseGraph::new(poses.clone(), fixed_flags, edges);
        g.optimize(self.config.pose_graph_iterations);
        // Points: moved with their reference keyframe (from its pose before this step).
        let pts: Vec<(MapPointId, Option<KeyFrameId>)> =
            map.points().map(|(id, p)| (id, p.reference_kf)).collect();
        for (p, r) in pts {
            let Some(r) = moved_by.get(&p).copied().or(r).or_else(|| {
                map.point(p)
                    .and_then(|mp| mp.observations.first().map(|&(k, _)| k))
            }) else {
                continue;
            };
            let Some(&ir) = index.get(&r) else { continue };
            let (s_old, s_new) = (poses[ir as usize], g.poses[ir as usize]);
            if let Some(mp) = map.point_mut(p) {
                mp.position = s_new.inverse().transform(&s_old.transform(&mp.position));
            }
        }
        for (i, &id) in ids.iter().enumerate() {
            if let Some(k) = map.keyframe_mut(id) {
                k.t_cw = sim3_to_camera(&g.poses[i]);
            }
        }
        let all: Vec<MapPointId> = map.points().map(|(id, _)| id).collect();
        for p in all {
            map.update_point_geometry(p);
        }
    }
}

/// Loop fusion: the loop side's points replace the current side's duplicates in `kf` (and
/// are added where `kf` had none); then the loop edge, and the connections of `kf`, its
/// neighbours and the loop keyframe. Returns how many points were fused.
pub(super) fn fuse_and_link(
    map: &mut Map,
    kf: KeyFrameId,
    loop_kf: KeyFrameId,
    matched: &[Option<MapPointId>],
) -> usize {
    let neighbours: Vec<KeyFrameId> = map
        .keyframe(kf)
        .map(|k| k.covisibles.iter().map(|&(x, _)| x).collect())
        .unwrap_or_default();
    let mut fused = 0;
    for (i, m) in matched.iter().enumerate() {
        let Some(loop_p) = *m else { continue };
        if map.point(loop_p).is_none() {
            continue;
        }
        match map.keyframe(kf).and_then(|k| k.points[i]) {
            Some(cur) if cur != loop_p => {
                map.replace_point(cur, loop_p);
                fused += 1;
            }
            Some(_) => {}
            None => {
                map.add_observation(loop_p, kf, i);
                map.update_point_geometry(loop_p);
            }
        }
    }
    if let Some(k) = map.keyframe_mut(kf) {
        if !k.loop_edges.contains(&loop_kf) {
            k.loop_edges.push(loop_kf);
        }
    }
    if let Some(k) = map.keyframe_mut(loop_kf) {
        if !k.loop_edges.contains(&kf) {
            k.loop_edges.push(kf);
        }
    }
    for &n in neighbours.iter().chain([kf, loop_kf].iter()) {
        map.update_connections(n);
    }
    fused
}

pub(super) fn se3_to_sim3(t: &Se3) -> Sim3 {
    Sim3 {
        scale: 1.0,
        rotation: t.rotation,
        translation: t.translation.vector,
    }
}

/// The rigid pose of a similarity `S_cw` (translation divided by the scale; ORB-SLAM's
/// `[R t/s]`).
pub(super) fn sim3_to_camera(s: &Sim3) -> CameraFromWorld {
    CameraFromWorld(Se3::from_parts(
        nalgebra::Translation3::from(s.translation / s.scale),
        s.rotation,
    ))
}
