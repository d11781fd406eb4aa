//! Loop closing (ORB-SLAM, after Mur-Artal et al. 2015): a keyframe's bag of words finds
//! candidates in the keyframe database scoring above its worst covisible neighbour; a
//! candidate is accepted when candidates of 3 consecutive keyframes are covisibility-
//! consistent; the similarity between the keyframe and the candidate comes from matched map
//! points (Sim3 RANSAC with a few seeds; each distinct hypothesis refined on the reprojections
//! of the loop's points into a window of the keyframe and its best covisibles, the one with
//! the most inliers taken, refused while its scale is poorly fixed or a different solution
//! is nearly as good; then >= 40 matches by projection); the keyframe and its
//! neighbours are corrected by it, duplicated points fused, and the essential graph optimised
//! as a Sim3 pose graph with the loop keyframe fixed, moving every keyframe and point.
//!
//! When the drift around a loop is small, tracking finds the old place's points by projection
//! before any of this runs, and bag-of-words detection (which skips covisible keyframes) has
//! nothing left to find. Such a loop shows as a covisibility edge between keyframes that are
//! close in space but far apart along the path travelled between them (`revisit.rs`); it gets
//! the same loop edge, loop fusion and full BA, but no pose correction (tracking already made
//! the new keyframe agree with the old place).

mod correction;
use correction::{fuse_and_link, se3_to_sim3};
mod revisit;

mod global_ba;

pub use global_ba::GlobalBaJob;

use std::collections::{HashMap, HashSet};

use nalgebra::{Matrix3, Vector2};

use crate::camera_model::PinholeRadtan;
use crate::features::Descriptor;
use crate::geometry::sim3::{sim3_ransac, Sim3Matches, Sim3RansacConfig};
use crate::geometry::{CameraFromWorld, Se3, Sim3};
use crate::map::{KeyFrameId, Map, MapPointId};
use crate::matching::hamming;
use crate::optimize::lie::sim3_compose;
use crate::optimize::{
    optimize_window_sim3, window_sim3_covariance, PoseGraph, PoseGraphEdge, WindowObservation,
};
use crate::place_recognition::{l1_score, BowVector};

pub use crate::config::LoopClosingConfig;

/// Runs a step of loop closing with the map (locked for the step, in threaded mode).
pub type MapAccess<'a> = dyn FnMut(&mut dyn FnMut(&mut Map)) + 'a;

/// Keyframes of the current side, besides the current one, over which a loop's similarity is
/// refined.
const WINDOW_KEYFRAMES: usize = 5;

/// Sim3 RANSAC runs (seeds) whose distinct hypotheses are refined and compared.
const SIM3_HYPOTHESES: u64 = 4;

/// The best refined hypothesis must have this many times the window inliers of any different
/// solution.
const AMBIGUITY_RATIO: f64 = 1.5;

/// Refined similarities placing the current keyframe within 2% of the map's unit scene depth
/// and 1 deg of each other: one solution reached from two hypotheses.
fn same_solution(a: &Sim3, b: &Sim3) -> bool {
    let centre = |s: &Sim3| s.inverse().translation;
    (centre(a) - centre(b)).norm() < 0.02 && a.rotation.angle_to(&b.rotation) < 1f64.to_radians()
}

/// Two similarities within a millimetre-and-milliradian of each other (one hypothesis found
/// twice).
fn same_similarity(a: &Sim3, b: &Sim3) -> bool {
    (a.translation - b.translation).norm() < 1e-3
        && a.rotation.angle_to(&b.rotation) < 1e-3
        && (a.scale / b.scale - 1.0).abs() < 1e-3
}

pub use crate::place_recognition::PlaceIndex;

/// How a loop was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoopKind {
    /// Bag-of-words detection, Sim3 and a pose correction.
    Place,
    /// Tracking had already joined the old place (see `revisit.rs`): no pose correction.
    Revisit,
    /// The candidate is in another map of the atlas: the keyframe's whole map is moved into
    /// the candidate's by the Sim3 and the two become one.
    Merge,
}

