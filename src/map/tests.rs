use super::*;
use crate::features::KeyPoint;

fn small() -> MapConfig {
    MapConfig {
        max_keyframes: 8,
        max_map_points: 200,
        max_features: 100,
        width: 64,
        height: 48,
        ..MapConfig::default()
    }
}

/// A keyframe with `n` keypoints spread over the image, camera at x = `x`.
fn add_kf(map: &mut Map, n: usize, x: f64) -> KeyFrameId {
    map.insert_keyframe(|k| {
        for i in 0..n {
            let kp = KeyPoint {
                x: (i % 60) as f32,
                y: (i / 60) as f32,
                ux: (i % 60) as f32,
                uy: (i / 60) as f32,
                ..Default::default()
            };
            k.keypoints.push(kp);
            k.descriptors.push([i as u64, 0, 0, 0]);
        }
        k.t_cw = crate::geometry::WorldFromCamera::from_parts(
            Vector3::new(x, 0.0, 0.0),
            nalgebra::UnitQuaternion::identity(),
        )
        .inverse();
    })
    .unwrap()
}

/// Points 0..n seen by both keyframes at the same keypoint index.
fn share(map: &mut Map, a: KeyFrameId, b: KeyFrameId, range: std::ops::Range<usize>) {
    for i in range {
        let p = map
            .insert_point(Vector3::new(i as f64 * 0.01, 0.0, 3.0), a)
            .unwrap();
        map.add_observation(p, a, i);
        map.add_observation(p, b, i);
    }
}

#[test]
fn covisibility_weights_threshold_and_parent() {
    let mut m = Map::new(small());
    let k0 = add_kf(&mut m, 100, 0.0);
    let k1 = add_kf(&mut m, 100, 0.1);
    let k2 = add_kf(&mut m, 100, 0.2);
    share(&mut m, k0, k1, 0..40);
    share(&mut m, k1, k2, 40..50); // 10 < 15: weak
    m.update_connections(k1);
    m.update_connections(k2);
    let c1 = &m.keyframe(k1).unwrap().covisibles;
    assert_eq!(c1[0], (k0, 40));
    // k2's only neighbour is weak but kept as the single strongest.
    assert_eq!(m.keyframe(k2).unwrap().covisibles, vec![(k1, 10)]);
    assert_eq!(m.keyframe(k1).unwrap().parent, Some(k0));
    assert_eq!(m.keyframe(k2).unwrap().parent, Some(k1));
    assert_eq!(m.keyframe(k0).unwrap().weight_with(k1), 40);
    assert!(m.keyframe(k0).unwrap().children.contains(&k1));
}

#[test]
fn erasing_a_keyframe_reparents_children_and_drops_orphan_points() {
    let mut m = Map::new(small());
    let k0 = add_kf(&mut m, 100, 0.0);
    let k1 = add_kf(&mut m, 100, 0.1);
    let k2 = add_kf(&mut m, 100, 0.2);
    share(&mut m, k0, k1, 0..30);
    share(&mut m, k1, k2, 30..60);
    share(&mut m, k0, k2, 60..80);
    for k in [k1, k2] {
        m.update_connections(k);
    }
    assert_eq!(m.keyframe(k2).unwrap().parent, Some(k1));
    let points_before = m.n_points();
    assert!(m.erase_keyframe(k1));
    assert!(m.keyframe(k1).is_none());
    // k2 re-attached to k0 (its only tree neighbour).
    assert_eq!(m.keyframe(k2).unwrap().parent, Some(k0));
    assert!(m.keyframe(k0).unwrap().children.contains(&k2));
    // Points seen by k1 and one other keyframe lost their second view: erased.
    assert_eq!(m.n_points(), points_before - 60);
    assert!(m.keyframe(k2).unwrap().points[30].is_none());
    assert!(m.keyframe(k2).unwrap().points[60].is_some());
    // The root cannot be erased.
    assert!(!m.erase_keyframe(k0));
    // A keyframe not connected yet (local mapping has not run on it) can, with its views.
    let k3 = add_kf(&mut m, 100, 0.3);
    share(&mut m, k0, k3, 80..90);
    assert!(m.keyframe(k3).is_some_and(|k| k.parent.is_none()));
    let points_before = m.n_points();
    assert!(m.erase_keyframe(k3));
    assert!(m.keyframe(k3).is_none());
    assert_eq!(
        m.n_points(),
        points_before - 10,
        "points it alone confirmed"
    );
    assert!(m.keyframe(k0).is_some_and(|k| !k.children.contains(&k3)));
}

