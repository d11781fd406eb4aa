//! Stage tests on rendered images with exact poses and depth (the built-in synthetic scene).

use super::*;
use crate::camera::Frame;
use crate::config::SemiDenseConfig;
use crate::synthetic::{SyntheticConfig, SyntheticSequence};

struct Rendered {
    gray: Vec<u8>,
    depth: Vec<f32>,
    t_cw: crate::geometry::CameraFromWorld,
}

fn render(seq: &SyntheticSequence, i: usize) -> Rendered {
    let c = &seq.config;
    let mut f = Frame::new(c.width, c.height);
    let mut depth = vec![0.0f32; (c.width * c.height) as usize];
    seq.render_with_depth(i, &mut f, &mut depth);
    Rendered {
        gray: f.gray.clone(),
        depth,
        t_cw: seq.ground_truth()[i].t_wc.inverse(),
    }
}

fn intrinsics(c: &SyntheticConfig) -> Intrinsics {
    let cam = c.camera();
    Intrinsics {
        fx: cam.fx,
        fy: cam.fy,
        cx: cam.cx,
        cy: cam.cy,
    }
}

fn sequence() -> SyntheticSequence {
    SyntheticSequence::new(SyntheticConfig {
        frames: 300,
        ..SyntheticConfig::default()
    })
}

/// Relative depth errors of the pixels with estimates.
fn relative_errors(rho: &[f32], s2: &[f32], depth: &[f32]) -> Vec<f64> {
    let mut e: Vec<f64> = rho
        .iter()
        .zip(s2)
        .zip(depth)
        .filter(|((_, s), d)| **s > 0.0 && **d > 0.0)
        .map(|((r, _), d)| ((1.0 / *r as f64) - *d as f64).abs() / *d as f64)
        .collect();
    e.sort_by(|a, b| a.total_cmp(b));
    e
}

/// Projection into the neighbour of reference pixel (x, y) at inverse depth `rho`.
fn project_into(
    k: &Intrinsics,
    t_ji: &crate::geometry::Se3,
    x: usize,
    y: usize,
    rho: f64,
) -> (f64, f64) {
    let p = t_ji * nalgebra::Point3::from(k.ray(x as f64, y as f64) / rho);
    (k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy)
}

#[test]
fn epipolar_matches_are_subpixel_and_sigma_covers_their_error() {
    let seq = sequence();
    let k = intrinsics(&seq.config);
    let params = SearchParams::from_config(&SemiDenseConfig::default());
    let (w, h) = (seq.config.width as usize, seq.config.height as usize);
    let r = render(&seq, 100);
    let (mut px_err, mut within_2s, mut inliers, mut total) = (Vec::new(), 0, 0, 0);
    for other in [95, 105, 110] {
        let nb = render(&seq, other);
        let (mut gr, mut gn) = (GradientImage::new(w, h), GradientImage::new(w, h));
        gr.compute(&r.gray, params.lambda_g);
        gn.compute(&nb.gray, params.lambda_g);
        let t_ji = nb.t_cw.0 * r.t_cw.0.inverse();
        let pair = StereoPair::new(&k, &t_ji, 0.0);
        for y in (4..h - 4).step_by(3) {
            for x in (4..w - 4).step_by(3) {
                let p = gr.at(x, y);
                let d = r.depth[y * w + x] as f64;
                if p.modulus <= params.lambda_g || d <= 0.0 {
                    continue;
                }
                let Some(hy) =
                    pair.search(&params, x as f64, y as f64, &p, (0.1, 2.0), &gn, &mut 0)
                else {
                    continue;
                };
                total += 1;
                let (ut, vt) = project_into(&k, &t_ji, x, y, 1.0 / d);
                let (uh, vh) = project_into(&k, &t_ji, x, y, hy.rho as f64);
                let e = ((ut - uh).powi(2) + (vt - vh).powi(2)).sqrt();
                // Matches of the true surface point (others are ambiguities left to fusion).
                if e < 2.0 {
                    inliers += 1;
                    px_err.push(e);
                    if (hy.rho as f64 - 1.0 / d).abs() < 2.0 * hy.sigma as f64 {
                        within_2s += 1;
                    }
                }
            }
        }
    }
    px_err.sort_by(|a, b| a.total_cmp(b));
    let median = px_err[px_err.len() / 2];
    let covered = within_2s as f64 / inliers as f64;
    eprintln!(
        "{total} hypotheses, {inliers} on the true point: median match error {median:.3} px, {:.1}% within 2 sigma",
        covered * 100.0
    );
    assert!(inliers > 3000, "{inliers}");
    assert!(median < 0.25, "median sub-pixel error {median}");
    // sigma_I = 20 (the paper's) is far above the rendering noise: sigma is conservative.
    assert!(covered > 0.95, "{covered}");
}

