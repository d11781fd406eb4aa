//! Per-keyframe reconstruction on preallocated image-size buffers: gradients, epipolar search
//! in the N neighbours with hypothesis fusion (stage "depth"), then intra-keyframe checking,
//! smoothing and growing (stage "intra"). Bands of rows (depth stage) and rows (intra stage)
//! are processed in parallel on a private rayon pool of `threads` workers.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rayon::prelude::*;

use super::depth_stage::{mark_support, DepthContext, RowPass, DEPTH_BAND_ROWS};
use super::epipolar::{Intrinsics, SearchParams, StereoPair};
use super::gradients::{contrast_scale, GradientImage};
use super::intra::check_smooth_grow_row;
use super::patch::fails_patch_check;
use super::{DepthPixel, RegionalPrior};
use crate::config::SemiDenseConfig;
use crate::geometry::Se3;

/// Most neighbours a keyframe is searched in (the paper uses N = 7).
pub use crate::config::MAX_NEIGHBOURS;

/// What earlier depth maps tell a keyframe's search: per-cell inverse-depth ranges where they
/// had estimates, and the early-rejection point of the pixels they narrow. End of session
/// (`[semidense] final_seed_*`) the keyframe's own online map: pixels elsewhere are not
/// searched (`skip_unseeded`). Online (`propagate_*`) its neighbours' maps carried into it:
/// pixels elsewhere are searched over the prior as usual.
#[derive(Clone, Copy, Debug)]
pub struct Seed<'a> {
    pub ranges: &'a RegionalPrior,
    pub early_reject_after: usize,
    pub skip_unseeded: bool,
    /// The window is a proposal: kept for a pixel once a full search agrees with it.
    pub verify: bool,
}

/// Time spent in each stage of one keyframe.
#[derive(Clone, Copy, Debug, Default)]
pub struct StageTimes {
    pub depth: Duration,
    /// The intra-keyframe step (III-D) and the patch check after it.
    pub intra: Duration,
    /// Reference pixels searched, and epipolar samples visited over all neighbours.
    pub searched_pixels: u64,
    pub samples: u64,
    /// Of the searched pixels, those whose range a [`Seed`] narrowed; pixels with G >
    /// lambda_G it left unsearched (nothing around them in the earlier map).
    pub seeded: u64,
    pub seed_skipped: u64,
    /// Pixels with G > lambda_G of odd rows not searched: nothing above or below them was
    /// fused (`row_support_gate`).
    pub support_skipped: u64,
    /// Pixels per stage: searches stopped before the last neighbour (no estimate could
    /// result: too few neighbours left, or early rejection), pixels fused (III-C), fused
    /// pixels the intra-keyframe check kept, and pixels it grew (III-D).
    pub abandoned: u64,
    pub fused: u64,
    pub intra_kept: u64,
    pub grown: u64,
    /// Of those, estimates the patch check removed (`min_patch_zncc`).
    pub patch_removed: u64,
}

struct CachedImage {
    /// Keyframe serial number (unique over a run), `None` when free.
    key: Option<u64>,
    last_used: u64,
    image: GradientImage,
    /// The image's contrast (see [`contrast_scale`]): its lambda_G, and sigma_I when it is
    /// the reference, are scaled by it.
    contrast: f32,
}

pub struct KeyframeReconstructor {
    pub k: Intrinsics,
    pub width: usize,
    pub height: usize,
    params: SearchParams,
    lambda_n: usize,
    consensus_window: bool,
    early_reject_after: usize,
    /// `[semidense] row_support_gate`: odd rows searched only beside fused pixels.
    row_support_gate: bool,
    /// Per pixel of an even row: whether it or a pixel beside it in its row was fused
    /// (the odd rows' gate, built between the two passes).
    support: Vec<bool>,
    /// `[semidense] min_patch_zncc` (0 = off).
    min_patch_zncc: f32,
    contrast_reference: f64,
    /// Gradient images of recent keyframes (least recently used replaced): a keyframe is the
    /// neighbour of about N others, so most are computed once.
    cache: Vec<CachedImage>,
    clock: u64,
    reference: usize,
    neighbours: heapless::Vec<usize, MAX_NEIGHBOURS>,
    max_neighbours: usize,
    pairs: Vec<StereoPair>,
    /// Fused map (eq. 11) and the intra-checked map; sigma^2 = 0 marks "no estimate".
    raw_rho: Vec<f32>,
    raw_s2: Vec<f32>,
    rho: Vec<f32>,
    s2: Vec<f32>,
    pool: Option<rayon::ThreadPool>,
    /// Set online: rows wait while tracking works on a frame.
    gate: Option<crate::threads::ForegroundGate>,
}

