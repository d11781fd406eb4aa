//! The depth stage of a keyframe (III-B, III-C): every pixel with G > lambda_G searched along
//! its epipolar segment in each neighbour and its hypotheses fused, in bands of rows that the
//! reconstructor's workers share, with the additions that cut the searches (early rejection,
//! the regional prior, the row support gate).

use std::sync::atomic::{AtomicU64, Ordering};

use super::epipolar::{Hypothesis, SearchParams, StereoPair};
use super::fusion::fuse;
use super::gradients::GradientImage;
use super::RegionalPrior;
use super::MAX_NEIGHBOURS;

/// What the depth stage reads, shared by the row workers.
pub(super) struct DepthContext<'a> {
    pub(super) params: SearchParams,
    pub(super) lambda_n: usize,
    pub(super) consensus_window: bool,
    pub(super) early_reject_after: usize,
    pub(super) reference: &'a GradientImage,
    pub(super) neighbours: &'a [&'a GradientImage],
    pub(super) pairs: &'a [StereoPair],
    pub(super) rho_range: (f64, f64),
    /// Per-region ranges (inside `rho_range`), when on.
    pub(super) prior: Option<&'a RegionalPrior>,
    pub(super) seed: Option<&'a RegionalPrior>,
    /// Pixels the seed has no range for are left unsearched (end of session: the keyframe's
    /// own earlier map searched them) rather than searched over the prior (online
    /// propagation: the neighbours' maps miss what only this keyframe sees).
    pub(super) skip_unseeded: bool,
    /// Early rejection of the pixels the seed narrowed.
    pub(super) seeded_reject_after: usize,
    /// The seed's window is only a proposal, kept once a search of the full segment agrees
    /// with it (online propagation).
    pub(super) verify_seed: bool,
    pub(super) pixels: AtomicU64,
    pub(super) samples: AtomicU64,
    pub(super) seeded: AtomicU64,
    pub(super) seed_skipped: AtomicU64,
    pub(super) support_skipped: AtomicU64,
    pub(super) abandoned: AtomicU64,
    pub(super) fused: AtomicU64,
}

/// Which rows a pass of the depth stage searches (`row_support_gate`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum RowPass {
    All,
    Even,
    /// Odd rows, each pixel only where the support mask marks the pixel above or below.
    OddSupported,
}

impl RowPass {
    fn searches(self, y: usize) -> bool {
        match self {
            RowPass::All => true,
            RowPass::Even => y.is_multiple_of(2),
            RowPass::OddSupported => !y.is_multiple_of(2),
        }
    }
}

/// Marks each pixel of an even row that was fused or has a fused pixel beside it in its row
/// (odd rows' entries are not read).
pub(super) fn mark_support(fused_s2: &[f32], w: usize, support: &mut [bool]) {
    if w == 0 {
        return;
    }
    for (row, (s2, out)) in fused_s2
        .chunks_exact(w)
        .zip(support.chunks_exact_mut(w))
        .enumerate()
    {
        if !row.is_multiple_of(2) {
            continue;
        }
        for (x, o) in out.iter_mut().enumerate() {
            let (a, b) = (x.saturating_sub(1), (x + 1).min(w - 1));
            *o = s2[a..=b].iter().any(|&v| v > 0.0);
        }
    }
}

/// Rows per task of the depth stage, and columns per block within it.
pub(super) const DEPTH_BAND_ROWS: usize = 8;
const DEPTH_BLOCK_COLUMNS: usize = 16;

