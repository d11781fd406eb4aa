//! `sdslam run`: replay or stream a source through the pipeline and write every output.

use std::path::PathBuf;

use clap::Args;

use sdslam::runtime::Report;
use sdslam::Result;

use super::source;

mod finish;
mod frames;
mod outputs;
mod session;

#[derive(Args, Debug)]
pub struct RunArgs {
    /// `synthetic` (default), a TUM RGB-D folder, a EuRoC folder (`mav0`), an image folder with
    /// `times.txt`, or `v4l2:/dev/videoN`.
    pub source: Option<String>,
    /// Calibration file (ORB-SLAM YAML or EuRoC sensor.yaml); a TUM folder's camera.yaml and a
    /// EuRoC folder's sensor.yaml are used by default.
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Output folder.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Release frames at their timestamps (a slow pipeline drops the oldest frames).
    #[arg(long)]
    pub realtime: bool,
    /// Do not run the semi-dense mapping thread.
    #[arg(long)]
    pub no_semidense: bool,
    /// Configuration file (TOML); unknown keys are errors.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// One thread, fixed seeds: identical results on re-runs.
    #[arg(long)]
    deterministic: bool,
    /// Use only the first N frames.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Simulated blackout: frames START..START+COUNT of the source are read but not given to
    /// SLAM (as a covered lens or a dropped link), e.g. `--drop 300:60`.
    #[arg(long, value_parser = parse_drop)]
    drop: Option<(u64, u64)>,
    /// Also write each reconstructed keyframe's depth map to OUT/depth/<timestamp>.png
    /// (16-bit, depth x 5000 in map units, 0 = no estimate).
    #[arg(long)]
    depth_maps: bool,
    /// After the final full BA, reconstruct every keyframe again with its covisible
    /// neighbours of the final map (the paper's end-of-session reconstruction): semidense.ply
    /// is then that cloud, the online one is semidense_online.ply.
    #[arg(long, conflicts_with = "no_semidense")]
    semidense_final: bool,
    /// Save the map at the end (versioned binary with checksum, written atomically).
    #[arg(long, value_name = "FILE")]
    save_map: Option<PathBuf>,
    /// Start from a saved map (same camera and vocabulary); tracking relocalises against it.
    #[arg(long, value_name = "FILE")]
    load_map: Option<PathBuf>,
    /// Show the run live in Rerun (a build with `--features rerun`).
    #[arg(long)]
    rerun: bool,
    /// Record the run for Rerun to FILE.rrd (a build with `--features rerun`).
    #[arg(long, value_name = "FILE")]
    rerun_save: Option<PathBuf>,
    /// Write the run to FILE.mcap with Foxglove's well-known schemas: camera pose and `/tf`
    /// per frame, keyframes, the sparse map, the semi-dense cloud(s), tracking state and timing.
    /// Written as the run goes and finished (renamed into place) on every way out.
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Put the camera images in the MCAP file and the live view too (`/camera/image`).
    #[arg(long)]
    pub mcap_images: bool,
    /// Serve the run live over Foxglove's WebSocket protocol on HOST:PORT (a build with
    /// `--features foxglove`); open Foxglove and connect to ws://HOST:PORT.
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<String>,
    /// Do not draw trajectory.png, cloud.png and timing.png.
    #[arg(long)]
    no_plots: bool,
    /// Track against the loaded map without changing it (no keyframes, no BA).
    #[arg(long, requires = "load_map")]
    localize_only: bool,
    #[command(flatten)]
    pub camera: source::CameraArgs,
}

impl RunArgs {
    pub fn default_synthetic() -> Self {
        RunArgs {
            source: None,
            calib: None,
            out: super::default_out(),
            realtime: false,
            no_semidense: false,
            config: None,
            deterministic: false,
            frames: None,
            depth_maps: false,
            semidense_final: false,
            drop: None,
            camera: source::CameraArgs::default(),
            save_map: None,
            load_map: None,
            no_plots: false,
            rerun: false,
            rerun_save: None,
            localize_only: false,
            mcap: None,
            mcap_images: false,
            foxglove: None,
        }
    }
}

pub fn run(a: RunArgs) -> Result<()> {
    run_with(a).map(|_| ())
}

/// What a run measured, for `sdslam bench latency`.
pub struct RunOutcome {
    pub report: Report,
    /// Frame arrival to pose out, per frame (evenly thinned on very long runs).
    pub latencies_ms: Vec<f32>,
}

/// `sdslam run` in its stages: open (refuse bad input before any work), start (the
/// pipeline and the source's clock), the frame loop, finish (tracking outputs, then the
/// semi-dense backlog) and write (pictures, final report, exit status).
pub fn run_with(a: RunArgs) -> Result<RunOutcome> {
    let (mut session, source) = session::open(a)?;
    let (mut running, source) = session::start(&session, source)?;
    frames::track(&session, &mut running, source);
    let finished = finish::finish(&mut session, &mut running);
    finish::write(session, running, finished)
}

/// Parses `START:COUNT`.
fn parse_drop(s: &str) -> std::result::Result<(u64, u64), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("`{s}`: expected START:COUNT, e.g. 300:60"))?;
    let start = a
        .trim()
        .parse()
        .map_err(|_| format!("`{a}`: START is not a frame number"))?;
    let count = b
        .trim()
        .parse()
        .map_err(|_| format!("`{b}`: COUNT is not a number of frames"))?;
    Ok((start, count))
}
