//! Reconstructing one keyframe from the map: what it needs besides the results (the
//! reconstructor with its gradient cache, copies taken under the map lock, scratch) and where
//! the results go. Split from the mapper so the end-of-session pass can run two keyframes at
//! once, one per core, each in its own workspace.

use std::sync::atomic::{AtomicUsize, Ordering};

use super::*;

/// A neighbour as read from the map for one reconstruction.
struct Neighbour {
    id: KeyFrameId,
    serial: u64,
    /// Reference camera to this neighbour's camera.
    t_ji: Se3,
    /// In-plane rotation of image content from the reference (radians).
    delta_theta: f64,
    /// Its intensity over the reference's (exposure; 1 when not measured).
    gain: f32,
    /// Its grey image was copied (its gradients are not cached).
    staged: bool,
}

/// What one keyframe's reconstruction reads from the map (copied under the lock).
struct Snapshot {
    t_cw: CameraFromWorld,
    timestamp: f64,
    serial: u64,
    has_color: bool,
    neighbours: heapless::Vec<Neighbour, MAX_NEIGHBOURS>,
    rho_range: (f64, f64),
    anchors: heapless::Vec<Anchor, MAX_ANCHORS>,
    seeded: bool,
    /// The neighbours' maps narrow the search (online propagation).
    propagated: bool,
}

/// The buffers one keyframe's reconstruction works in, reserved at construction.
pub(super) struct Workspace {
    pub reconstructor: KeyframeReconstructor,
    // Staging copies taken under the map lock, processed without it.
    gray_ref: Vec<u8>,
    /// The reference keyframe's colour residuals (see [`crate::image::colour`]).
    colour_ref: Vec<u8>,
    gray_nb: Vec<Vec<u8>>,
    pub scratch_f32: Vec<f32>,
    /// Patch-mean ratios of the exposure measurement (reused).
    scratch_gain: Vec<f32>,
    /// Keypoints (reference, neighbour) of the points a keyframe pair shares (reused).
    scratch_shared: Vec<(crate::features::KeyPoint, crate::features::KeyPoint)>,
    scratch_pixels: Vec<DepthPixel>,
    /// The reference keyframe's regional prior (`[semidense] prior_cell_px`), built under
    /// the map lock with the keyframe-wide one.
    prior: RegionalPrior,
    /// Ranges from the keyframe's online depth map (end of session, `final_seed_cell_px`).
    seed_ranges: RegionalPrior,
    /// Ranges from the neighbours' depth maps (online, `propagate_cell_px`; see
    /// `propagate.rs`), and how many of their points the next reconstruction's grid holds.
    pub(super) propagated: RegionalPrior,
    pub(super) propagated_points: usize,
}

/// Where reconstructed keyframes go: the mapper's own store, or a second worker's until it
/// is merged.
pub(super) struct Sink<'a> {
    pub entries: &'a mut Vec<KeyframeDepth>,
    pub arena: &'a mut Vec<CloudPixel>,
    pub stats: &'a mut SemiDenseStats,
    pub t_depth: &'a mut StageTimer,
    pub t_intra: &'a mut StageTimer,
    /// Arena pixels still free, shared by the workers filling one store: a keyframe
    /// reserves a whole image before it starts and gives back what it did not use.
    pub room: &'a AtomicUsize,
}

impl Workspace {
    pub fn new(
        k: Intrinsics,
        width: usize,
        height: usize,
        config: &SemiDenseConfig,
        max_features: usize,
    ) -> Self {
        let reconstructor = KeyframeReconstructor::new(k, width, height, config);
        let n = reconstructor.max_neighbours();
        Workspace {
            reconstructor,
            gray_ref: Vec::with_capacity(width * height),
            colour_ref: Vec::with_capacity(crate::image::colour::residual_len(width, height)),
            gray_nb: (0..n).map(|_| Vec::with_capacity(width * height)).collect(),
            scratch_f32: Vec::with_capacity(max_features.max(64)),
            scratch_gain: Vec::with_capacity(max_features.max(64)),
            scratch_shared: Vec::with_capacity(max_features.max(64)),
            scratch_pixels: Vec::with_capacity(width * height),
            prior: RegionalPrior::new(width, height, config.prior_cell_px),
            seed_ranges: RegionalPrior::new(width, height, config.final_seed_cell_px),
            propagated: RegionalPrior::new(width, height, config.propagate_cell_px),
            propagated_points: 0,
        }
    }

