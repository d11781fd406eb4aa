//! The robustness suite: stress scenes of the built-in renderer (`sdslam run synthetic:NAME`,
//! exact ground truth) replayed in the deterministic mode, each with the thresholds it is held
//! to: the frame of the first pose, the share of frames tracked after it, the keyframe ATE as a
//! share of the path length, and no frame reported `Ok` far off. Figures for every scene, also
//! those not yet held here, are in docs/PERFORMANCE.md ("Robustness suite").

mod common;

use common::sdslam;
use sdslam::eval::ate;
use sdslam::io::read_tum_trajectory;

struct Bar {
    scene: &'static str,
    /// First pose at or before this frame (frames before initialisation get poses by
    /// backfill, so 0 when it works).
    first_pose: usize,
    min_tracked: f64,
    max_kf_ate_of_path: f64,
}

fn check(bar: &Bar) {
    check_source(bar, &format!("synthetic:{}", bar.scene));
}

fn check_source(bar: &Bar, source: &str) {
    check_source_with(bar, source, true);
}

/// [`check_source`] in the deterministic mode or threaded (a recording replayed back to
/// back: local mapping on its own thread).
fn check_source_with(bar: &Bar, source: &str, deterministic: bool) {
    check_source_configured(bar, source, deterministic, None);
}

/// [`check_source_with`] with a configuration file of the given TOML text.
fn check_source_configured(bar: &Bar, source: &str, deterministic: bool, config: Option<&str>) {
    let out = tempfile::tempdir().unwrap();
    let config_path = out.path().join("config.toml");
    let mut args = vec!["-q", "run", source, "--no-semidense", "--no-plots"];
    if deterministic {
        args.push("--deterministic");
    }
    if let Some(text) = config {
        std::fs::write(&config_path, text).unwrap();
        args.extend(["--config", config_path.to_str().unwrap()]);
    }
    args.extend(["--out", out.path().to_str().unwrap()]);
    let (ok, _, err) = sdslam(&args);
    assert!(ok, "{}: sdslam run failed: {err}", bar.scene);
    let gt = read_tum_trajectory(&out.path().join("groundtruth.txt")).unwrap();
    let traj = read_tum_trajectory(&out.path().join("trajectory.txt")).unwrap();
    let kfs = read_tum_trajectory(&out.path().join("keyframes.txt")).unwrap();
    let path: f64 = gt
        .windows(2)
        .map(|w| (w[1].t_wc.position() - w[0].t_wc.position()).norm())
        .sum();
    let first = traj
        .first()
        .map(|p| {
            gt.iter()
                .position(|g| (g.timestamp - p.timestamp).abs() < 0.02)
                .unwrap_or(usize::MAX)
        })
        .unwrap_or(usize::MAX);
    assert!(
        first <= bar.first_pose,
        "{}: first pose at frame {first}, bar {}",
        bar.scene,
        bar.first_pose
    );
    let tracked = traj.len() as f64 / (gt.len() - first) as f64;
    let kf = ate(&gt, &kfs, 0.02, true).expect("keyframe ATE");
    // Every frame reported Ok, aligned with the keyframes' Sim3: none may be off by > 5% of
    // the path (a pose a robot would drive on).
    let frames = ate(&gt, &traj, 0.02, true).expect("frame ATE");
    let worst = frames.max_m / path;
    eprintln!(
        "{}: first pose {first}, tracked {:.1}%, keyframe ATE {:.4} m = {:.3}% of {path:.2} m, worst Ok frame {:.2}% of path",
        bar.scene,
        100.0 * tracked,
        kf.rmse_m,
        100.0 * kf.rmse_m / path,
        100.0 * worst
    );
    assert!(
        tracked >= bar.min_tracked,
        "{}: tracked {tracked:.3}",
        bar.scene
    );
    assert!(
        kf.rmse_m / path <= bar.max_kf_ate_of_path,
        "{}: keyframe ATE {:.4} m on {path:.2} m",
        bar.scene,
        kf.rmse_m
    );
    assert!(
        worst <= 0.05,
        "{}: a frame reported Ok is off by {:.1}% of the path",
        bar.scene,
        100.0 * worst
    );
}

/// Forward motion down a corridor from rest: a homography fits the low-parallax radial flow
/// and its decomposition gives a wrong motion unless F cross-checks it; the initialisation
/// window must follow the features (they leave a fixed window near the borders), and the young
/// map must keep its keyframes (each looks redundant to the next at this speed).
#[test]
fn forward_motion_from_rest_is_tracked_right() {
    check(&Bar {
        scene: "forward",
        first_pose: 0,
        min_tracked: 0.99,
        max_kf_ate_of_path: 0.01,
    });
}

