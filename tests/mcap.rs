//! MCAP in and out through the `sdslam` binary: a bag of the built-in sequence replays to the
//! same poses as the sequence itself, a damaged bag keeps the frames before the damage, and
//! topic mistakes list what the file has.

mod common;

use common::sdslam;

fn run(source: &str, out: &std::path::Path, extra: &[&str]) -> (bool, String) {
    let mut args = vec![
        "-q",
        "run",
        source,
        "--deterministic",
        "--no-semidense",
        "--no-plots",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let (ok, _, err) = sdslam(&args);
    (ok, err)
}

fn read(p: &std::path::Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn a_bag_of_the_built_in_sequence_replays_to_identical_poses() {
    let d = tempfile::tempdir().unwrap();
    let direct = d.path().join("direct");
    let (ok, err) = run("synthetic", &direct, &["--frames", "40"]);
    assert!(ok, "{err}");
    let want = read(&direct.join("trajectory.txt"));
    assert_eq!(want.lines().count(), 40);
    for (name, images, compression) in [
        ("raw.mcap", "raw", "none"),
        ("png.mcap", "png", "zstd"),
        ("lz4.mcap", "raw", "lz4"),
    ] {
        let bag = d.path().join(name);
        let (ok, _, err) = sdslam(&[
            "-q",
            "bag",
            "--frames",
            "40",
            "--images",
            images,
            "--compression",
            compression,
            "--out",
            bag.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        // The calibration comes from the bag's CameraInfo.
        let out = d.path().join(format!("out_{name}"));
        let (ok, err) = run(bag.to_str().unwrap(), &out, &[]);
        assert!(ok, "{name}: {err}");
        assert_eq!(read(&out.join("trajectory.txt")), want, "{name}");
        assert_eq!(
            read(&out.join("keyframes.txt")),
            read(&direct.join("keyframes.txt")),
            "{name}"
        );
    }
}

#[test]
fn a_damaged_bag_keeps_its_first_frames_and_topic_mistakes_list_the_topics() {
    let d = tempfile::tempdir().unwrap();
    let bag = d.path().join("b.mcap");
    let (ok, _, err) = sdslam(&[
        "-q",
        "bag",
        "--frames",
        "30",
        "--out",
        bag.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    // No compression and the default 768 KiB chunks: a cut at 60% leaves whole chunks
    // before it.
    let bytes = std::fs::read(&bag).unwrap();
    let cut = d.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let out = d.path().join("out_cut");
    let (_, err) = run(cut.to_str().unwrap(), &out, &[]);
    let traj = read(&out.join("trajectory.txt"));
    let n = traj.lines().count();
    assert!((5..30).contains(&n), "{n} frames posed; {err}");
    let report: serde_json::Value = serde_json::from_str(&read(&out.join("report.json"))).unwrap();
    let why = report["stopped_early"].as_str().unwrap_or_default();
    assert!(
        why.contains("cut.mcap") && why.contains("truncated") && why.contains("bytes"),
        "{why}"
    );
    let (ok, _, err) = sdslam(&[
        "-q",
        "run",
        bag.to_str().unwrap(),
        "--topic",
        "/cam/image",
        "--out",
        d.path().join("o2").to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        err.contains("no topic `/cam/image`")
            && err.contains("/camera/image_raw (sensor_msgs/msg/Image, 30 messages)"),
        "{err}"
    );
}
