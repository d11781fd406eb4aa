//! Semi-dense mapping settings: the paper's published parameters and the tuned additions,
//! with the mode that switches the additions off.

use serde::{Deserialize, Serialize};

/// Which semi-dense algorithm runs: the paper's, or the paper's with the additions measured
/// to help (docs/DECISIONS.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SemiDenseMode {
    /// The paper as written: every addition below off, whatever its setting (readings of
    /// the text where it is ambiguous: [`SemiDenseConfig::PAPER_READINGS`]).
    Paper,
    /// The additions on as configured (`early_reject_after`, `row_support_gate`, `min_baseline_ratio`,
    /// `max_similarity_error`, `consensus_window`, `prior_cell_px`, `min_patch_zncc`,
    /// `contrast_reference`, `photometric_gain`, `final_seed_cell_px`).
    #[default]
    Tuned,
}

/// Semi-dense mapping (Mur-Artal & Tardós, RSS 2015, section III).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SemiDenseConfig {
    pub enabled: bool,
    /// `paper` switches off every addition to the paper; `tuned` (default) keeps them.
    pub mode: SemiDenseMode,
    /// The inter-keyframe consistency check (section III-E); off only to measure what it
    /// removes (the paper's claim of few outliers rests on it).
    pub inter_check: bool,
    /// N: covisible keyframes searched per keyframe.
    pub n_neighbours: usize,
    /// sigma_I: intensity noise, grey levels.
    pub sigma_i: f64,
    /// lambda_G: gradient modulus threshold (Scharr / 32, intensity per pixel).
    pub lambda_g: f64,
    /// lambda_L: maximum angle between gradient and epipolar line, degrees.
    pub lambda_l_deg: f64,
    /// lambda_theta: maximum gradient orientation difference, degrees.
    pub lambda_theta_deg: f64,
    /// lambda_N: compatible hypotheses needed.
    pub lambda_n: usize,
    /// theta: gradient-to-intensity noise variance ratio of the Scharr operator.
    pub theta: f64,
    /// Keyframes of delay before a keyframe is reconstructed.
    pub keyframe_delay: usize,
    /// Worker threads for per-pixel work.
    pub threads: usize,
    /// Largest similarity error e(u0) (eq. 3) accepted as a match; not in the paper, which
    /// keeps the best pixel whatever its error. 5.99 is the 95% chi-square bound of eq. 3's
    /// two normalised residuals.
    pub max_similarity_error: f64,
    /// Smallest baseline of a neighbour, as a fraction of the keyframe's mean scene depth
    /// (from its prior). Not in the paper, which relies on keyframes being wide-baseline:
    /// near-duplicate keyframes give wide hypotheses compatible with wrong ones.
    pub min_baseline_ratio: f64,
    /// Once two neighbours give compatible hypotheses (eq. 10), search the remaining ones only
    /// where a hypothesis could still be compatible with them (rho +- 2.45 sigma of each, 2.45
    /// = sqrt(chi2 95%, 2 dof)) instead of the whole prior interval. Not in the paper, off by
    /// default: a remaining neighbour whose best match lies elsewhere contributes its best
    /// match inside the window instead of an outlier, which on `desk` gave ~10% more points
    /// but 0.9-1.2% outliers (0.65-0.9% without) for only ~5% less depth-stage time.
    pub consensus_window: bool,
    /// Early rejection (not in the paper, which searches all N neighbours): once this many
    /// neighbours have been searched, a pixel whose hypotheses include no compatible pair
    /// (eq. 10) is dropped. On `desk` four in five pixels are in that state after three
    /// neighbours and only 4% of them would be fused: they are ambiguous (several similar
    /// pixels on each line), and the search stops after 3 of 7 neighbours. 0 = off.
    pub early_reject_after: usize,
    /// Two-pass search (not in the paper, which searches every pixel): even rows first,
    /// then a pixel of an odd row only where one of the six pixels above and below it
    /// (columns x-1..=x+1 of rows y-1 and y+1) was fused. An unsupported pixel is rarely
    /// kept by the intra-keyframe check (III-D needs neighbours that agree): on desk half
    /// the odd-row pixels are unsupported and they hold about 1% of the odd rows' points the
    /// check keeps, while their searches are a quarter of the depth stage. It makes the depth
    /// stage about 10% faster and costs 2-6% of the points; with propagation
    /// (`propagate_cell_px`) the cloud keeps more points than without either (posters and
    /// low-light 10.3-10.5k per keyframe, desk +23%, docs/PERFORMANCE.md).
    pub row_support_gate: bool,
    /// Regional prior (not in the paper, see `semidense::prior`): cell side in pixels of the
    /// grid whose cells search only the inverse depths of the ORB map points around them
    /// (widened by `prior_margin`, within the paper's interval); 0 = the paper's one interval.
    pub prior_cell_px: usize,
    /// Patch check (not in the paper, see `semidense::patch`): after the intra-keyframe step
    /// an estimate whose 3 x 3 patch, carried into the first 3 neighbours at its inverse
    /// depth, correlates (ZNCC) below this with any of them is dropped: a background pixel
    /// beside an occluding contour that took the foreground's depth. 0 = off.
    pub min_patch_zncc: f64,
    /// Relative widening of a cell's [min, max] map-point inverse depth.
    pub prior_margin: f64,
    /// Map points needed in a cell and its 8 neighbours for a regional range.
    pub prior_min_points: usize,
    /// Nice value added to the semi-dense threads (Linux), so tracking always wins a core.
    pub nice: i32,
    /// Run the semi-dense threads in Linux's SCHED_IDLE class (only on otherwise idle CPUs;
    /// a waking tracking thread preempts them at once).
    pub sched_idle: bool,
    /// Semi-dense workers also wait between blocks of pixels while a frame is being tracked
    /// (not only yield the CPU, as SCHED_IDLE does). Off by default: since ORB extraction
    /// runs on both cores, a frame leaves one core idle only while tracking is
    /// single-threaded, and 15 paired desk runs showed no effect of the wait on tracking
    /// (p50 7.0 vs 7.1 ms, same misses) but 6% slower keyframes (docs/DECISIONS.md). For CPUs
    /// whose cores share execution units (SMT siblings) turn it on.
    pub yield_to_tracking: bool,
    /// CPUs for the semi-dense thread and its workers; empty = no pinning.
    pub cpus: Vec<usize>,
    /// Capacity of the stored semi-dense pixels over the run (a full store skips keyframes,
    /// counted in the report).
    pub max_points: usize,
    /// Contrast normalisation (not in the paper, whose lambda_G and sigma_I are grey levels
    /// of a well-exposed image): a keyframe whose grey-level spread (5th to 95th percentile)
    /// is below this has both scaled down with its spread (at most 8x), as if its contrast
    /// were stretched to this. In a dim room (`synthetic:low-light`, spread 23-28) the cloud
    /// otherwise keeps 1.1k points per keyframe instead of 10k, at the same accuracy. 0 = off.
    /// Desk, posters, KITTI and EuRoC frames spread 100-240 and are untouched.
    pub contrast_reference: f64,
    /// Exposure compensation (not in the paper, which compares intensities as they are):
    /// each neighbour's intensity over the keyframe's is measured at their shared ORB points
    /// (median ratio of 5x5 patch means, see `semidense::photometric`) and the keyframe's
    /// intensity and gradient modulus are scaled by it before the comparison (eq. 2). With
    /// auto exposure (most USB cameras) the gain moves from frame to frame; on desk with a
    /// random 0.75-1.25 gain per frame the cloud otherwise loses most of its points.
    pub photometric_gain: bool,
    /// End-of-session seed (not in the paper): the end-of-session pass re-reconstructs a
    /// keyframe where its online depth map found depth. A pixel is searched only near the
    /// inverse depths that map (brought to today's scale) holds in the 3 x 3 cells of this
    /// side around it, widened by `final_seed_margin`, when they hold
    /// `final_seed_min_points`; other pixels are not searched (on the synthetic scenes they
    /// gave about 1% of the points for a third of the time). A keyframe without an online
    /// map, or whose online search had fewer neighbours than this pass, is searched in full.
    /// A seeded keyframe's pixels are dropped after `final_seed_early_reject_after`
    /// neighbours without a compatible pair (see `early_reject_after`): in a narrow window
    /// good pixels agree early. On desk 2x faster, more points, fewer outliers; elsewhere
    /// 10-20% fewer points with better medians (docs/PERFORMANCE.md). 0 = off.
    pub final_seed_cell_px: usize,
    pub final_seed_margin: f64,
    pub final_seed_min_points: usize,
    pub final_seed_early_reject_after: usize,
    /// Online propagation (not in the paper, which searches each keyframe from scratch):
    /// the depth maps of the keyframe's neighbours already reconstructed are carried into
    /// it (at today's poses and scale) and, where the 3 x 3 cells of this side around a
    /// pixel hold `propagate_min_points` of their inverse depths, the pixel's search visits
    /// only their [min, max] widened by `propagate_margin`, and it is dropped after
    /// `propagate_early_reject_after` neighbours without a compatible pair. Pixels elsewhere
    /// (what the neighbours did not reconstruct: new or uncertain surfaces) are searched
    /// over the prior as usual. A window hides the rest of the segment, and with it the
    /// ambiguity of a repetitive texture (a wrong depth carried in would be confirmed in
    /// every neighbour: repetitive's outliers 0.17 -> 2.3%): a pixel's neighbours are searched
    /// in full until one gives a hypothesis, and the window is kept only if that one lands
    /// in it. Desk keeps 23% more points at the same accuracy; with the row support gate the
    /// depth stage is 7-23% faster than without either (docs/PERFORMANCE.md). 0 = off.
    pub propagate_cell_px: usize,
    pub propagate_margin: f64,
    pub propagate_min_points: usize,
    pub propagate_early_reject_after: usize,
}