impl DepthContext<'_> {
    /// The rows of `pass` among rows `y0..` of the output (`out_*` hold whole rows; a pass
    /// clears its rows first); each block of columns first waits for `gate` (tracking busy).
    pub(super) fn band(
        &self,
        y0: usize,
        (w, h): (usize, usize),
        (out_rho, out_s2): (&mut [f32], &mut [f32]),
        pass: RowPass,
        support: &[bool],
        gate: Option<&crate::threads::ForegroundGate>,
    ) {
        let rows = out_rho.len() / w.max(1);
        for r in 0..rows {
            if pass.searches(y0 + r) {
                out_rho[r * w..(r + 1) * w].fill(0.0);
                out_s2[r * w..(r + 1) * w].fill(0.0);
            }
        }
        let (ya, yb) = (y0.max(2), (y0 + rows).min(h.saturating_sub(2)));
        let mut counts = RowCounts::default();
        let mut x0 = 2;
        while x0 + 2 < w {
            if let Some(g) = gate {
                g.wait();
            }
            let x1 = (x0 + DEPTH_BLOCK_COLUMNS).min(w - 2);
            for y in (ya..yb).filter(|&y| pass.searches(y)) {
                let o = (y - y0) * w;
                // Rows 2.. h-3 only, so the rows above and below exist.
                let gate_rows = (pass == RowPass::OddSupported).then(|| {
                    (
                        &support[(y - 1) * w..y * w],
                        &support[(y + 1) * w..(y + 2) * w],
                    )
                });
                self.pixels_of_row(
                    y,
                    x0..x1,
                    w,
                    (&mut out_rho[o..o + w], &mut out_s2[o..o + w]),
                    gate_rows,
                    &mut counts,
                );
            }
            x0 = x1;
        }
        self.pixels.fetch_add(counts.pixels, Ordering::Relaxed);
        self.samples.fetch_add(counts.samples, Ordering::Relaxed);
        self.seeded.fetch_add(counts.seeded, Ordering::Relaxed);
        self.seed_skipped
            .fetch_add(counts.seed_skipped, Ordering::Relaxed);
        self.support_skipped
            .fetch_add(counts.support_skipped, Ordering::Relaxed);
        self.abandoned
            .fetch_add(counts.abandoned, Ordering::Relaxed);
        self.fused.fetch_add(counts.fused, Ordering::Relaxed);
    }

    /// Pixels `xs` of row `y` (at least two pixels inside the image); with `support` (the
    /// marks of the rows above and below), only the pixels it marks.
    fn pixels_of_row(
        &self,
        y: usize,
        xs: std::ops::Range<usize>,
        w: usize,
        (out_rho, out_s2): (&mut [f32], &mut [f32]),
        support: Option<(&[bool], &[bool])>,
        counts: &mut RowCounts,
    ) {
        let samples = &mut counts.samples;
        let codes = &self.reference.packed[y * w..(y + 1) * w];
        let mut hyps = [Hypothesis::default(); MAX_NEIGHBOURS];
        for x in xs {
            // Pixels with G > lambda_G carry a non-zero code.
            if codes[x] & 255 == 0 {
                continue;
            }
            if support.is_some_and(|(above, below)| !above[x] && !below[x]) {
                counts.support_skipped += 1;
                continue;
            }
            // A seed narrows the samples visited, not the segment: its parallax check and
            // sub-pixel step stay those of the prior range (a few-percent window on a short
            // baseline is under a pixel of line). Where it has nothing, nothing is searched.
            let mut window = None;
            if let Some(seed) = self.seed {
                window = seed.narrowed_range(x, y);
                if window.is_some() {
                    counts.seeded += 1;
                } else if self.skip_unseeded {
                    counts.seed_skipped += 1;
                    continue;
                }
            }
            // A propagated window hides the rest of the segment, and with it the ambiguity
            // of a repetitive texture (a wrong depth carried in from a neighbour would be
            // confirmed in every neighbour). Neighbours are searched in full until one gives
            // a hypothesis; the window is kept for the rest only when that one lands in it.
            let mut proposed = None;
            if self.verify_seed {
                proposed = window.take();
            }
            let mut reject_after = if window.is_some() {
                self.seeded_reject_after
            } else {
                self.early_reject_after
            };
            let p = &self.reference.at(x, y);
            counts.pixels += 1;
            let rho_range = self.prior.map_or(self.rho_range, |p| p.range(x, y));
            let mut agreed = false;
            let mut n = 0;
            let total = self.pairs.len();
            for (j, (pair, img)) in self.pairs.iter().zip(self.neighbours).enumerate() {
                if self.gives_up(j, total, reject_after, &hyps[..n]) {
                    counts.abandoned += 1;
                    break;
                }
                if let Some(hy) = pair.search_within(
                    &self.params,
                    x as f64,
                    y as f64,
                    p,
                    rho_range,
                    window,
                    img,
                    samples,
                ) {
                    hyps[n] = hy;
                    n += 1;
                    if let Some((lo, hi)) = proposed.take() {
                        let k = 2.0 * hy.sigma as f64;
                        if hy.rho as f64 + k >= lo && hy.rho as f64 - k <= hi {
                            window = Some((lo, hi));
                            reject_after = self.seeded_reject_after;
                        }
                    }
                    if self.consensus_window && !agreed {
                        if let Some(w) = consensus_window(&hyps[..n]) {
                            (window, agreed) = (Some(w), true);
                        }
                    }
                }
            }
            if let Some((r, s2)) = fuse(&hyps[..n], self.lambda_n) {
                out_rho[x] = r;
                out_s2[x] = s2;
                counts.fused += 1;
            }
        }
    }
}