/// (count, median, share within 2%, share beyond 10%) of sorted relative errors.
fn stats(label: &str, e: &[f64]) -> (usize, f64, f64, f64) {
    let n = e.len() as f64;
    let f = |t: f64| e.iter().filter(|x| **x <= t).count() as f64 / n;
    let s = (e.len(), e[e.len() / 2], f(0.02), 1.0 - f(0.1));
    eprintln!(
        "{label}: {} px, median {:.4}, within 2% {:.3}, beyond 10% {:.4}",
        s.0, s.1, s.2, s.3
    );
    s
}

type Stats = (usize, f64, f64, f64);

/// One keyframe with 7 neighbours at exact poses, reconstructed with `cfg`: stats of the fused
/// and of the intra-checked maps.
fn keyframe_stages(cfg: &SemiDenseConfig) -> (Stats, Stats) {
    keyframe_stages_exposed(cfg, 1.0, false)
}

/// [`keyframe_stages`] with every neighbour's image `exposure` times brighter (clipped, as a
/// camera's auto exposure gives), its gain measured at projected points of the exact depth
/// and given to the search when `compensate`.
fn keyframe_stages_exposed(
    cfg: &SemiDenseConfig,
    exposure: f32,
    compensate: bool,
) -> (Stats, Stats) {
    let (fused, intra, _) = keyframe_run(cfg, exposure, compensate);
    (fused, intra)
}

/// [`keyframe_stages_exposed`] with the reconstruction's stage counts.
fn keyframe_run(
    cfg: &SemiDenseConfig,
    exposure: f32,
    compensate: bool,
) -> (Stats, Stats, super::reconstructor::StageTimes) {
    keyframe_run_seeded(cfg, exposure, compensate, None)
}

