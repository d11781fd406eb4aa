//! File IO at the edge of the library: calibration files, trajectories, images, reports.
//! Every output is written atomically (temporary file + rename), so a crash never leaves a
//! half-written file behind.

mod atomic;
mod images;
mod ply;
mod trajectory;

pub use atomic::{write_atomic, write_atomic_file, write_atomic_with, write_json_atomic};
pub use images::{
    load_tum_depth_frames, read_depth_png, write_depth_png, write_gray_png, write_rgb_png,
};
pub use ply::{decode_ply, encode_ply, write_ply, CloudPoint};
pub use trajectory::{
    parse_tum_trajectory, read_tum_trajectory, tum_trajectory_text, write_tum_trajectory,
};

use std::path::Path;

use crate::camera_model::Calibration;
use crate::error::{Error, Result};

/// Reads and parses a calibration file (ORB-SLAM YAML or EuRoC `sensor.yaml`).
pub fn load_calibration(path: &Path) -> Result<Calibration> {
    let text = sdslam_camera::capped::read_text_capped(path, sdslam_camera::capped::SETTINGS_CAP)
        .map_err(|e| Error::io(path, e))?;
    Ok(Calibration::parse(&text, &path.display().to_string())?)
}

/// Creates `dir` (and parents) and checks it can be written, before any work is done.
pub fn prepare_output_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let probe = dir.join(".sdslam-write-test");
    std::fs::write(&probe, b"").map_err(|e| Error::io(dir, e))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

/// Peak resident memory of this process in MiB (Linux `VmHWM`); 0 where unavailable.
pub fn peak_rss_mb() -> f64 {
    proc_status_mb("VmHWM:")
}

/// Hands memory the process freed back to the system (glibc keeps freed blocks in its
/// per-thread arenas, where the semi-dense workers' buffers stay resident after they are
/// dropped); a no-op elsewhere. Called once tracking and mapping are over, before the
/// final outputs are built, so those reuse memory instead of raising the peak.
pub fn return_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own free lists; no pointer is passed.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Most glibc malloc arenas the sdslam binary lets its threads use (see
/// [`limit_allocator_arenas`]).
pub const ALLOCATOR_ARENAS: i32 = 2;

/// Caps glibc's malloc arenas at `n` for the whole process, unless the user set
/// `MALLOC_ARENA_MAX` (which glibc then honours); a no-op elsewhere. glibc gives each new
/// thread its own arena (up to 8 per core) and keeps what a thread frees resident in it: with
/// tracking, local mapping, loop closing and three semi-dense threads allocating at start-up
/// and on each keyframe, the arenas hold freed blocks side by side. On desk's latency bench
/// (docs/PERFORMANCE.md) one arena gave a peak RSS of 263 and 255 MB against 285 and 271 MB
/// uncapped, two arenas a median of 266 MB against 277 MB over three interleaved pairs. After
/// warm-up the per-frame code does not allocate, so the arenas' locks are not on the frame
/// path. Call before any thread starts (the binary does, first thing); an application
/// embedding the library decides for its own process.
pub fn limit_allocator_arenas(n: i32) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    if std::env::var_os("MALLOC_ARENA_MAX").is_none() {
        // SAFETY: mallopt only sets an allocator parameter; it takes no pointer.
        unsafe {
            libc::mallopt(libc::M_ARENA_MAX, n.max(1));
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    let _ = n;
}

/// Physical memory of the machine in bytes (Linux `MemTotal`); `None` where unknown.
pub fn machine_memory_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kb: u64 = s
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024)
}

/// Current resident memory of the process in MB (Linux; 0 elsewhere).
pub fn current_rss_mb() -> f64 {
    proc_status_mb("VmRSS:")
}

fn proc_status_mb(key: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix(key))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        })
        .map(|kb| kb / 1024.0)
        .unwrap_or(0.0)
}

/// Reads a vocabulary: sdslam's binary format, or a DBoW2 text vocabulary (`ORBvoc.txt`
/// layout, recognised by its text header). Errors name the file.
pub fn load_vocabulary(path: &Path) -> Result<crate::place_recognition::Vocabulary> {
    // Recognise the format from the head first: an endless or binary non-vocabulary file
    // (`/dev/zero`) is refused without reading it.
    let head = sdslam_camera::capped::read_head(path, 4096).map_err(|e| Error::io(path, e))?;
    if !head.starts_with(b"SDSLVOC") && head.contains(&0) {
        return Err(Error::Invalid(format!(
            "{}: neither an sdslam vocabulary nor DBoW2 text",
            path.display()
        )));
    }
    let bytes = sdslam_camera::capped::read_capped(path, sdslam_camera::capped::BULK_CAP)
        .map_err(|e| Error::io(path, e))?;
    let named = |e: crate::place_recognition::VocabularyFormatError| Error::format(path, e);
    if bytes.starts_with(b"SDSLVOC") {
        return crate::place_recognition::decode_vocabulary(&bytes).map_err(named);
    }
    let text = std::str::from_utf8(&bytes).map_err(|_| {
        Error::Invalid(format!(
            "{}: neither an sdslam vocabulary nor DBoW2 text",
            path.display()
        ))
    })?;
    crate::place_recognition::parse_dbow2_text(text).map_err(named)
}

/// Writes a vocabulary in sdslam's binary format (atomically).
pub fn save_vocabulary(path: &Path, v: &crate::place_recognition::Vocabulary) -> Result<()> {
    write_atomic(path, &crate::place_recognition::encode_vocabulary(v))
}
