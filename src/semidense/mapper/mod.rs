//! Drives semi-dense reconstruction from the SLAM map: keyframes are reconstructed
//! `keyframe_delay` keyframes after they were made (local BA has settled them and newer
//! covisible keyframes exist), checked against their neighbours once those are reconstructed
//! too, and turned into the cloud with the keyframe poses current at output time (so loop
//! corrections move the cloud). Buffers are reserved at construction: after warm-up a
//! keyframe allocates nothing.

mod output;
use output::{pose_and_scale_now, reanchor, sample_anchors, Anchor};

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Instant;

use super::{
    median_rotation, photometric_gain, prior_range, DepthPixel, InterChecker, Intrinsics,
    KeyframeReconstructor, RegionalPrior, MAX_NEIGHBOURS,
};
use crate::config::SemiDenseConfig;
use crate::geometry::CloudPoint;
use crate::geometry::{CameraFromWorld, Se3};
use crate::map::{KeyFrame, KeyFrameId, Map, MapPointId};
use crate::timing::StageTimer;

/// A reconstructed keyframe: its pixels live in the mapper's arena at `start..start + len`.
#[derive(Clone, Debug)]
pub struct KeyframeDepth {
    pub keyframe: KeyFrameId,
    pub timestamp: f64,
    /// Pose when last read from the map (kept if the keyframe is culled later).
    pub t_cw: CameraFromWorld,
    pub neighbours: heapless::Vec<KeyFrameId, MAX_NEIGHBOURS>,
    start: usize,
    len: usize,
    /// Map points seen by the keyframe with their camera-frame positions at reconstruction:
    /// the anchors of its depth scale. A Sim3 loop correction or global BA rescales the map
    /// around a keyframe; the ratio of then/now inverse depths of these points carries the
    /// depths along, and once the keyframe is culled their Sim3 gives its pose. Followed
    /// through fusion by keypoint, renewed while the keyframe lives (`output::reanchor`).
    anchors: heapless::Vec<Anchor, MAX_ANCHORS>,
    /// A live neighbour with an entry, this keyframe's pose relative to it and its depth
    /// scale, when both were last read: the pose of this keyframe once culled with its
    /// anchors gone (`output::pose_and_scale_now`).
    relative_to: Option<(KeyFrameId, Se3, f32)>,
    /// Serials of `neighbours` (a neighbour newer than every keyframe received so far is
    /// not reconstructed yet even though it is not pending).
    neighbour_serials: heapless::Vec<u64, MAX_NEIGHBOURS>,
    /// Depth scale when the pose was last read (the median then/now inverse-depth ratio of its anchor points).
    pub scale: f32,
    /// The inter-keyframe check has run.
    pub checked: bool,
    /// An interrupted run cut a neighbour this keyframe's check needs: never checked, so
    /// never in the cloud.
    unverifiable: bool,
    /// Depth + intra time, milliseconds (inter is added when it runs).
    elapsed_ms: f64,
}

/// Map points kept per keyframe to follow its scale.
pub const MAX_ANCHORS: usize = 48;

/// A pixel of the arena: the intra-checked estimate (what neighbours are checked against),
/// the final inverse depth after the inter-keyframe check (0 = rejected) and its colour.
#[derive(Clone, Copy, Debug, Default)]
struct CloudPixel {
    raw: DepthPixel,
    rho: f32,
    rgb: [u8; 3],
}

/// A neighbour as read from the map for one reconstruction.
struct Neighbour {
    id: KeyFrameId,
    serial: u64,
    /// Reference camera to this neighbour's camera.
    t_ji: crate::geometry::Se3,
    /// In-plane rotation of image content from the reference (radians).
    delta_theta: f64,
    /// Its intensity over the reference's (exposure; 1 when not measured).
    gain: f32,
    /// Its grey image was copied (its gradients are not cached).
    staged: bool,
}

/// Counters for the report.
#[derive(Clone, Debug, Default)]
pub struct SemiDenseStats {
    pub keyframes_reconstructed: usize,
    /// Keyframes not reconstructed (the sum of the reasons below).
    pub keyframes_skipped: usize,
    /// ... because local mapping culled them (redundant) before their turn.
    pub skipped_culled: usize,
    /// ... because they had fewer than lambda_N neighbours with enough baseline, or fewer
    /// than 10 map points for the depth prior.
    pub skipped_no_neighbours: usize,
    /// ... because the store was full or, online, the thread's queue was full (overload).
    pub skipped_overload: usize,
    /// ... because the run was interrupted (Ctrl-C) and the backlog was cut to end quickly.
    pub skipped_cut: usize,
    /// Wall time spent reconstructing and checking keyframes, seconds.
    pub busy_s: f64,
    /// Pixels through each stage, summed over the keyframes.
    pub pixels: PixelCounts,
}

