//! Helpers shared by integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// `../shared/data` beside the checkout. In CI (`CI=true`) its absence fails the test loudly;
/// elsewhere the test is skipped with a message.
pub fn shared_data() -> Option<PathBuf> {
    let p = checkout_root().join("../shared/data");
    if p.is_dir() {
        return Some(p);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
        panic!(
            "../shared/data is missing: CI must provide it ({})",
            p.display()
        );
    }
    eprintln!("skipping: {} not found", p.display());
    None
}

/// The checkout's top folder (the workspace root, where Cargo.lock is), whichever of its
/// crates (the library, or the binary in src/cli) this test belongs to.
pub fn checkout_root() -> PathBuf {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut dir = here.as_path();
    while !dir.join("Cargo.lock").exists() {
        match dir.parent() {
            Some(p) => dir = p,
            None => return here,
        }
    }
    dir.to_path_buf()
}

/// Path of the `sdslam` binary built for this test run.
pub fn sdslam_bin() -> PathBuf {
    match option_env!("CARGO_BIN_EXE_sdslam") {
        Some(p) => PathBuf::from(p),
        None => panic!("this test runs the sdslam binary: list it in src/cli/Cargo.toml"),
    }
}

/// Runs `sdslam ARGS` in the checkout's top folder (relative paths such as `calib/...` resolve
/// there), returning (success, stdout, stderr).
pub fn sdslam(args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(sdslam_bin())
        .args(args)
        .current_dir(checkout_root())
        .env_remove("RUST_BACKTRACE")
        .output()
        .expect("run sdslam");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
pub mod counting_alloc;
pub mod problems;

/// Writes the built-in sequence (`frames` frames, ground-truth depth every `depth_every`th,
/// 0 = none) as a TUM folder `dir` with `sdslam synth`; panics with its error output on failure.
pub fn synth_folder(dir: &std::path::Path, frames: usize, depth_every: usize) {
    let (ok, _, err) = sdslam(&[
        "synth",
        "--out",
        dir.to_str().unwrap(),
        "--frames",
        &frames.to_string(),
        "--depth-every",
        &depth_every.to_string(),
    ]);
    assert!(ok, "sdslam synth failed: {err}");
}
