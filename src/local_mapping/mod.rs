//! Local mapping (ORB-SLAM, section "Local Mapping"), run per new keyframe: point geometry
//! updates, recent map-point culling, triangulation of new points with the best covisible
//! keyframes (epipolar search, parallax, positive depth, reprojection and scale checks),
//! duplicate fusion with the neighbours, local BA (the keyframe and its covisibles; keyframes that only see their points stay fixed), and
//! keyframe culling (90% of points seen by >= 3 others at the same or finer scale).

mod fusion;
pub use fusion::fuse_into;

use nalgebra::{Matrix3, Vector2};

use crate::camera_model::PinholeRadtan;
use crate::features::FeatureView;
use crate::geometry::epipolar::fundamental_from_poses;
use crate::geometry::triangulate::{triangulate_checked, TriangulationChecks};
use crate::map::{KeyFrameId, Map, MapPointId};
use crate::matching::search::{search_for_triangulation, EpipolarSearch};
use crate::optimize::{BaObservation, BaOptions, BaProblem, BundleAdjuster};

pub use crate::config::LocalMappingConfig;

/// Runs a step of local mapping with the map (locked for the step, in threaded mode).
pub type MapAccess<'a> = dyn FnMut(&mut dyn FnMut(&mut Map)) + 'a;

pub struct LocalMapper {
    pub config: LocalMappingConfig,
    camera: PinholeRadtan,
    k: Matrix3<f64>,
    sigma2: Vec<f64>,
    scales: Vec<f64>,
    recent: Vec<MapPointId>,
    ba: BundleAdjuster,
    problem: BaProblem,
    pairs: Vec<(u32, u32)>,
    has_ba: bool,
    /// The map's correction epoch when the BA problem was copied out.
    ba_epoch: u64,
    ba_poses: Vec<KeyFrameId>,
    ba_points: Vec<MapPointId>,
    obs_src: Vec<(MapPointId, KeyFrameId)>,
    /// Keyframes erased by culling (reported).
    pub culled_keyframes: usize,
}

impl LocalMapper {
    pub fn new(camera: PinholeRadtan, scales: &[f64]) -> Self {
        LocalMapper {
            config: LocalMappingConfig::default(),
            k: camera.k(),
            camera,
            sigma2: scales.iter().map(|s| s * s).collect(),
            scales: scales.to_vec(),
            recent: Vec::new(),
            ba: BundleAdjuster::new(),
            problem: BaProblem::default(),
            pairs: Vec::new(),
            has_ba: false,
            ba_epoch: 0,
            ba_poses: Vec::new(),
            ba_points: Vec::new(),
            obs_src: Vec::new(),
            culled_keyframes: 0,
        }
    }

    /// Processes a keyframe just inserted by tracking (its observations already added), all
    /// under the caller's access to the map (deterministic mode).
    pub fn process(&mut self, map: &mut Map, kf: KeyFrameId) {
        if self.prepare(map, kf) {
            self.solve();
        }
        self.finish(map, kf);
    }

    /// Phase 1 (map locked): geometry, connections, point culling, triangulation, and the local
    /// BA problem copied out of the map. Returns whether there is a BA to solve.
    pub fn prepare(&mut self, map: &mut Map, kf: KeyFrameId) -> bool {
        self.prepare_in_steps(kf, &mut |f: &mut dyn FnMut(&mut Map)| f(map))
    }

