//! Online propagation (not in the paper, `[semidense] propagate_*`): a keyframe's
//! neighbours were mostly reconstructed before it, and what they found is where its own
//! pixels will find depth. Their depth maps, carried into the keyframe at today's poses and
//! scales, give per-cell inverse-depth ranges; a pixel inside them searches only that
//! window of its epipolar segments once a full search agrees with it (see
//! [`super::Seed`]). The paper searches each keyframe over the whole prior interval; most
//! of the samples of a search then lie where no neighbour saw a surface.

use super::workspace::Workspace;
use super::*;

/// A neighbour's entry to carry into the keyframe: its index in the entries, the transform
/// from its camera to the keyframe's, and its depth scale now.
pub(super) type Source = (usize, Se3, f32);

/// The entries of `kf`'s covisible keyframes (at most `max` of them) already reconstructed,
/// with their poses relative to `kf` and depth scales now: read under the map lock, so the
/// pixels can be carried without it.
pub(super) fn sources(
    map: &Map,
    kf: KeyFrameId,
    entries: &[KeyframeDepth],
    max: usize,
    scratch: &mut Vec<f32>,
) -> heapless::Vec<Source, MAX_NEIGHBOURS> {
    let mut out = heapless::Vec::new();
    let Some(k) = map.keyframe(kf) else {
        return out;
    };
    for nb in k.best_covisibles(max) {
        let Some(e) = entries.iter().rposition(|e| e.keyframe == nb) else {
            continue;
        };
        let (t_cw_j, scale) = pose_and_scale_now(map, &entries[e], entries, scratch);
        if out.push((e, k.t_cw.0 * t_cw_j.0.inverse(), scale)).is_err() {
            break;
        }
    }
    out
}

impl Workspace {
    /// Adds the estimates of the `sources` (their pixels in `arena`: the inter-checked depth
    /// once checked, the intra-checked one before) to the propagation grid, as seen from the
    /// keyframe. The grid is finished against the keyframe's prior interval in
    /// [`Workspace::snapshot`].
    pub(super) fn propagate(
        &mut self,
        sources: &[Source],
        entries: &[KeyframeDepth],
        arena: &[CloudPixel],
    ) {
        self.propagated_points = 0;
        if !self.propagated.enabled() {
            return;
        }
        self.propagated.clear();
        let (intr, w, h) = (
            self.reconstructor.k,
            self.reconstructor.width,
            self.reconstructor.height,
        );
        let mut n = 0;
        for (e, t_kj, scale) in sources {
            let e = &entries[*e];
            for p in &arena[e.start..e.start + e.len] {
                let rho = if e.checked { p.rho } else { p.raw.rho };
                if rho.is_nan() || rho <= 0.0 {
                    continue;
                }
                let i = p.raw.idx as usize;
                let x_j = intr.ray((i % w) as f64, (i / w) as f64) * (*scale as f64 / rho as f64);
                let x_k = t_kj.rotation * x_j + t_kj.translation.vector;
                if x_k.z.is_nan() || x_k.z <= 1e-9 {
                    continue;
                }
                let uv = intr.project(&x_k);
                if uv.x < 0.0 || uv.y < 0.0 || uv.x >= w as f64 || uv.y >= h as f64 {
                    continue;
                }
                self.propagated
                    .add(uv.x as f32, uv.y as f32, (1.0 / x_k.z) as f32);
                n += 1;
            }
        }
        self.propagated_points = n;
    }
}
