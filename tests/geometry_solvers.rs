//! Property tests of the geometry solvers on random scenes (planar and general, 0.5-1 px noise,
//! 0-50% outliers), with seeded RANSAC so every case is reproducible.

mod common;

use common::problems::Rng;
use nalgebra::{Matrix3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use proptest::prelude::*;
use sdslam::geometry::pnp::{pnp_ransac, PnpRansacConfig};
use sdslam::geometry::sim3::{sim3_ransac, Sim3Matches, Sim3RansacConfig};
use sdslam::geometry::two_view::{initialize, TwoViewConfig, TwoViewError, TwoViewModel};
use sdslam::geometry::{Se3, Sim3};

fn k() -> Matrix3<f64> {
    Matrix3::new(520.0, 0.0, 320.0, 0.0, 520.0, 240.0, 0.0, 0.0, 1.0)
}

fn project(p: &Vector3<f64>) -> Vector2<f64> {
    Vector2::new(520.0 * p.x / p.z + 320.0, 520.0 * p.y / p.z + 240.0)
}

fn in_image(u: &Vector2<f64>) -> bool {
    u.x >= 0.0 && u.y >= 0.0 && u.x < 640.0 && u.y < 480.0
}

/// Matches of a random scene seen from identity and from `t_21`: 500 points at 1.5-5 m (or on a
/// randomly tilted plane 3 m away), as when a desk-scale map is initialised with a 0.5 m
/// baseline (parallax 6-19 degrees).
fn scene(
    rng: &mut Rng,
    t_21: &Se3,
    planar: bool,
    n: usize,
    noise: f64,
    outliers: f64,
) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
    let (mut x1, mut x2) = (Vec::new(), Vec::new());
    // A plane facing the camera with a random tilt.
    let normal = Vector3::new(rng.range(-0.4, 0.4), rng.range(-0.4, 0.4), -1.0).normalize();
    let d = 3.0;
    while x1.len() < n {
        let u = Vector2::new(rng.range(20.0, 620.0), rng.range(20.0, 460.0));
        let ray = Vector3::new((u.x - 320.0) / 520.0, (u.y - 240.0) / 520.0, 1.0);
        let depth = if planar {
            -d / normal.dot(&ray)
        } else {
            rng.range(1.5, 5.0)
        };
        if depth <= 0.5 {
            continue;
        }
        let p = ray * depth;
        let q = t_21 * Point3::from(p);
        if q.z < 0.5 {
            continue;
        }
        let u2 = project(&q.coords);
        if !in_image(&u2) {
            continue;
        }
        let nz = |r: &mut Rng| Vector2::new(r.gauss(), r.gauss()) * noise;
        let u1 = project(&p) + nz(rng);
        let u2 = if rng.f() < outliers {
            Vector2::new(rng.range(0.0, 640.0), rng.range(0.0, 480.0))
        } else {
            u2 + nz(rng)
        };
        x1.push(u1);
        x2.push(u2);
    }
    (x1, x2)
}

fn random_motion(rng: &mut Rng, baseline: f64) -> Se3 {
    let rot = UnitQuaternion::from_euler_angles(
        rng.range(-0.1, 0.1),
        rng.range(-0.15, 0.15),
        rng.range(-0.1, 0.1),
    );
    let dir = Vector3::new(
        rng.range(-1.0, 1.0),
        rng.range(-0.5, 0.5),
        rng.range(-0.3, 0.3),
    )
    .normalize();
    Se3::from_parts(Translation3::from(dir * baseline), rot)
}

fn check_motion(est: &Se3, truth: &Se3) -> (f64, f64) {
    let rot_err = est.rotation.angle_to(&truth.rotation).to_degrees();
    let (a, b) = (
        est.translation.vector.normalize(),
        truth.translation.vector.normalize(),
    );
    (rot_err, a.dot(&b).clamp(-1.0, 1.0).acos().to_degrees())
}