/// The real car camera clips: straight driving (every frame, ATE <= 0.1% of the path) and
/// the highway with distant structure (first pose by frame 10, >= 97% tracked after it, ATE
/// <= 2%); the frames between the initialisation's two views are backfilled even at highway
/// speed (guessed from the keyframes' interpolation when stepping back from the second one
/// fails).
#[test]
fn the_real_kitti_clips_are_tracked() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let clip = |name: &str| data.join("real").join(name);
    check_source(
        &Bar {
            scene: "kitti06_51",
            first_pose: 0,
            min_tracked: 1.0,
            max_kf_ate_of_path: 0.001,
        },
        clip("kitti06_51").to_str().unwrap(),
    );
    check_source(
        &Bar {
            scene: "kitti01_51",
            // The map starts at frame 15 from reference 9; the frames before the reference
            // are kept and backfilled through it.
            first_pose: 0,
            min_tracked: 0.97,
            max_kf_ate_of_path: 0.02,
        },
        clip("kitti01_51").to_str().unwrap(),
    );
}

/// ORB-SLAM's feature count for KITTI, which a user coming from it may well keep.
const ORB_SLAM_KITTI_FEATURES: &str = "[orb]\nn_features = 2000\n";

/// The highway clip with ORB-SLAM's KITTI feature count (2000). The map made at frame 9
/// collapses in the real 29 deg curve of frames 13-24: its new points sit at 0.32 of the depth
/// of the older points beside them, so the turn does not excuse the depth it lost, and it is
/// rolled back. Before, all 43 frames after frame 8 were reported `Ok`, 28 of them off by more
/// than 5% of the path (up to 48%), at 10.3% keyframe ATE. The bar is the for this
/// clip: the frames reported tracked within 2% of the path, none far off.
#[test]
fn the_highway_with_2000_features_reports_no_collapsed_pose() {
    let Some(data) = common::shared_data() else {
        return;
    };
    check_source_configured(
        &Bar {
            scene: "kitti01_51, 2000 features",
            // Since 3b49369 the map that lasts starts at frame 5 (before: 29, backfilled to 25).
            first_pose: 30,
            min_tracked: 0.97,
            max_kf_ate_of_path: 0.02,
        },
        data.join("real").join("kitti01_51").to_str().unwrap(),
        true,
        Some(ORB_SLAM_KITTI_FEATURES),
    );
}

/// Desk with 1750 features: the map starts at frame 25 from 1.17 deg of parallax. Local BA
/// fixed only the first keyframe, so the scale was free while every keyframe of the young map
/// was local: the initial pair's baseline halved over 5 keyframes, the points' rays closed
/// below the kept parallax (133 of 549 erased at the first BA), keyframes made every frame
/// triangulated 3-14 points, and the map was reported `Ok` up to 6.7% of the path off until it
/// was lost at frame 136. With the pair's second keyframe fixed too (a start under 3 deg of
/// median parallax) the first map lasts.
#[test]
fn desk_with_1750_features_keeps_its_first_map() {
    let Some(data) = common::shared_data() else {
        return;
    };
    check_source_configured(
        &Bar {
            scene: "desk, 1750 features",
            first_pose: 0,
            min_tracked: 0.99,
            max_kf_ate_of_path: 0.001,
        },
        data.join("synthetic").join("desk").to_str().unwrap(),
        true,
        Some("[orb]\nn_features = 1750\n"),
    );
}

/// The built-in orbit with 2000 features: the homography is chosen at frame 1 (1.8 deg of
/// parallax) and its decomposition picks a vertical translation, 81 deg from the horizontal
/// motion its own refinement and F find. That map shrank steadily (the per-frame step fell
/// 1000x by frame 110), 257 frames were reported `Ok` up to 19% of the path off. F's
/// reconstruction is taken instead.
#[test]
fn the_orbit_with_2000_features_starts_from_the_right_motion() {
    check_source_configured(
        &Bar {
            scene: "orbit, 2000 features",
            first_pose: 0,
            min_tracked: 0.99,
            max_kf_ate_of_path: 0.001,
        },
        "synthetic",
        true,
        Some(ORB_SLAM_KITTI_FEATURES),
    );
}

