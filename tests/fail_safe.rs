//! Every way out of `sdslam run` leaves a complete, consistent set of outputs: runs ended at
//! random frames (right after initialisation included) and by random signals at random times,
//! a file size limit, injected writer failures, a closed stderr and a full stdout. Each run's
//! outputs must parse and agree with each other (report.json's counts against the files,
//! and the MCAP file of the run against both).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use common::{sdslam_bin, synth_folder};

/// One short rendered sequence (60 frames, depth every 10th) shared by the tests.
fn sequence() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("sdslam-failsafe-seq-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        synth_folder(&d, 60, 10);
        d
    })
}

fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdslam-failsafe-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn run_cmd(out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(sdslam_bin());
    c.args(["-q", "run"])
        .arg(sequence())
        .arg("--out")
        .arg(out)
        .args(["--no-plots", "--mcap"])
        .arg(out.join("run.mcap"))
        .args(extra)
        .env_remove("RUST_BACKTRACE")
        .env_remove("SDSLAM_FAULT");
    c
}

/// Parses every output of a run and checks they agree; returns report.json.
fn check_outputs(out: &Path) -> serde_json::Value {
    let read = |n: &str| {
        std::fs::read(out.join(n)).unwrap_or_else(|e| panic!("{}: {e}", out.join(n).display()))
    };
    let report: serde_json::Value = serde_json::from_slice(&read("report.json"))
        .unwrap_or_else(|e| panic!("{}/report.json does not parse: {e}", out.display()));
    let traj = sdslam::io::read_tum_trajectory(&out.join("trajectory.txt")).unwrap();
    let kfs = sdslam::io::read_tum_trajectory(&out.join("keyframes.txt")).unwrap();
    let gt = sdslam::io::read_tum_trajectory(&out.join("groundtruth.txt")).unwrap();
    let cloud = sdslam::io::decode_ply(&read("semidense.ply"), &out.join("semidense.ply")).unwrap();
    let n = |k: &str| {
        report[k]
            .as_u64()
            .unwrap_or_else(|| panic!("report.json has no count {k}: {report}")) as usize
    };
    assert_eq!(
        n("tracked_frames"),
        traj.len(),
        "tracked frames vs trajectory.txt"
    );
    assert_eq!(n("keyframes"), kfs.len(), "keyframes vs keyframes.txt");
    assert_eq!(
        n("semidense_points"),
        cloud.len(),
        "points vs semidense.ply"
    );
    assert!(traj.len() <= n("frames") && n("frames") <= 60);
    assert_eq!(gt.len(), 60, "groundtruth.txt");
    // Every pose is one of a frame of the sequence (no stale or foreign timestamps).
    for p in &traj {
        assert!(
            gt.iter().any(|g| (g.timestamp - p.timestamp).abs() < 1e-4),
            "trajectory pose at {} is no frame of the sequence",
            p.timestamp
        );
    }
    check_mcap(out, &report, traj.len(), kfs.len(), cloud.len());
    report
}

/// The run's MCAP file is finished (summary with every channel's schema) and says what the
/// other outputs say: a status per frame, the final trajectory, keyframes and cloud.
fn check_mcap(out: &Path, report: &serde_json::Value, poses: usize, kfs: usize, points: usize) {
    use foxglove::messages::{PointCloud, PosesInFrame};
    use foxglove::Decode;
    use sdslam_camera::mcap::format as mcap;
    let path = out.join("run.mcap");
    let buf = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let summary = mcap::Summary::read(&buf)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .unwrap_or_else(|| panic!("{}: no summary (not finished)", path.display()));
    for ch in summary.channels.values() {
        assert!(
            ch.schema.is_some(),
            "{}: channel {} has no schema",
            path.display(),
            ch.topic
        );
    }
    let mut status = 0;
    let (mut traj, mut keyframes, mut cloud) = (None, None, None);
    for m in mcap::MessageStream::new(&buf).unwrap() {
        let m = m.unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        match m.channel.topic.as_str() {
            "/sdslam/tracking" => {
                let s: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
                assert!(s["state"].is_string(), "{s}");
                status += 1;
            }
            "/sdslam/trajectory" => traj = Some(PosesInFrame::decode(&m.data[..]).unwrap()),
            "/sdslam/keyframes" => keyframes = Some(PosesInFrame::decode(&m.data[..]).unwrap()),
            "/sdslam/semidense" => cloud = Some(PointCloud::decode(&m.data[..]).unwrap()),
            _ => {}
        }
    }
    assert_eq!(
        Some(status),
        report["frames"].as_u64(),
        "status messages vs frames"
    );
    assert_eq!(traj.expect("a final trajectory").poses.len(), poses);
    assert_eq!(keyframes.expect("keyframes").poses.len(), kfs);
    let cloud = cloud.expect("a semi-dense cloud");
    assert_eq!(cloud.data.len(), points * cloud.point_stride as usize);
    assert!(
        !out.read_dir()
            .unwrap()
            .flatten()
            .any(|e| e.file_name().to_string_lossy().contains(".tmp")),
        "a temporary file is left in {}",
        out.display()
    );
}