/// How many pixels each stage of the paper's pipeline passed on, summed over keyframes: what
/// each check removes.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PixelCounts {
    /// Reference pixels with G > lambda_G searched (III-B).
    pub searched: u64,
    /// ... whose search stopped early (fewer than lambda_N neighbours left, or early
    /// rejection: no compatible pair after `early_reject_after` neighbours).
    pub search_abandoned: u64,
    /// ... fused from at least lambda_N compatible hypotheses (III-C).
    pub fused: u64,
    /// Fused pixels the intra-keyframe check kept, and pixels it grew (III-D).
    pub intra_kept: u64,
    pub intra_grown: u64,
    /// Of those, estimates the patch check dropped (not in the paper; `min_patch_zncc`).
    pub patch_removed: u64,
    /// Pixels the inter-keyframe check looked at and kept (III-E).
    pub inter_checked: u64,
    pub inter_kept: u64,
}

pub struct SemiDenseMapper {
    config: SemiDenseConfig,
    reconstructor: KeyframeReconstructor,
    inter: InterChecker,
    pending: VecDeque<KeyFrameId>,
    /// Serial of the newest keyframe received: keyframes come in creation order, so a
    /// neighbour with a larger serial has not been received (its message may still be in
    /// the channel) and is not reconstructed yet.
    received_serial: u64,
    entries: Vec<KeyframeDepth>,
    arena: Vec<CloudPixel>,
    // Staging copies taken under the map lock, processed without it.
    gray_ref: Vec<u8>,
    /// The reference keyframe's colour residuals (see [`crate::image::colour`]).
    colour_ref: Vec<u8>,
    gray_nb: Vec<Vec<u8>>,
    scratch_f32: Vec<f32>,
    /// Patch-mean ratios of the exposure measurement (reused).
    scratch_gain: Vec<f32>,
    /// Keypoints (reference, neighbour) of the points a keyframe pair shares (reused).
    scratch_shared: Vec<(crate::features::KeyPoint, crate::features::KeyPoint)>,
    scratch_pixels: Vec<DepthPixel>,
    /// The reference keyframe's regional prior (`[semidense] prior_cell_px`), built under
    /// the map lock with the keyframe-wide one.
    prior: RegionalPrior,
    pub stats: SemiDenseStats,
    pub t_depth: StageTimer,
    pub t_intra: StageTimer,
    pub t_inter: StageTimer,
    pub t_keyframe: StageTimer,
}

/// Bytes per stored semi-dense pixel (`[semidense] max_points` of them are reserved).
pub const STORED_PIXEL_BYTES: usize = std::mem::size_of::<CloudPixel>();

impl SemiDenseMapper {
    /// Reserves everything for `width` x `height` keyframes, `max_keyframes` reconstructed
    /// keyframes and `max_points` stored pixels.
    /// Online: the per-pixel work steps aside while tracking works on a frame.
    pub fn set_foreground_gate(&mut self, gate: crate::threads::ForegroundGate) {
        self.reconstructor.set_foreground_gate(gate);
    }

    pub fn new(
        k: Intrinsics,
        width: usize,
        height: usize,
        config: &SemiDenseConfig,
        max_keyframes: usize,
        max_features: usize,
    ) -> Self {
        let config = &config.in_force();
        let reconstructor = KeyframeReconstructor::new(k, width, height, config);
        let n = reconstructor.max_neighbours();
        let timer = || StageTimer::with_capacity(max_keyframes.max(16));
        SemiDenseMapper {
            config: config.clone(),
            inter: InterChecker::new(k, width, height, n),
            reconstructor,
            pending: VecDeque::with_capacity(config.keyframe_delay + 2),
            received_serial: 0,
            entries: Vec::with_capacity(max_keyframes),
            arena: Vec::with_capacity(config.max_points),
            gray_ref: Vec::with_capacity(width * height),
            colour_ref: Vec::with_capacity(crate::image::colour::residual_len(width, height)),
            gray_nb: (0..n).map(|_| Vec::with_capacity(width * height)).collect(),
            scratch_f32: Vec::with_capacity(max_features.max(64)),
            scratch_gain: Vec::with_capacity(max_features.max(64)),
            scratch_shared: Vec::with_capacity(max_features.max(64)),
            scratch_pixels: Vec::with_capacity(width * height),
            prior: RegionalPrior::new(width, height, config.prior_cell_px),
            stats: SemiDenseStats::default(),
            t_depth: timer(),
            t_intra: timer(),
            t_inter: timer(),
            t_keyframe: timer(),
        }
    }