    /// [`prepare`](Self::prepare) as a sequence of short steps, each run through `access`
    /// (which locks the map for it): the start, one triangulation neighbour per step, then
    /// fusion and the BA copy. A threaded caller releases the map between steps so tracking
    /// never waits for a whole triangulation (10-20 ms with 20 neighbours). Tracking may
    /// change the map between steps; every step re-reads what it uses.
    pub fn prepare_in_steps(&mut self, kf: KeyFrameId, access: &mut MapAccess<'_>) -> bool {
        let mut neighbours = Vec::new();
        access(&mut |map: &mut Map| {
            let pts: Vec<MapPointId> = map
                .keyframe(kf)
                .map(|k| k.observed().map(|(_, p)| p).collect())
                .unwrap_or_default();
            for p in pts {
                map.update_point_geometry(p);
            }
            map.update_connections(kf);
            self.cull_points(map, kf);
            if let Some(k) = map.keyframe(kf) {
                neighbours.extend(k.best_covisibles(self.config.triangulation_neighbours));
            }
        });
        let mut created = Vec::new();
        for &n in &neighbours {
            access(&mut |map: &mut Map| self.triangulate_pair(map, kf, n, &mut created));
        }
        // Duplicate fusion: the new keyframe's points into each neighbour (a step each), then
        // the neighbours' points into it.
        let mut plan = None;
        tracing::debug!(
            keyframe = ?kf,
            neighbours = neighbours.len(),
            created = created.len(),
            "keyframe triangulated"
        );
        access(&mut |map: &mut Map| {
            self.recent.append(&mut created);
            map.update_connections(kf);
            plan = fusion::fusion_targets(map, kf, self.config.triangulation_neighbours);
        });
        if let Some((targets, own)) = plan {
            for &t in &targets {
                access(&mut |map: &mut Map| {
                    fusion::fuse_into(map, &self.camera, &self.scales, t, &own, 3.0);
                });
            }
            access(&mut |map: &mut Map| {
                fusion::fuse_neighbours_into(map, &self.camera, &self.scales, kf, &targets);
            });
        }
        let mut has_ba = false;
        access(&mut |map: &mut Map| {
            has_ba = keyframes_in_map_of(map, kf) > 2 && self.build_local_ba(map, kf);
            self.ba_epoch = map.correction_epoch();
        });
        self.has_ba = has_ba;
        has_ba
    }

    /// Phase 2 (map not locked): local BA on the copied problem.
    pub fn solve(&mut self) {
        if !self.has_ba {
            return;
        }
        let p = &mut self.problem;
        let cfg = &self.config;
        self.ba.solve(
            p,
            &BaOptions {
                iterations: cfg.ba_iterations_robust,
                ..BaOptions::default()
            },
        );
        p.classify_outliers(5.991);
        self.ba.solve(
            p,
            &BaOptions {
                iterations: cfg.ba_iterations,
                robust_delta2: None,
                ..BaOptions::default()
            },
        );
        p.excluded.iter_mut().for_each(|e| *e = false);
        p.classify_outliers(5.991);
    }

    /// Phase 3 (map locked): write the BA result back (entities erased meanwhile are skipped),
    /// drop outlier observations, cull redundant keyframes. A result solved from poses that a
    /// loop correction or full BA has since moved is dropped: writing it would undo that.
    pub fn finish(&mut self, map: &mut Map, kf: KeyFrameId) {
        if self.has_ba {
            if self.ba_epoch == map.correction_epoch() {
                self.write_back(map);
            }
            self.has_ba = false;
        }
        self.cull_keyframes(map, kf);
    }

    fn cull_points(&mut self, map: &mut Map, kf: KeyFrameId) {
        let cur = map.keyframe(kf).map_or(0, |k| k.serial);
        let cfg = &self.config;
        let mut keep = Vec::with_capacity(self.recent.len());
        for &p in &self.recent {
            let Some(mp) = map.point(p) else { continue };
            let age = cur.saturating_sub(mp.first_kf_serial);
            if mp.found_ratio() < cfg.min_found_ratio
                || (age >= 2 && mp.observations.len() <= cfg.min_observations)
            {
                map.erase_point(p);
            } else if age < 3 {
                keep.push(p);
            }
        }
        self.recent = keep;
    }

    /// Triangulates new points between `kf` and each of `neighbours` (unmatched keypoints,
    /// epipolar search, parallax/reprojection/scale checks), then updates `kf`'s connections.
    /// Also used with keyframes chosen by time when poses are given (offline densification).
    pub fn triangulate_with(&mut self, map: &mut Map, kf: KeyFrameId, neighbours: &[KeyFrameId]) {
        let mut created = Vec::new();
        for &n in neighbours {
            self.triangulate_pair(map, kf, n, &mut created);
        }
        self.recent.extend(created);
        map.update_connections(kf);
    }

