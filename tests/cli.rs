//! The command-line contract: outputs, report keys, evaluation, and clear errors on bad input.

mod common;

use common::sdslam;
use sdslam::camera::{Frame, FrameSource, FrameStatus, ImageListSource};
use sdslam::io::read_tum_trajectory;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn report(dir: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

#[test]
fn run_on_synthetic_writes_every_output_with_stable_report_keys() {
    let out = tempfile::tempdir().unwrap();
    let (ok, _, err) = sdslam(&[
        "run",
        "synthetic",
        "--frames",
        "4",
        "--out",
        out.path().to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    for f in [
        "trajectory.txt",
        "keyframes.txt",
        "semidense.ply",
        "report.json",
        "groundtruth.txt",
    ] {
        assert!(out.path().join(f).is_file(), "{f} missing");
    }
    let r = report(out.path());
    for k in [
        "frames",
        "tracked_frames",
        "lost_episodes",
        "keyframes",
        "map_points",
        "loops_closed",
        "relocalisations",
        "skipped_frames",
        "deadline_misses",
        "dropped_frames",
        "peak_rss_mb",
    ] {
        assert!(r.get(k).is_some(), "report.json lacks {k}");
    }
    for k in [
        "tracking",
        "orb_extraction",
        "initialisation",
        "map_lock_wait",
        "local_ba",
        "loop_closing",
        "semidense_keyframe",
        "semidense_depth",
        "semidense_intra",
        "semidense_inter",
    ] {
        let t = &r["timing_ms"][k];
        for p in ["p50", "p90", "p99", "max", "count"] {
            assert!(t.get(p).is_some(), "timing_ms.{k}.{p} missing");
        }
    }
    assert_eq!(r["frames"], 4);
}

#[test]
fn eval_ate_json_on_known_transform() {
    let d = tempfile::tempdir().unwrap();
    let mut gt = String::new();
    let mut est = String::new();
    for i in 0..50 {
        let t = i as f64 * 0.1;
        let (x, y, z) = (t.cos(), t.sin(), 0.1 * t);
        gt.push_str(&format!("{:.6} {x} {y} {z} 0 0 0 1\n", 100.0 + t));
        // Estimate: scaled by 2, shifted, 5 ms later.
        est.push_str(&format!(
            "{:.6} {} {} {} 0 0 0 1\n",
            100.005 + t,
            2.0 * x + 1.0,
            2.0 * y,
            2.0 * z
        ));
    }
    std::fs::write(d.path().join("gt.txt"), gt).unwrap();
    std::fs::write(d.path().join("est.txt"), est).unwrap();
    let (ok, out, err) = sdslam(&[
        "eval",
        "ate",
        d.path().join("gt.txt").to_str().unwrap(),
        d.path().join("est.txt").to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert!(v["rmse_m"].as_f64().unwrap() < 1e-5);
    assert!((v["scale"].as_f64().unwrap() - 0.5).abs() < 1e-5);
    assert_eq!(v["matched"], 50);
    assert!(v.get("median_m").is_some() && v.get("max_m").is_some());
}

#[test]
fn bad_inputs_give_clear_errors_without_panics() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let outs = out.to_str().unwrap();
    let check = |args: &[&str], needles: &[&str]| {
        let (ok, _, err) = sdslam(args);
        assert!(!ok, "{args:?} should fail");
        assert!(
            !err.contains("panicked") && !err.contains("RUST_BACKTRACE"),
            "{err}"
        );
        for n in needles {
            assert!(err.contains(n), "{args:?}: {err:?} lacks {n:?}");
        }
    };
    // Empty folder.
    let empty = d.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    check(
        &["run", empty.to_str().unwrap(), "--out", outs],
        &["empty", "no PNG/JPEG"],
    );
    // Nonexistent source.
    check(
        &["run", "/no/such/folder", "--out", outs],
        &["/no/such/folder"],
    );
    // TUM folder with a list naming a missing image, and with time going backwards.
    let tum = d.path().join("tum");
    std::fs::create_dir_all(tum.join("rgb")).unwrap();
    image::GrayImage::new(8, 8)
        .save(tum.join("rgb/a.png"))
        .unwrap();
    std::fs::write(tum.join("rgb.txt"), "1.0 rgb/a.png\n2.0 rgb/missing.png\n").unwrap();
    check(
        &["run", tum.to_str().unwrap(), "--out", outs],
        &["rgb.txt:2", "missing.png"],
    );
    std::fs::write(tum.join("rgb.txt"), "2.0 rgb/a.png\n1.0 rgb/a.png\n").unwrap();
    check(
        &["run", tum.to_str().unwrap(), "--out", outs],
        &["rgb.txt:2", "does not increase"],
    );
    // No calibration available.
    std::fs::write(tum.join("rgb.txt"), "1.0 rgb/a.png\n").unwrap();
    check(&["run", tum.to_str().unwrap(), "--out", outs], &["--calib"]);
    // Calibration with a bad field, and one for another image size.
    let cal = d.path().join("cal.yaml");
    std::fs::write(&cal, "%YAML:1.0\nCamera.fx: -5\nCamera.fy: 5\nCamera.cx: 4\nCamera.cy: 4\nCamera.width: 8\nCamera.height: 8\n").unwrap();
    check(
        &[
            "run",
            tum.to_str().unwrap(),
            "--calib",
            cal.to_str().unwrap(),
            "--out",
            outs,
        ],
        &["cal.yaml:2", "Camera.fx"],
    );
    std::fs::write(&cal, "%YAML:1.0\nCamera.fx: 5\nCamera.fy: 5\nCamera.cx: 4\nCamera.cy: 4\nCamera.width: 16\nCamera.height: 8\n").unwrap();
    check(
        &[
            "run",
            tum.to_str().unwrap(),
            "--calib",
            cal.to_str().unwrap(),
            "--out",
            outs,
        ],
        &["cal.yaml", "16x8", "8x8"],
    );
    // Unknown config key.
    let cfg = d.path().join("c.toml");
    std::fs::write(&cfg, "[orb]\nnfeatures = 3\n").unwrap();
    check(
        &[
            "run",
            "synthetic",
            "--frames",
            "1",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            outs,
        ],
        &["c.toml", "nfeatures"],
    );
    // Output folder that cannot be created.
    let file = d.path().join("file");
    std::fs::write(&file, "x").unwrap();
    check(
        &[
            "run",
            "synthetic",
            "--frames",
            "1",
            "--out",
            file.join("sub").to_str().unwrap(),
        ],
        &["file/sub"],
    );
    // Malformed trajectory for eval.
    std::fs::write(d.path().join("bad.txt"), "1 2 3\n").unwrap();
    let b = d.path().join("bad.txt");
    check(
        &["eval", "ate", b.to_str().unwrap(), b.to_str().unwrap()],
        &["bad.txt:1", "8 fields"],
    );
}

#[test]
fn corrupt_frame_mid_sequence_is_skipped_and_counted() {
    let d = tempfile::tempdir().unwrap();
    let tum = d.path().join("tum");
    std::fs::create_dir_all(tum.join("rgb")).unwrap();
    let mut list = String::new();
    for i in 0..4 {
        let name = format!("rgb/{i}.png");
        image::GrayImage::from_pixel(8, 8, image::Luma([i as u8 * 40]))
            .save(tum.join(&name))
            .unwrap();
        list.push_str(&format!("{}.0 {name}\n", i + 1));
    }
    std::fs::write(tum.join("rgb/2.png"), b"\x89PNG truncated").unwrap();
    std::fs::write(tum.join("rgb.txt"), list).unwrap();
    std::fs::write(tum.join("camera.yaml"), "%YAML:1.0\nCamera.fx: 5\nCamera.fy: 5\nCamera.cx: 4\nCamera.cy: 4\nCamera.width: 8\nCamera.height: 8\n").unwrap();
    let out = d.path().join("out");
    let (ok, _, err) = sdslam(&["run", tum.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(err.contains("warning") && err.contains("2.png"), "{err}");
    let r = report(&out);
    assert_eq!(r["frames"], 3);
    assert_eq!(r["skipped_frames"], 1);
}

#[test]
fn vocab_train_import_and_bad_files() {
    let d = tempfile::tempdir().unwrap();
    // Train on a few rendered frames of the built-in sequence.
    let seq = d.path().join("seq");
    common::synth_folder(&seq, 6, 0);
    let voc = d.path().join("v.bin");
    let (ok, out, err) = sdslam(&[
        "vocab",
        "train",
        seq.to_str().unwrap(),
        "--k",
        "8",
        "--levels",
        "3",
        "--every",
        "2",
        "--out",
        voc.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("trained on 3 images"), "{out}");
    // Re-import of the binary file gives the same bytes.
    let again = d.path().join("v2.bin");
    let (ok, _, err) = sdslam(&[
        "vocab",
        "import",
        voc.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert_eq!(std::fs::read(&voc).unwrap(), std::fs::read(&again).unwrap());
    // A truncated file and a text file that is not a vocabulary: clear errors naming the file.
    let bytes = std::fs::read(&voc).unwrap();
    let trunc = d.path().join("trunc.bin");
    std::fs::write(&trunc, &bytes[..bytes.len() / 2]).unwrap();
    let (ok, _, err) = sdslam(&[
        "vocab",
        "import",
        trunc.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("trunc.bin") && err.contains("truncated"),
        "{err}"
    );
    let junk = d.path().join("junk.txt");
    std::fs::write(&junk, "hello world\n").unwrap();
    let (ok, _, err) = sdslam(&[
        "vocab",
        "import",
        junk.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("junk.txt") && err.contains("line 1"),
        "{err}"
    );
}

#[test]
fn densify_writes_cloud_depth_maps_and_accuracy_and_eval_cloud_agrees() {
    let d = tempfile::tempdir().unwrap();
    let seq = d.path().join("seq");
    let out = d.path().join("out");
    common::synth_folder(&seq, 90, 8);
    let poses = seq.join("groundtruth.txt");
    let (ok, _, err) = sdslam(&[
        "densify",
        seq.to_str().unwrap(),
        "--poses",
        poses.to_str().unwrap(),
        // The 90-frame orbit turns 4 degrees per frame: every 2nd frame is a keyframe.
        "--every",
        "2",
        "--depth-maps",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let r = report(&out);
    let n = r["semidense_points"].as_u64().unwrap();
    assert!(n > 10_000, "{n} points");
    let acc = &r["semidense_accuracy"];
    assert!(
        acc["median_relative_error"].as_f64().unwrap() < 0.01,
        "{acc}"
    );
    let ply = std::fs::read(out.join("semidense.ply")).unwrap();
    let cloud = sdslam::io::decode_ply(&ply, &out.join("semidense.ply")).unwrap();
    assert_eq!(cloud.len() as u64, n);
    // One 16-bit depth map per reconstructed keyframe, at the calibration's size.
    let maps: Vec<_> = std::fs::read_dir(out.join("depth")).unwrap().collect();
    assert_eq!(
        maps.len() as u64,
        r["semidense_keyframes"].as_u64().unwrap()
    );
    let first = maps[0].as_ref().unwrap().path();
    let (w, h, depth) = sdslam::io::read_depth_png(&first, 5000.0).unwrap();
    assert_eq!((w, h), (640, 480));
    assert!(depth.iter().filter(|d| **d > 0.0).count() > 1000);
    // The evaluation subcommand reproduces the report's figure.
    let (ok, stdout, err) = sdslam(&[
        "eval",
        "cloud",
        out.to_str().unwrap(),
        "--gt",
        seq.to_str().unwrap(),
        "--keyframes",
        poses.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let e: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(e["points"], acc["points"]);
    assert!(
        (e["median_relative_error"].as_f64().unwrap()
            - acc["median_relative_error"].as_f64().unwrap())
        .abs()
            < 1e-9
    );
}

#[test]
fn bad_drop_and_densify_arguments_are_clear_errors() {
    let (ok, _, err) = sdslam(&["run", "--drop", "10-5"]);
    assert!(!ok && err.contains("START:COUNT"), "{err}");
    let d = tempfile::tempdir().unwrap();
    let missing = d.path().join("nope.txt");
    let (ok, _, err) = sdslam(&[
        "densify",
        "synthetic",
        "--poses",
        missing.to_str().unwrap(),
        "--out",
        d.path().join("o").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("nope.txt"), "{err}");
}

#[test]
fn bench_latency_prints_a_histogram_and_rejects_impossible_cores() {
    let d = tempfile::tempdir().unwrap();
    let (ok, out, err) = sdslam(&[
        "bench",
        "latency",
        "synthetic",
        "--frames",
        "30",
        "--no-semidense",
        "--cores",
        "0",
        "--out",
        d.path().join("o").to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(
        out.contains("deadline misses") && out.contains("p99"),
        "{out}"
    );
    let (ok, _, err) = sdslam(&["bench", "latency", "--cores", "100000"]);
    assert!(!ok && err.contains("--cores"), "{err}");
}

#[test]
fn cameras_without_devices_says_so_and_succeeds() {
    let (ok, out, err) = sdslam(&["cameras"]);
    assert!(ok, "{err}");
    // The build machines have no /dev/video*; on a machine with a camera it is listed.
    if !std::path::Path::new("/dev/video0").exists() {
        assert!(out.contains("no cameras found"), "{out}");
    } else {
        assert!(out.contains("v4l2:/dev/video"), "{out}");
    }
}

#[test]
fn live_camera_errors_name_the_device_and_the_fix() {
    let out = tempfile::tempdir().unwrap();
    let o = out.path().to_str().unwrap();
    let (ok, _, err) = sdslam(&["run", "v4l2:/dev/video97", "--out", o]);
    assert!(!ok && err.contains("--calib"), "{err}");
    let (ok, _, err) = sdslam(&[
        "run",
        "v4l2:/dev/video97",
        "--calib",
        "calib/synthetic.yaml",
        "--out",
        o,
    ]);
    assert!(
        !ok && err.contains("/dev/video97") && err.contains("no such camera"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    let (ok, _, err) = sdslam(&["run", "fakecam:h264", "--out", o]);
    assert!(!ok && err.contains("expected GREY, YUYV or MJPG"), "{err}");
}

/// The live path end to end without a device: the built-in sequence through the fake camera in
/// YUYV, newest-frame-wins pacing, then the camera unplugged at frame 90: the run ends cleanly
/// with every output written and the reason in the report.
#[test]
fn fake_camera_tracks_and_an_unplug_still_writes_every_output() {
    let out = tempfile::tempdir().unwrap();
    let (ok, _, err) = sdslam(&[
        "run",
        "fakecam:yuyv,unplug=90",
        "--no-semidense",
        "--out",
        out.path().to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("disconnected"), "{err}");
    let r = report(out.path());
    assert!(
        r["source"].as_str().unwrap().contains("YUYV 640x480"),
        "{}",
        r["source"]
    );
    let frames = r["frames"].as_u64().unwrap();
    assert!(frames > 30 && frames <= 90, "{frames} frames");
    // Tracking starts after initialisation (frame ~30 of the built-in sequence).
    assert!(r["tracked_frames"].as_u64().unwrap() + 35 >= frames, "{r}");
    assert!(r["stopped_early"]
        .as_str()
        .unwrap()
        .contains("disconnected"));
    for f in [
        "trajectory.txt",
        "keyframes.txt",
        "semidense.ply",
        "report.json",
    ] {
        assert!(out.path().join(f).is_file(), "{f} missing");
    }
    let traj = std::fs::read_to_string(out.path().join("trajectory.txt")).unwrap();
    assert!(traj.lines().filter(|l| !l.starts_with('#')).count() > 20);
}

/// `record` writes a TUM folder that replays through the file-backed mock with the same frames.
#[test]
fn record_from_the_fake_camera_replays_as_a_tum_folder() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let (ok, _, err) = sdslam(&[
        "record",
        "fakecam:grey",
        "--calib",
        "calib/synthetic.yaml",
        "--frames",
        "12",
        "--out",
        rec.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let list = std::fs::read_to_string(rec.join("rgb.txt")).unwrap();
    let stamps: Vec<f64> = list
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect();
    // A camera never waits: on a loaded machine the frames that come while a PNG is still
    // being written are dropped (and counted). Every frame is saved or counted as dropped.
    let dropped: usize = err
        .split(" dropped because writing was behind")
        .next()
        .and_then(|s| s.rsplit(", ").next())
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("no dropped count in: {err}"));
    assert_eq!(stamps.len() + dropped, 12, "{err}");
    assert!(stamps.len() >= 6, "most frames dropped: {err}");
    assert!(stamps.windows(2).all(|w| w[1] > w[0]));
    assert!(rec.join("camera.yaml").is_file());
    let out = dir.path().join("out");
    let (ok, _, err) = sdslam(&[
        "run",
        rec.to_str().unwrap(),
        "--no-semidense",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert_eq!(report(&out)["frames"], stamps.len());
    // Recording into a non-empty folder is refused.
    let (ok, _, err) = sdslam(&[
        "record",
        "fakecam",
        "--frames",
        "1",
        "--out",
        rec.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("not empty"), "{err}");
}

/// Ctrl-C (SIGINT) mid-run: the run stops, joins its threads and writes every output.
#[test]
fn interrupt_mid_run_writes_the_outputs_so_far() {
    let out = tempfile::tempdir().unwrap();
    let mut child = std::process::Command::new(common::sdslam_bin())
        .args(["run", "fakecam:yuyv", "--out", out.path().to_str().unwrap()])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_secs(4));
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    let r = report(out.path());
    assert!(
        r["stopped_early"].as_str().unwrap().contains("interrupted"),
        "{r}"
    );
    assert!(r["frames"].as_u64().unwrap() > 0);
    for f in ["trajectory.txt", "keyframes.txt", "semidense.ply"] {
        assert!(out.path().join(f).is_file(), "{f} missing");
    }
}

/// Ctrl-C during the end-of-session pass: the pass stops at once and is dropped; the
/// online cloud is written as semidense.ply and the report says so.
#[test]
fn interrupt_during_the_end_of_session_pass_keeps_the_online_cloud() {
    let d = tempfile::tempdir().unwrap();
    let (seq, run) = (d.path().join("seq"), d.path().join("run"));
    common::synth_folder(&seq, 90, 1);
    let out = std::process::Command::new(common::sdslam_bin())
        .args([
            "run",
            seq.to_str().unwrap(),
            "--deterministic",
            "--semidense-final",
        ])
        .args(["--no-plots", "--out", run.to_str().unwrap()])
        .env("SDSLAM_FAULT", "interrupt:semidense_final")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("end-of-session pass is dropped"), "{err}");
    let r = report(&run);
    assert!(
        r["stopped_early"]
            .as_str()
            .unwrap()
            .contains("during the end-of-session"),
        "{r}"
    );
    assert!(r["semidense_final"].is_null(), "{r}");
    let p = run.join("semidense.ply");
    let n = sdslam::io::decode_ply(&std::fs::read(&p).unwrap(), &p)
        .unwrap()
        .len() as u64;
    assert!(n > 0);
    assert_eq!(n, r["semidense_points"].as_u64().unwrap());
    assert!(!run.join("semidense_online.ply").exists());
}

/// `calibrate` on rendered chessboard views recovers the camera they were rendered with, and
/// writes YAML that `run --calib` reads.
#[test]
fn calibrate_rendered_chessboards_recovers_the_camera() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    let (ok, _, err) = sdslam(&["synth", "--chessboard", "--out", views.to_str().unwrap()]);
    assert!(ok, "{err}");
    let out = dir.path().join("cam.yaml");
    let (ok, stdout, err) = sdslam(&[
        "calibrate",
        views.to_str().unwrap(),
        "--board",
        "9x6",
        "--square",
        "0.025",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("found in 15 of 15"), "{err}");
    assert!(stdout.contains("reprojection RMS"), "{stdout}");
    let got = sdslam::camera_model::Calibration::parse(
        &std::fs::read_to_string(&out).unwrap(),
        "cam.yaml",
    )
    .unwrap();
    let want = sdslam::camera_model::Calibration::parse(
        &std::fs::read_to_string(views.join("truth.yaml")).unwrap(),
        "truth.yaml",
    )
    .unwrap();
    let (g, w) = (got.camera, want.camera);
    for (a, b) in [(g.fx, w.fx), (g.fy, w.fy), (g.cx, w.cx), (g.cy, w.cy)] {
        assert!(((a - b) / b).abs() < 0.005, "{a} vs {b}");
    }
    assert!((g.k1 - w.k1).abs() < 0.01);
    // Bad inputs: clear errors.
    let (ok, _, err) = sdslam(&[
        "calibrate",
        views.to_str().unwrap(),
        "--board",
        "9",
        "--square",
        "0.025",
        "--out",
        "x.yaml",
    ]);
    assert!(!ok && err.contains("COLSxROWS"), "{err}");
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let (ok, _, err) = sdslam(&[
        "calibrate",
        empty.to_str().unwrap(),
        "--board",
        "9x6",
        "--square",
        "0.025",
        "--out",
        "x.yaml",
    ]);
    assert!(!ok && err.contains("no PNG or JPEG images"), "{err}");
    // The board named wrongly (7x5 instead of 9x6): found nowhere, said so.
    let (ok, _, err) = sdslam(&[
        "calibrate",
        views.to_str().unwrap(),
        "--board",
        "7x5",
        "--square",
        "0.025",
        "--out",
        "x.yaml",
    ]);
    assert!(!ok && err.contains("found in 0 views"), "{err}");
}

/// A worker thread that panics mid-run (fault injected through `SDSLAM_FAULT`): the run stops
/// without hanging, says which thread failed, exits non-zero and still writes every output.
#[test]
fn a_panicking_worker_thread_stops_the_run_with_outputs_written() {
    for (fault, thread) in [
        ("panic:local_mapping", "local-mapping"),
        ("panic:semidense", "semi-dense"),
    ] {
        let out = tempfile::tempdir().unwrap();
        let o = std::process::Command::new(common::sdslam_bin())
            .args([
                "run",
                "synthetic",
                "--frames",
                "200",
                "--out",
                out.path().to_str().unwrap(),
            ])
            .env("SDSLAM_FAULT", fault)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{fault}: {err}");
        assert!(
            err.contains(thread) && err.contains("every output was written"),
            "{fault}: {err}"
        );
        let r = report(out.path());
        assert!(
            r["stopped_early"].as_str().unwrap().contains("panicked"),
            "{fault}: {r}"
        );
        for f in [
            "trajectory.txt",
            "keyframes.txt",
            "semidense.ply",
            "report.json",
        ] {
            assert!(out.path().join(f).is_file(), "{fault}: {f} missing");
        }
    }
}

/// Every kind of bad image in the middle of a replay is skipped, counted and warned about once;
/// a sequence with no readable image at all is a clear error.
#[test]
fn every_kind_of_bad_image_mid_sequence_is_skipped_and_counted() {
    let d = tempfile::tempdir().unwrap();
    let tum = d.path().join("tum");
    std::fs::create_dir_all(tum.join("rgb")).unwrap();
    let mut list = String::new();
    for i in 0..8 {
        let name = format!("rgb/{i}.png");
        image::GrayImage::from_fn(8, 8, |x, y| image::Luma([(x * 20 + y * 7 + i) as u8]))
            .save(tum.join(&name))
            .unwrap();
        list.push_str(&format!("{}.0 {name}\n", i + 1));
    }
    std::fs::write(tum.join("rgb.txt"), &list).unwrap();
    std::fs::write(tum.join("camera.yaml"), "%YAML:1.0\nCamera.fx: 5\nCamera.fy: 5\nCamera.cx: 4\nCamera.cy: 4\nCamera.width: 8\nCamera.height: 8\n").unwrap();
    // 1: zero bytes; 2: garbage; 3: a truncated JPEG; 4: the wrong size; 5: a truncated PNG.
    std::fs::write(tum.join("rgb/1.png"), b"").unwrap();
    std::fs::write(tum.join("rgb/2.png"), b"this is not an image at all").unwrap();
    let mut jpeg = Vec::new();
    image::GrayImage::from_pixel(8, 8, image::Luma([9]))
        .write_to(
            &mut std::io::Cursor::new(&mut jpeg),
            image::ImageFormat::Jpeg,
        )
        .unwrap();
    std::fs::write(tum.join("rgb/3.png"), &jpeg[..jpeg.len() / 2]).unwrap();
    image::GrayImage::new(16, 8)
        .save(tum.join("rgb/4.png"))
        .unwrap();
    let png = std::fs::read(tum.join("rgb/5.png")).unwrap();
    std::fs::write(tum.join("rgb/5.png"), &png[..png.len() - 20]).unwrap();
    let out = d.path().join("out");
    let (ok, _, err) = sdslam(&["run", tum.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert_eq!(
        err.matches("warning: skipping").count(),
        1,
        "warned once: {err}"
    );
    let r = report(&out);
    assert_eq!(r["skipped_frames"], 5, "{r}");
    assert_eq!(r["frames"], 3, "{r}");
    // No readable image at all: a clear error naming a file.
    for i in 0..8 {
        std::fs::write(tum.join(format!("rgb/{i}.png")), b"").unwrap();
    }
    let (ok, _, err) = sdslam(&["run", tum.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(
        !ok && err.contains("rgb/0.png") && !err.contains("panicked"),
        "{err}"
    );
    // A list naming a directory, a NaN timestamp, a non-numeric one.
    std::fs::create_dir_all(tum.join("rgb/dir.png")).unwrap();
    for (text, needle) in [
        ("1.0 rgb/dir.png\n", "not a file"),
        ("nan rgb/0.png\n", "rgb.txt:1"),
        ("1.0 rgb/0.png\nabc rgb/1.png\n", "rgb.txt:2"),
    ] {
        std::fs::write(tum.join("rgb.txt"), text).unwrap();
        let (ok, _, err) = sdslam(&["run", tum.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        assert!(!ok && err.contains(needle), "{text:?}: {err}");
    }
    // A configuration value out of range names the field.
    let cfg = d.path().join("c.toml");
    std::fs::write(&cfg, "[orb]\nscale_factor = 1.0\n").unwrap();
    let (ok, _, err) = sdslam(&[
        "run",
        "synthetic",
        "--frames",
        "1",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("orb.scale_factor"), "{err}");
}

/// `--save-map`, then `--load-map --localize-only`: the second run tracks against the first
/// run's map without changing it; a damaged map file is a clear error.
#[test]
fn save_map_then_localize_only_and_a_damaged_map_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let map = d.path().join("room.map");
    let (o1, o2) = (d.path().join("a"), d.path().join("b"));
    let (ok, _, err) = sdslam(&[
        "run",
        "synthetic",
        "--frames",
        "150",
        "--no-semidense",
        "--save-map",
        map.to_str().unwrap(),
        "--out",
        o1.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let (ok, _, err) = sdslam(&[
        "run",
        "synthetic",
        "--frames",
        "150",
        "--no-semidense",
        "--load-map",
        map.to_str().unwrap(),
        "--localize-only",
        "--out",
        o2.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("loaded map"), "{err}");
    let (r1, r2) = (report(&o1), report(&o2));
    assert_eq!(
        r1["keyframes"], r2["keyframes"],
        "localisation changed the keyframes"
    );
    assert!(r2["tracked_frames"].as_u64().unwrap() >= 145, "{r2}");
    let mut bytes = std::fs::read(&map).unwrap();
    bytes.truncate(bytes.len() / 2);
    std::fs::write(&map, &bytes).unwrap();
    let (ok, _, err) = sdslam(&[
        "run",
        "synthetic",
        "--frames",
        "5",
        "--load-map",
        map.to_str().unwrap(),
        "--out",
        o2.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("room.map") && err.contains("truncated"),
        "{err}"
    );
    let (ok, _, err) = sdslam(&[
        "run",
        "synthetic",
        "--localize-only",
        "--out",
        o2.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("--load-map"), "{err}");
}

/// A run draws its pictures; `eval rpe` and `eval report` summarise it.
#[test]
fn run_pictures_rpe_and_html_report() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("run");
    let o = out.to_str().unwrap();
    let (ok, _, err) = sdslam(&["run", "synthetic", "--frames", "120", "--out", o]);
    assert!(ok, "{err}");
    for (png, w) in [
        ("trajectory.png", 1200),
        ("cloud.png", 1000),
        ("timing.png", 1200),
    ] {
        let img = image::open(out.join(png)).unwrap_or_else(|e| panic!("{png}: {e}"));
        assert_eq!(img.width(), w, "{png}");
        // Not a blank canvas: the plot drew lines and text.
        let rgb = img.to_rgb8();
        let non_white = rgb.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        assert!(non_white > 2000, "{png}: {non_white} drawn pixels");
    }
    let gt = out.join("groundtruth.txt");
    let (ok, stdout, err) = sdslam(&[
        "eval",
        "rpe",
        gt.to_str().unwrap(),
        out.join("trajectory.txt").to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(r["pairs"].as_u64().unwrap() > 50, "{r}");
    assert!(r["trans_rmse"].as_f64().unwrap() < 0.05, "{r}");
    let (ok, _, err) = sdslam(&["eval", "report", o]);
    assert!(ok, "{err}");
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    for needle in [
        "ATE rmse",
        "RPE 1 s",
        "<img src=\"trajectory.png\"",
        "timing.png",
        "tracked_frames",
        "semidense_depth",
    ] {
        assert!(html.contains(needle), "report.html lacks {needle}");
    }
    let (ok, _, err) = sdslam(&["eval", "report", d.path().to_str().unwrap()]);
    assert!(!ok && err.contains("report.json"), "{err}");
    let (ok, _, err) = sdslam(&[
        "run",
        "synthetic",
        "--frames",
        "3",
        "--no-plots",
        "--quiet",
        "--out",
        d.path().join("np").to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(!d.path().join("np/trajectory.png").exists());
}

/// `config --defaults` prints a tree that `config --check` and `run --config` accept, and a
/// bad value in any section is refused naming it.
#[test]
fn printed_defaults_are_a_valid_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, text, err) = sdslam(&["config", "--defaults"]);
    assert!(ok, "{err}");
    let p = dir.path().join("all.toml");
    std::fs::write(&p, &text).unwrap();
    let (ok, out, err) = sdslam(&["config", "--check", p.to_str().unwrap()]);
    assert!(ok && out.contains("valid"), "{err}");
    let bad = text.replace("min_inliers = 30", "min_inliers = 0");
    std::fs::write(&p, bad).unwrap();
    let (ok, _, err) = sdslam(&["config", "--check", p.to_str().unwrap()]);
    assert!(!ok && err.contains("tracking.min_inliers"), "{err}");
}

#[test]
fn synth_folder_replays_through_the_file_backed_mock() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("seq");
    common::synth_folder(&out, 12, 5);
    let mut src = ImageListSource::open(&out).unwrap();
    assert_eq!(src.info().len, Some(12));
    let seq = SyntheticSequence::new(SyntheticConfig {
        frames: 12,
        ..SyntheticConfig::default()
    });
    let (mut a, mut b) = (Frame::new(640, 480), Frame::new(640, 480));
    for i in 0..12 {
        assert_eq!(src.next_frame(&mut a).unwrap(), FrameStatus::Ready);
        seq.render_frame(i, &mut b);
        assert_eq!(a.rgb, b.rgb, "frame {i}: PNG replay must be lossless");
        assert!((a.timestamp - b.timestamp).abs() < 1e-6);
    }
    let gt = read_tum_trajectory(&out.join("groundtruth.txt")).unwrap();
    assert_eq!(gt.len(), 12);
    let depth_list = std::fs::read_to_string(out.join("depth.txt")).unwrap();
    assert_eq!(
        depth_list.lines().filter(|l| !l.starts_with('#')).count(),
        3
    );
}

#[test]
fn semidense_final_writes_both_clouds_and_densify_takes_its_keyframes() {
    let d = tempfile::tempdir().unwrap();
    let seq = d.path().join("seq");
    let run = d.path().join("run");
    common::synth_folder(&seq, 90, 1);
    let (ok, _, err) = sdslam(&[
        "run",
        seq.to_str().unwrap(),
        "--deterministic",
        "--semidense-final",
        "--no-plots",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let r = report(&run);
    assert_eq!(r["semidense_mode"], "tuned");
    assert!(r["semidense_non_paper_settings"]["early_reject_after"].is_string());
    let f = &r["semidense_final"];
    assert!(f["keyframes"].as_u64().unwrap() >= 5, "{f}");
    // Every reconstructed keyframe's stages are timed, whichever worker ran it.
    for stage in ["keyframe_ms", "depth_ms", "intra_ms", "inter_ms"] {
        assert_eq!(f[stage]["count"], f["keyframes"], "{stage}: {f}");
    }
    let read = |name: &str| {
        let p = run.join(name);
        sdslam::io::decode_ply(&std::fs::read(&p).unwrap(), &p)
            .unwrap()
            .len() as u64
    };
    assert_eq!(read("semidense.ply"), f["points"].as_u64().unwrap());
    // Pixels per stage add up: every stage passes on at most what it was given, and what
    // the inter-keyframe check kept is the cloud.
    for (px, points) in [
        (&r["semidense_pixels"], f["points"].as_u64().unwrap()),
        (&f["online_pixels"], f["online_points"].as_u64().unwrap()),
    ] {
        let n = |k: &str| {
            px[k]
                .as_u64()
                .unwrap_or_else(|| panic!("{k} missing in {px}"))
        };
        assert!(n("search_abandoned") + n("fused") <= n("searched"), "{px}");
        assert!(n("intra_kept") <= n("fused"), "{px}");
        // The patch check (tuned mode) removes some of what the intra step passed on.
        assert!(n("patch_removed") > 0, "{px}");
        assert_eq!(
            n("inter_checked"),
            n("intra_kept") + n("intra_grown") - n("patch_removed"),
            "{px}"
        );
        assert!(n("inter_kept") < n("inter_checked"), "{px}");
        assert_eq!(n("inter_kept"), points, "{px}");
    }
    assert_eq!(
        read("semidense_online.ply"),
        f["online_points"].as_u64().unwrap()
    );
    let (final_acc, online_acc) = (&r["semidense_accuracy"], &f["online_accuracy"]);
    assert!(
        final_acc["median_relative_error"].as_f64().unwrap() < 0.01,
        "{final_acc} (online {online_acc})"
    );
    // The run's keyframes, their poses and order, densified offline.
    let out = d.path().join("densify");
    let kfs = run.join("keyframes.txt");
    let (ok, _, err) = sdslam(&[
        "densify",
        seq.to_str().unwrap(),
        "--keyframes",
        kfs.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let dr = report(&out);
    assert_eq!(
        dr["keyframes"].as_u64().unwrap() as usize,
        read_tum_trajectory(&kfs).unwrap().len()
    );
    assert!(
        dr["semidense_accuracy"]["median_relative_error"]
            .as_f64()
            .unwrap()
            < 0.01
    );
    // Paper mode says so, with nothing non-paper in force.
    let paper = d.path().join("paper.toml");
    std::fs::write(&paper, "[semidense]\nmode = \"paper\"\n").unwrap();
    let out = d.path().join("paper");
    let (ok, _, err) = sdslam(&[
        "run",
        seq.to_str().unwrap(),
        "--deterministic",
        "--frames",
        "40",
        "--no-plots",
        "--config",
        paper.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let r = report(&out);
    assert_eq!(r["semidense_mode"], "paper");
    assert_eq!(r["semidense_non_paper_settings"], serde_json::json!({}));
    assert_eq!(r["semidense_pixels"]["patch_removed"], 0);
    assert!(r["semidense_final"].is_null());
}

/// The 128-bit profile (`--simd 128`: only the SSE4.2 baseline, the width of an ARM robot's
/// NEON) runs the portable twins of every wide kernel; they must give the same trajectory
/// and the same semi-dense cloud, bit for bit, as the AVX2/AVX-512 paths.
#[test]
fn the_128_bit_profile_gives_the_same_trajectory_and_cloud() {
    let d = tempfile::tempdir().unwrap();
    let mut outputs = Vec::new();
    for width in ["auto", "128"] {
        let out = d.path().join(width);
        let (ok, _, err) = sdslam(&[
            "-q",
            "--simd",
            width,
            "run",
            "synthetic",
            "--frames",
            "30",
            "--deterministic",
            "--no-plots",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "--simd {width}: {err}");
        let read = |n: &str| std::fs::read(out.join(n)).unwrap();
        assert!(!read("semidense.ply").is_empty());
        outputs.push((read("trajectory.txt"), read("semidense.ply")));
        let bits = if width == "128" { 128 } else { 512 };
        assert_eq!(report(&out)["simd_max_bits"], bits);
    }
    assert!(outputs[0].0 == outputs[1].0, "trajectories differ");
    assert!(outputs[0].1 == outputs[1].1, "semi-dense clouds differ");
    let (ok, _, err) = sdslam(&["--simd", "64", "config", "--defaults"]);
    assert!(
        !ok && err.contains("expected 128, 256, 512 or auto"),
        "{err}"
    );
}