    /// Drops the buffers only reconstruction needs (the run is over); the cloud, entries and
    /// depth maps stay readable.
    pub fn release_working_memory(&mut self) {
        self.reconstructor.release_working_memory();
        self.inter.release_working_memory();
        self.gray_ref = Vec::new();
        self.colour_ref = Vec::new();
        self.gray_nb = Vec::new();
        self.scratch_pixels = Vec::new();
    }

    /// Forgets everything (the map was reset: old keyframes are in another frame).
    pub fn reset(&mut self) {
        self.reconstructor.forget();
        self.pending.clear();
        self.received_serial = 0;
        self.entries.clear();
        self.arena.clear();
    }

    /// Notes a keyframe as received (its serial raises the watermark of
    /// [`neighbours_done`](Self::neighbours_done)).
    fn receive(&mut self, map: &Mutex<Map>, kf: KeyFrameId) {
        let m = map.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(k) = m.keyframe(kf) {
            self.received_serial = self.received_serial.max(k.serial);
        }
    }

    /// Every neighbour of `e` is reconstructed or never will be: received and no longer
    /// pending.
    fn neighbours_done(&self, e: &KeyframeDepth) -> bool {
        e.neighbours
            .iter()
            .zip(&e.neighbour_serials)
            .all(|(n, &s)| s <= self.received_serial && !self.pending.contains(n))
    }

    /// A keyframe was made. The keyframe `keyframe_delay` places earlier is reconstructed now.
    pub fn on_keyframe(&mut self, map: &Mutex<Map>, kf: KeyFrameId) {
        self.receive(map, kf);
        self.pending.push_back(kf);
        while self.pending.len() > self.config.keyframe_delay {
            if let Some(k) = self.pending.pop_front() {
                self.reconstruct(map, k);
                self.check_ready(map, false);
            }
        }
    }

    /// Reconstructs every pending keyframe and checks every keyframe with the neighbours it
    /// has (end of the run).
    pub fn flush(&mut self, map: &Mutex<Map>) {
        while let Some(k) = self.pending.pop_front() {
            self.reconstruct(map, k);
            self.check_ready(map, false);
        }
        self.check_ready(map, true);
    }

    /// Reconstructs `keyframes` in their order and checks each against all its neighbours:
    /// the end-of-session reconstruction (every keyframe is there at once).
    pub fn reconstruct_all(&mut self, map: &Mutex<Map>, keyframes: &[KeyFrameId]) {
        for &k in keyframes {
            self.receive(map, k);
            self.pending.push_back(k);
        }
        self.flush(map);
    }

    /// End of an interrupted run: drops the keyframes still waiting for reconstruction
    /// (counted as cut) and checks the reconstructed ones with the neighbours they have, so
    /// the run ends within about one keyframe's time. Returns how many were cut.
    pub fn flush_cut(&mut self, map: &Mutex<Map>) -> usize {
        // Keyframes with a cut neighbour cannot get the inter-keyframe check they were
        // reconstructed for; unchecked, they stay out of the cloud (and are counted as cut).
        let mut unverifiable = 0;
        for e in 0..self.entries.len() {
            if !self.entries[e].checked && !self.neighbours_done(&self.entries[e]) {
                self.entries[e].unverifiable = true;
                unverifiable += 1;
            }
        }
        let n = self.pending.len() + unverifiable;
        self.pending.clear();
        self.cut(n);
        self.stats.keyframes_reconstructed -= unverifiable.min(self.stats.keyframes_reconstructed);
        for e in 0..self.entries.len() {
            if !self.entries[e].checked && !self.entries[e].unverifiable {
                self.check(map, e);
            }
        }
        n
    }

    /// Counts `n` keyframes that an interrupted run did not reconstruct or could not verify.
    pub fn cut(&mut self, n: usize) {
        self.stats.keyframes_skipped += n;
        self.stats.skipped_cut += n;
    }