/// [`keyframe_run`] with a seed of the true inverse depths in 8 px cells (5% margin) when
/// `seed_verify` is given: `Some(true)` as online propagation uses it (a window a first full
/// search must confirm), `Some(false)` as the end-of-session pass does (trusted).
fn keyframe_run_seeded(
    cfg: &SemiDenseConfig,
    exposure: f32,
    compensate: bool,
    seed_verify: Option<bool>,
) -> (Stats, Stats, super::reconstructor::StageTimes) {
    let seq = sequence();
    let k = intrinsics(&seq.config);
    let (w, h) = (seq.config.width as usize, seq.config.height as usize);
    let r = render(&seq, 150);
    let offs: [i64; 7] = [-15, -10, -5, 5, 10, 15, 20];
    let nbs: Vec<Rendered> = offs
        .iter()
        .map(|o| {
            let mut n = render(&seq, (150 + o) as usize);
            for v in n.gray.iter_mut() {
                *v = (*v as f32 * exposure).round().min(255.0) as u8;
            }
            n
        })
        .collect();
    let inv: Vec<f32> = r
        .depth
        .iter()
        .step_by(97)
        .filter(|d| **d > 0.0)
        .map(|d| 1.0 / d)
        .collect();
    let range = prior_range(&inv).unwrap();
    let mut rec = KeyframeReconstructor::new(k, w, h, cfg);
    rec.set_reference(1000, Some(&r.gray));
    let mut scratch = Vec::with_capacity(512);
    for (i, n) in nbs.iter().enumerate() {
        let t_ji = n.t_cw.0 * r.t_cw.0.inverse();
        // Matches as ORB would give them: a grid of reference pixels and where they land.
        let matched = (0..h)
            .step_by(23)
            .flat_map(|y| (0..w).step_by(29).map(move |x| (x, y)))
            .filter(|&(x, y)| r.depth[y * w + x] > 0.0)
            .map(|(x, y)| {
                let (u, v) = project_into(&k, &t_ji, x, y, 1.0 / r.depth[y * w + x] as f64);
                ((x as f32, y as f32), (u as f32, v as f32))
            });
        let gain = photometric_gain(&r.gray, &n.gray, w, h, matched, &mut scratch);
        if compensate {
            assert!((gain - exposure).abs() < 0.05 * exposure, "gain {gain}");
        }
        rec.add_neighbour(
            i as u64,
            Some(&n.gray),
            &t_ji,
            0.0,
            if compensate { gain } else { 1.0 },
        );
    }
    let mut ranges = RegionalPrior::new(w, h, 8);
    for (i, &d) in r.depth.iter().enumerate().step_by(3) {
        if d > 0.0 {
            ranges.add((i % w) as f32, (i / w) as f32, 1.0 / d);
        }
    }
    ranges.finish(range, 3, 0.05);
    let seed = seed_verify.map(|verify| super::reconstructor::Seed {
        ranges: &ranges,
        early_reject_after: cfg.early_reject_after,
        skip_unseeded: false,
        verify,
    });
    let t = std::time::Instant::now();
    let times = rec.reconstruct_seeded(range, None, seed);
    eprintln!("range {range:?} times {times:?} total {:?}", t.elapsed());
    let (fr, fs) = rec.fused();
    let fused = stats("fused", &relative_errors(fr, fs, &r.depth));
    let mut px = Vec::new();
    rec.export(&mut px);
    let mut rho = vec![0.0f32; w * h];
    let mut s2 = vec![0.0f32; w * h];
    for p in &px {
        rho[p.idx as usize] = p.rho;
        s2[p.idx as usize] = p.sigma * p.sigma;
    }
    let intra = stats("intra", &relative_errors(&rho, &s2, &r.depth));
    (fused, intra, times)
}

/// The paper's search (all N neighbours of every pixel): the fused and intra-checked maps
/// before the inter-keyframe check (which removes most remaining outliers; see
/// tests/semidense.rs).
#[test]
fn keyframe_depth_and_intra_stages_are_accurate() {
    let (fused, intra) = keyframe_stages(&SemiDenseConfig {
        early_reject_after: 0,
        min_patch_zncc: 0.0,
        ..SemiDenseConfig::default()
    });
    for (n, median, within, beyond) in [fused, intra] {
        assert!(n > 15_000, "{n} points");
        assert!(median < 0.005, "median {median}");
        assert!(within > 0.85, "within 2%: {within}");
        assert!(beyond < 0.06, "beyond 10%: {beyond}");
    }
    // Smoothing and growing: more points, no worse.
    assert!(intra.0 > fused.0 && intra.3 <= fused.3 + 0.002);
}

/// The patch check after the intra-keyframe step removes a few of the estimates and more
/// of the bad ones: the share beyond 10% falls, the median does not rise.
#[test]
fn patch_check_removes_more_bad_estimates_than_good_ones() {
    let (_, off) = keyframe_stages(&SemiDenseConfig {
        min_patch_zncc: 0.0,
        ..SemiDenseConfig::default()
    });
    let (_, on) = keyframe_stages(&SemiDenseConfig::default());
    assert!(SemiDenseConfig::default().min_patch_zncc > 0.0);
    assert!(
        on.0 < off.0 && on.0 as f64 > 0.8 * off.0 as f64,
        "{} of {} points kept",
        on.0,
        off.0
    );
    assert!(on.3 < off.3, "beyond 10%: {} vs {}", on.3, off.3);
    assert!(on.1 <= off.1 + 0.0002, "median {} vs {}", on.1, off.1);
}