    /// Triangulates new points between `kf` and neighbour `n`, appending them to `created`.
    fn triangulate_pair(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        n: KeyFrameId,
        created: &mut Vec<MapPointId>,
    ) {
        let new_pts = {
            let (Some(k1), Some(k2)) = (map.keyframe(kf), map.keyframe(n)) else {
                return;
            };
            let t1 = k1.t_cw;
            let c1 = t1.center();
            // Baseline against the neighbour's scene depth (monocular: skip tiny baselines).
            let baseline = (k2.t_cw.center() - c1).norm();
            let depths: Vec<f64> = k2
                .observed()
                .filter_map(|(_, p)| map.point(p))
                .map(|p| k2.t_cw.transform(&p.position).z)
                .collect();
            // (A neighbour without points yet, as with given poses, is not checked.)
            if !depths.is_empty() {
                let mut d = depths.clone();
                d.sort_by(|a, b| a.total_cmp(b));
                if baseline / d[d.len() / 2] < 0.01 {
                    return;
                }
            }
            let Some(f21) = fundamental_from_poses(&self.k, &t1, &self.k, &k2.t_cw) else {
                return;
            };
            let epi = k2.t_cw.transform(&c1);
            let epipole = (epi.z > 1e-9).then(|| {
                Vector2::new(
                    self.camera.fx * epi.x / epi.z + self.camera.cx,
                    self.camera.fy * epi.y / epi.z + self.camera.cy,
                )
            });
            let free1: Vec<bool> = k1.points.iter().map(|p| p.is_none()).collect();
            let free2: Vec<bool> = k2.points.iter().map(|p| p.is_none()).collect();
            let search = EpipolarSearch {
                f21: &f21,
                epipole2: epipole,
                sigma2: &self.sigma2,
                check_orientation: true,
            };
            search_for_triangulation(
                FeatureView::new(&k1.keypoints, &k1.descriptors),
                &free1,
                FeatureView::new(&k2.keypoints, &k2.descriptors),
                &free2,
                &search,
                &mut self.pairs,
            );
            let t_21 = k2.t_cw.0 * t1.0.inverse();
            let mut new_pts = Vec::new();
            for &(i, j) in &self.pairs {
                let (a, b) = (&k1.keypoints[i as usize], &k2.keypoints[j as usize]);
                let checks = TriangulationChecks {
                    max_cos_parallax: 0.9998,
                    max_sq_error_1: 5.991 * self.sigma2[a.octave as usize],
                    max_sq_error_2: 5.991 * self.sigma2[b.octave as usize],
                    k: self.camera.intrinsics(),
                };
                let Ok(p1) = triangulate_checked(
                    &Vector2::new(a.ux as f64, a.uy as f64),
                    &Vector2::new(b.ux as f64, b.uy as f64),
                    &t_21,
                    &checks,
                ) else {
                    continue;
                };
                let pw = t1.inverse().transform(&p1);
                // Scale consistency: distance ratio vs octave ratio within 1.5x.
                let (d1, d2) = ((pw - c1).norm(), (pw - k2.t_cw.center()).norm());
                if d1 <= 0.0 || d2 <= 0.0 {
                    continue;
                }
                let ratio_dist = d2 / d1;
                let ratio_oct =
                    (self.sigma2[a.octave as usize] / self.sigma2[b.octave as usize]).sqrt();
                if ratio_dist * 1.5 < ratio_oct || ratio_dist > ratio_oct * 1.5 {
                    continue;
                }
                new_pts.push((i, j, pw));
            }
            new_pts
        };
        for (i, j, pw) in new_pts {
            // A keypoint may have been taken by a previous neighbour in this loop.
            if map
                .keyframe(kf)
                .is_some_and(|k| k.points[i as usize].is_some())
                || map
                    .keyframe(n)
                    .is_some_and(|k| k.points[j as usize].is_some())
            {
                continue;
            }
            let Ok(p) = map.insert_two_view_point(pw, (kf, i as usize), (n, j as usize)) else {
                return;
            };
            created.push(p);
        }
    }

