//! Every tunable, with its published name and default. Loaded from TOML (`--config FILE`);
//! unknown keys are rejected so a typo never silently falls back to a default.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

mod pipeline;
mod semidense;

pub use crate::geometry::pnp::PnpRansacConfig;
pub use crate::geometry::two_view::TwoViewConfig;
pub use pipeline::{LocalMappingConfig, LoopClosingConfig, MotionOnlyConfig, TrackingConfig};
pub use semidense::{SemiDenseConfig, SemiDenseMode};

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

/// Upper bound of `[tracking] recovery_frames` (10 s at 30 fps: the motion model carried
/// further is a guess).
pub const MAX_RECOVERY_FRAMES: usize = 300;
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
        if sd.final_seed_cell_px != 0 && !(2..=1024).contains(&sd.final_seed_cell_px) {
            return bad(
                "semidense.final_seed_cell_px",
                "must be 0 (off) or 2..=1024",
            );
        }
        if !(sd.final_seed_margin >= 0.0 && sd.final_seed_margin < 1.0) {
            return bad("semidense.final_seed_margin", "must be in [0, 1)");
        }
        if sd.propagate_cell_px != 0 && !(2..=1024).contains(&sd.propagate_cell_px) {
            return bad("semidense.propagate_cell_px", "must be 0 (off) or 2..=1024");
        }
        if !(sd.propagate_margin >= 0.0 && sd.propagate_margin < 1.0) {
            return bad("semidense.propagate_margin", "must be in [0, 1)");
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
            (
                "tracking.collapse_young_over_old",
                t.collapse_young_over_old,
            ),
            (
                "tracking.collapse_min_kept_baseline",
                t.collapse_min_kept_baseline,
            ),
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
            ("initialisation.min_match_share", i.min_match_share),
            ("tracking.collapse_depth_shrink", t.collapse_depth_shrink),
            (
                "tracking.collapse_young_over_old",
                t.collapse_young_over_old,
            ),
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
            (
                "tracking.min_inliers_after_relocalisation",
                t.min_inliers_after_relocalisation,
            ),
            ("initialisation.ransac_iterations", i.ransac_iterations),
            ("initialisation.min_triangulated", i.min_triangulated),
            ("initialisation.min_matches", i.min_matches),
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
        if t.recovery_frames > MAX_RECOVERY_FRAMES {
            return bad(
                "tracking.recovery_frames",
                &format!("must be in 0..={MAX_RECOVERY_FRAMES} (0: off)"),
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
