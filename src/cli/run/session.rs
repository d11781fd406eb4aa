//! The first two stages of `sdslam run`: open (configuration, output folder, source,
//! calibration, ground truth) and start (the `System`, a loaded map, pacing, the report).

use std::sync::Arc;
use std::time::Instant;

use sdslam::camera::device::LiveStats;
use sdslam::camera::{FrameSource, PacedSource, Pacing, PacingStats};
use sdslam::camera_model::Calibration;
use sdslam::eval::TimedPose;
use sdslam::io::write_tum_trajectory;
use sdslam::runtime::{Report, StageTimer, System};
use sdslam::{Config, Result};

use super::outputs::Outputs;
use super::RunArgs;
use crate::source::{self, DepthTruth};

/// What the run knows before its first frame and keeps to the end.
pub struct Session {
    pub args: RunArgs,
    pub config: Config,
    pub calib: Calibration,
    pub outputs: Outputs,
    pub groundtruth: Option<Vec<TimedPose>>,
    pub depth_truth: DepthTruth,
    pub info: sdslam::camera::SourceInfo,
    pub live: Option<Arc<LiveStats>>,
    pub pacing: Option<Pacing>,
    pub deadline_ms: f64,
    pub started: Instant,
}

/// The running pipeline and what the frame loop measures.
pub struct Running {
    pub system: System,
    pub pacing_stats: Option<Arc<PacingStats>>,
    pub frame_timer: StageTimer,
    pub report: Report,
    #[cfg(feature = "rerun")]
    pub viewer: Option<crate::viewer::Viewer>,
    pub progress: Option<indicatif::ProgressBar>,
    /// `--mcap` / `--foxglove`: the run's Foxglove channels.
    pub publish: Option<crate::foxglove_out::Publisher>,
}

/// Stage 1: everything that can be refused before any work (bad config, unusable output
/// folder, unknown source, a map too large for this machine).
pub fn open(args: RunArgs) -> Result<(Session, Box<dyn FrameSource>)> {
    let started = Instant::now();
    let mut config = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    if args.no_semidense {
        config.semidense.enabled = false;
    }
    let mut outputs =
        Outputs::prepare(&args.out, args.source.as_deref(), args.save_map.as_deref())?;
    let opened = source::open(
        args.source.as_deref(),
        args.calib.as_deref(),
        args.frames,
        &args.camera,
    )?;
    if let Some(p) = &args.mcap {
        super::outputs::check_writable_file(p, "--mcap")?;
    }
    crate::signal::install();
    crate::check_memory(&opened.calibration, &config)?;
    // Ground truth beside the outputs, so `sdslam eval ate OUT/groundtruth.txt OUT/keyframes.txt`
    // works for every source that has it.
    if let Some(gt) = &opened.groundtruth {
        outputs.write("groundtruth.txt", |p| write_tum_trajectory(p, gt));
    }
    let info = opened.source.info().clone();
    note!(
        "sdslam: {} ({}x{} @ {:.1} fps{}), calibration {}",
        info.name,
        info.width,
        info.height,
        info.fps,
        info.len
            .map(|n| format!(", {n} frames"))
            .unwrap_or_default(),
        opened.calibration_name
    );
    // Cameras: newest frame wins. Replays: real time on request, else every frame in order.
    let pacing = match (&opened.live, args.realtime && !args.deterministic) {
        (Some(_), _) => Some(Pacing::Live),
        (None, true) => Some(Pacing::RealTime {
            speed: config.runtime.realtime_speed,
        }),
        (None, false) => None,
    };
    let deadline_ms = config
        .runtime
        .deadline_ms
        .unwrap_or(1e3 / opened.calibration.fps);
    let session = Session {
        args,
        config,
        calib: opened.calibration,
        outputs,
        groundtruth: opened.groundtruth,
        depth_truth: opened.depth_truth,
        info,
        live: opened.live,
        pacing,
        deadline_ms,
        started,
    };
    Ok((session, opened.source))
}