    fn build_local_ba(&mut self, map: &Map, kf: KeyFrameId) -> bool {
        let Some(k) = map.keyframe(kf) else {
            return false;
        };
        let mut local: Vec<KeyFrameId> = vec![kf];
        local.extend(k.covisibles.iter().map(|&(f, _)| f));
        self.ba_points.clear();
        let mut seen = std::collections::HashSet::new();
        for &l in &local {
            if let Some(lk) = map.keyframe(l) {
                for (_, p) in lk.observed() {
                    if seen.insert(p) {
                        self.ba_points.push(p);
                    }
                }
            }
        }
        // Fixed: keyframes seeing local points but not local themselves; the first keyframe.
        self.ba_poses.clear();
        self.ba_poses.extend_from_slice(&local);
        let mut fixed: Vec<bool> = local
            .iter()
            .map(|&l| map.keyframe(l).is_some_and(|k| k.parent.is_none()))
            .collect();
        let mut pose_index = std::collections::HashMap::new();
        for (i, &l) in self.ba_poses.iter().enumerate() {
            pose_index.insert(l, i as u32);
        }
        let p = &mut self.problem;
        p.k = self.camera.intrinsics();
        p.points.clear();
        p.observations.clear();
        p.excluded.clear();
        self.obs_src.clear();
        for (j, &mp) in self.ba_points.iter().enumerate() {
            let Some(m) = map.point(mp) else { continue };
            p.points.push(m.position);
            for &(okf, i) in &m.observations {
                let Some(ok) = map.keyframe(okf) else {
                    continue;
                };
                let poses = &mut self.ba_poses;
                let idx = *pose_index.entry(okf).or_insert_with(|| {
                    poses.push(okf);
                    fixed.push(true);
                    (poses.len() - 1) as u32
                });
                let kp = &ok.keypoints[i as usize];
                p.observations.push(BaObservation {
                    pose: idx,
                    point: j as u32,
                    uv: Vector2::new(kp.ux as f64, kp.uy as f64),
                    inv_sigma2: 1.0 / self.sigma2[kp.octave as usize],
                });
                self.obs_src.push((mp, okf));
            }
        }
        let poses = &self.ba_poses;
        // A young map (one pose fixed: its first keyframe) that started at low parallax and in
        // which no keyframe yet sees the first one's points from a wide angle.
        if let Some(first) = (fixed.iter().filter(|&&f| f).count() < 2)
            .then(|| (0..poses.len()).find(|&i| fixed[i]))
            .flatten()
        {
            let serial = |i: usize| map.keyframe(poses[i]).map_or(u64::MAX, |k| k.serial);
            // Each free keyframe's parallax with the first: the oldest one's is the initial
            // pair's, the largest the widest.
            let (mut second, mut widest) = (None::<(u64, Option<f64>)>, None::<f64>);
            for i in (0..poses.len()).filter(|&i| !fixed[i]) {
                let par = pair_parallax_deg(map, poses[first], poses[i]);
                if second.is_none_or(|(s, _)| serial(i) < s) {
                    second = Some((serial(i), par));
                }
                widest = match (widest, par) {
                    (Some(w), Some(p)) => Some(w.max(p)),
                    (w, p) => w.or(p),
                };
            }
            let weak_start =
                second.is_some_and(|(_, p)| p.is_some_and(|p| p < WEAK_PAIR_PARALLAX_DEG));
            if weak_start && widest.is_some_and(|p| p < WIDE_KEYFRAME_PARALLAX_DEG) {
                fix_scale_gauge(&mut fixed, serial);
            }
        }
        p.poses = self
            .ba_poses
            .iter()
            .map(|&l| {
                map.keyframe(l)
                    .map(|k| k.t_cw)
                    .unwrap_or_else(crate::geometry::CameraFromWorld::identity)
            })
            .collect();
        p.pose_fixed = fixed;
        !p.pose_fixed.iter().all(|&f| f)
    }

    fn write_back(&mut self, map: &mut Map) {
        let p = &self.problem;
        for (i, &l) in self.ba_poses.iter().enumerate() {
            if !p.pose_fixed[i] {
                if let Some(k) = map.keyframe_mut(l) {
                    k.t_cw = p.poses[i];
                }
            }
        }
        for (j, &mp) in self.ba_points.iter().enumerate() {
            if let Some(m) = map.point_mut(mp) {
                m.position = p.points[j];
            }
        }
        for (o, &(mp, okf)) in self.obs_src.iter().enumerate() {
            if p.excluded[o] {
                map.erase_observation(mp, okf);
            }
        }
        let mut erased = 0usize;
        for &mp in &self.ba_points {
            if depth_unobservable(map, mp) {
                map.erase_point(mp);
                erased += 1;
            } else {
                map.update_point_geometry(mp);
            }
        }
        // A rotation in place shows here first: most of a young map's points erased at once.
        tracing::trace!(
            points = self.ba_points.len(),
            depth_unobservable = erased,
            "local BA written back"
        );
    }