proptest! {
    // Fixed seed: the same cases on every run (solvers are seeded too).
    #![proptest_config(ProptestConfig { cases: 32, rng_seed: proptest::test_runner::RngSeed::Fixed(2015), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn pure_rotation_is_degenerate(seed in 0u64..1_000_000, planar in proptest::bool::ANY) {
        let mut rng = Rng(seed);
        let mut truth = random_motion(&mut rng, 0.5);
        truth.translation.vector = Vector3::zeros();
        let (x1, x2) = scene(&mut rng, &truth, planar, 400, 1.0, 0.1);
        let r = initialize(&x1, &x2, &k(), &TwoViewConfig { seed, ..TwoViewConfig::default() });
        prop_assert!(matches!(r, Err(TwoViewError::Degenerate { .. })), "{:?}", r.map(|m| (m.model, m.parallax_deg)));
    }

    #[test]
    fn pnp_ransac_recovers_pose(seed in 0u64..1_000_000, noise in 0.5f64..1.0, outliers in 0.0f64..0.5) {
        let mut rng = Rng(seed);
        let t_cw = random_motion(&mut rng, 1.0);
        let t_wc = t_cw.inverse();
        let (mut pw, mut px) = (Vec::new(), Vec::new());
        while pw.len() < 200 {
            let u = Vector2::new(rng.range(0.0, 640.0), rng.range(0.0, 480.0));
            let pc = Vector3::new((u.x - 320.0) / 520.0, (u.y - 240.0) / 520.0, 1.0) * rng.range(2.0, 8.0);
            pw.push((t_wc * Point3::from(pc)).coords);
            px.push(if rng.f() < outliers { Vector2::new(rng.range(0.0, 640.0), rng.range(0.0, 480.0)) } else { u + Vector2::new(rng.gauss(), rng.gauss()) * noise });
        }
        let sol = pnp_ransac(&pw, &px, &vec![1.0; 200], &k(), &PnpRansacConfig { seed, ..PnpRansacConfig::default() });
        let sol = sol.ok_or_else(|| TestCaseError::fail("no pose"))?;
        let rot = sol.t_cw.0.rotation.angle_to(&t_cw.rotation).to_degrees();
        let cdist = (sol.t_cw.center() - t_wc.translation.vector).norm();
        prop_assert!(rot < 0.5 && cdist < 0.05, "rotation {rot:.3} deg, centre {cdist:.4} m");
        prop_assert!(sol.n_inliers as f64 > 0.8 * 200.0 * (1.0 - outliers));
    }

    #[test]
    fn sim3_ransac_recovers_similarity(seed in 0u64..1_000_000, outliers in 0.0f64..0.5, scale in 0.3f64..3.0) {
        let mut rng = Rng(seed);
        let m12 = random_motion(&mut rng, 0.4);
        let s12 = Sim3 { scale, rotation: m12.rotation, translation: m12.translation.vector };
        let s21 = s12.inverse();
        let (mut p1, mut u1, mut p2, mut u2) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        while p1.len() < 150 {
            let a = Vector3::new(rng.range(-2.0, 2.0), rng.range(-1.5, 1.5), rng.range(3.0, 7.0));
            let b = s21.transform(&a);
            if b.z < 0.3 || !in_image(&project(&a)) || !in_image(&project(&b)) {
                continue;
            }
            let bad = rng.f() < outliers;
            let b_obs = if bad { b + Vector3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 0.0) * scale.recip() } else { b };
            p1.push(a + Vector3::new(rng.gauss(), rng.gauss(), rng.gauss()) * 0.005);
            u1.push(project(&a) + Vector2::new(rng.gauss(), rng.gauss()));
            p2.push(b_obs);
            u2.push(project(&b) + Vector2::new(rng.gauss(), rng.gauss()));
        }
        let s1 = vec![1.0; p1.len()];
        let m = Sim3Matches { p1: &p1, u1: &u1, sigma2_1: &s1, p2: &p2, u2: &u2, sigma2_2: &s1 };
        let sol = sim3_ransac(&m, &k(), &k(), &Sim3RansacConfig { seed, ..Sim3RansacConfig::default() }).ok_or_else(|| TestCaseError::fail("no sim3"))?;
        prop_assert!((sol.s12.scale / scale - 1.0).abs() < 0.02, "scale {} vs {scale}", sol.s12.scale);
        prop_assert!(sol.s12.rotation.angle_to(&s12.rotation).to_degrees() < 0.5);
    }
}