/// A recording replayed back to back, threaded: tracking waits for local mapping before each
/// frame (no frame deadline in a replay), so keyframes are made as in real time. Without the
/// wait tracking ran ahead, local mapping was rarely idle, and kitti06_51 kept 17-18
/// keyframes instead of 31 at 0.09-0.13% of the path.
#[test]
fn a_threaded_replay_keeps_its_keyframes() {
    let Some(data) = common::shared_data() else {
        return;
    };
    check_source_with(
        &Bar {
            scene: "kitti06_51 (threaded)",
            first_pose: 0,
            min_tracked: 1.0,
            max_kf_ate_of_path: 0.001,
        },
        data.join("real").join("kitti06_51").to_str().unwrap(),
        false,
    );
}

/// One orbit in a third of the frames, three-sample motion blur.
#[test]
fn fast_blurred_motion_is_tracked() {
    check(&Bar {
        scene: "fast-blur",
        first_pose: 0,
        min_tracked: 0.97,
        max_kf_ate_of_path: 0.01,
    });
}

/// Looking outward while travelling a loop past weakly textured walls (22-76 FAST corners a
/// frame at ORB-SLAM's thresholds): the third FAST pass (`[orb] starved_th_fast`) finds the
/// faint corners, so one map holds every frame instead of four maps with gaps between them.
/// Parallax reaches 1 deg by frame 2, so the first pose is due by frame 12.
#[test]
fn an_outward_loop_past_weak_walls_is_tracked() {
    check(&Bar {
        scene: "outward-loop",
        first_pose: 12,
        min_tracked: 0.97,
        max_kf_ate_of_path: 0.01,
    });
}

/// The image gain steps by 1.6 half way (auto exposure).
#[test]
fn an_exposure_step_is_tracked_through() {
    check(&Bar {
        scene: "exposure-step",
        first_pose: 0,
        min_tracked: 0.97,
        max_kf_ate_of_path: 0.01,
    });
}

/// Every surface a repetitive pattern (fine noise, stripes, tiles, rows of glyphs): ORB
/// matches are ambiguous between repeats, so matching must hold to the predicted positions.
#[test]
fn repetitive_textures_are_tracked() {
    check(&Bar {
        scene: "repetitive",
        first_pose: 0,
        min_tracked: 0.97,
        max_kf_ate_of_path: 0.01,
    });
}

/// Three boxes move through the scene (across the desk, along the floor, up and down a
/// wall): their features are outliers to the static map.
#[test]
fn moving_objects_do_not_pull_the_pose() {
    check(&Bar {
        scene: "moving-objects",
        first_pose: 0,
        min_tracked: 0.97,
        max_kf_ate_of_path: 0.01,
    });
}

/// What a run with a blackout gave: report.json, ground truth, trajectory, keyframes and the
/// path length.
struct BlackoutRun {
    report: serde_json::Value,
    gt: Vec<sdslam::eval::TimedPose>,
    traj: Vec<sdslam::eval::TimedPose>,
    kfs: Vec<sdslam::eval::TimedPose>,
    path: f64,
}

/// The built-in orbit (`frames` long) with frames 150..195 withheld (`--drop 150:45`).
fn run_blackout(deterministic: bool, frames: usize) -> BlackoutRun {
    let out = tempfile::tempdir().unwrap();
    let frames = frames.to_string();
    let mut args = vec![
        "-q",
        "run",
        "synthetic",
        "--frames",
        &frames,
        "--no-semidense",
        "--no-plots",
    ];
    if deterministic {
        args.push("--deterministic");
    }
    args.extend(["--drop", "150:45", "--out", out.path().to_str().unwrap()]);
    let (ok, _, err) = sdslam(&args);
    assert!(ok, "sdslam run failed: {err}");
    let read = |name: &str| read_tum_trajectory(&out.path().join(name)).unwrap();
    let gt = read("groundtruth.txt");
    let path = gt
        .windows(2)
        .map(|w| (w[1].t_wc.position() - w[0].t_wc.position()).norm())
        .sum();
    BlackoutRun {
        report: serde_json::from_str(
            &std::fs::read_to_string(out.path().join("report.json")).unwrap(),
        )
        .unwrap(),
        traj: read("trajectory.txt"),
        kfs: read("keyframes.txt"),
        gt,
        path,
    }
}