#[test]
fn capacity_is_fixed_and_slots_recycle() {
    let mut m = Map::new(MapConfig {
        max_keyframes: 2,
        ..small()
    });
    let k0 = add_kf(&mut m, 10, 0.0);
    let k1 = add_kf(&mut m, 10, 0.1);
    assert_eq!(
        m.insert_keyframe(|_| {}).unwrap_err(),
        MapFull::KeyFrames(2)
    );
    share(&mut m, k0, k1, 0..20);
    m.update_connections(k1);
    assert!(m.erase_keyframe(k1));
    let k2 = add_kf(&mut m, 10, 0.2);
    assert_eq!(k2.index(), k1.index());
    assert!(m.keyframe(k1).is_none(), "the old handle stays stale");
    assert!(m.keyframe(k2).unwrap().serial > m.keyframe(k0).unwrap().serial);
}

#[test]
fn fusion_moves_observations_and_geometry_updates() {
    let mut m = Map::new(small());
    let k0 = add_kf(&mut m, 100, 0.0);
    let k1 = add_kf(&mut m, 100, 0.5);
    let k2 = add_kf(&mut m, 100, 1.0);
    let a = m.insert_point(Vector3::new(0.0, 0.0, 3.0), k0).unwrap();
    m.add_observation(a, k0, 5);
    m.add_observation(a, k1, 6);
    let b = m.insert_point(Vector3::new(0.0, 0.0, 3.0), k2).unwrap();
    m.add_observation(b, k2, 7);
    m.add_observation(b, k1, 8);
    m.replace_point(b, a);
    assert!(m.point(b).is_none());
    let p = m.point(a).unwrap();
    assert_eq!(p.observations.len(), 3, "k2 moved over; k1 already saw a");
    assert_eq!(m.keyframe(k2).unwrap().points[7], Some(a));
    assert_eq!(m.keyframe(k1).unwrap().points[8], None);
    assert!(p.max_distance > p.min_distance && p.max_distance.is_finite());
    assert!((p.normal.norm() - 1.0).abs() < 1e-9);
}

#[test]
fn essential_graph_keeps_tree_strong_and_loop_edges() {
    let mut m = Map::new(MapConfig {
        essential_min_weight: 50,
        ..small()
    });
    let k0 = add_kf(&mut m, 100, 0.0);
    let k1 = add_kf(&mut m, 100, 0.1);
    let k2 = add_kf(&mut m, 100, 0.2);
    share(&mut m, k0, k1, 0..60);
    share(&mut m, k1, k2, 60..90);
    share(&mut m, k0, k2, 90..100);
    m.update_connections(k1);
    m.update_connections(k2);
    assert_eq!(m.keyframe(k2).unwrap().parent, Some(k1));
    // Weak k0-k2 covisibility (10 < 50) enters only as a loop edge.
    m.keyframe_mut(k2).unwrap().loop_edges.push(k0);
    let e = m.essential_edges();
    assert!(e.contains(&(k0.min(k1), k0.max(k1))));
    assert!(e.contains(&(k1.min(k2), k1.max(k2))));
    assert!(e.contains(&(k0.min(k2), k0.max(k2))), "loop edge");
    assert_eq!(e.len(), 3);
}

#[test]
fn a_full_map_evicts_instead_of_growing() {
    let mut m = Map::new(MapConfig {
        max_keyframes: RECENT_PROTECTED + 3,
        max_map_points: 50,
        ..small()
    });
    let root = add_kf(&mut m, 100, 0.0);
    let mut prev = root;
    for i in 1..40 {
        let k = add_kf(&mut m, 100, i as f64 * 0.1);
        share(&mut m, prev, k, (i % 5) * 10..(i % 5) * 10 + 10);
        m.update_connections(k);
        prev = k;
        assert!(m.n_keyframes() <= RECENT_PROTECTED + 3);
        assert!(m.n_points() <= 50);
    }
    assert!(m.keyframe(root).is_some(), "the root is never evicted");
    assert!(m.keyframe(prev).is_some(), "the newest keyframe stays");
}

#[test]
fn a_point_moved_to_another_keypoint_leaves_no_dangling_slot() {
    let mut m = Map::new(small());
    let k0 = add_kf(&mut m, 100, 0.0);
    let k1 = add_kf(&mut m, 100, 0.5);
    let a = m.insert_point(Vector3::new(0.0, 0.0, 3.0), k0).unwrap();
    m.add_observation(a, k0, 5);
    m.add_observation(a, k1, 6);
    // The same keyframe now sees `a` at another keypoint: the old slot lets go of it.
    m.add_observation(a, k1, 9);
    assert_eq!(m.keyframe(k1).unwrap().points[6], None);
    assert_eq!(m.keyframe(k1).unwrap().points[9], Some(a));
    assert_eq!(m.point(a).unwrap().observations.len(), 2);
    // Erasing the point then leaves no keyframe pointing at it.
    m.erase_point(a);
    for k in [k0, k1] {
        assert!(m.keyframe(k).unwrap().observed().all(|(_, p)| p != a));
    }
}