impl Default for SemiDenseConfig {
    fn default() -> Self {
        SemiDenseConfig {
            enabled: true,
            mode: SemiDenseMode::Tuned,
            inter_check: true,
            n_neighbours: 7,
            sigma_i: 20.0,
            lambda_g: 8.0,
            lambda_l_deg: 80.0,
            lambda_theta_deg: 45.0,
            lambda_n: 3,
            theta: 0.23,
            keyframe_delay: 10,
            threads: 2,
            max_similarity_error: 5.99,
            consensus_window: false,
            early_reject_after: 3,
            row_support_gate: true,
            prior_cell_px: 32,
            min_patch_zncc: 0.5,
            prior_margin: 0.25,
            prior_min_points: 6,
            nice: 10,
            sched_idle: true,
            yield_to_tracking: false,
            cpus: Vec::new(),
            min_baseline_ratio: 0.05,
            max_points: 8_000_000,
            contrast_reference: 64.0,
            photometric_gain: true,
            final_seed_cell_px: 8,
            final_seed_margin: 0.02,
            final_seed_min_points: 3,
            final_seed_early_reject_after: 2,
            propagate_cell_px: 8,
            propagate_margin: 0.05,
            propagate_min_points: 3,
            propagate_early_reject_after: 3,
        }
    }
}