/// What a closed loop did.
#[derive(Clone, Debug)]
pub struct LoopReport {
    pub kind: LoopKind,
    pub keyframe: KeyFrameId,
    pub loop_keyframe: KeyFrameId,
    pub matches: usize,
    pub fused_points: usize,
}

/// One closed loop as the run report lists it: keyframes by timestamp, so it can be checked
/// against ground truth.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LoopRecord {
    pub kind: &'static str,
    /// The keyframe that closed the loop, and the old keyframe it was joined to.
    pub timestamp: f64,
    pub loop_timestamp: f64,
    pub matches: usize,
    pub fused_points: usize,
}

/// Loops listed per run at most (the counters go on).
const MAX_LOOP_RECORDS: usize = 256;

pub struct LoopCloser {
    pub config: LoopClosingConfig,
    camera: PinholeRadtan,
    k: Matrix3<f64>,
    sigma2: Vec<f64>,
    /// Consistent groups of the previous keyframe: (group, consistency count).
    groups: Vec<(HashSet<KeyFrameId>, usize)>,
    last_loop_serial: u64,
    pub loops_closed: usize,
    /// Of `loops_closed`, those found as revisits.
    pub revisits_closed: usize,
    /// The loops closed, in order (the first 256).
    pub history: Vec<LoopRecord>,
}

impl LoopCloser {
    pub fn new(camera: PinholeRadtan, scales: &[f64]) -> Self {
        LoopCloser {
            config: LoopClosingConfig::default(),
            k: camera.k(),
            camera,
            sigma2: scales.iter().map(|s| s * s).collect(),
            groups: Vec::new(),
            last_loop_serial: 0,
            loops_closed: 0,
            revisits_closed: 0,
            history: Vec::new(),
        }
    }

    /// Detects and closes a loop at keyframe `kf` (just mapped), all under the caller's access
    /// to the map (deterministic mode). `index` gives its bag of words and the candidates.
    pub fn process(
        &mut self,
        map: &mut Map,
        index: &PlaceIndex,
        kf: KeyFrameId,
    ) -> Option<LoopReport> {
        let candidates = self.candidates(map, index, kf);
        self.close_in_steps(kf, candidates, &mut |step: &mut dyn FnMut(&mut Map)| {
            step(map)
        })
    }

    /// Loop detection for `kf` (map and place index locked by the caller): the candidates
    /// consistent over the last keyframes. Runs on every keyframe: it carries the consistency
    /// groups forward.
    pub fn candidates(&mut self, map: &Map, index: &PlaceIndex, kf: KeyFrameId) -> Vec<KeyFrameId> {
        self.detect(map, index, kf).unwrap_or_default()
    }

    /// Closes a loop at `kf` with the first of `candidates` that verifies (else a revisit), in
    /// short steps each run through `access` (which locks the map for it): the hypotheses of one
    /// candidate, the refinement of one hypothesis, the correction. A threaded caller releases
    /// the map between steps, so tracking waits for one step at most; every step re-reads
    /// what it uses.
    pub fn close_in_steps(
        &mut self,
        kf: KeyFrameId,
        candidates: Vec<KeyFrameId>,
        access: &mut MapAccess<'_>,
    ) -> Option<LoopReport> {
        let mut report = None;
        for c in candidates {
            let mut hypotheses = Vec::new();
            access(&mut |map: &mut Map| hypotheses = self.hypotheses(map, kf, c));
            // The hypothesis the most window matches agree with (see `hypotheses`); when a
            // different solution is nearly as good, the place is ambiguous and the loop waits
            // for a later keyframe.
            let mut refined: Vec<(Sim3, usize)> = Vec::new();
            for h in &hypotheses {
                access(&mut |map: &mut Map| {
                    refined.extend(self.refine_over_window(map, kf, c, h));
                });
            }
            if let Some(&(s_cw, n)) = refined.iter().max_by_key(|r| r.1) {
                let rival = refined
                    .iter()
                    .filter(|r| !same_solution(&r.0, &s_cw))
                    .map(|r| r.1)
                    .max()
                    .unwrap_or(0);
                if n as f64 >= AMBIGUITY_RATIO * rival as f64 {
                    access(&mut |map: &mut Map| report = self.close_with(map, kf, c, &s_cw));
                }
            }
            if report.is_some() {
                break;
            }
        }
        if report.is_none() {
            access(&mut |map: &mut Map| {
                report = self
                    .detect_revisit(map, kf)
                    .and_then(|c| self.close_revisit(map, kf, c));
            });
        }
        let r = report?;
        access(&mut |map: &mut Map| self.note_closed(map, kf, &r));
        Some(r)
    }

