//! Fisheye cameras end to end: the built-in sequence rendered through a 170-degree
//! Kannala-Brandt lens is tracked as well as through the pinhole camera, its semi-dense cloud
//! is as accurate, and the lens survives the trip through a ROS 2 bag (CameraInfo
//! `equidistant`) and a TUM folder (ORB-SLAM3 `KannalaBrandt8` YAML).

mod common;

use common::sdslam;

fn run(source: &str, out: &std::path::Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "-q",
        "run",
        source,
        "--deterministic",
        "--no-plots",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let (ok, _, err) = sdslam(&args);
    assert!(ok, "{source}: {err}");
    let text = std::fs::read_to_string(out.join("report.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

#[test]
fn the_fisheye_sequence_is_tracked_and_mapped_as_well_as_the_pinhole_one() {
    let d = tempfile::tempdir().unwrap();
    let pinhole = run("synthetic", &d.path().join("pinhole"), &[]);
    let fisheye = run("synthetic:fisheye", &d.path().join("fisheye"), &[]);
    for r in [&pinhole, &fisheye] {
        assert_eq!(r["tracked_frames"], r["frames"], "{r}");
    }
    let ate = |r: &serde_json::Value| r["keyframe_ate_rmse_m"].as_f64().unwrap();
    eprintln!(
        "keyframe ATE: pinhole {:.2} mm, fisheye {:.2} mm",
        ate(&pinhole) * 1e3,
        ate(&fisheye) * 1e3
    );
    assert!(
        ate(&fisheye) <= 1.5 * ate(&pinhole),
        "fisheye {} against pinhole {}",
        ate(&fisheye),
        ate(&pinhole)
    );
    let acc = &fisheye["semidense_accuracy"];
    let median = acc["median_relative_error"].as_f64().unwrap();
    eprintln!(
        "fisheye semi-dense: median {:.3}%, {:.2}% outliers, {:.0} points per keyframe",
        median * 100.0,
        acc["outliers_10pct"].as_f64().unwrap() * 100.0,
        acc["points_per_keyframe"].as_f64().unwrap()
    );
    assert!(median <= 0.005, "{acc}");
    assert!(
        acc["points_per_keyframe"].as_f64().unwrap() > 5000.0,
        "{acc}"
    );
}

#[test]
fn a_fisheye_replays_the_same_from_a_bag_and_from_a_folder() {
    let d = tempfile::tempdir().unwrap();
    let p = |n: &str| d.path().join(n);
    let args = ["--frames", "40", "--no-semidense"];
    run("synthetic:fisheye", &p("direct"), &args);
    let want = std::fs::read_to_string(p("direct/trajectory.txt")).unwrap();
    assert_eq!(want.lines().count(), 40);
    let bag = p("fisheye.mcap");
    let (ok, _, err) = sdslam(&[
        "-q",
        "bag",
        "synthetic:fisheye",
        "--frames",
        "40",
        "--out",
        bag.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    run(bag.to_str().unwrap(), &p("bag"), &["--no-semidense"]);
    let folder = p("folder");
    let (ok, _, err) = sdslam(&[
        "synth",
        "--camera",
        "fisheye",
        "--frames",
        "40",
        "--out",
        folder.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let yaml = std::fs::read_to_string(folder.join("camera.yaml")).unwrap();
    assert!(yaml.contains("KannalaBrandt8"), "{yaml}");
    run(
        folder.to_str().unwrap(),
        &p("from_folder"),
        &["--no-semidense"],
    );
    for out in ["bag", "from_folder"] {
        let got = std::fs::read_to_string(p(out).join("trajectory.txt")).unwrap();
        assert_eq!(got, want, "{out}");
    }
}
