//! Every tunable, with its published name and default. Loaded from TOML (`--config FILE`);
//! unknown keys are rejected so a typo never silently falls back to a default.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

mod pipeline;

pub use crate::geometry::pnp::PnpRansacConfig;
pub use crate::geometry::two_view::TwoViewConfig;
pub use pipeline::{LocalMappingConfig, LoopClosingConfig, MotionOnlyConfig, TrackingConfig};

/// ORB extraction (Rublee et al. 2011; ORB-SLAM's defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OrbConfig {
    /// Features per 640x480 image.
    pub n_features: usize,
    /// Pyramid scale factor between levels.
    pub scale_factor: f64,
    /// Pyramid levels.
    pub n_levels: usize,
    /// FAST threshold, then the fallback for cells with no corner.
    pub ini_th_fast: u8,
    pub min_th_fast: u8,
    /// A third FAST pass for weakly textured images (blank walls): when a pyramid level has
    /// fewer corners than its share of `n_features` after the two passes above, its cells
    /// still empty are searched again at this threshold. Only those cells of those levels:
    /// textured images are unchanged. 0 = off (ORB-SLAM has no such pass). 5 by default: on
    /// the weak walls of the outward loop it keeps one map over every frame (4 let the scale
    /// collapse, 6 finds too few corners; docs/PERFORMANCE.md).
    pub starved_th_fast: u8,
    /// Quadtree nodes per wanted feature before keeping the strongest node winners. 1.0 is
    /// ORB-SLAM's distribution (most even, least repeatable); larger values favour strong,
    /// repeatable corners (see docs/DECISIONS.md for the measurements).
    pub quadtree_oversampling: f64,
    /// Response ranking the node winners (and reported as keypoint response): `fast` (the
    /// FAST threshold score, ORB-SLAM) or `harris` (OpenCV's ORB default).
    pub score_type: OrbScore,
    /// How a level's corners are spread: `quadtree` (ORB-SLAM), `strongest` (no spreading,
    /// OpenCV's ORB: most repeatable, but 2-3x the keyframe error on the synthetic sequences,
    /// docs/DECISIONS.md) or `radius` (strongest first with the largest suppression radius
    /// that keeps the count).
    pub distribution: OrbDistribution,
    /// Candidates per wanted feature whose response is computed (the strongest by FAST score).
    pub candidates: f64,
    /// Threads for one extraction (1 or 2): with 2 the pyramid levels are shared out between
    /// two workers (same output). `sdslam features` always measures one thread.
    pub threads: usize,
}

impl Default for OrbConfig {
    fn default() -> Self {
        OrbConfig {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            ini_th_fast: 20,
            min_th_fast: 7,
            starved_th_fast: 5,
            quadtree_oversampling: 2.0,
            score_type: OrbScore::Fast,
            distribution: OrbDistribution::Quadtree,
            candidates: 10.0,
            threads: 2,
        }
    }
}

/// How ORB spreads a level's corners over the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OrbDistribution {
    Quadtree,
    Radius,
    Strongest,
}

/// How ORB ranks corners (Rublee et al. 2011 rank FAST corners by the Harris measure).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OrbScore {
    Harris,
    Fast,
}

/// Which semi-dense algorithm runs: the paper's, or the paper's with the additions measured
/// to help (docs/DECISIONS.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SemiDenseMode {
    /// The paper as written: every addition below off, whatever its setting (readings of
    /// the text where it is ambiguous: [`SemiDenseConfig::PAPER_READINGS`]).
    Paper,
    /// The additions on as configured (`early_reject_after`, `min_baseline_ratio`,
    /// `max_similarity_error`, `consensus_window`, `prior_cell_px`, `min_patch_zncc`,
    /// `contrast_reference`, `photometric_gain`).
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
                min_baseline_ratio: 0.0,
                max_similarity_error: f64::INFINITY,
                consensus_window: false,
                prior_cell_px: 0,
                min_patch_zncc: 0.0,
                contrast_reference: 0.0,
                photometric_gain: false,
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
        out
    }
}

/// Real-time behaviour.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RuntimeConfig {
    /// Per-frame budget in milliseconds; `None` means 1/fps of the source.
    pub deadline_ms: Option<f64>,
    /// Real-time replay speed (1.0 = recorded rate).
    pub realtime_speed: f64,
    /// CPUs for the tracking (calling) thread and the local-mapping thread; empty = no pinning.
    pub tracking_cpus: Vec<usize>,
    pub mapping_cpus: Vec<usize>,
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        RuntimeConfig {
            deadline_ms: None,
            realtime_speed: 1.0,
            tracking_cpus: Vec::new(),
            mapping_cpus: Vec::new(),
        }
    }
}