    /// Counts, records and logs a closed loop; detection starts afresh.
    fn note_closed(&mut self, map: &Map, kf: KeyFrameId, r: &LoopReport) {
        self.loops_closed += 1;
        if r.kind == LoopKind::Revisit {
            self.revisits_closed += 1;
        }
        if self.history.len() < MAX_LOOP_RECORDS {
            let stamp = |k| map.keyframe(k).map_or(f64::NAN, |k| k.timestamp);
            self.history.push(LoopRecord {
                kind: match r.kind {
                    LoopKind::Place => "place",
                    LoopKind::Revisit => "revisit",
                    LoopKind::Merge => "merge",
                },
                timestamp: stamp(r.keyframe),
                loop_timestamp: stamp(r.loop_keyframe),
                matches: r.matches,
                fused_points: r.fused_points,
            });
        }
        tracing::info!(kind = ?r.kind, matches = r.matches, fused = r.fused_points, "loop closed");
        self.groups.clear();
        self.last_loop_serial = map.keyframe(kf).map_or(0, |k| k.serial);
    }

    /// Whether `kf` may close a loop at all: enough keyframes, and not too soon after the last.
    fn may_close(&self, map: &Map, kf: KeyFrameId) -> bool {
        map.keyframe(kf).is_some_and(|k| {
            map.n_keyframes() >= self.config.min_keyframes_between_loops
                && k.serial
                    >= self.last_loop_serial + self.config.min_keyframes_between_loops as u64
        })
    }