/// Two maps of three keyframes each (a chain k0 - k1 - k2 sharing points), the second
/// started with `start_new_map`.
fn two_maps() -> (Map, [KeyFrameId; 3], [KeyFrameId; 3]) {
    let mut m = Map::new(MapConfig {
        max_keyframes: 8,
        max_map_points: 400,
        ..small()
    });
    let chain = |m: &mut Map| {
        let k = [
            add_kf(m, 100, 0.0),
            add_kf(m, 100, 0.1),
            add_kf(m, 100, 0.2),
        ];
        share(m, k[0], k[1], 0..40);
        share(m, k[1], k[2], 40..80);
        for &x in &k {
            m.update_connections(x);
        }
        k
    };
    let a = chain(&mut m);
    assert_eq!(m.start_new_map(), 1);
    let b = chain(&mut m);
    (m, a, b)
}

#[test]
fn a_new_map_keeps_to_itself_and_erasing_it_leaves_the_other() {
    let (mut m, a, b) = two_maps();
    assert_eq!(m.map_ids(), vec![0, 1]);
    assert!(a.iter().all(|&k| m.keyframe(k).unwrap().map_id == 0));
    assert!(b.iter().all(|&k| m.keyframe(k).unwrap().map_id == 1));
    assert_eq!(m.n_keyframes_of(1), 3);
    // Each map has its own root; no covisibility crosses between them.
    assert!(m.keyframe(b[0]).unwrap().parent.is_none());
    assert!(m
        .keyframe(b[0])
        .unwrap()
        .covisibles
        .iter()
        .all(|(k, _)| b.contains(k)));
    // A culled keyframe still tells its map.
    assert!(m.erase_keyframe(b[1]));
    assert_eq!(m.map_of(b[1]), Some(1));
    let points_a = m.keyframe(a[1]).unwrap().observed().count();
    m.erase_map(1);
    assert_eq!(m.map_ids(), vec![0]);
    assert_eq!(m.map_of(b[1]), None, "its tombstone went with the map");
    assert_eq!(m.keyframe(a[1]).unwrap().observed().count(), points_a);
    assert_eq!(m.n_points(), 80, "map 0's points stay, map 1's are gone");
}

#[test]
fn a_cancelled_new_map_gives_its_id_back() {
    let (mut m, _, _) = two_maps();
    assert_eq!(m.start_new_map(), 2);
    add_kf(&mut m, 10, 1.0);
    m.cancel_new_map(1);
    assert_eq!(m.active_map(), 1);
    assert_eq!(m.map_ids(), vec![0, 1]);
    assert_eq!(m.start_new_map(), 2);
}

#[test]
fn merging_retags_and_hangs_the_tree_under_the_anchor_with_one_root() {
    let (mut m, a, b) = two_maps();
    assert_eq!(m.active_map(), 1);
    // Joint b[2] (a leaf of map 1) under anchor a[1].
    m.merge_maps(1, 0, b[2], a[1]);
    assert_eq!(m.map_ids(), vec![0]);
    assert_eq!(m.active_map(), 0);
    assert_eq!(m.maps_merged(), 1);
    let roots: Vec<KeyFrameId> = m
        .keyframes()
        .filter(|(_, k)| k.parent.is_none())
        .map(|(id, _)| id)
        .collect();
    assert_eq!(roots, vec![a[0]]);
    // The old root is now below the joint: b[0] -> b[1] -> b[2] -> a[1].
    assert_eq!(m.keyframe(b[2]).unwrap().parent, Some(a[1]));
    assert_eq!(m.keyframe(b[1]).unwrap().parent, Some(b[2]));
    assert_eq!(m.keyframe(b[0]).unwrap().parent, Some(b[1]));
    assert!(m.keyframe(a[1]).unwrap().children.contains(&b[2]));
    assert!(m.keyframe(b[2]).unwrap().children.contains(&b[1]));
    assert!(!m.keyframe(b[1]).unwrap().children.contains(&b[2]));
    // Every keyframe reaches the root through its parents.
    for (id, _) in m.keyframes() {
        let mut at = id;
        for _ in 0..8 {
            match m.keyframe(at).unwrap().parent {
                Some(p) => at = p,
                None => break,
            }
        }
        assert_eq!(at, a[0]);
    }
}