/// Capacities of the preallocated map (a full map evicts, never grows).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapCapacityConfig {
    pub max_keyframes: usize,
    pub max_map_points: usize,
    /// A full bundle adjustment of the map when a run finishes (offline refinement of the
    /// keyframe poses written to keyframes.txt and used by the cloud).
    pub final_global_ba: bool,
    /// A full BA on a background thread after each loop closure, merged without stopping
    /// tracking (built-in sequence, deterministic: keyframe ATE 0.36 -> 0.20 cm).
    pub global_ba_after_loop: bool,
    /// Levenberg-Marquardt iterations of the full BA after a loop (ORB-SLAM: 10) and of the
    /// final one.
    pub global_ba_iterations: usize,
    pub final_ba_iterations: usize,
}

impl Default for MapCapacityConfig {
    fn default() -> Self {
        MapCapacityConfig {
            max_keyframes: 500,
            max_map_points: 100_000,
            final_global_ba: true,
            global_ba_after_loop: true,
            global_ba_iterations: 10,
            final_ba_iterations: 15,
        }
    }
}

/// Upper bounds of the sizes, far beyond any use but below where counts overflow or a
/// machine's memory runs out before the run starts. What a configuration reserves within them
/// is checked against the machine's memory by the caller (`System::reserved_memory`).
pub const MAX_FEATURES: usize = 100_000;
pub const MAX_KEYFRAMES: usize = 100_000;
pub const MAX_MAP_POINTS: usize = 50_000_000;
pub const MAX_SEMIDENSE_POINTS: usize = 2_000_000_000;
/// Largest count of iterations, rounds, neighbours or matches a stage accepts.
pub const MAX_ITERATIONS: usize = 100_000;
/// Worker threads for per-pixel work (more only oversubscribe the cores).
pub const MAX_THREADS: usize = 64;
/// Most neighbours a semi-dense keyframe is searched against (fixed-size buffers).
pub const MAX_NEIGHBOURS: usize = 16;

/// The whole configuration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub orb: OrbConfig,
    /// Two-view initialisation (H and F by RANSAC, model selection, parallax).
    pub initialisation: TwoViewConfig,
    pub tracking: TrackingConfig,
    /// Motion-only BA of every tracked frame.
    pub motion_only: MotionOnlyConfig,
    /// EPnP + RANSAC of relocalisation.
    pub relocalisation: PnpRansacConfig,
    pub local_mapping: LocalMappingConfig,
    pub loop_closing: LoopClosingConfig,
    pub semidense: SemiDenseConfig,
    pub runtime: RuntimeConfig,
    pub map: MapCapacityConfig,
}