/// Planar scenes: H is always selected. A plane seen from two views can have two physically valid
/// motions (Faugeras' twofold ambiguity); those are reported as `Ambiguous`, never guessed.
/// Returned motions: rotation within 0.5 deg always, translation within 1 deg in the share
/// recorded in docs/PERFORMANCE.md.
#[test]
fn two_view_planar_scenes_select_h_and_recover_motion_or_report_ambiguity() {
    let (mut solved, mut ambiguous, mut cases, mut accurate) = (0, 0, 0, 0);
    for seed in 0..40u64 {
        let mut rng = Rng(seed * 7919 + 1);
        let noise = 0.5 + 0.5 * rng.f();
        let outliers = 0.3 * rng.f();
        let truth = random_motion(&mut rng, 0.5);
        let (x1, x2) = scene(&mut rng, &truth, true, 500, noise, outliers);
        let cfg = TwoViewConfig {
            seed,
            ..TwoViewConfig::default()
        };
        let est = sdslam::geometry::two_view::estimate_models(&x1, &x2, &cfg).unwrap();
        assert_eq!(
            est.selected(&cfg),
            TwoViewModel::Homography,
            "seed {seed}: ratio {}",
            est.ratio
        );
        cases += 1;
        match initialize(&x1, &x2, &k(), &cfg) {
            Ok(mut m) => {
                sdslam::optimize::refine_two_view(&mut m, &x1, &x2, &k(), 1.0);
                let (re, te) = check_motion(&m.t_21, &truth);
                assert!(
                    re < 0.5 && te < 3.0,
                    "seed {seed}: rotation {re:.3} deg, translation {te:.3} deg"
                );
                accurate += (te < 1.0) as usize;
                solved += 1;
            }
            // Two-fold, or one of the pair not yet confirmed by F: refused, not guessed.
            Err(TwoViewError::Ambiguous { .. } | TwoViewError::Unconfirmed { .. }) => {
                ambiguous += 1
            }
            Err(e) => panic!("seed {seed}: {e}"),
        }
    }
    eprintln!(
        "planar: {solved} solved ({accurate} within 1 deg), {ambiguous} ambiguous of {cases}"
    );
    // Genuinely two-fold cases are common for planes; the rest must be solved, never guessed.
    assert!(
        solved * 4 >= cases,
        "only {solved} of {cases} planar cases resolved"
    );
    assert!(
        accurate * 100 >= solved * 90,
        "translation within 1 deg in only {accurate}/{solved}"
    );
}

/// Accuracy over 200 random general scenes (0.5-1 px noise, 0-30% outliers, any translation
/// direction), initialisation followed by two-view BA as in the SLAM bootstrap: F is always
/// selected; rotation within 0.5 deg and translation within 1 deg in the shares recorded in
/// docs/PERFORMANCE.md. The few misses are at the maximum-likelihood optimum (their reprojection
/// cost is below the true motion's), i.e. the noise of those samples, not the solver.
#[test]
fn two_view_general_scenes_select_f_and_recover_motion() {
    let (mut rot_ok, mut trans_ok, mut n) = (0, 0, 0);
    let mut t_errs = Vec::new();
    for seed in 0..200u64 {
        let mut rng = Rng(seed * 31 + 7);
        let noise = 0.5 + 0.5 * rng.f();
        let outliers = 0.3 * rng.f();
        let truth = random_motion(&mut rng, 0.5);
        let (x1, x2) = scene(&mut rng, &truth, false, 500, noise, outliers);
        let cfg = TwoViewConfig {
            seed,
            ..TwoViewConfig::default()
        };
        let mut m = initialize(&x1, &x2, &k(), &cfg).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        sdslam::optimize::refine_two_view(&mut m, &x1, &x2, &k(), 1.0);
        assert_eq!(
            m.model,
            TwoViewModel::Fundamental,
            "seed {seed}: ratio {}",
            m.score_ratio
        );
        let pts = m.points.iter().filter(|p| p.is_some()).count();
        assert!(
            pts as f64 > 0.6 * 500.0 * (1.0 - outliers),
            "seed {seed}: {pts} points"
        );
        let (re, te) = check_motion(&m.t_21, &truth);
        rot_ok += (re < 0.5) as usize;
        trans_ok += (te < 1.0) as usize;
        n += 1;
        t_errs.push(te);
    }
    t_errs.sort_by(|a, b| a.total_cmp(b));
    let (median, max) = (t_errs[n / 2], t_errs[n - 1]);
    eprintln!("general: rotation < 0.5 deg in {rot_ok}/{n}, translation < 1 deg in {trans_ok}/{n}, median {median:.3} deg, max {max:.3} deg");
    assert!(
        rot_ok * 100 >= n * 98,
        "rotation within 0.5 deg in only {rot_ok}/{n}"
    );
    assert!(
        trans_ok * 100 >= n * 94,
        "translation within 1 deg in only {trans_ok}/{n}"
    );
    assert!(median < 0.5 && max < 3.0, "median {median}, max {max}");
}