/// The default early rejection of ambiguous pixels keeps the 8,000 points on this
/// keyframe, and is no less accurate than the full search.
#[test]
fn early_rejection_keeps_points_and_accuracy() {
    let full = keyframe_stages(&SemiDenseConfig {
        early_reject_after: 0,
        ..SemiDenseConfig::default()
    });
    let early = keyframe_stages(&SemiDenseConfig::default());
    assert!(SemiDenseConfig::default().early_reject_after > 0);
    for (e, f) in [(early.0, full.0), (early.1, full.1)] {
        assert!(
            e.0 > 8_000 && e.0 < f.0,
            "{} points (full search {})",
            e.0,
            f.0
        );
        assert_no_less_accurate(&e, &f);
    }
}

/// `a` is no less accurate than `b`: median at most 0.05 points higher, the share within 2%
/// at most 0.5 points lower, the share beyond 10% at most 0.2 points higher.
fn assert_no_less_accurate(a: &Stats, b: &Stats) {
    assert!(a.1 <= b.1 + 0.0005, "median {} vs {}", a.1, b.1);
    assert!(a.2 >= b.2 - 0.005, "within 2%: {} vs {}", a.2, b.2);
    assert!(a.3 <= b.3 + 0.002, "beyond 10%: {} vs {}", a.3, b.3);
}

/// `a` keeps more than 95% of `b`'s points and is no less accurate.
fn assert_keeps_points_and_accuracy(a: &Stats, b: &Stats) {
    assert!(
        a.0 as f64 > 0.95 * b.0 as f64,
        "{} points, {} before",
        a.0,
        b.0
    );
    assert_no_less_accurate(a, b);
}

/// The row support gate leaves the odd-row pixels with nothing fused above or below them
/// unsearched (a fifth of this keyframe's pixels) and keeps the points and accuracy of the
/// search of every pixel: such pixels rarely survive the intra-keyframe check.
#[test]
fn row_support_gate_skips_unsupported_pixels_and_keeps_points_and_accuracy() {
    let gate = SemiDenseConfig {
        row_support_gate: true,
        ..SemiDenseConfig::default()
    };
    let every_row = SemiDenseConfig {
        row_support_gate: false,
        ..SemiDenseConfig::default()
    };
    let (_, full, t_full) = keyframe_run(&every_row, 1.0, false);
    let (_, gated, t_gated) = keyframe_run(&gate, 1.0, false);
    assert_eq!(t_full.support_skipped, 0);
    assert_eq!(
        t_gated.searched_pixels + t_gated.support_skipped,
        t_full.searched_pixels
    );
    assert!(
        (t_gated.searched_pixels as f64) < 0.9 * t_full.searched_pixels as f64,
        "{} of {} pixels searched",
        t_gated.searched_pixels,
        t_full.searched_pixels
    );
    assert_keeps_points_and_accuracy(&gated, &full);
}

/// A window is searched alone when trusted (the end-of-session seed) and after one full
/// search when it must be confirmed (online propagation): the confirmed search visits more
/// samples. Right windows keep the points and accuracy of the full search either way.
#[test]
fn a_trusted_window_spares_the_full_search_and_a_confirmed_one_does_not() {
    let cfg = SemiDenseConfig::default();
    let (_, full, t_full) = keyframe_run(&cfg, 1.0, false);
    let (_, trusted, t_trusted) = keyframe_run_seeded(&cfg, 1.0, false, Some(false));
    let (_, confirmed, t_confirmed) = keyframe_run_seeded(&cfg, 1.0, false, Some(true));
    assert!(t_full.seeded == 0 && t_trusted.seeded > t_trusted.searched_pixels / 2);
    assert!(
        (t_trusted.samples as f64) < 0.5 * t_confirmed.samples as f64,
        "samples: trusted {}, confirmed {}, full {}",
        t_trusted.samples,
        t_confirmed.samples,
        t_full.samples
    );
    assert!(t_confirmed.samples < t_full.samples);
    for got in [trusted, confirmed] {
        assert_keeps_points_and_accuracy(&got, &full);
    }
}