    /// Candidates consistent over `covisibility_consistency` consecutive keyframes.
    fn detect(&mut self, map: &Map, index: &PlaceIndex, kf: KeyFrameId) -> Option<Vec<KeyFrameId>> {
        let k = map.keyframe(kf)?;
        if !self.may_close(map, kf) {
            return None;
        }
        let key = k.serial as u32;
        let bow: &BowVector = index.database.bow(key)?;
        let connected: HashSet<KeyFrameId> = k.covisibles.iter().map(|&(c, _)| c).collect();
        let mut min_score = 1.0f32;
        for c in &connected {
            if let Some(b) = map
                .keyframe(*c)
                .and_then(|ck| index.database.bow(ck.serial as u32))
            {
                min_score = min_score.min(l1_score(bow, b));
            }
        }
        let hits = index.database.query(bow, min_score, 50, |h| {
            h == key
                || index
                    .keys
                    .get(&h)
                    .is_none_or(|id| connected.contains(id) || map.keyframe(*id).is_none())
        });
        // ORB-SLAM's accumulated score: a candidate's group (it and its 10 best covisibles
        // among the hits) sums their scores; the best keyframe of each group above 0.75 of
        // the best group score goes on.
        let score: HashMap<KeyFrameId, f32> = hits
            .iter()
            .filter_map(|&(h, s)| index.keys.get(&h).map(|&id| (id, s)))
            .collect();
        let mut groups_acc: Vec<(KeyFrameId, f32)> = Vec::new();
        for (&id, &s0) in &score {
            let Some(ck) = map.keyframe(id) else { continue };
            let (mut acc, mut best, mut best_id) = (s0, s0, id);
            for (n, _) in ck.covisibles.iter().take(10) {
                if let Some(&sn) = score.get(n) {
                    acc += sn;
                    if sn > best {
                        best = sn;
                        best_id = *n;
                    }
                }
            }
            groups_acc.push((best_id, acc));
        }
        let best_acc = groups_acc.iter().map(|g| g.1).fold(0.0f32, f32::max);
        let mut hits: Vec<KeyFrameId> = groups_acc
            .iter()
            .filter(|g| g.1 > 0.75 * best_acc)
            .map(|g| g.0)
            .collect();
        hits.sort();
        hits.dedup();
        let mut current: Vec<(HashSet<KeyFrameId>, usize)> = Vec::new();
        let mut accepted = Vec::new();
        for cand in hits {
            let Some(ck) = map.keyframe(cand) else {
                continue;
            };
            let mut group: HashSet<KeyFrameId> = ck.covisibles.iter().map(|&(c, _)| c).collect();
            group.insert(cand);
            let mut best = 0;
            for (g, n) in &self.groups {
                if !g.is_disjoint(&group) {
                    best = best.max(*n + 1);
                }
            }
            let count = best.max(1);
            if count >= self.config.covisibility_consistency {
                accepted.push(cand);
            }
            current.push((group, count));
        }
        tracing::debug!(
            keyframe = ?kf,
            candidates = current.len(),
            best_consistency = current.iter().map(|g| g.1).max().unwrap_or(0),
            accepted = accepted.len(),
            "loop candidates"
        );
        self.groups = current;
        (!accepted.is_empty()).then_some(accepted)
    }

    /// Similarity hypotheses `S_cw` of `kf` in the frame of candidate `c`, from their map points
    /// matched by descriptor: RANSAC over Horn's closed form with a few seeds, the distinct
    /// solutions. The 3D fit of its few inliers, often one patch of the image (a far wall: a
    /// plane leaves two poses that fit its points about equally well), can take the wrong one
    /// of two poses; each hypothesis is refined over a window of `kf` and its best covisibles
    /// and the one the most matches agree with is taken (a merge was placed half a metre off
    /// by the first seed's hypothesis: 381 window inliers, against 772 for the right one).
    fn hypotheses(&self, map: &Map, kf: KeyFrameId, c: KeyFrameId) -> Vec<Sim3> {
        let (Some(k1), Some(k2)) = (map.keyframe(kf), map.keyframe(c)) else {
            return Vec::new();
        };
        // Map points of both keyframes matched by descriptor (ratio 0.75, unique).
        let pts2: Vec<(usize, MapPointId)> = k2.observed().collect();
        let mut pairs: Vec<(usize, usize, MapPointId, MapPointId)> = Vec::new();
        let mut taken: HashSet<usize> = HashSet::new();
        for (i, mp1) in k1.observed() {
            let d1: &Descriptor = &k1.descriptors[i];
            let (mut b, mut s, mut bj) = (u32::MAX, u32::MAX, usize::MAX);
            for (jj, &(j, _)) in pts2.iter().enumerate() {
                let d = hamming(d1, &k2.descriptors[j]);
                if d < b {
                    s = b;
                    b = d;
                    bj = jj;
                } else if d < s {
                    s = d;
                }
            }
            if bj != usize::MAX && b <= 50 && (b as f32) < 0.75 * s as f32 && taken.insert(bj) {
                let (j, mp2) = pts2[bj];
                if mp1 != mp2 {
                    pairs.push((i, j, mp1, mp2));
                }
            }
        }
        if pairs.len() < 20 {
            return Vec::new();
        }
        let (t1, t2) = (k1.t_cw, k2.t_cw);
        let mut p1 = Vec::with_capacity(pairs.len());
        let mut p2 = Vec::with_capacity(pairs.len());
        let (mut u1, mut u2, mut s1, mut s2) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for &(i, j, a, b) in &pairs {
            let (Some(pa), Some(pb)) = (map.point(a), map.point(b)) else {
                continue;
            };
            p1.push(t1.transform(&pa.position));
            p2.push(t2.transform(&pb.position));
            let (ka, kb) = (&k1.keypoints[i], &k2.keypoints[j]);
            u1.push(Vector2::new(ka.ux as f64, ka.uy as f64));
            u2.push(Vector2::new(kb.ux as f64, kb.uy as f64));
            s1.push(self.sigma2[ka.octave as usize]);
            s2.push(self.sigma2[kb.octave as usize]);
        }
        let m = Sim3Matches {
            p1: &p1,
            u1: &u1,
            sigma2_1: &s1,
            p2: &p2,
            u2: &u2,
            sigma2_2: &s2,
        };
        let mut tried: Vec<Sim3> = Vec::new();
        for seed in 0..SIM3_HYPOTHESES {
            let cfg = Sim3RansacConfig {
                seed,
                ..Sim3RansacConfig::default()
            };
            let Some(sol) = sim3_ransac(&m, &self.k, &self.k, &cfg) else {
                continue;
            };
            let s_cw = sim3_compose(&sol.s12, &se3_to_sim3(&t2.0));
            if !tried.iter().any(|t| same_similarity(t, &s_cw)) {
                tried.push(s_cw);
            }
        }
        tried
    }

