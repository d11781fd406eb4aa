//! The configuration's defaults, parsing and validation.

use super::*;

#[test]
fn defaults_are_the_published_parameters() {
    let c = Config::default();
    assert_eq!(
        (
            c.orb.n_features,
            c.orb.n_levels,
            c.orb.ini_th_fast,
            c.orb.min_th_fast
        ),
        (1000, 8, 20, 7)
    );
    assert_eq!(c.semidense.n_neighbours, 7);
    assert_eq!(c.semidense.lambda_n, 3);
    assert_eq!(c.semidense.theta, 0.23);
    // ORB-SLAM's monocular initialisation: 100 matches, 100 points in the initial map.
    assert_eq!(
        (
            c.initialisation.min_matches,
            c.initialisation.min_initial_map_points
        ),
        (100, 100)
    );
}

#[test]
fn partial_file_overrides_and_unknown_keys_fail() {
    let c = Config::parse("[orb]\nn_features = 2000\n", Path::new("c.toml")).unwrap();
    assert_eq!(c.orb.n_features, 2000);
    assert_eq!(c.orb.n_levels, 8);
    let e = Config::parse("[orb]\nn_feature = 2000\n", Path::new("c.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("c.toml") && e.contains("line 2") && e.contains("n_feature"),
        "{e}"
    );
    let e = Config::parse("[orb]\nscale_factor = 0.5\n", Path::new("c.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("orb.scale_factor"), "{e}");
    for bad in [
        "prior_margin = 1.5",
        "prior_cell_px = 2",
        "min_patch_zncc = 1.5",
        "min_patch_zncc = -0.1",
    ] {
        let e = Config::parse(&format!("[semidense]\n{bad}\n"), Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        let field = bad.split(' ').next().unwrap_or_default();
        assert!(e.contains(&format!("semidense.{field}")), "{e}");
    }
}

#[test]
fn the_printed_defaults_parse_back_to_the_defaults() {
    let text = toml::to_string_pretty(&Config::default()).unwrap();
    for section in [
        "[tracking]",
        "[initialisation]",
        "[motion_only]",
        "[relocalisation]",
        "[local_mapping]",
        "[loop_closing]",
    ] {
        assert!(
            text.contains(section),
            "{section} missing from the printed tree"
        );
    }
    assert_eq!(
        Config::parse(&text, Path::new("d.toml")).unwrap(),
        Config::default()
    );
}

#[test]
fn every_stage_is_configurable_and_checked() {
    let c = Config::parse(
        "[tracking]\nmin_inliers = 40\n[initialisation]\nmin_parallax_deg = 0.5\n[loop_closing]\nmin_matches = 50\n",
        Path::new("c.toml"),
    )
    .unwrap();
    assert_eq!(
        (c.tracking.min_inliers, c.loop_closing.min_matches),
        (40, 50)
    );
    assert_eq!(c.initialisation.min_parallax_deg, 0.5);
    for (bad, field) in [
        (
            "[tracking]\nkeyframe_ratio = 1.5",
            "tracking.keyframe_ratio",
        ),
        ("[initialisation]\nsigma = nan", "initialisation.sigma"),
        (
            "[initialisation]\nmin_matches = 0",
            "initialisation.min_matches",
        ),
        (
            "[initialisation]\nmin_match_share = 1.5",
            "initialisation.min_match_share",
        ),
        (
            "[relocalisation]\nmin_inliers = 0",
            "relocalisation.min_inliers",
        ),
        (
            "[tracking]\ncollapse_young_over_old = 0",
            "tracking.collapse_young_over_old",
        ),
        (
            "[local_mapping]\nredundancy = 0",
            "local_mapping.redundancy",
        ),
        ("[tracking]\nmin_inlier = 3", "min_inlier"),
        (
            "[tracking]\nrecovery_frames = 100000",
            "tracking.recovery_frames",
        ),
    ] {
        let e = Config::parse(bad, Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains(field), "{bad}: {e}");
    }
}