impl SemiDenseConfig {
    /// How the paper's text is read where it is ambiguous (recorded in report.json). On
    /// "n >= lambda_N": sections III-C and III-E say "at least lambda_N"; the sentence
    /// before eq. 10 says "n > lambda_N".
    pub const PAPER_READINGS: &'static [&'static str] = &[
        "fusion and inter-keyframe check: n >= lambda_N ('at least lambda_N')",
        "prior interval rho_0 +- 2 sigma_rho0, lower bound clamped at 0 (infinity)",
        "rho_0, sigma_rho0: mean and std of the observed map points' inverse depths (>= 10 points)",
        "neighbours: the N best covisible keyframes, no baseline filter",
        "best match kept whatever its similarity error",
    ];

    /// The settings in force: in paper mode every addition is switched off.
    pub fn in_force(&self) -> SemiDenseConfig {
        match self.mode {
            SemiDenseMode::Tuned => self.clone(),
            SemiDenseMode::Paper => SemiDenseConfig {
                early_reject_after: 0,
                row_support_gate: false,
                min_baseline_ratio: 0.0,
                max_similarity_error: f64::INFINITY,
                consensus_window: false,
                prior_cell_px: 0,
                min_patch_zncc: 0.0,
                contrast_reference: 0.0,
                photometric_gain: false,
                final_seed_cell_px: 0,
                propagate_cell_px: 0,
                ..self.clone()
            },
        }
    }

    /// The settings in force that are not the paper's, as (name, value) for the report.
    pub fn non_paper_settings(&self) -> Vec<(String, String)> {
        let c = self.in_force();
        let mut out = Vec::new();
        let mut add = |on: bool, name: &str, value: String| {
            if on {
                out.push((name.to_string(), value));
            }
        };
        add(
            c.early_reject_after > 0,
            "early_reject_after",
            c.early_reject_after.to_string(),
        );
        add(c.row_support_gate, "row_support_gate", "true".into());
        add(
            c.min_baseline_ratio > 0.0,
            "min_baseline_ratio",
            c.min_baseline_ratio.to_string(),
        );
        add(
            c.max_similarity_error.is_finite(),
            "max_similarity_error",
            c.max_similarity_error.to_string(),
        );
        add(c.consensus_window, "consensus_window", "true".into());
        add(
            c.prior_cell_px > 0,
            "prior_cell_px",
            c.prior_cell_px.to_string(),
        );
        add(
            c.min_patch_zncc > 0.0,
            "min_patch_zncc",
            c.min_patch_zncc.to_string(),
        );
        add(!c.inter_check, "inter_check", "false".into());
        add(
            c.contrast_reference > 0.0,
            "contrast_reference",
            c.contrast_reference.to_string(),
        );
        add(c.photometric_gain, "photometric_gain", "true".into());
        add(
            c.final_seed_cell_px > 0,
            "final_seed_cell_px",
            format!(
                "{} (margin {}, {} points, early rejection after {})",
                c.final_seed_cell_px,
                c.final_seed_margin,
                c.final_seed_min_points,
                c.final_seed_early_reject_after
            ),
        );
        add(
            c.propagate_cell_px > 0,
            "propagate_cell_px",
            format!(
                "{} (margin {}, {} points, early rejection after {})",
                c.propagate_cell_px,
                c.propagate_margin,
                c.propagate_min_points,
                c.propagate_early_reject_after
            ),
        );
        out
    }
}