    /// The loop at `kf` with candidate `c` and the verified `s_cw`: at least `min_matches`
    /// matches by projection, then the correction.
    fn close_with(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        c: KeyFrameId,
        s_cw: &Sim3,
    ) -> Option<LoopReport> {
        let mut matched: Vec<Option<MapPointId>> = vec![None; map.keyframe(kf)?.keypoints.len()];
        let n_matches = self.match_loop_group(map, kf, c, s_cw, &mut matched);
        if n_matches < self.config.min_matches {
            return None;
        }
        Some(self.correct(map, kf, c, s_cw, &matched, n_matches))
    }

    /// `s_cw` refined over a window of `kf` and its best covisibles (at their poses relative
    /// to `kf`, as their own map has them): the loop group's points are matched by projection
    /// into each, and [`optimize_window_sim3`] fits the one similarity to all of them; twice,
    /// the second time matching with the refined similarity. Returns it and its inliers, or
    /// None with fewer than `min_matches` inliers.
    fn refine_over_window(
        &self,
        map: &Map,
        kf: KeyFrameId,
        c: KeyFrameId,
        s_cw: &Sim3,
    ) -> Option<(Sim3, usize)> {
        let (k, loop_kf) = (map.keyframe(kf)?, map.keyframe(c)?);
        // Only keyframes the correction moves with `kf`: not the loop side (`c` and its
        // covisibles), which tracking may already have joined to `kf` near the loop.
        let loop_side = |w: KeyFrameId| w == c || loop_kf.covisibles.iter().any(|&(x, _)| x == w);
        let window: Vec<KeyFrameId> = std::iter::once(kf)
            .chain(
                k.covisibles
                    .iter()
                    .map(|&(w, _)| w)
                    .filter(|&w| !loop_side(w))
                    .take(WINDOW_KEYFRAMES),
            )
            .collect();
        let t_kc = k.t_cw.0.inverse();
        let rel: Vec<Sim3> = window
            .iter()
            .map(|&w| {
                map.keyframe(w)
                    .map_or(Sim3::identity(), |wk| se3_to_sim3(&(wk.t_cw.0 * t_kc)))
            })
            .collect();
        let intrinsics = self.camera.intrinsics();
        let (mut s, mut n) = (*s_cw, 0);
        let (mut obs, mut out) = (Vec::new(), Vec::new());
        for _ in 0..2 {
            obs.clear();
            for (v, (&w, r)) in window.iter().zip(&rel).enumerate() {
                let Some(wk) = map.keyframe(w) else { continue };
                let mut matched = vec![None; wk.keypoints.len()];
                self.match_loop_group(map, w, c, &sim3_compose(r, &s), &mut matched);
                for (i, m) in matched.iter().enumerate() {
                    let Some(p) = m.and_then(|p| map.point(p)) else {
                        continue;
                    };
                    let kp = &wk.keypoints[i];
                    obs.push(WindowObservation {
                        view: v as u32,
                        point: p.position,
                        uv: Vector2::new(kp.ux as f64, kp.uy as f64),
                        inv_sigma2: 1.0 / self.sigma2[kp.octave as usize],
                    });
                }
            }
            out.clear();
            out.resize(obs.len(), false);
            n = optimize_window_sim3(&mut s, &rel, &obs, &intrinsics, 5.991, &mut out);
        }
        // A similarity its matches fix poorly in scale (the window's cameras too close
        // together for the distances involved) would move a whole map by the error: refused,
        // and a later keyframe tries again.
        let scale_sigma = window_sim3_covariance(&s, &rel, &obs, &intrinsics, &out)
            .map_or(f64::INFINITY, |c| c[(6, 6)].max(0.0).sqrt());
        if scale_sigma.is_nan() || scale_sigma > self.config.max_scale_sigma {
            tracing::debug!(scale_sigma, "loop similarity poorly fixed: refused");
            return None;
        }
        (n >= self.config.min_matches).then_some((s, n))
    }

