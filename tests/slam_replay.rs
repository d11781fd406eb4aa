//! End to end: the built-in sequence, written as a TUM folder and replayed through the
//! file-backed mock, is tracked (>= 95% of frames, ATE under 2% of the trajectory's extent) with
//! local mapping inline or on its own thread, and `--deterministic` runs give identical
//! trajectories.

mod common;

use common::sdslam;
use sdslam::eval::ate;
use sdslam::io::read_tum_trajectory;

#[test]
fn built_in_sequence_replays_tracked_accurate_and_deterministic() {
    let d = tempfile::tempdir().unwrap();
    let seq = d.path().join("seq");
    common::synth_folder(&seq, 300, 0);
    let mut trajectories = Vec::new();
    // Runs 0 and 1: deterministic (one thread); run 2: local mapping on its own thread.
    for run in 0..3 {
        let out = d.path().join(format!("out{run}"));
        let mut args = vec![
            "run",
            seq.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-semidense",
        ];
        if run < 2 {
            args.push("--deterministic");
        }
        let (ok, _, err) = sdslam(&args);
        assert!(ok, "{err}");
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        let (frames, tracked) = (
            report["frames"].as_u64().unwrap(),
            report["tracked_frames"].as_u64().unwrap(),
        );
        assert_eq!(frames, 300);
        assert!(
            tracked * 100 >= frames * 95,
            "tracked {tracked} of {frames}"
        );
        let gt = read_tum_trajectory(&seq.join("groundtruth.txt")).unwrap();
        let est = read_tum_trajectory(&out.join("trajectory.txt")).unwrap();
        let r = ate(&gt, &est, 0.02, true).unwrap();
        // Extent: the largest distance between two ground-truth positions.
        let mut extent: f64 = 0.0;
        for a in gt.iter().step_by(5) {
            for b in gt.iter().step_by(5) {
                extent = extent.max((a.t_wc.position() - b.t_wc.position()).norm());
            }
        }
        eprintln!("run {run}: tracked {tracked}/{frames}, ATE {:.4} m over extent {extent:.2} m ({:.2}%), {} keyframes", r.rmse_m, 100.0 * r.rmse_m / extent, report["keyframes"]);
        assert!(
            r.rmse_m < 0.02 * extent,
            "ATE {} vs extent {extent}",
            r.rmse_m
        );
        trajectories.push(std::fs::read_to_string(out.join("trajectory.txt")).unwrap());
    }
    assert_eq!(
        trajectories[0], trajectories[1],
        "deterministic runs differ"
    );
}