    fn cull_keyframes(&mut self, map: &mut Map, kf: KeyFrameId) {
        if keyframes_in_map_of(map, kf) < self.config.cull_after_keyframes {
            return;
        }
        let Some(k) = map.keyframe(kf) else { return };
        let candidates: Vec<KeyFrameId> = k.covisibles.iter().map(|&(f, _)| f).collect();
        for c in candidates {
            let Some(ck) = map.keyframe(c) else { continue };
            // The root, and keyframes holding a loop edge (the loop's record in the essential
            // graph, and the revisit test's shortcut), stay (as in ORB-SLAM).
            if ck.parent.is_none() || !ck.loop_edges.is_empty() {
                continue;
            }
            let (mut total, mut redundant) = (0usize, 0usize);
            for (i, mp) in ck.observed() {
                let Some(p) = map.point(mp) else { continue };
                total += 1;
                if p.observations.len() <= 3 {
                    continue;
                }
                let oct = ck.keypoints[i].octave;
                let others = p
                    .observations
                    .iter()
                    .filter(|&&(f, j)| {
                        f != c
                            && map
                                .keyframe(f)
                                .is_some_and(|fk| fk.keypoints[j as usize].octave <= oct + 1)
                    })
                    .count();
                if others >= 3 {
                    redundant += 1;
                }
            }
            if total > 0
                && redundant as f64 > self.config.redundancy * total as f64
                && map.erase_keyframe(c)
            {
                self.culled_keyframes += 1;
            }
        }
    }
}

/// Monocular BA is free up to a similarity, so one fixed keyframe leaves the scale free. In a
/// young map every keyframe is local and only the first is fixed; there local BA shrank the
/// initial pair's baseline while the depths stayed (desk with 1750 features: 0.016 -> 0.008
/// over 5 keyframes), its points' rays closed below the kept parallax, and the map starved.
/// So while fewer than two poses are fixed, the initial pair's points have a median parallax
/// under [`WEAK_PAIR_PARALLAX_DEG`] and no free keyframe sees the first one's points at
/// [`WIDE_KEYFRAME_PARALLAX_DEG`], the oldest free ones (by `serial`) are fixed too: in a
/// young map the initial pair's second keyframe. A wide keyframe releases it: on desk every
/// keyframe stays in the local window for most of the run, and keeping the second keyframe
/// fixed all that time doubled the cloud's median depth error (0.08 -> 0.16%).
fn fix_scale_gauge(fixed: &mut [bool], serial: impl Fn(usize) -> u64) {
    while fixed.iter().filter(|&&f| f).count() < 2 {
        let Some(i) = (0..fixed.len())
            .filter(|&i| !fixed[i])
            .min_by_key(|&i| serial(i))
        else {
            return;
        };
        fixed[i] = true;
    }
}

/// Median parallax of the points the two oldest keyframes of a young map share below which
/// local BA keeps the second one fixed (see [`fix_scale_gauge`]): three times the
/// initialisation's 1 deg minimum. desk's starts measure 0.8-1.7 deg, the highway's 0.9-1.2,
/// the blackout's new map 2.4; a fast orbit (9 deg per frame) 6.7, where its first keyframes
/// need BA to refine them.
const WEAK_PAIR_PARALLAX_DEG: f64 = 3.0;

/// Median parallax of the points the first keyframe shares with a free keyframe at which that
/// keyframe carries the scale on its own and the second is released (see
/// [`fix_scale_gauge`]). On desk the widest keyframe reaches 3 deg at the tenth local BA and
/// 10 deg at the twenty-fourth of about fifty that include the first keyframe. Released at 3
/// deg, the highway with 1750 features lost its scale again (4% of the path, 3 wrong `Ok`
/// frames); at 6 deg the outward loop's ATE tripled; never released, desk's cloud had twice
/// the median depth error (0.16%).
const WIDE_KEYFRAME_PARALLAX_DEG: f64 = 10.0;