impl KeyframeReconstructor {
    /// Allocates every buffer for `width` x `height` keyframes.
    pub fn new(k: Intrinsics, width: usize, height: usize, config: &SemiDenseConfig) -> Self {
        let config = &config.in_force();
        let n = config.n_neighbours.clamp(1, MAX_NEIGHBOURS);
        let pool = (config.threads > 1)
            .then(|| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(config.threads)
                    .thread_name(|i| format!("semidense-{i}"))
                    .start_handler({
                        let (nice, idle, cpus) =
                            (config.nice, config.sched_idle, config.cpus.clone());
                        move |_| {
                            crate::threads::lower_current_thread_priority(nice);
                            if idle {
                                crate::threads::set_current_thread_idle();
                            }
                            crate::threads::pin_current_thread(&cpus);
                        }
                    })
                    .build()
                    .ok()
            })
            .flatten();
        KeyframeReconstructor {
            k,
            width,
            height,
            params: SearchParams::from_config(config),
            lambda_n: config.lambda_n,
            consensus_window: config.consensus_window,
            early_reject_after: config.early_reject_after,
            row_support_gate: config.row_support_gate,
            // Only the gate reads it.
            support: vec![
                false;
                if config.row_support_gate {
                    width * height
                } else {
                    0
                }
            ],
            min_patch_zncc: config.min_patch_zncc as f32,
            contrast_reference: config.contrast_reference,
            cache: (0..2 * n + 2)
                .map(|_| CachedImage {
                    key: None,
                    last_used: 0,
                    image: GradientImage::new(width, height),
                    contrast: 1.0,
                })
                .collect(),
            clock: 0,
            reference: 0,
            neighbours: heapless::Vec::new(),
            max_neighbours: n,
            pairs: Vec::with_capacity(n),
            raw_rho: vec![0.0; width * height],
            raw_s2: vec![0.0; width * height],
            rho: vec![0.0; width * height],
            s2: vec![0.0; width * height],
            pool,
            gate: None,
        }
    }

    /// Takes the worker pool out: rows then run on the calling thread (the end-of-session
    /// pass runs two reconstructors at once instead).
    pub fn take_pool(&mut self) -> Option<rayon::ThreadPool> {
        self.pool.take()
    }

    pub fn restore_pool(&mut self, pool: Option<rayon::ThreadPool>) {
        self.pool = pool;
    }

    pub fn max_neighbours(&self) -> usize {
        self.max_neighbours
    }

    /// Frees the image buffers and worker threads (no reconstruction follows).
    pub fn release_working_memory(&mut self) {
        self.cache = Vec::new();
        self.neighbours.clear();
        self.pairs = Vec::new();
        (self.raw_rho, self.raw_s2, self.rho, self.s2) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        self.support = Vec::new();
        self.pool = None;
    }

    /// Forgets every cached gradient image (the map was reset).
    pub fn forget(&mut self) {
        for c in &mut self.cache {
            c.key = None;
            c.last_used = 0;
        }
    }

    /// Whether the gradient image of keyframe `key` is cached (its grey image need not be
    /// given again).
    pub fn is_cached(&self, key: u64) -> bool {
        self.cache.iter().any(|c| c.key == Some(key))
    }

    /// The cache slot of `key`, computing it from `gray` if not cached. `None` when it is not
    /// cached and no image is given.
    fn slot(&mut self, key: u64, gray: Option<&[u8]>) -> Option<usize> {
        self.clock += 1;
        if let Some(i) = self.cache.iter().position(|c| c.key == Some(key)) {
            self.cache[i].last_used = self.clock;
            return Some(i);
        }
        let gray = gray?;
        // Least recently used; slots of the keyframe being set up are the most recent.
        let i = (0..self.cache.len()).min_by_key(|&i| self.cache[i].last_used)?;
        let c = &mut self.cache[i];
        c.contrast = contrast_scale(gray, self.contrast_reference);
        c.image
            .compute(gray, self.params.for_contrast(c.contrast).lambda_g);
        c.key = Some(key);
        c.last_used = self.clock;
        Some(i)
    }

    /// Sets the keyframe to reconstruct (`key`: its serial number; grey, undistorted) and
    /// forgets the neighbours. False when it is not cached and no image is given.
    pub fn set_reference(&mut self, key: u64, gray: Option<&[u8]>) -> bool {
        self.neighbours.clear();
        self.pairs.clear();
        match self.slot(key, gray) {
            Some(i) => {
                self.reference = i;
                true
            }
            None => false,
        }
    }

    /// Adds a neighbour: its serial and grey image (may be `None` when cached), the transform
    /// from the reference camera to it, the in-plane rotation (radians) of image content
    /// from the reference to it, and its intensity over the reference's (exposure; 1 = the
    /// paper's photometric constancy). False when the capacity is reached or the image is
    /// missing.
    pub fn add_neighbour(
        &mut self,
        key: u64,
        gray: Option<&[u8]>,
        t_ji: &Se3,
        delta_theta: f64,
        gain: f32,
    ) -> bool {
        if self.neighbours.len() == self.max_neighbours {
            return false;
        }
        let Some(i) = self.slot(key, gray) else {
            return false;
        };
        let _ = self.neighbours.push(i);
        self.pairs
            .push(StereoPair::new(&self.k, t_ji, delta_theta).with_gain(gain));
        true
    }

    pub fn neighbours(&self) -> usize {
        self.neighbours.len()
    }

    /// Runs `f` on every item, `chunk` items per task in the worker pool when there is one
    /// (each task first waits while tracking is busy, like the rows of the depth stage).
    pub fn par_for_each<T: Send>(&self, items: &mut [T], chunk: usize, f: impl Fn(&mut T) + Sync) {
        let gate = self.gate.as_ref();
        let run = |c: &mut [T]| {
            if let Some(g) = gate {
                g.wait();
            }
            c.iter_mut().for_each(&f)
        };
        match self.pool.as_ref() {
            Some(p) => p.install(|| items.par_chunks_mut(chunk.max(1)).for_each(run)),
            None => items.chunks_mut(chunk.max(1)).for_each(run),
        }
    }

    /// Rows wait (between rows) while `gate` says tracking is busy.
    pub fn set_foreground_gate(&mut self, gate: crate::threads::ForegroundGate) {
        self.gate = Some(gate);
    }

    /// Reconstructs the reference keyframe for inverse depths in `rho_range`; the result is
    /// read with [`export`](Self::export).
    pub fn reconstruct(&mut self, rho_range: (f64, f64)) -> StageTimes {
        self.reconstruct_with(rho_range, None)
    }

    /// [`reconstruct`](Self::reconstruct) with per-region ranges inside `rho_range`.
    pub fn reconstruct_with(
        &mut self,
        rho_range: (f64, f64),
        prior: Option<&RegionalPrior>,
    ) -> StageTimes {
        self.reconstruct_seeded(rho_range, prior, None)
    }

    /// [`reconstruct_with`](Self::reconstruct_with) where `seed` (ranges from an earlier
    /// depth map of this keyframe) narrows the cells it covers and sets early rejection.
    pub fn reconstruct_seeded(
        &mut self,
        rho_range: (f64, f64),
        prior: Option<&RegionalPrior>,
        seed: Option<Seed>,
    ) -> StageTimes {
        let seed = seed.filter(|s| s.ranges.enabled());
        let t0 = Instant::now();
        let (w, h) = (self.width, self.height);
        let mut neighbours: heapless::Vec<&GradientImage, MAX_NEIGHBOURS> = heapless::Vec::new();
        for &i in &self.neighbours {
            let _ = neighbours.push(&self.cache[i].image);
        }
        let reference = &self.cache[self.reference].image;
        let params = self
            .params
            .for_contrast(self.cache[self.reference].contrast);
        let ctx = DepthContext {
            params,
            lambda_n: self.lambda_n,
            consensus_window: self.consensus_window,
            early_reject_after: self.early_reject_after,
            skip_unseeded: seed.is_some_and(|s| s.skip_unseeded),
            verify_seed: seed.is_some_and(|s| s.verify),
            seeded_reject_after: seed.map_or(self.early_reject_after, |s| s.early_reject_after),
            reference,
            neighbours: &neighbours[..],
            pairs: &self.pairs,
            rho_range,
            prior: prior.filter(|p| p.enabled()),
            seed: seed.map(|s| s.ranges),
            pixels: AtomicU64::new(0),
            samples: AtomicU64::new(0),
            seeded: AtomicU64::new(0),
            seed_skipped: AtomicU64::new(0),
            support_skipped: AtomicU64::new(0),
            abandoned: AtomicU64::new(0),
            fused: AtomicU64::new(0),
        };
        // Bands of rows, walked in blocks of columns: steep epipolar lines walk columns of
        // the neighbours (their transposed words), so a block's pixels reuse the same few
        // cached columns, which a full image row (640 columns x 7 neighbours) would evict.
        let gate = self.gate.as_ref();
        let passes: &[RowPass] = if self.row_support_gate {
            &[RowPass::Even, RowPass::OddSupported]
        } else {
            &[RowPass::All]
        };
        for &pass in passes {
            if pass == RowPass::OddSupported {
                mark_support(&self.raw_s2, w, &mut self.support);
            }
            let support = &self.support[..];
            let depth_bands = |band: (usize, (&mut [f32], &mut [f32]))| {
                let (b, (r, s)) = band;
                ctx.band(b * DEPTH_BAND_ROWS, (w, h), (r, s), pass, support, gate);
            };
            run_rows(
                self.pool.as_ref(),
                None,
                &mut self.raw_rho,
                &mut self.raw_s2,
                w * DEPTH_BAND_ROWS,
                depth_bands,
            );
        }
        let t1 = Instant::now();
        let (raw_rho, raw_s2) = (&self.raw_rho, &self.raw_s2);
        let lambda_g = params.lambda_g;
        let intra_rows = |rows: (usize, (&mut [f32], &mut [f32]))| {
            let (y, (r, s)) = rows;
            check_smooth_grow_row(
                y,
                w,
                h,
                raw_rho,
                raw_s2,
                |x| reference.modulus(y * w + x) > lambda_g,
                r,
                s,
            );
        };
        run_rows(
            self.pool.as_ref(),
            self.gate.as_ref(),
            &mut self.rho,
            &mut self.s2,
            w,
            intra_rows,
        );
        let (mut intra_kept, mut grown) = (0u64, 0u64);
        for (&raw, &now) in self.raw_s2.iter().zip(&self.s2) {
            if now > 0.0 {
                if raw > 0.0 {
                    intra_kept += 1;
                } else {
                    grown += 1;
                }
            }
        }
        let patch_removed = AtomicU64::new(0);
        if self.min_patch_zncc > 0.0 {
            let (tau, pairs, nb) = (self.min_patch_zncc, &self.pairs[..], &neighbours[..]);
            let patch_rows = |rows: (usize, (&mut [f32], &mut [f32]))| {
                let (y, (r, s)) = rows;
                let mut removed = 0;
                for x in 0..w {
                    if s[x] > 0.0 && fails_patch_check(reference, x, y, r[x] as f64, pairs, nb, tau)
                    {
                        r[x] = 0.0;
                        s[x] = 0.0;
                        removed += 1;
                    }
                }
                patch_removed.fetch_add(removed, Ordering::Relaxed);
            };
            run_rows(
                self.pool.as_ref(),
                self.gate.as_ref(),
                &mut self.rho,
                &mut self.s2,
                w,
                patch_rows,
            );
        }
        StageTimes {
            depth: t1 - t0,
            intra: t1.elapsed(),
            searched_pixels: ctx.pixels.load(Ordering::Relaxed),
            samples: ctx.samples.load(Ordering::Relaxed),
            seeded: ctx.seeded.load(Ordering::Relaxed),
            seed_skipped: ctx.seed_skipped.load(Ordering::Relaxed),
            support_skipped: ctx.support_skipped.load(Ordering::Relaxed),
            abandoned: ctx.abandoned.load(Ordering::Relaxed),
            fused: ctx.fused.load(Ordering::Relaxed),
            intra_kept,
            grown,
            patch_removed: patch_removed.into_inner(),
        }
    }

    /// The reconstructed inverse-depth map as pixels with estimates (cleared first; no
    /// allocation when `out` has the capacity of an image).
    pub fn export(&self, out: &mut Vec<DepthPixel>) {
        out.clear();
        for (i, (&r, &s2)) in self.rho.iter().zip(&self.s2).enumerate() {
            if s2 > 0.0 {
                out.push(DepthPixel {
                    idx: i as u32,
                    rho: r,
                    sigma: s2.sqrt(),
                });
            }
        }
    }

    /// The fused map before the intra-keyframe step (for tests and diagnostics).
    pub fn fused(&self) -> (&[f32], &[f32]) {
        (&self.raw_rho, &self.raw_s2)
    }
}

/// Runs `f` on every (row index, (row of a, row of b)), in parallel when a pool is given;
/// each row first waits for `gate` (tracking busy).
fn run_rows<F>(
    pool: Option<&rayon::ThreadPool>,
    gate: Option<&crate::threads::ForegroundGate>,
    a: &mut [f32],
    b: &mut [f32],
    w: usize,
    f: F,
) where
    F: Fn((usize, (&mut [f32], &mut [f32]))) + Sync + Send,
{
    let f = |row| {
        if let Some(g) = gate {
            g.wait();
        }
        f(row)
    };
    match pool {
        Some(p) => p.install(|| {
            a.par_chunks_mut(w)
                .zip(b.par_chunks_mut(w))
                .enumerate()
                .for_each(f)
        }),
        None => a.chunks_mut(w).zip(b.chunks_mut(w)).enumerate().for_each(f),
    }
}