/// A small deterministic generator (the cases are random but reproducible).
struct Lcg(u64);
impl Lcg {
    fn below(&mut self, n: u64) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 33) % n
    }
}

#[test]
fn runs_ended_at_random_frames_leave_consistent_outputs() {
    let mut rng = Lcg(25);
    // Always the frames right after initialisation (the backfill still running), then random.
    let mut ends = vec![13, 14, 40];
    ends.extend((0..4).map(|_| 1 + rng.below(60)));
    for frames in ends {
        let out = out_dir(&format!("frames{frames}"));
        let st = run_cmd(&out, &["--frames", &frames.to_string()])
            .output()
            .unwrap();
        assert!(
            st.status.success(),
            "--frames {frames}: {:?}\n{}",
            st.status,
            String::from_utf8_lossy(&st.stderr)
        );
        let report = check_outputs(&out);
        assert_eq!(report["frames"].as_u64(), Some(frames), "--frames {frames}");
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn runs_ended_by_random_signals_leave_consistent_outputs() {
    let mut rng = Lcg(2025);
    for (k, sig) in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP, libc::SIGINT]
        .into_iter()
        .enumerate()
    {
        let out = out_dir(&format!("signal{k}"));
        // Real time: 60 frames take 2 s, the signal comes within them.
        let child = run_cmd(&out, &["--realtime"])
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(200 + rng.below(1600)));
        // SAFETY: kill() on our own child's pid.
        unsafe { libc::kill(child.id() as i32, sig) };
        let t = Instant::now();
        let st = child.wait_with_output().unwrap();
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "signal {sig}: took {:?} to end",
            t.elapsed()
        );
        assert!(
            st.status.success(),
            "signal {sig}: {:?}\n{}",
            st.status,
            String::from_utf8_lossy(&st.stderr)
        );
        let report = check_outputs(&out);
        let frames = report["frames"].as_u64().unwrap();
        if frames < 60 {
            let why = report["stopped_early"].as_str().unwrap_or_default();
            assert!(why.contains("interrupted"), "signal {sig}: {report}");
        }
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn ctrl_c_ends_a_real_time_wait_for_a_far_off_timestamp() {
    // A copy of the sequence whose frames from the 20th on are a day later (a gap, or
    // nanosecond timestamps read as seconds).
    let dir = out_dir("gap-seq");
    std::fs::create_dir_all(&dir).unwrap();
    for e in std::fs::read_dir(sequence()).unwrap().flatten() {
        let to = dir.join(e.file_name());
        if e.path().is_dir() {
            std::os::unix::fs::symlink(e.path(), &to).unwrap();
        } else {
            std::fs::copy(e.path(), &to).unwrap();
        }
    }
    let list = std::fs::read_to_string(dir.join("rgb.txt")).unwrap();
    let shifted: String = list
        .lines()
        .filter(|l| !l.starts_with('#'))
        .enumerate()
        .map(|(i, l)| {
            let (t, f) = l.split_once(' ').unwrap();
            let t: f64 = t.parse().unwrap();
            format!("{:.6} {f}\n", if i >= 20 { t + 86_400.0 } else { t })
        })
        .collect();
    std::fs::write(dir.join("rgb.txt"), shifted).unwrap();
    let out = out_dir("gap");
    let mut child = Command::new(sdslam_bin())
        .args(["-q", "run"])
        .arg(&dir)
        .arg("--out")
        .arg(&out)
        .args(["--realtime", "--no-plots", "--no-semidense"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    // SAFETY: kill() on our own child's pid.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let t = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if t.elapsed() > Duration::from_secs(5) {
            let _ = child.kill();
            panic!("Ctrl-C was ignored while waiting for a frame a day away");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["frames"].as_u64(), Some(20), "{report}");
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_file_size_limit_fails_the_big_outputs_and_keeps_the_others() {
    let out = out_dir("ulimit");
    // 64 kB per file: the trajectory and report fit, the point cloud does not.
    let st = Command::new("sh")
        .arg("-c")
        .arg("ulimit -f 64; exec \"$0\" \"$@\"")
        .arg(sdslam_bin())
        .args(["-q", "run"])
        .arg(sequence())
        .arg("--out")
        .arg(&out)
        .arg("--no-plots")
        .arg("--mcap")
        .arg(out.join("run.mcap"))
        .env_remove("SDSLAM_FAULT")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(1), "{:?}\n{err}", st.status);
    for big in ["semidense.ply", "mcap"] {
        assert!(
            err.contains(&format!("{big} not written")) && err.contains("File too large"),
            "{err}"
        );
    }
    assert!(!out.join("semidense.ply").exists());
    // No unfinished MCAP, under its name or a temporary one.
    assert_eq!(
        std::fs::read_dir(&out)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().contains("mcap"))
            .count(),
        0
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let traj = sdslam::io::read_tum_trajectory(&out.join("trajectory.txt")).unwrap();
    assert_eq!(report["tracked_frames"].as_u64(), Some(traj.len() as u64));
    assert!(report["semidense_points"].as_u64().unwrap() > 0);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn an_injected_writer_failure_is_reported_and_the_other_outputs_are_written() {
    let all = [
        "trajectory.txt",
        "keyframes.txt",
        "report.json",
        "semidense.ply",
        "mcap",
    ];
    fn file(name: &str) -> &str {
        if name == "mcap" {
            "run.mcap"
        } else {
            name
        }
    }
    for failing in all {
        let out = out_dir(&format!("fault-{failing}"));
        let st = run_cmd(&out, &["--frames", "40"])
            .env("SDSLAM_FAULT", format!("write:{failing}"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&st.stderr);
        assert_eq!(
            st.status.code(),
            Some(1),
            "{failing}: {:?}\n{err}",
            st.status
        );
        assert!(err.contains(&format!("{failing} not written")), "{err}");
        for name in all {
            assert_eq!(
                out.join(file(name)).exists(),
                name != failing,
                "{name} with {failing} failing"
            );
        }
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn a_closed_stderr_or_a_full_stdout_is_not_a_crash() {
    let out = out_dir("devfull");
    let full = || {
        std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap()
    };
    // -v: log events (map initialised, ...) are written too, not only plain messages.
    let st = run_cmd(&out, &["--frames", "30", "-v"])
        .stderr(Stdio::from(full()))
        .status()
        .unwrap();
    assert!(st.success(), "stderr on /dev/full: {st:?}");
    check_outputs(&out);
    let st = Command::new(sdslam_bin())
        .args(["eval", "ate"])
        .arg(out.join("groundtruth.txt"))
        .arg(out.join("keyframes.txt"))
        .stdout(Stdio::from(full()))
        .output()
        .unwrap();
    assert_eq!(
        st.status.code(),
        Some(1),
        "eval ate > /dev/full: {:?}",
        st.status
    );
    assert!(String::from_utf8_lossy(&st.stderr).contains("No space left"));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_reused_output_folder_keeps_nothing_of_the_earlier_run() {
    let out = out_dir("reused");
    std::fs::create_dir_all(out.join("depth")).unwrap();
    for stale in ["trajectory.png", "cloud.png", "depth/1.000000.png"] {
        std::fs::write(out.join(stale), "stale").unwrap();
    }
    std::fs::write(out.join("report.json"), "{\"stale\": true}").unwrap();
    let st = run_cmd(&out, &["--frames", "20", "--no-semidense"])
        .status()
        .unwrap();
    assert!(st.success());
    check_outputs(&out);
    for stale in ["trajectory.png", "cloud.png", "depth/1.000000.png"] {
        assert!(!out.join(stale).exists(), "{stale} of the earlier run kept");
    }
    let _ = std::fs::remove_dir_all(&out);
}