#[test]
fn median_rotation_of_angles_straddling_180_degrees_is_near_180() {
    let mut scratch = Vec::with_capacity(16);
    // In-plane rotations of 170..190 deg (a camera rolled upside down): as wrapped
    // differences they sit at both ends of (-180, 180].
    let pairs = [170.0f32, 175.0, 178.0, 182.0, 185.0, 190.0, 181.0].map(|d| (10.0f32, 10.0 + d));
    let m = super::median_rotation(pairs.into_iter(), &mut scratch).to_degrees();
    let off = (m - 181.0).rem_euclid(360.0);
    assert!(off.min(360.0 - off) < 0.01, "median {m:.2} deg, want 181");
    // Away from the seam it is the plain median.
    let pairs = [-5.0f32, 1.0, 2.0, 3.0, 40.0].map(|d| (100.0f32, 100.0 + d));
    let m = super::median_rotation(pairs.into_iter(), &mut scratch).to_degrees();
    assert!((m - 2.0).abs() < 1e-3, "{m}");
    assert_eq!(
        super::median_rotation(std::iter::empty(), &mut scratch),
        0.0
    );
}

#[test]
fn paper_mode_switches_every_addition_off_and_says_so() {
    use crate::config::SemiDenseMode;
    let tuned = SemiDenseConfig::default();
    let names: Vec<String> = tuned
        .non_paper_settings()
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    for n in [
        "early_reject_after",
        "min_baseline_ratio",
        "max_similarity_error",
        "photometric_gain",
        "final_seed_cell_px",
    ] {
        assert!(
            names.iter().any(|x| x == n),
            "{n} not reported in {names:?}"
        );
    }
    let gated = SemiDenseConfig {
        row_support_gate: true,
        ..SemiDenseConfig::default()
    };
    assert!(gated
        .non_paper_settings()
        .iter()
        .any(|(n, _)| n == "row_support_gate"));
    let paper = SemiDenseConfig {
        mode: SemiDenseMode::Paper,
        consensus_window: true,
        row_support_gate: true,
        prior_cell_px: 16,
        ..SemiDenseConfig::default()
    };
    assert!(
        paper.non_paper_settings().is_empty(),
        "{:?}",
        paper.non_paper_settings()
    );
    let f = paper.in_force();
    assert_eq!(f.early_reject_after, 0);
    assert!(!f.row_support_gate);
    assert_eq!(f.min_baseline_ratio, 0.0);
    assert!(f.max_similarity_error.is_infinite());
    assert!(!f.consensus_window);
    assert_eq!(f.prior_cell_px, 0);
    assert_eq!(f.final_seed_cell_px, 0);
    // The paper's own parameters are untouched.
    assert_eq!((f.n_neighbours, f.lambda_n, f.sigma_i), (7, 3, 20.0));
    let mode: SemiDenseMode = toml::from_str::<toml::Value>("m = \"paper\"")
        .ok()
        .and_then(|v| v.get("m").cloned())
        .and_then(|m| m.try_into().ok())
        .unwrap();
    assert_eq!(mode, SemiDenseMode::Paper);
}

/// Auto exposure between keyframes: neighbours 25% brighter than the keyframe leave the
/// paper's comparison (eq. 2, intensities as they are) a fraction of the points; with the
/// measured gain the keyframe gets back the points and accuracy of equal exposures.
#[test]
fn exposure_changes_between_keyframes_are_compensated() {
    let cfg = SemiDenseConfig::default();
    let (same, _) = keyframe_stages(&cfg);
    let (raw, _) = keyframe_stages_exposed(&cfg, 1.25, false);
    let (compensated, _) = keyframe_stages_exposed(&cfg, 1.25, true);
    assert!(raw.0 * 2 < same.0, "uncompensated {} vs {}", raw.0, same.0);
    assert!(
        compensated.0 as f64 > 0.9 * same.0 as f64,
        "compensated {} vs {}",
        compensated.0,
        same.0
    );
    assert!(compensated.1 < 0.005 && compensated.3 < same.3 + 0.01);
}
