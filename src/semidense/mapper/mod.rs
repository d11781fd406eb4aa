//! Drives semi-dense reconstruction from the SLAM map: keyframes are reconstructed
//! `keyframe_delay` keyframes after they were made (local BA has settled them and newer
//! covisible keyframes exist), checked against their neighbours once those are reconstructed
//! too, and turned into the cloud with the keyframe poses current at output time (so loop
//! corrections move the cloud). Buffers are reserved at construction: after warm-up a
//! keyframe allocates nothing.

mod output;
mod propagate;
mod workspace;
use output::{pose_and_scale_now, reanchor, sample_anchors, Anchor};
use workspace::{Sink, Workspace};

use std::collections::VecDeque;
use std::sync::atomic::AtomicUsize;
use std::sync::Mutex;
use std::time::Instant;

use super::{
    median_rotation, photometric_gain, prior_range, DepthPixel, InterChecker, Intrinsics,
    KeyframeReconstructor, RegionalPrior, Seed, MAX_NEIGHBOURS,
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
    /// ... whose range earlier depth maps narrowed (end of session, the keyframe's own:
    /// `final_seed_cell_px`; online, its neighbours' carried into it, as a window a first
    /// full search must confirm: `propagate_cell_px`); pixels with G > lambda_G left
    /// unsearched because the end-of-session seed has nothing around them (not in
    /// `searched`).
    pub seeded: u64,
    pub seed_skipped: u64,
    /// Epipolar samples visited by the searches, over all neighbours (the depth stage's
    /// work: a window visits only its part of a segment).
    pub samples: u64,
    /// Pixels with G > lambda_G of odd rows left unsearched: no fused pixel above or below
    /// them (`row_support_gate`; not in `searched`).
    pub support_skipped: u64,
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

/// A second worker's results until they join the mapper's.
struct Store {
    entries: Vec<KeyframeDepth>,
    arena: Vec<CloudPixel>,
    stats: SemiDenseStats,
    t_depth: StageTimer,
    t_intra: StageTimer,
}

impl Store {
    fn with_capacity(entries: usize, samples: usize) -> Self {
        Store {
            entries: Vec::with_capacity(entries),
            // Grows as keyframes come (end of session: no frame deadline).
            arena: Vec::new(),
            stats: SemiDenseStats::default(),
            t_depth: StageTimer::with_capacity(samples),
            t_intra: StageTimer::with_capacity(samples),
        }
    }

    fn sink<'a>(&'a mut self, room: &'a AtomicUsize) -> Sink<'a> {
        Sink {
            entries: &mut self.entries,
            arena: &mut self.arena,
            stats: &mut self.stats,
            t_depth: &mut self.t_depth,
            t_intra: &mut self.t_intra,
            room,
        }
    }
}

impl SemiDenseStats {
    /// Adds another worker's counts (its busy time too: `busy_s` then sums workers).
    fn absorb(&mut self, o: &SemiDenseStats) {
        self.keyframes_reconstructed += o.keyframes_reconstructed;
        self.keyframes_skipped += o.keyframes_skipped;
        self.skipped_culled += o.skipped_culled;
        self.skipped_no_neighbours += o.skipped_no_neighbours;
        self.skipped_overload += o.skipped_overload;
        self.skipped_cut += o.skipped_cut;
        self.busy_s += o.busy_s;
        self.pixels += &o.pixels;
    }
}

impl std::ops::AddAssign<&PixelCounts> for PixelCounts {
    fn add_assign(&mut self, b: &PixelCounts) {
        self.searched += b.searched;
        self.seeded += b.seeded;
        self.seed_skipped += b.seed_skipped;
        self.samples += b.samples;
        self.support_skipped += b.support_skipped;
        self.search_abandoned += b.search_abandoned;
        self.fused += b.fused;
        self.intra_kept += b.intra_kept;
        self.intra_grown += b.intra_grown;
        self.patch_removed += b.patch_removed;
        self.inter_checked += b.inter_checked;
        self.inter_kept += b.inter_kept;
    }
}

pub struct SemiDenseMapper {
    config: SemiDenseConfig,
    /// The reconstructor and buffers keyframes are reconstructed in (the end-of-session
    /// pass adds a second, see [`reconstruct_all`](Self::reconstruct_all)).
    ws: Workspace,
    /// Capacity of the per-keyframe feature scratch (for a second workspace).
    max_features: usize,
    inter: InterChecker,
    pending: VecDeque<KeyFrameId>,
    /// Serial of the newest keyframe received: keyframes come in creation order, so a
    /// neighbour with a larger serial has not been received (its message may still be in
    /// the channel) and is not reconstructed yet.
    received_serial: u64,
    entries: Vec<KeyframeDepth>,
    arena: Vec<CloudPixel>,
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
        self.ws.reconstructor.set_foreground_gate(gate);
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
        let ws = Workspace::new(k, width, height, config, max_features);
        let n = ws.reconstructor.max_neighbours();
        let timer = || StageTimer::with_capacity(max_keyframes.max(16));
        SemiDenseMapper {
            config: config.clone(),
            inter: InterChecker::new(k, width, height, n),
            ws,
            pending: VecDeque::with_capacity(config.keyframe_delay + 2),
            received_serial: 0,
            entries: Vec::with_capacity(max_keyframes),
            arena: Vec::with_capacity(config.max_points),
            max_features,
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
        self.ws.release();
        self.inter.release_working_memory();
    }

    /// Forgets everything (the map was reset: old keyframes are in another frame).
    pub fn reset(&mut self) {
        self.ws.reconstructor.forget();
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
                self.reconstruct_online(map, k);
                self.check_ready(map, false);
            }
        }
    }

    /// Reconstructs every pending keyframe and checks every keyframe with the neighbours it
    /// has (end of the run).
    pub fn flush(&mut self, map: &Mutex<Map>) {
        while let Some(k) = self.pending.pop_front() {
            self.reconstruct_online(map, k);
            self.check_ready(map, false);
        }
        self.check_ready(map, true);
    }

    /// Reconstructs `keyframes` and checks each against all its neighbours: the
    /// end-of-session reconstruction (every keyframe is there at once). With `threads` >= 2,
    /// two keyframes are reconstructed at a time, one per core, each in its own workspace
    /// (rows are not split): part of a keyframe's work is serial (gradients of new
    /// neighbours, set-up, export), and splitting rows left a core idle there. One worker
    /// takes keyframes from the front and the other from the back, so each mostly finds
    /// its neighbours' gradients in its own cache; the results are stored in keyframe
    /// order, whichever worker made them, so the cloud does not depend on the split. The
    /// checks then split rows over the pool. `seed`: the online mapper, whose depth maps
    /// narrow each keyframe's search (`final_seed_cell_px`). Stops taking keyframes once
    /// `stop` says so (Ctrl-C) and returns false: the pass is then incomplete.
    pub fn reconstruct_all(
        &mut self,
        map: &Mutex<Map>,
        keyframes: &[KeyFrameId],
        seed: Option<&SemiDenseMapper>,
        stop: &(dyn Fn() -> bool + Sync),
    ) -> bool {
        for &k in keyframes {
            self.receive(map, k);
        }
        let pool = self.ws.reconstructor.take_pool();
        if pool.is_some() && keyframes.len() >= 2 {
            self.reconstruct_two_at_a_time(map, keyframes, seed, stop);
        } else {
            for &k in keyframes {
                if stop() {
                    break;
                }
                self.reconstruct(map, k, seed);
            }
        }
        self.ws.reconstructor.restore_pool(pool);
        if stop() {
            return false;
        }
        self.check_ready(map, true);
        true
    }

    /// [`reconstruct_all`](Self::reconstruct_all)'s two workers (the calling thread takes
    /// the front).
    fn reconstruct_two_at_a_time(
        &mut self,
        map: &Mutex<Map>,
        keyframes: &[KeyFrameId],
        seed: Option<&SemiDenseMapper>,
        stop: &(dyn Fn() -> bool + Sync),
    ) {
        let (k, w, h) = {
            let r = &self.ws.reconstructor;
            (r.k, r.width, r.height)
        };
        let serial = SemiDenseConfig {
            threads: 1,
            ..self.config.clone()
        };
        let mut second = Workspace::new(k, w, h, &serial, self.max_features);
        // Next keyframe from the front, and one past the next from the back.
        let next = Mutex::new((0, keyframes.len()));
        let take = |front: bool| {
            let mut g = next.lock().unwrap_or_else(|e| e.into_inner());
            let (f, b) = *g;
            (f < b && !stop()).then(|| {
                if front {
                    g.0 += 1;
                    keyframes[f]
                } else {
                    g.1 -= 1;
                    keyframes[b - 1]
                }
            })
        };
        let room = AtomicUsize::new(self.arena.capacity() - self.arena.len());
        let free_entries = self.entries.capacity() - self.entries.len();
        let mut back = Store::with_capacity(free_entries, self.t_depth.capacity());
        let (second, back_store, room) = (&mut second, &mut back, &room);
        let (ws, config, mut front) = self.parts(room);
        let joined = std::thread::scope(|s| {
            let spawned = std::thread::Builder::new()
                .name("semidense-final".into())
                .spawn_scoped(s, move || {
                    let mut out = back_store.sink(room);
                    while let Some(kf) = take(false) {
                        second.reconstruct(config, map, kf, &mut out, seed);
                    }
                });
            while let Some(kf) = take(true) {
                ws.reconstruct(config, map, kf, &mut front, seed);
            }
            spawned.map(|h| h.join().is_ok())
        });
        match joined {
            Ok(true) => {}
            // Not spawned: the front worker took every keyframe.
            Err(e) => tracing::warn!("end-of-session reconstruction on one core: {e}"),
            Ok(false) => tracing::error!("an end-of-session reconstruction worker panicked"),
        }
        self.absorb(back);
    }

    /// Appends a second worker's keyframes (taken from the back: stored in reverse).
    fn absorb(&mut self, back: Store) {
        for mut e in back.entries.into_iter().rev() {
            let pixels = &back.arena[e.start..e.start + e.len];
            if self.entries.len() == self.entries.capacity()
                || self.arena.len() + pixels.len() > self.arena.capacity()
            {
                self.stats.keyframes_skipped += 1;
                self.stats.skipped_overload += 1;
                self.stats.keyframes_reconstructed -= 1;
                continue;
            }
            e.start = self.arena.len();
            self.arena.extend_from_slice(pixels);
            self.entries.push(e);
        }
        self.stats.absorb(&back.stats);
        self.t_depth.absorb(&back.t_depth);
        self.t_intra.absorb(&back.t_intra);
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

    /// Reconstructs `kf` into this mapper's store (`seed`: see
    /// [`reconstruct_all`](Self::reconstruct_all); `None` online).
    fn reconstruct(&mut self, map: &Mutex<Map>, kf: KeyFrameId, seed: Option<&SemiDenseMapper>) {
        let room = AtomicUsize::new(self.arena.capacity() - self.arena.len());
        let (ws, config, mut out) = self.parts(&room);
        ws.reconstruct(config, map, kf, &mut out, seed);
    }

    /// Reconstructs `kf` online: its search narrowed by the depth maps of its neighbours
    /// reconstructed before it (`propagate_cell_px`).
    fn reconstruct_online(&mut self, map: &Mutex<Map>, kf: KeyFrameId) {
        if self.config.propagate_cell_px > 0 {
            // Poses under the map lock; the pixels are carried after it is released.
            let sources = {
                let m = map.lock().unwrap_or_else(|e| e.into_inner());
                let max = self.ws.reconstructor.max_neighbours();
                propagate::sources(&m, kf, &self.entries, max, &mut self.ws.scratch_f32)
            };
            self.ws.propagate(&sources, &self.entries, &self.arena);
        }
        self.reconstruct(map, kf, None);
    }

    /// The workspace, the settings and a sink into this mapper's store (`room`: its free
    /// arena pixels), borrowed at once.
    fn parts<'a>(
        &'a mut self,
        room: &'a AtomicUsize,
    ) -> (&'a mut Workspace, &'a SemiDenseConfig, Sink<'a>) {
        let out = Sink {
            entries: &mut self.entries,
            arena: &mut self.arena,
            stats: &mut self.stats,
            t_depth: &mut self.t_depth,
            t_intra: &mut self.t_intra,
            room,
        };
        (&mut self.ws, &self.config, out)
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
        let mut scratch = std::mem::take(&mut self.ws.scratch_f32);
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
        self.ws.scratch_f32 = scratch;
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
        self.ws
            .reconstructor
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
        self.ws
            .reconstructor
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