/// Forward motion down a corridor at low parallax (0.2-0.8 m, 1.7-6 degrees): the flow is
/// radial and a wall or the floor can dominate the matches. Every returned motion must be the
/// true one (translation within 10 deg, rotation within 0.5 deg, after two-view BA); refusing
/// is allowed, guessing is not, and baselines from 0.3 m must be solved.
#[test]
fn two_view_forward_motion_at_low_parallax_is_right_or_refused() {
    let (mut solved, mut cases, mut solved_long) = (0, 0, 0);
    for seed in 0..60u64 {
        let mut rng = Rng(seed * 104_729 + 3);
        let noise = 0.5 + 0.5 * rng.f();
        let baseline = 0.2 + 0.6 * (seed % 6) as f64 / 5.0;
        let rot = UnitQuaternion::from_euler_angles(
            rng.range(-0.01, 0.01),
            rng.range(-0.01, 0.01),
            rng.range(-0.005, 0.005),
        );
        let dir = Vector3::new(rng.range(-0.15, 0.15), rng.range(-0.1, 0.1), -1.0).normalize();
        let truth = Se3::from_parts(Translation3::from(dir * baseline), rot);
        // A corridor 3 m wide, floor 1.2 m below, ceiling 1.3 m above, end wall 15 m ahead:
        // every point on one of five planes, as in a real corridor.
        let (mut x1, mut x2) = (Vec::new(), Vec::new());
        while x1.len() < 500 {
            let u = Vector2::new(rng.range(20.0, 620.0), rng.range(20.0, 460.0));
            let ray = Vector3::new((u.x - 320.0) / 520.0, (u.y - 240.0) / 520.0, 1.0);
            let hits = [
                (1.5 / ray.x, ray.x > 1e-6),
                (-1.5 / ray.x, ray.x < -1e-6),
                (1.2 / ray.y, ray.y > 1e-6),
                (-1.3 / ray.y, ray.y < -1e-6),
                (15.0, true),
            ];
            let depth = hits
                .iter()
                .filter(|h| h.1)
                .map(|h| h.0)
                .fold(f64::MAX, f64::min);
            let p = ray * depth;
            let q = truth * Point3::from(p);
            let u2 = project(&q.coords);
            if q.z < 0.5 || !in_image(&u2) {
                continue;
            }
            x1.push(project(&p) + Vector2::new(rng.gauss(), rng.gauss()) * noise);
            x2.push(u2 + Vector2::new(rng.gauss(), rng.gauss()) * noise);
        }
        let cfg = TwoViewConfig {
            seed,
            ..TwoViewConfig::default()
        };
        cases += 1;
        let r = initialize(&x1, &x2, &k(), &cfg);
        if let Ok(mut m) = r {
            sdslam::optimize::refine_two_view(&mut m, &x1, &x2, &k(), 1.0);
            let (re, te) = check_motion(&m.t_21, &truth);
            assert!(
                re < 0.5 && te < 10.0,
                "seed {seed} ({:?}, baseline {baseline:.2} m): rotation {re:.2} deg, translation {te:.2} deg",
                m.model
            );
            solved += 1;
            solved_long += (baseline >= 0.3) as usize;
        }
    }
    eprintln!("forward: {solved} of {cases} solved, {solved_long} of 50 with baseline >= 0.3 m");
    assert!(
        solved_long >= 48,
        "only {solved_long} of 50 long baselines solved"
    );
}