/// A 45-frame blackout (a covered lens, a dropped link) during which the camera moves on to a
/// part of the orbit no map has seen: relocalisation cannot succeed there, so a new map of
/// the atlas starts at once, and place recognition merges it into the first map when the
/// orbit comes back. Every frame after the blackout gets a pose, all in one frame at the end.
#[test]
fn a_blackout_in_unmapped_space_starts_a_new_map_that_is_merged_back() {
    let BlackoutRun {
        report,
        gt,
        traj,
        kfs,
        path,
    } = run_blackout(true, 300);
    let frames = report["frames"].as_u64().unwrap() as f64;
    assert_eq!(report["maps_made"], 2, "{}", report["maps"]);
    assert_eq!(report["maps_merged"], 1, "{}", report["maps"]);
    assert_eq!(
        report["maps"].as_array().map(|m| m.len()),
        Some(1),
        "one map at the end: {}",
        report["maps"]
    );
    let tracked = traj.len() as f64 / frames;
    let kf = ate(&gt, &kfs, 0.02, true).expect("keyframe ATE");
    let worst = ate(&gt, &traj, 0.02, true).expect("frame ATE").max_m / path;
    eprintln!(
        "blackout 150:45: tracked {:.1}% of {frames} frames, keyframe ATE {:.4} m = {:.3}% of {path:.2} m, worst Ok frame {:.2}%",
        100.0 * tracked,
        kf.rmse_m,
        100.0 * kf.rmse_m / path,
        100.0 * worst
    );
    assert!(tracked >= 0.97, "tracked {tracked:.3}");
    assert!(kf.rmse_m / path <= 0.01, "keyframe ATE {:.4} m", kf.rmse_m);
    assert!(
        worst <= 0.05,
        "a frame reported Ok is off by {:.1}%",
        100.0 * worst
    );
}

/// The same blackout with every thread running (initialisation on `sdslam-init`, mapping and
/// loop closing on theirs): the new map starts, frames keep getting poses, and no frame
/// reported `Ok` is far off. (How well the merged map fits varies run to run here, so ATE is
/// held in the deterministic test above.)
#[test]
fn threaded_a_blackout_in_unmapped_space_keeps_every_frame_posed() {
    let BlackoutRun {
        report,
        gt,
        traj,
        path,
        ..
    } = run_blackout(false, 300);
    let frames = report["frames"].as_u64().unwrap() as f64;
    let tracked = report["tracked_frames_all_maps"].as_u64().unwrap() as f64;
    assert!(
        report["maps_made"].as_u64().unwrap() >= 2,
        "{}",
        report["maps"]
    );
    assert!(
        tracked / frames >= 0.97,
        "{tracked} of {frames} frames posed"
    );
    let worst = ate(&gt, &traj, 0.02, true).expect("frame ATE").max_m / path;
    eprintln!(
        "threaded blackout: maps {} made / {} merged, {tracked} of {frames} posed, worst Ok {:.2}%",
        report["maps_made"],
        report["maps_merged"],
        100.0 * worst
    );
    assert!(
        worst <= 0.05,
        "a frame reported Ok is off by {:.1}%",
        100.0 * worst
    );
}

/// The same blackout on a faster orbit (240 frames), every thread running: the new map rejoins
/// the first only where the orbit closes, from matches in one part of the image. The merge's
/// similarity is chosen among several RANSAC hypotheses by how many matches a window of
/// keyframes finds with it, and refused while its scale is poorly fixed; taken from the first
/// hypothesis at once, it left the merged map 2.4% of the path off (5% on its worst frame).
#[test]
fn threaded_a_merge_from_matches_in_one_part_of_the_image_is_placed_right() {
    let BlackoutRun {
        report,
        gt,
        traj,
        kfs,
        path,
    } = run_blackout(false, 240);
    assert_eq!(report["maps_merged"], 1, "{}", report["maps"]);
    let kf = ate(&gt, &kfs, 0.02, true).expect("keyframe ATE");
    let worst = ate(&gt, &traj, 0.02, true).expect("frame ATE").max_m / path;
    eprintln!(
        "threaded merge on a 240-frame orbit: keyframe ATE {:.4} m = {:.3}% of {path:.2} m, worst Ok {:.2}%",
        kf.rmse_m,
        100.0 * kf.rmse_m / path,
        100.0 * worst
    );
    assert!(kf.rmse_m / path <= 0.01, "keyframe ATE {:.4} m", kf.rmse_m);
    assert!(
        worst <= 0.05,
        "a frame reported Ok is off by {:.1}%",
        100.0 * worst
    );
}

/// A dim room, from rest (`synthetic:low-light`): a quarter of the light and 3 grey levels of
/// sensor noise after the gain, so fewer, weaker and noisier corners.
#[test]
fn a_dim_room_from_rest_is_tracked() {
    check(&Bar {
        scene: "low-light",
        first_pose: 0,
        min_tracked: 0.99,
        max_kf_ate_of_path: 0.01,
    });
}