    /// More matches for `kf`'s keypoints (those not yet in `matched`): the points of the loop
    /// keyframe `c` and its covisible neighbours, projected with `s_cw`. Returns the matches.
    fn match_loop_group(
        &self,
        map: &Map,
        kf: KeyFrameId,
        c: KeyFrameId,
        s_cw: &Sim3,
        matched: &mut [Option<MapPointId>],
    ) -> usize {
        let (Some(k1), Some(k2)) = (map.keyframe(kf), map.keyframe(c)) else {
            return 0;
        };
        let mut loop_points: Vec<MapPointId> = Vec::new();
        let mut seen = HashSet::new();
        let group: Vec<KeyFrameId> = std::iter::once(c)
            .chain(k2.covisibles.iter().map(|&(x, _)| x))
            .collect();
        for g in &group {
            if let Some(gk) = map.keyframe(*g) {
                for (_, p) in gk.observed() {
                    if seen.insert(p) {
                        loop_points.push(p);
                    }
                }
            }
        }
        // Points `kf` observes already are matched (or are its own): never a second keypoint.
        let already: HashSet<MapPointId> = matched
            .iter()
            .flatten()
            .copied()
            .chain(k1.observed().map(|(_, p)| p))
            .collect();
        let mut area = Vec::new();
        for &p in &loop_points {
            if already.contains(&p) {
                continue;
            }
            let Some(mp) = map.point(p) else { continue };
            let pc = s_cw.transform(&mp.position);
            let Some(uv) = self.camera.project(&pc) else {
                continue;
            };
            if !self.camera.in_image(uv.x, uv.y, 0.0) {
                continue;
            }
            let level = mp.predict_level(
                pc.norm() / s_cw.scale,
                map.config.scale_factor,
                map.config.n_levels,
            );
            let r = 8.0 * self.sigma2[level].sqrt();
            let mut best = (u32::MAX, usize::MAX);
            let (lo, hi) = (level.saturating_sub(1) as u8, (level + 1) as u8);
            k1.grid.in_area(
                &k1.keypoints,
                uv.x as f32,
                uv.y as f32,
                r as f32,
                lo,
                hi,
                &mut area,
            );
            for &i in &area {
                let i = i as usize;
                if matched[i].is_some() {
                    continue;
                }
                let d = hamming(&mp.descriptor, &k1.descriptors[i]);
                if d < best.0 {
                    best = (d, i);
                }
            }
            if best.0 <= 50 {
                matched[best.1] = Some(p);
            }
        }
        matched.iter().filter(|m| m.is_some()).count()
    }
}