    /// Drops the buffers (no reconstruction follows).
    pub fn release(&mut self) {
        self.reconstructor.release_working_memory();
        self.gray_ref = Vec::new();
        self.colour_ref = Vec::new();
        self.gray_nb = Vec::new();
        self.scratch_pixels = Vec::new();
    }

    /// Reconstructs keyframe `kf` (depth and intra stages) into `out`, or counts why not.
    pub fn reconstruct(
        &mut self,
        config: &SemiDenseConfig,
        map: &Mutex<Map>,
        kf: KeyFrameId,
        out: &mut Sink,
        seed: Option<&SemiDenseMapper>,
    ) {
        let t0 = Instant::now();
        let Some(snap) = self.snapshot(config, map, kf, seed) else {
            out.stats.keyframes_skipped += 1;
            let alive = map
                .lock()
                .map(|m| m.keyframe(kf).is_some())
                .unwrap_or(false);
            if alive {
                out.stats.skipped_no_neighbours += 1;
            } else {
                out.stats.skipped_culled += 1;
            }
            return;
        };
        let (w, h) = (self.reconstructor.width, self.reconstructor.height);
        let reserved = out
            .room
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |r| {
                r.checked_sub(w * h)
            })
            .is_ok();
        if !reserved || out.entries.len() == out.entries.capacity() {
            if reserved {
                out.room.fetch_add(w * h, Ordering::AcqRel);
            }
            out.stats.keyframes_skipped += 1;
            out.stats.skipped_overload += 1;
            return;
        }
        let times = {
            // Neighbour poses were read under the lock with the reference's; grey images
            // were copied only for keyframes whose gradients are not cached.
            let r = &mut self.reconstructor;
            if !r.set_reference(snap.serial, Some(&self.gray_ref)) {
                out.room.fetch_add(w * h, Ordering::AcqRel);
                out.stats.keyframes_skipped += 1;
                out.stats.skipped_overload += 1;
                return;
            }
            for (k, n) in snap.neighbours.iter().enumerate() {
                let gray = n.staged.then(|| &self.gray_nb[k][..]);
                r.add_neighbour(n.serial, gray, &n.t_ji, n.delta_theta, n.gain);
            }
            let seed = if snap.seeded {
                Some(Seed {
                    ranges: &self.seed_ranges,
                    early_reject_after: config.final_seed_early_reject_after,
                    skip_unseeded: true,
                    // The keyframe's own map, searched in full online: its windows stand.
                    verify: false,
                })
            } else {
                snap.propagated.then_some(Seed {
                    ranges: &self.propagated,
                    early_reject_after: config.propagate_early_reject_after,
                    skip_unseeded: false,
                    verify: true,
                })
            };
            r.reconstruct_seeded(snap.rho_range, Some(&self.prior), seed)
        };
        self.reconstructor.export(&mut self.scratch_pixels);
        let start = out.arena.len();
        for p in &self.scratch_pixels {
            let i = p.idx as usize;
            let rgb = if snap.has_color {
                crate::image::colour::colour_at(&self.gray_ref, &self.colour_ref, w, i % w, i / w)
            } else {
                [self.gray_ref[i]; 3]
            };
            out.arena.push(CloudPixel {
                raw: *p,
                rho: 0.0,
                rgb,
            });
        }
        let len = out.arena.len() - start;
        out.room.fetch_add(w * h - len, Ordering::AcqRel);
        let (mut nb, mut nb_serials) = (heapless::Vec::new(), heapless::Vec::new());
        for n in &snap.neighbours {
            let _ = nb.push(n.id);
            let _ = nb_serials.push(n.serial);
        }
        out.entries.push(KeyframeDepth {
            keyframe: kf,
            timestamp: snap.timestamp,
            t_cw: snap.t_cw,
            neighbours: nb,
            neighbour_serials: nb_serials,
            relative_to: None,
            start,
            len,
            anchors: snap.anchors,
            scale: 1.0,
            checked: false,
            unverifiable: false,
            elapsed_ms: t0.elapsed().as_secs_f64() * 1e3,
        });
        out.stats.busy_s += t0.elapsed().as_secs_f64();
        tracing::debug!(
            timestamp = snap.timestamp,
            neighbours = snap.neighbours.len(),
            searched_pixels = times.searched_pixels,
            samples = times.samples,
            points = len,
            depth_ms = times.depth.as_secs_f64() * 1e3,
            "semi-dense keyframe"
        );
        out.t_depth.record(times.depth);
        out.t_intra.record(times.intra);
        out.stats.pixels += &PixelCounts {
            searched: times.searched_pixels,
            seeded: times.seeded,
            seed_skipped: times.seed_skipped,
            samples: times.samples,
            support_skipped: times.support_skipped,
            search_abandoned: times.abandoned,
            fused: times.fused,
            intra_kept: times.intra_kept,
            intra_grown: times.grown,
            patch_removed: times.patch_removed,
            ..PixelCounts::default()
        };
        out.stats.keyframes_reconstructed += 1;
    }

    /// Copies what reconstruction needs out of the map (short lock): images, poses, the
    /// neighbours with relative poses and in-plane rotations, and the inverse-depth prior.
    fn snapshot(
        &mut self,
        config: &SemiDenseConfig,
        map: &Mutex<Map>,
        kf: KeyFrameId,
        seed: Option<&SemiDenseMapper>,
    ) -> Option<Snapshot> {
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
        self.prior
            .finish(rho_range, config.prior_min_points, config.prior_margin);
        let mut neighbours = heapless::Vec::new();
        let max_n = self.reconstructor.max_neighbours();
        let mut angles = std::mem::take(&mut self.scratch_f32);
        let mean_rho = 0.5 * (rho_range.0 + rho_range.1);
        let min_baseline = config.min_baseline_ratio / mean_rho.max(1e-9);
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
            let gain = if config.photometric_gain {
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
        if neighbours.len() < config.lambda_n {
            return None;
        }
        let seeded =
            seed.is_some_and(|s| self.seed_from(config, s, &map, kf, rho_range, neighbours.len()));
        let propagated = !seeded
            && std::mem::take(&mut self.propagated_points) >= config.propagate_min_points.max(1);
        if propagated {
            self.propagated.finish(
                rho_range,
                config.propagate_min_points,
                config.propagate_margin,
            );
        }
        self.gray_ref.clear();
        self.gray_ref.extend_from_slice(&k.gray);
        self.colour_ref.clear();
        if k.has_color {
            self.colour_ref.extend_from_slice(&k.colour);
        }
        Some(Snapshot {
            t_cw: k.t_cw,
            timestamp: k.timestamp,
            serial: k.serial,
            has_color: k.has_color,
            neighbours,
            rho_range,
            anchors,
            seeded,
            propagated,
        })
    }

    /// Fills the seed ranges from `online`'s depth map of keyframe `kf` (checked pixels, in
    /// today's depth scale). False when it has none, too few to narrow anything, or was
    /// searched in fewer neighbours than the `n_neighbours` of this pass (its gaps may be
    /// what the missing neighbours would fill: the keyframe is then searched in full).
    fn seed_from(
        &mut self,
        config: &SemiDenseConfig,
        online: &SemiDenseMapper,
        map: &Map,
        kf: KeyFrameId,
        rho_range: (f64, f64),
        n_neighbours: usize,
    ) -> bool {
        if !self.seed_ranges.enabled() {
            return false;
        }
        let Some(e) = online
            .entries
            .iter()
            .find(|e| e.keyframe == kf && e.checked)
        else {
            return false;
        };
        if e.neighbours.len() < n_neighbours {
            return false;
        }
        let Some(k) = map.keyframe(kf) else {
            return false;
        };
        // depth now = depth then x scale (loop corrections and BA since).
        let scale =
            super::output::anchor_scale(map, e, &k.t_cw, &mut self.scratch_f32).unwrap_or(e.scale);
        self.seed_ranges.clear();
        let w = self.reconstructor.width;
        let mut n = 0;
        for p in online.pixels(e).filter(|p| p.rho > 0.0) {
            let i = p.raw.idx as usize;
            self.seed_ranges
                .add((i % w) as f32, (i / w) as f32, p.rho / scale);
            n += 1;
        }
        self.seed_ranges.finish(
            rho_range,
            config.final_seed_min_points,
            config.final_seed_margin,
        );
        n >= config.final_seed_min_points.max(1)
    }
}