    pub fn entries(&self) -> &[KeyframeDepth] {
        &self.entries
    }

    /// Points that passed every check so far.
    pub fn n_points(&self) -> usize {
        self.entries
            .iter()
            .filter(|e| e.checked)
            .map(|e| self.pixels(e).filter(|p| p.rho > 0.0).count())
            .sum()
    }

    fn pixels<'a>(&'a self, e: &KeyframeDepth) -> impl Iterator<Item = &'a CloudPixel> + 'a {
        self.arena[e.start..e.start + e.len].iter()
    }

    fn reconstruct(&mut self, map: &Mutex<Map>, kf: KeyFrameId) {
        let t0 = Instant::now();
        let Some((t_cw, timestamp, serial, has_color, neighbours, rho_range, anchors)) =
            self.snapshot(map, kf)
        else {
            self.stats.keyframes_skipped += 1;
            let alive = map
                .lock()
                .map(|m| m.keyframe(kf).is_some())
                .unwrap_or(false);
            if alive {
                self.stats.skipped_no_neighbours += 1;
            } else {
                self.stats.skipped_culled += 1;
            }
            return;
        };
        let (w, h) = (self.reconstructor.width, self.reconstructor.height);
        if self.entries.len() == self.entries.capacity()
            || self.arena.len() + w * h > self.arena.capacity()
        {
            self.stats.keyframes_skipped += 1;
            self.stats.skipped_overload += 1;
            return;
        }
        let times = {
            // Neighbour poses were read under the lock with the reference's; grey images
            // were copied only for keyframes whose gradients are not cached.
            let r = &mut self.reconstructor;
            if !r.set_reference(serial, Some(&self.gray_ref)) {
                self.stats.keyframes_skipped += 1;
                self.stats.skipped_overload += 1;
                return;
            }
            for (k, n) in neighbours.iter().enumerate() {
                let gray = n.staged.then(|| &self.gray_nb[k][..]);
                r.add_neighbour(n.serial, gray, &n.t_ji, n.delta_theta, n.gain);
            }
            r.reconstruct_with(rho_range, Some(&self.prior))
        };
        self.reconstructor.export(&mut self.scratch_pixels);
        let start = self.arena.len();
        for p in &self.scratch_pixels {
            let i = p.idx as usize;
            let rgb = if has_color {
                crate::image::colour::colour_at(&self.gray_ref, &self.colour_ref, w, i % w, i / w)
            } else {
                [self.gray_ref[i]; 3]
            };
            self.arena.push(CloudPixel {
                raw: *p,
                rho: 0.0,
                rgb,
            });
        }
        let (mut nb, mut nb_serials) = (heapless::Vec::new(), heapless::Vec::new());
        for n in &neighbours {
            let _ = nb.push(n.id);
            let _ = nb_serials.push(n.serial);
        }
        self.entries.push(KeyframeDepth {
            keyframe: kf,
            timestamp,
            t_cw,
            neighbours: nb,
            neighbour_serials: nb_serials,
            relative_to: None,
            start,
            len: self.arena.len() - start,
            anchors,
            scale: 1.0,
            checked: false,
            unverifiable: false,
            elapsed_ms: t0.elapsed().as_secs_f64() * 1e3,
        });
        self.stats.busy_s += t0.elapsed().as_secs_f64();
        tracing::debug!(
            timestamp,
            neighbours = neighbours.len(),
            searched_pixels = times.searched_pixels,
            samples = times.samples,
            points = self.arena.len() - start,
            depth_ms = times.depth.as_secs_f64() * 1e3,
            "semi-dense keyframe"
        );
        self.t_depth.record(times.depth);
        self.t_intra.record(times.intra);
        let c = &mut self.stats.pixels;
        c.searched += times.searched_pixels;
        c.search_abandoned += times.abandoned;
        c.fused += times.fused;
        c.intra_kept += times.intra_kept;
        c.intra_grown += times.grown;
        c.patch_removed += times.patch_removed;
        self.stats.keyframes_reconstructed += 1;
    }

    /// Copies what reconstruction needs out of the map (short lock): images, poses, the
    /// neighbours with relative poses and in-plane rotations, and the inverse-depth prior.
    #[allow(clippy::type_complexity)]
    fn snapshot(
        &mut self,
        map: &Mutex<Map>,
        kf: KeyFrameId,
    ) -> Option<(
        CameraFromWorld,
        f64,
        u64,
        bool,
        heapless::Vec<Neighbour, MAX_NEIGHBOURS>,
        (f64, f64),
        heapless::Vec<Anchor, MAX_ANCHORS>,
    )> {
        let map = map.lock().unwrap_or_else(|e| e.into_inner());
        let k = map.keyframe(kf)?;
        if k.gray.len() != self.gray_ref.capacity() {
            return None;
        }
        // Prior from the ORB map points' inverse depths in this keyframe; a spread of them
        // anchors the keyframe's depth scale.
        self.scratch_f32.clear();
        self.prior.clear();
        let anchors = sample_anchors(&map, k, &k.t_cw, 1.0);
        for (i, mp) in k.observed() {
            let Some(p) = map.point(mp) else { continue };
            let x = k.t_cw.transform(&p.position);
            // In front of the camera (NaN is not).
            if x.z.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                continue;
            }
            let rho = (1.0 / x.z) as f32;
            if self.scratch_f32.len() < self.scratch_f32.capacity() {
                self.scratch_f32.push(rho);
            }
            if let Some(kp) = k.keypoints.get(i) {
                self.prior.add(kp.ux, kp.uy, rho);
            }
        }
        let rho_range = prior_range(&self.scratch_f32)?;
        self.prior.finish(
            rho_range,
            self.config.prior_min_points,
            self.config.prior_margin,
        );
        let mut neighbours = heapless::Vec::new();
        let max_n = self.reconstructor.max_neighbours();
        let mut angles = std::mem::take(&mut self.scratch_f32);
        let mean_rho = 0.5 * (rho_range.0 + rho_range.1);
        let min_baseline = self.config.min_baseline_ratio / mean_rho.max(1e-9);
        for nb in k.best_covisibles(4 * max_n) {
            if neighbours.len() == max_n {
                break;
            }
            let Some(j) = map.keyframe(nb) else { continue };
            if j.gray.len() != k.gray.len() {
                continue;
            }
            let t_ji = j.t_cw.0 * k.t_cw.0.inverse();
            if t_ji.translation.vector.norm() < min_baseline {
                continue;
            }
            // The keypoints of the points both observe, found once for the in-plane rotation
            // and the exposure.
            self.scratch_shared.clear();
            for (i, mp) in k.observed() {
                if self.scratch_shared.len() == self.scratch_shared.capacity() {
                    break;
                }
                let Some(p) = map.point(mp) else { continue };
                let Some(&(_, jj)) = p.observations.iter().find(|(o, _)| *o == nb) else {
                    continue;
                };
                if let (Some(a), Some(b)) = (k.keypoints.get(i), j.keypoints.get(jj as usize)) {
                    self.scratch_shared.push((*a, *b));
                }
            }
            let shared = &self.scratch_shared;
            let delta_theta =
                median_rotation(shared.iter().map(|(a, b)| (a.angle, b.angle)), &mut angles);
            let gain = if self.config.photometric_gain {
                let (w, h) = (self.reconstructor.width, self.reconstructor.height);
                let matched = shared.iter().map(|(a, b)| ((a.ux, a.uy), (b.ux, b.uy)));
                photometric_gain(&k.gray, &j.gray, w, h, matched, &mut self.scratch_gain)
            } else {
                1.0
            };
            let slot = neighbours.len();
            let staged = !self.reconstructor.is_cached(j.serial);
            if staged {
                self.gray_nb[slot].clear();
                self.gray_nb[slot].extend_from_slice(&j.gray);
            }
            let n = Neighbour {
                id: nb,
                serial: j.serial,
                t_ji,
                delta_theta,
                gain,
                staged,
            };
            if neighbours.push(n).is_err() {
                break;
            }
        }
        self.scratch_f32 = angles;
        if neighbours.len() < self.config.lambda_n {
            return None;
        }
        self.gray_ref.clear();
        self.gray_ref.extend_from_slice(&k.gray);
        self.colour_ref.clear();
        if k.has_color {
            self.colour_ref.extend_from_slice(&k.colour);
        }
        Some((
            k.t_cw,
            k.timestamp,
            k.serial,
            k.has_color,
            neighbours,
            rho_range,
            anchors,
        ))
    }

    /// Runs the inter-keyframe check of every unchecked keyframe whose neighbours are all
    /// reconstructed (or will never be); `force` checks all of them.
    fn check_ready(&mut self, map: &Mutex<Map>, force: bool) {
        for e in 0..self.entries.len() {
            if self.entries[e].checked {
                continue;
            }
            let ready = force || self.neighbours_done(&self.entries[e]);
            if ready {
                self.check(map, e);
            }
        }
    }

    /// Re-reads current poses of an entry and its neighbours from the map (loop closure and BA
    /// move keyframes after reconstruction).
    fn refresh_poses(&mut self, map: &Map, e: usize) {
        let mut scratch = std::mem::take(&mut self.scratch_f32);
        let mut ids: heapless::Vec<usize, { MAX_NEIGHBOURS + 1 }> = heapless::Vec::new();
        let _ = ids.push(e);
        for n in &self.entries[e].neighbours {
            if let Some(d) = self.entries.iter().position(|d| d.keyframe == *n) {
                let _ = ids.push(d);
            }
        }
        for &i in &ids {
            let (t_cw, scale) =
                pose_and_scale_now(map, &self.entries[i], &self.entries, &mut scratch);
            let d = &mut self.entries[i];
            (d.t_cw, d.scale) = (t_cw, scale);
            reanchor(map, d, &t_cw, scale);
        }
        // A live neighbour to follow once this keyframe is culled.
        if map.keyframe(self.entries[e].keyframe).is_some() {
            let me = &self.entries[e];
            let via = ids[1..]
                .iter()
                .map(|&i| &self.entries[i])
                .find(|d| map.keyframe(d.keyframe).is_some());
            let rel = via.map(|d| (d.keyframe, me.t_cw.0 * d.t_cw.0.inverse(), d.scale));
            if rel.is_some() {
                self.entries[e].relative_to = rel;
            }
        }
        self.scratch_f32 = scratch;
    }

    fn check(&mut self, map: &Mutex<Map>, e: usize) {
        let t0 = Instant::now();
        {
            let m = map.lock().unwrap_or_else(|p| p.into_inner());
            self.refresh_poses(&m, e);
        }
        let me = &self.entries[e];
        // The neighbours' maps, in today's map scale (depth x scale), each filled by a task
        // of the worker pool.
        let mut jobs: heapless::Vec<(usize, usize, f32, Se3), MAX_NEIGHBOURS> =
            heapless::Vec::new();
        for n in &me.neighbours {
            if let Some(d) = self.entries.iter().find(|d| d.keyframe == *n) {
                let t_ji = d.t_cw.0 * me.t_cw.0.inverse();
                let _ = jobs.push((d.start, d.len, 1.0 / d.scale, t_ji));
            }
        }
        let arena = &self.arena;
        let (k, maps) = self.inter.begin(jobs.len());
        let mut work: heapless::Vec<_, MAX_NEIGHBOURS> = heapless::Vec::new();
        for pair in maps.iter_mut().zip(&jobs) {
            let _ = work.push(pair);
        }
        self.reconstructor
            .par_for_each(&mut work, 1, |(m, (start, len, s, t_ji))| {
                let pixels = arena[*start..*start + *len].iter().map(|p| {
                    let mut r = p.raw;
                    r.rho *= s;
                    r.sigma *= s;
                    r
                });
                m.fill(&k, pixels, t_ji);
            });
        drop(work); // ends the borrow of the maps before the check reads them
        let (start, len, scale) = (me.start, me.len, me.scale);
        let lambda_n = self.config.lambda_n;
        let inter = &self.inter;
        let inter_check = self.config.inter_check;
        // Pixels are independent: checked in the worker pool, a few rows' worth per task.
        self.reconstructor
            .par_for_each(&mut self.arena[start..start + len], 2048, |p| {
                // Checked in today's scale, stored in the reconstruction's (as `raw`).
                p.rho = if inter_check {
                    inter
                        .check(p.raw.idx, p.raw.rho / scale, lambda_n)
                        .map_or(0.0, |rho| rho * scale)
                } else {
                    p.raw.rho
                };
            });
        let dt = t0.elapsed();
        self.stats.busy_s += dt.as_secs_f64();
        self.t_inter.record(dt);
        let kept = self.arena[start..start + len]
            .iter()
            .filter(|p| p.rho > 0.0)
            .count() as u64;
        self.stats.pixels.inter_checked += len as u64;
        self.stats.pixels.inter_kept += kept;
        let me = &mut self.entries[e];
        me.checked = true;
        me.elapsed_ms += dt.as_secs_f64() * 1e3;
        self.t_keyframe.record_ms(me.elapsed_ms);
    }
}

#[cfg(test)]
mod tests;