/// A band's counters, added to the context's once per band.
#[derive(Default)]
struct RowCounts {
    pixels: u64,
    samples: u64,
    seeded: u64,
    seed_skipped: u64,
    support_skipped: u64,
    abandoned: u64,
    fused: u64,
}

impl DepthContext<'_> {
    /// Whether searching neighbour `j` (of `total`) on, with hypotheses `h` so far, cannot
    /// give the pixel an estimate: fewer than lambda_N hypotheses remain possible (fusion
    /// would reject it), or it is ambiguous at the early-rejection point (config
    /// `early_reject_after`, here `at`: no two hypotheses agree), or will be (no pair can
    /// form by then).
    fn gives_up(&self, j: usize, total: usize, at: usize, h: &[Hypothesis]) -> bool {
        let n = h.len();
        if n + (total - j) < self.lambda_n {
            return true;
        }
        if at == 0 || at > total {
            return false;
        }
        (j < at && n + (at - j) < 2) || (j == at && !has_compatible_pair(h))
    }
}

/// Whether two of the hypotheses pass eq. 10's compatibility test.
fn has_compatible_pair(h: &[Hypothesis]) -> bool {
    h.iter().enumerate().any(|(i, a)| {
        h[i + 1..]
            .iter()
            .any(|b| super::fusion::compatible(a.rho, a.sigma * a.sigma, b.rho, b.sigma * b.sigma))
    })
}

/// The inverse depths a further hypothesis must fall in to be compatible (eq. 10) with the
/// newest hypothesis and one earlier hypothesis it is compatible with: rho +- sqrt(5.99) sigma
/// of each of the two (a wider new hypothesis only narrows the test). `None` until such a
/// pair exists.
fn consensus_window(h: &[Hypothesis]) -> Option<(f64, f64)> {
    let (last, earlier) = h.split_last()?;
    let k = super::fusion::CHI2_2DOF_95.sqrt();
    let partner = earlier.iter().find(|e| {
        super::fusion::compatible(e.rho, e.sigma * e.sigma, last.rho, last.sigma * last.sigma)
    })?;
    let lo = (last.rho - k * last.sigma).min(partner.rho - k * partner.sigma);
    let hi = (last.rho + k * last.sigma).max(partner.rho + k * partner.sigma);
    Some((lo as f64, hi as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn h(rho: f32, sigma: f32) -> Hypothesis {
        Hypothesis { rho, sigma }
    }

    #[test]
    fn support_marks_fused_pixels_and_their_row_neighbours_on_even_rows_only() {
        let (w, h) = (6, 4);
        let mut s2 = vec![0.0f32; w * h];
        s2[2] = 0.1; // row 0, x = 2
        s2[w * 2 + 5] = 0.1; // row 2, last column
        s2[w + 3] = 0.1; // row 1 (odd): not a support
        let mut support = vec![false; w * h];
        mark_support(&s2, w, &mut support);
        let row = |y: usize| support[y * w..(y + 1) * w].to_vec();
        assert_eq!(row(0), [false, true, true, true, false, false]);
        assert_eq!(row(1), [false; 6]);
        assert_eq!(row(2), [false, false, false, false, true, true]);
        assert!(RowPass::Even.searches(2) && !RowPass::Even.searches(3));
        assert!(RowPass::OddSupported.searches(3) && RowPass::All.searches(3));
    }

    #[test]
    fn a_compatible_pair_is_found_among_incompatible_hypotheses() {
        assert!(!has_compatible_pair(&[]));
        assert!(!has_compatible_pair(&[h(1.0, 0.01)]));
        assert!(!has_compatible_pair(&[
            h(1.0, 0.01),
            h(1.5, 0.01),
            h(2.0, 0.01)
        ]));
        assert!(has_compatible_pair(&[
            h(1.0, 0.01),
            h(1.5, 0.01),
            h(1.505, 0.01)
        ]));
    }

    #[test]
    fn consensus_window_needs_a_compatible_pair_and_covers_both() {
        assert_eq!(consensus_window(&[h(1.0, 0.01)]), None);
        // Incompatible: 0.5 apart with sigmas 0.01.
        assert_eq!(consensus_window(&[h(1.0, 0.01), h(1.5, 0.01)]), None);
        let (lo, hi) = consensus_window(&[h(1.5, 0.01), h(1.0, 0.01), h(1.01, 0.02)]).unwrap();
        let k = super::super::fusion::CHI2_2DOF_95.sqrt() as f64;
        assert!((lo - (1.01 - k * 0.02)).abs() < 1e-6, "{lo}");
        assert!((hi - (1.01 + k * 0.02)).abs() < 1e-6, "{hi}");
    }
}