/// Stage 2: the pipeline, a loaded map, then the source's clock (a paced source starts
/// counting now, so allocating or loading a map is not inside the first frame's deadline).
pub fn start(s: &Session, source: Box<dyn FrameSource>) -> Result<(Running, Box<dyn FrameSource>)> {
    // Deterministic: one thread (mapping inline). Otherwise local mapping gets its own thread.
    let mut system = System::new(
        &s.calib,
        &s.config,
        s.info.len.unwrap_or(10_000),
        !s.args.deterministic,
    );
    if let Some(path) = &s.args.load_map {
        load_map(&mut system, path)?;
    }
    system.set_localize_only(s.args.localize_only);
    // A recording fed as fast as it is processed: initialisation attempts on every frame.
    system.set_replay(s.pacing.is_none());
    // The caller's thread tracks; the mapping threads were pinned (if configured) as they
    // started.
    let cpus = &s.config.runtime.tracking_cpus;
    if !sdslam::runtime::pin_current_thread(cpus) {
        note!("warning: could not pin tracking to CPUs {cpus:?}");
    }
    #[cfg(feature = "rerun")]
    let viewer = if s.args.rerun || s.args.rerun_save.is_some() {
        Some(crate::viewer::Viewer::open(s.args.rerun_save.as_deref())?)
    } else {
        None
    };
    #[cfg(not(feature = "rerun"))]
    if s.args.rerun || s.args.rerun_save.is_some() {
        return Err(sdslam::Error::Invalid(
            "--rerun needs a build with the viewer: cargo build --release --features rerun".into(),
        ));
    }
    let publish = crate::foxglove_out::Publisher::open(
        s.args.mcap.as_deref(),
        s.args.foxglove.as_deref(),
        s.args.mcap_images,
        &s.calib,
    )?;
    let mut pacing_stats = None;
    let source: Box<dyn FrameSource> = match s.pacing {
        Some(p) => {
            let mut paced = PacedSource::spawn(source, p)?;
            paced.set_interrupt(crate::signal::interrupted);
            pacing_stats = Some(paced.stats());
            Box::new(paced)
        }
        None => source,
    };
    let report = Report {
        sdslam_version: env!("CARGO_PKG_VERSION").into(),
        source: s.info.name.clone(),
        deadline_ms: s.deadline_ms,
        simd_max_bits: match sdslam::simd::max_width() {
            sdslam::simd::Width::W128 => 128,
            sdslam::simd::Width::W256 => 256,
            sdslam::simd::Width::W512 => 512,
        },
        ..Report::default()
    };
    let running = Running {
        system,
        pacing_stats,
        frame_timer: StageTimer::with_capacity(s.info.len.unwrap_or(100_000).max(16)),
        report,
        #[cfg(feature = "rerun")]
        viewer,
        progress: progress_bar(s.info.len),
        publish,
    };
    Ok((running, source))
}

/// Reads, checks and installs a saved map.
fn load_map(system: &mut System, path: &std::path::Path) -> Result<()> {
    let bytes = sdslam_camera::capped::read_capped(path, sdslam_camera::capped::BULK_CAP)
        .map_err(|e| sdslam::Error::io(path, e))?;
    let snap = sdslam::map::persist::MapSnapshot::decode(&bytes)
        .map_err(|e| sdslam::Error::format(path, e))?;
    let n = system
        .load_map(&snap)
        .map_err(|e| sdslam::Error::format(path, e))?;
    note!(
        "sdslam: loaded map {} ({n} keyframes, {} points)",
        path.display(),
        snap.n_points()
    );
    Ok(())
}

/// Progress for replays of known length, on a terminal only (indicatif hides otherwise).
fn progress_bar(len: Option<usize>) -> Option<indicatif::ProgressBar> {
    let n = len.filter(|_| !crate::quiet())?;
    let pb = indicatif::ProgressBar::new(n as u64);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} frames  {per_sec}  {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    Some(pb)
}