/// Median parallax (degrees) of the points keyframes `a` and `b` both observe.
fn pair_parallax_deg(map: &Map, a: KeyFrameId, b: KeyFrameId) -> Option<f64> {
    let (ka, kb) = (map.keyframe(a)?, map.keyframe(b)?);
    let (ca, cb) = (ka.t_cw.center(), kb.t_cw.center());
    let mut angles: Vec<f64> = ka
        .observed()
        .filter_map(|(_, p)| map.point(p))
        .filter(|p| p.observations.iter().any(|&(k, _)| k == b))
        .map(|p| {
            let (ra, rb) = (p.position - ca, p.position - cb);
            (ra.dot(&rb) / (ra.norm() * rb.norm()))
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .collect();
    if angles.is_empty() {
        return None;
    }
    let mid = angles.len() / 2;
    Some(*angles.select_nth_unstable_by(mid, |x, y| x.total_cmp(y)).1)
}

/// Median scene depth of a keyframe's points (for scale normalisation and baselines).
pub fn median_depth(map: &Map, kf: KeyFrameId) -> Option<f64> {
    let k = map.keyframe(kf)?;
    let mut d: Vec<f64> = k
        .observed()
        .filter_map(|(_, p)| map.point(p))
        .map(|p| k.t_cw.transform(&p.position).z)
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(|a, b| a.total_cmp(b));
    Some(d[d.len() / 2])
}

/// Below half the triangulation gate's angle (1.15 degrees), the rays of a point's observations
/// no longer fix its depth.
const MIN_COS_PARALLAX_KEPT: f64 = 0.99995;

/// True when BA left point `mp` with a depth its observations cannot fix: behind one of its
/// cameras, or seen only along nearly parallel rays (e.g. every observer at the same place
/// after a rotation in place), where BA lets it drift towards infinity.
fn depth_unobservable(map: &Map, mp: crate::map::MapPointId) -> bool {
    let Some(p) = map.point(mp) else { return false };
    let mut rays: heapless::Vec<nalgebra::Vector3<f64>, 16> = heapless::Vec::new();
    for &(kf, _) in &p.observations {
        let Some(k) = map.keyframe(kf) else { continue };
        if k.t_cw.transform(&p.position).z <= 0.0 {
            return true;
        }
        let r = p.position - k.t_cw.center();
        let n = r.norm();
        if n > 0.0 && rays.push(r / n).is_err() {
            break;
        }
    }
    if rays.len() < 2 {
        return false;
    }
    let mut min_cos = 1.0f64;
    for i in 0..rays.len() {
        for j in i + 1..rays.len() {
            min_cos = min_cos.min(rays[i].dot(&rays[j]));
        }
    }
    min_cos > MIN_COS_PARALLAX_KEPT
}

/// Keyframes of the atlas map `kf` belongs to (a new map is young however big the others are).
fn keyframes_in_map_of(map: &Map, kf: KeyFrameId) -> usize {
    map.keyframe(kf).map_or(0, |k| map.n_keyframes_of(k.map_id))
}

#[cfg(test)]
mod tests {
    use super::fix_scale_gauge;

    #[test]
    fn a_young_map_fixes_its_two_oldest_keyframes() {
        // The root (serial 0) fixed, the initial pair's second (1) and two later ones free.
        let serials = [3, 0, 1, 2];
        let mut fixed = [false, true, false, false];
        fix_scale_gauge(&mut fixed, |i| serials[i]);
        assert_eq!(fixed, [false, true, true, false]);
    }

    #[test]
    fn two_fixed_keyframes_are_left_as_they_are() {
        let mut fixed = [false, true, false, true];
        fix_scale_gauge(&mut fixed, |i| i as u64);
        assert_eq!(fixed, [false, true, false, true]);
    }

    #[test]
    fn with_none_fixed_the_two_oldest_are_and_a_lone_pose_is_fixed_alone() {
        let mut fixed = [false; 3];
        fix_scale_gauge(&mut fixed, |i| [5, 9, 7][i]);
        assert_eq!(fixed, [true, false, true]);
        let mut one = [false];
        fix_scale_gauge(&mut one, |_| 0);
        assert_eq!(one, [true]);
    }
}