impl Config {
    /// Parses TOML text; `path` names the file in errors (with line and column).
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let cfg: Config = toml::from_str(text).map_err(|e| Error::Config {
            path: path.to_path_buf(),
            message: {
                let loc = e.span().map(|s| {
                    let line = text[..s.start.min(text.len())].matches('\n').count() + 1;
                    format!("line {line}: ")
                });
                format!("{}{}", loc.unwrap_or_default(), e.message())
            },
        })?;
        cfg.validate(path)?;
        Ok(cfg)
    }

    pub fn load(path: &Path) -> Result<Self> {
        let text =
            sdslam_camera::capped::read_text_capped(path, sdslam_camera::capped::SETTINGS_CAP)
                .map_err(|e| Error::io(path, e))?;
        Self::parse(&text, path)
    }

    fn validate(&self, path: &Path) -> Result<()> {
        let bad = |field: &str, why: &str| {
            Err(Error::Config {
                path: path.to_path_buf(),
                message: format!("field `{field}`: {why}"),
            })
        };
        if self.orb.scale_factor <= 1.0 || !self.orb.scale_factor.is_finite() {
            return bad("orb.scale_factor", "must be a finite number > 1");
        }
        if !(1..=2).contains(&self.orb.threads) {
            return bad("orb.threads", "must be 1 or 2");
        }
        if self.orb.n_levels == 0 || self.orb.n_levels > 16 {
            return bad("orb.n_levels", "must be in 1..=16");
        }
        if !(1..=MAX_FEATURES).contains(&self.orb.n_features) {
            return bad("orb.n_features", &format!("must be in 1..={MAX_FEATURES}"));
        }
        if !(1.0..=100.0).contains(&self.orb.quadtree_oversampling) {
            return bad("orb.quadtree_oversampling", "must be in 1..=100");
        }
        if !(self.orb.candidates >= 1.0 && self.orb.candidates <= 1000.0) {
            return bad("orb.candidates", "must be in 1..=1000");
        }
        if self.orb.min_th_fast > self.orb.ini_th_fast {
            return bad("orb.min_th_fast", "must not exceed orb.ini_th_fast");
        }
        if self.orb.starved_th_fast > self.orb.min_th_fast {
            return bad(
                "orb.starved_th_fast",
                "must not exceed orb.min_th_fast (0 = off)",
            );
        }
        let sd = &self.semidense;
        // Written as `!(in range)` so that NaN, which fails every comparison, is refused.
        let floats = [
            (
                "semidense.sigma_i",
                sd.sigma_i,
                0.0,
                255.0,
                "a positive number of grey levels up to 255",
            ),
            (
                "semidense.theta",
                sd.theta,
                0.0,
                100.0,
                "a positive variance ratio",
            ),
            (
                "semidense.lambda_l_deg",
                sd.lambda_l_deg,
                0.0,
                90.0,
                "an angle in (0, 90] degrees",
            ),
            (
                "semidense.lambda_theta_deg",
                sd.lambda_theta_deg,
                0.0,
                180.0,
                "an angle in (0, 180] degrees",
            ),
            (
                "semidense.max_similarity_error",
                sd.max_similarity_error,
                0.0,
                1e6,
                "a positive number",
            ),
        ];
        for (field, v, lo, hi, what) in floats {
            if !(v > lo && v <= hi) {
                return bad(field, &format!("must be {what} (got {v})"));
            }
        }
        if !(sd.contrast_reference >= 0.0 && sd.contrast_reference <= 255.0) {
            return bad(
                "semidense.contrast_reference",
                "must be a grey-level spread in [0, 255] (0 = off)",
            );
        }
        if !(sd.lambda_g >= 0.0 && sd.lambda_g <= 1e4) {
            return bad("semidense.lambda_g", "must be a non-negative number");
        }
        if !(sd.min_baseline_ratio >= 0.0 && sd.min_baseline_ratio <= 10.0) {
            return bad("semidense.min_baseline_ratio", "must be in [0, 10]");
        }
        if !(sd.prior_margin >= 0.0 && sd.prior_margin < 1.0) {
            return bad("semidense.prior_margin", "must be in [0, 1)");
        }
        if !(sd.min_patch_zncc >= 0.0 && sd.min_patch_zncc < 1.0) {
            return bad("semidense.min_patch_zncc", "must be in [0, 1) (0 = off)");
        }
        if sd.prior_cell_px != 0 && !(4..=1024).contains(&sd.prior_cell_px) {
            return bad("semidense.prior_cell_px", "must be 0 (off) or 4..=1024");
        }
        if !(1..=MAX_NEIGHBOURS).contains(&sd.n_neighbours) {
            return bad(
                "semidense.n_neighbours",
                &format!("must be in 1..={MAX_NEIGHBOURS}"),
            );
        }
        if !(1..=sd.n_neighbours).contains(&sd.lambda_n) {
            return bad(
                "semidense.lambda_n",
                "must be in 1..=n_neighbours (more compatible hypotheses than neighbours can never be found)",
            );
        }
        if !(1..=MAX_THREADS).contains(&sd.threads) {
            return bad(
                "semidense.threads",
                &format!("must be in 1..={MAX_THREADS}"),
            );
        }
        if sd.keyframe_delay > 1000 {
            return bad("semidense.keyframe_delay", "must be at most 1000 keyframes");
        }
        if !(-20..=19).contains(&sd.nice) {
            return bad("semidense.nice", "must be a nice value in -20..=19");
        }
        if sd.max_points > MAX_SEMIDENSE_POINTS {
            return bad(
                "semidense.max_points",
                &format!("must be at most {MAX_SEMIDENSE_POINTS}"),
            );
        }
        if !(20..=MAX_KEYFRAMES).contains(&self.map.max_keyframes) {
            return bad(
                "map.max_keyframes",
                &format!("must be in 20..={MAX_KEYFRAMES}"),
            );
        }
        if !(1000..=MAX_MAP_POINTS).contains(&self.map.max_map_points) {
            return bad(
                "map.max_map_points",
                &format!("must be in 1000..={MAX_MAP_POINTS}"),
            );
        }
        self.validate_pipeline(path)?;
        if let Some(d) = self.runtime.deadline_ms {
            if d <= 0.0 || !d.is_finite() {
                return bad("runtime.deadline_ms", "must be a positive number");
            }
        }
        if self.runtime.realtime_speed <= 0.0 || !self.runtime.realtime_speed.is_finite() {
            return bad("runtime.realtime_speed", "must be a positive number");
        }
        Ok(())
    }

    /// Ranges of the tracking, initialisation, relocalisation and mapping parameters: counts
    /// positive where zero would stop the stage, shares in (0, 1], gates positive (NaN fails
    /// every check, as it fails `>`).
    fn validate_pipeline(&self, path: &Path) -> Result<()> {
        let bad = |field: &str, why: &str| {
            Err(Error::Config {
                path: path.to_path_buf(),
                message: format!("field `{field}`: {why}"),
            })
        };
        let (t, i, r, m) = (
            &self.tracking,
            &self.initialisation,
            &self.relocalisation,
            &self.motion_only,
        );
        let (l, c) = (&self.local_mapping, &self.loop_closing);
        let positive = [
            (
                "tracking.motion_search_radius",
                t.motion_search_radius as f64,
            ),
            ("initialisation.sigma", i.sigma),
            ("initialisation.min_parallax_deg", i.min_parallax_deg),
            (
                "initialisation.planar_tie_parallax_deg",
                i.planar_tie_parallax_deg,
            ),
            ("initialisation.agreement_deg", i.agreement_deg),
            ("tracking.collapse_path_ratio", t.collapse_path_ratio),
            ("tracking.collapse_max_turn_deg", t.collapse_max_turn_deg),
            ("tracking.max_centre_sigma_ratio", t.max_centre_sigma_ratio),
            ("tracking.max_mean_chi2", t.max_mean_chi2),
            ("tracking.max_jump_ratio", t.max_jump_ratio),
            ("relocalisation.chi2", r.chi2),
            ("motion_only.chi2", m.chi2),
            ("loop_closing.revisit_path_ratio", c.revisit_path_ratio),
            ("loop_closing.max_scale_sigma", c.max_scale_sigma),
            (
                "loop_closing.revisit_min_path_depths",
                c.revisit_min_path_depths,
            ),
        ];
        for (field, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return bad(field, &format!("must be a positive number (got {v})"));
            }
        }
        let shares = [
            ("tracking.keyframe_ratio", t.keyframe_ratio),
            ("initialisation.h_selection_ratio", i.h_selection_ratio),
            ("initialisation.min_good_share", i.min_good_share),
            ("tracking.collapse_depth_shrink", t.collapse_depth_shrink),
            ("relocalisation.probability", r.probability),
            ("local_mapping.min_found_ratio", l.min_found_ratio),
            ("local_mapping.redundancy", l.redundancy),
        ];
        if !(i.cross_check_margin >= 1.0 && i.cross_check_margin.is_finite()) {
            return bad(
                "initialisation.cross_check_margin",
                &format!("must be a number >= 1 (got {})", i.cross_check_margin),
            );
        }
        for (field, v) in shares {
            if !(v > 0.0 && v <= 1.0) {
                return bad(field, &format!("must be in (0, 1] (got {v})"));
            }
        }
        let counts = [
            ("tracking.min_inliers", t.min_inliers),
            ("tracking.max_local_keyframes", t.max_local_keyframes),
            ("initialisation.ransac_iterations", i.ransac_iterations),
            ("initialisation.min_triangulated", i.min_triangulated),
            ("relocalisation.min_inliers", r.min_inliers),
            ("relocalisation.max_iterations", r.max_iterations),
            ("motion_only.rounds", m.rounds),
            ("motion_only.iterations", m.iterations),
            (
                "local_mapping.triangulation_neighbours",
                l.triangulation_neighbours,
            ),
            (
                "loop_closing.covisibility_consistency",
                c.covisibility_consistency,
            ),
            ("loop_closing.min_matches", c.min_matches),
            (
                "tracking.relocalisation_candidates",
                t.relocalisation_candidates,
            ),
            (
                "tracking.young_map_patience_frames",
                t.young_map_patience_frames,
            ),
            ("tracking.collapse_keyframes", t.collapse_keyframes),
            (
                "initialisation.min_initial_map_points",
                i.min_initial_map_points,
            ),
            ("map.global_ba_iterations", self.map.global_ba_iterations),
            ("map.final_ba_iterations", self.map.final_ba_iterations),
        ];
        for (field, v) in counts {
            if !(1..=MAX_ITERATIONS).contains(&v) {
                return bad(field, &format!("must be in 1..={MAX_ITERATIONS} (got {v})"));
            }
        }
        if !(t.relocalisation_budget_ms.is_finite() && t.relocalisation_budget_ms >= 0.0) {
            return bad(
                "tracking.relocalisation_budget_ms",
                "must be a time in milliseconds >= 0 (0: no bound)",
            );
        }
        if !(-1.0..=1.0).contains(&t.min_view_cos) {
            return bad("tracking.min_view_cos", "must be a cosine in [-1, 1]");
        }
        if t.min_frames_between_keyframes > t.max_frames_between_keyframes {
            return bad(
                "tracking.min_frames_between_keyframes",
                "must not exceed tracking.max_frames_between_keyframes",
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
