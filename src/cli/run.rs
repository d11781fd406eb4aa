//! `sdslam run`: replay or stream a source through the pipeline and write every output.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

use sdslam::camera::{Frame, FrameSource, FrameStatus, PacedSource, Pacing};
use sdslam::io::{self, write_json_atomic, write_ply, write_tum_trajectory};
use sdslam::runtime::{Report, StageTimer, System};
use sdslam::tracking::TrackingState;
use sdslam::{Config, Result};

use super::source;

mod outputs;
use outputs::Outputs;

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
            drop: None,
            camera: source::CameraArgs::default(),
            save_map: None,
            load_map: None,
            no_plots: false,
            rerun: false,
            rerun_save: None,
            localize_only: false,
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

pub fn run_with(a: RunArgs) -> Result<RunOutcome> {
    let started = Instant::now();
    let mut config = match &a.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    if a.no_semidense {
        config.semidense.enabled = false;
    }
    let mut outputs = Outputs::prepare(&a.out, a.source.as_deref(), a.save_map.as_deref())?;
    let mut opened = source::open(a.source.as_deref(), a.calib.as_deref(), a.frames, &a.camera)?;
    super::signal::install();
    let calib = opened.calibration.clone();
    super::check_memory(&calib, &config)?;
    let groundtruth = opened.groundtruth.clone();
    let depth_truth = std::mem::replace(&mut opened.depth_truth, source::DepthTruth::None);
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
    let live = opened.live.clone();
    let pacing = match (&live, a.realtime && !a.deterministic) {
        (Some(_), _) => Some(Pacing::Live),
        (None, true) => Some(Pacing::RealTime {
            speed: config.runtime.realtime_speed,
        }),
        (None, false) => None,
    };
    let deadline_ms = config.runtime.deadline_ms.unwrap_or(1e3 / calib.fps);

    // Deterministic: one thread (mapping inline). Otherwise local mapping gets its own thread.
    let mut system = System::new(
        &calib,
        &config,
        info.len.unwrap_or(10_000),
        !a.deterministic,
    );
    if let Some(path) = &a.load_map {
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
    }
    system.set_localize_only(a.localize_only);
    // The caller's thread tracks; the mapping threads were pinned (if configured) as they
    // started.
    if !sdslam::runtime::pin_current_thread(&config.runtime.tracking_cpus) {
        note!(
            "warning: could not pin tracking to CPUs {:?}",
            config.runtime.tracking_cpus
        );
    }
    let mut frame = Frame::new(info.width, info.height);
    // The clock of a paced source starts now: everything above (allocating the map, loading
    // a saved one) happens before the first frame arrives, not inside its deadline.
    let mut pacing_stats = None;
    let mut src: Box<dyn FrameSource> = match pacing {
        Some(p) => {
            let mut paced = PacedSource::spawn(opened.source, p)?;
            paced.set_interrupt(super::signal::interrupted);
            pacing_stats = Some(paced.stats());
            Box::new(paced)
        }
        None => opened.source,
    };
    let capacity = info.len.unwrap_or(100_000).max(16);
    let mut frame_timer = StageTimer::with_capacity(capacity);
    let mut report = Report {
        sdslam_version: env!("CARGO_PKG_VERSION").into(),
        source: info.name.clone(),
        deadline_ms,
        ..Report::default()
    };
    #[cfg(feature = "rerun")]
    let viewer = if a.rerun || a.rerun_save.is_some() {
        Some(super::viewer::Viewer::open(a.rerun_save.as_deref())?)
    } else {
        None
    };
    #[cfg(not(feature = "rerun"))]
    if a.rerun || a.rerun_save.is_some() {
        return Err(sdslam::Error::Invalid(
            "--rerun needs a build with the viewer: cargo build --release --features rerun".into(),
        ));
    }
    let mut warned_skip = false;
    // Progress for replays of known length, on a terminal only (indicatif hides otherwise).
    let progress = match (info.len, super::quiet()) {
        (Some(n), false) => {
            let pb = indicatif::ProgressBar::new(n as u64);
            pb.set_style(
                indicatif::ProgressStyle::with_template(
                    "{bar:30} {pos}/{len} frames  {per_sec}  {msg}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            Some(pb)
        }
        _ => None,
    };
    loop {
        if let Some(t) = system.failed_thread() {
            report.stopped_early = Some(format!(
                "the {t} thread failed (panicked); outputs written from the run so far"
            ));
            note!("error: the {t} thread failed; stopping and writing the outputs computed so far");
            break;
        }
        // `--frames N` also bounds live cameras (replays are cut at the source).
        if a.frames.is_some_and(|n| report.frames >= n) {
            break;
        }
        if super::signal::interrupted() {
            report.stopped_early =
                Some("interrupted (Ctrl-C); outputs written from the run so far".into());
            note!(
                "sdslam: interrupted; stopping the threads and writing the outputs computed so far"
            );
            break;
        }
        match src.next_frame(&mut frame) {
            Ok(FrameStatus::Ready) => {}
            Ok(FrameStatus::Skipped { index, reason }) => {
                report.skipped_frames += 1;
                if !warned_skip {
                    note!("warning: skipping unreadable frame {index}: {reason} (further skips are counted in report.json)");
                    warned_skip = true;
                }
                continue;
            }
            Ok(FrameStatus::End) => break,
            Err(e) => {
                report.stopped_early = Some(e.to_string());
                note!("error: {e}; writing the outputs computed so far");
                break;
            }
        }
        if let Some((start, count)) = a.drop {
            if frame.index >= start && frame.index < start + count {
                report.blackout_frames += 1;
                continue;
            }
        }
        let t0 = frame.arrival.unwrap_or_else(Instant::now);
        let r = system.process_frame(&frame);
        if let (Some((start, count)), None) = (a.drop, report.frames_to_recover) {
            if frame.index >= start + count && r.state == TrackingState::Ok {
                report.frames_to_recover = Some(frame.index - (start + count));
            }
        }
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        frame_timer.record_ms(ms);
        if ms > deadline_ms {
            report.deadline_misses += 1;
            tracing::debug!(
                frame = frame.index,
                latency_ms = ms,
                state = ?r.state,
                keyframe = r.new_keyframe,
                "deadline missed"
            );
        }
        report.frames += 1;
        #[cfg(feature = "rerun")]
        if let Some(v) = &viewer {
            if let Some(t_wc) = &r.t_wc {
                v.frame(frame.timestamp, t_wc);
            }
            if r.new_keyframe {
                v.keyframes(frame.timestamp, &system.keyframe_trajectory());
                // The cloud so far is readable while running in the single-thread mode only
                // (the semi-dense thread hands its results over at the end).
                if system.semidense().is_some() && system.map_size().0.is_multiple_of(5) {
                    v.cloud(frame.timestamp, &system.semidense_cloud());
                }
            }
        }
        if let Some(pb) = &progress {
            pb.set_position(frame.index + 1);
            if report.frames.is_multiple_of(10) {
                let (k, p) = system.map_size();
                pb.set_message(format!("{:?}, {k} keyframes, {p} points", r.state));
            }
        }
    }
    if let Some(pb) = progress {
        pb.finish_and_clear();
    }
    drop(src);
    if let Some(p) = &pacing_stats {
        report.dropped_frames = p.dropped();
    }
    if let Some(l) = &live {
        use std::sync::atomic::Ordering::Relaxed;
        report.driver_dropped_frames = l.driver_drops.load(Relaxed);
        let age = l.mean_age_us.load(Relaxed);
        report.capture_to_dequeue_ms = (age > 0).then_some(age as f64 / 1e3);
    }

    report.wall_time_s = started.elapsed().as_secs_f64();
    let interrupted = super::signal::interrupted();
    if interrupted {
        report.stopped_early.get_or_insert_with(|| {
            "interrupted (Ctrl-C); outputs written from the run so far".into()
        });
    }
    let finishing = Instant::now();
    // Tracking outputs first (trajectory, keyframes, a first report.json): they are final
    // once the mapping threads are joined, and must not wait for the semi-dense backlog.
    let mut threads_ok = system.finish_tracking();
    fill_tracking_report(&mut report, &system, &frame_timer);
    let trajectory = system.trajectory();
    let keyframes = system.keyframe_trajectory();
    let alignment = groundtruth
        .as_ref()
        .and_then(|gt| sdslam::eval::ate(gt, &keyframes, 0.02, true));
    report.keyframe_ate_rmse_m = alignment.as_ref().map(|r| r.rmse_m);
    outputs.write("trajectory.txt", |p| write_tum_trajectory(p, &trajectory));
    outputs.write("keyframes.txt", |p| write_tum_trajectory(p, &keyframes));
    if let Some(path) = &a.save_map {
        outputs.write_at("map", path, |p| {
            let bytes = system
                .save_map()
                .encode()
                .map_err(|e| sdslam::Error::format(p, e))?;
            io::write_atomic(p, &bytes)?;
            note!(
                "sdslam: map saved to {} ({} kB)",
                p.display(),
                bytes.len() / 1024
            );
            Ok(())
        });
    }
    report.peak_rss_mb = io::peak_rss_mb();
    outputs.write("report.json", |p| write_json_atomic(p, &report));
    if interrupted && config.semidense.enabled {
        note!("sdslam: tracking outputs written; cutting the semi-dense backlog");
    }

    threads_ok &= system.finish_semidense(interrupted);
    system.release_working_memory();
    if !threads_ok {
        report.stopped_early.get_or_insert_with(|| {
            "a worker thread panicked; outputs written from the map as it was".into()
        });
    }
    let cloud = system.semidense_cloud();
    #[cfg(feature = "rerun")]
    if let Some(v) = &viewer {
        let t = keyframes.last().map_or(0.0, |k| k.timestamp);
        v.keyframes(t, &keyframes);
        v.cloud(t, &cloud);
    }
    outputs.write("semidense.ply", |p| write_ply(p, &cloud));
    report.semidense_points = cloud.len();
    if let Some(sd) = system.semidense() {
        report.semidense_keyframes = sd.stats.keyframes_reconstructed;
        report.semidense_skipped_keyframes = sd.stats.keyframes_skipped;
        report.semidense_skipped_culled = sd.stats.skipped_culled;
        report.semidense_skipped_no_neighbours = sd.stats.skipped_no_neighbours;
        report.semidense_skipped_overload = sd.stats.skipped_overload;
        report.semidense_skipped_cut = sd.stats.skipped_cut;
        report.semidense_busy_s = sd.stats.busy_s;
        report.semidense_finish_s = finishing.elapsed().as_secs_f64();
        report.timing_ms.semidense_keyframe = sd.t_keyframe.percentiles();
        report.timing_ms.semidense_depth = sd.t_depth.percentiles();
        report.timing_ms.semidense_intra = sd.t_intra.percentiles();
        report.timing_ms.semidense_inter = sd.t_inter.percentiles();
        if sd.stats.skipped_cut > 0 {
            note!(
                "sdslam: interrupted: {} keyframes of the semi-dense backlog were cut (not reconstructed, or not verified by the inter-keyframe check; semidense_skipped_cut in report.json)",
                sd.stats.skipped_cut
            );
        }
        if a.depth_maps {
            outputs.write("depth", |p| {
                let _ = p;
                super::densify::write_depth_maps(&a.out, sd, info.width, info.height)
            });
        }
        if let (Some(gt), Some(ate), false) = (&groundtruth, &alignment, cloud.is_empty()) {
            let stamps: Vec<f64> = sd.entries().iter().map(|e| e.timestamp).collect();
            match depth_truth.load(&stamps, gt, info.width, info.height) {
                Ok(frames) if !frames.is_empty() => {
                    report.semidense_accuracy = Some(sdslam::eval::cloud_accuracy(
                        &cloud,
                        &ate.alignment,
                        &calib.camera,
                        &frames,
                    ));
                }
                Ok(_) => {}
                Err(e) => note!("warning: semi-dense accuracy not evaluated: {e}"),
            }
        }
    }
    if !a.no_plots {
        let aligned = groundtruth.as_ref().zip(alignment.as_ref());
        outputs.write("trajectory.png", |p| {
            super::plots::trajectory(
                p,
                &keyframes,
                aligned.map(|(gt, r)| (gt.as_slice(), &r.alignment, r.rmse_m)),
            )
        });
        outputs.write("cloud.png", |p| super::plots::cloud(p, &cloud));
        outputs.write("timing.png", |p| {
            super::plots::timing(p, frame_timer.samples_ms(), deadline_ms)
        });
    }
    // Last, so the peak covers the whole run (finishing, the cloud, evaluation, plots).
    report.peak_rss_mb = io::peak_rss_mb();
    outputs.write("report.json", |p| write_json_atomic(p, &report));
    if let Some(acc) = &report.semidense_accuracy {
        note!(
            "sdslam: semi-dense {} points ({:.0} per keyframe): median relative depth error {}, {:.1}% within 2%, {:.2}% off by > 10%",
            acc.points,
            acc.points_per_keyframe,
            super::percent(acc.median_relative_error),
            acc.within_2pct * 100.0,
            acc.outliers_10pct * 100.0
        );
    }
    note!(
        "sdslam: {} frames ({} skipped), {} tracked, {} keyframes, {} points{}, {:.1} s; state {:?}; outputs in {}",
        report.frames,
        report.skipped_frames,
        report.tracked_frames,
        report.keyframes,
        report.map_points,
        report.keyframe_ate_rmse_m.map(|a| format!(", keyframe ATE {:.4} (Sim3-aligned)", a)).unwrap_or_default(),
        report.wall_time_s,
        system.state(),
        outputs.dir().display()
    );
    if !outputs.failures().is_empty() {
        return Err(sdslam::Error::Invalid(format!(
            "{} output(s) not written ({}); the others are in {}",
            outputs.failures().len(),
            outputs.failures().join("; "),
            outputs.dir().display()
        )));
    }
    if !threads_ok {
        return Err(sdslam::Error::Invalid(format!(
            "{}; every output was written to {}",
            report
                .stopped_early
                .as_deref()
                .unwrap_or("a worker thread failed"),
            outputs.dir().display()
        )));
    }
    Ok(RunOutcome {
        report,
        latencies_ms: frame_timer.samples_ms().to_vec(),
    })
}

/// The tracking and mapping figures of a finished run.
fn fill_tracking_report(report: &mut Report, system: &System, frame_timer: &StageTimer) {
    report.timing_ms.tracking = frame_timer.percentiles();
    report.timing_ms.orb_extraction = system.stats.orb_extraction.percentiles();
    report.timing_ms.local_ba = system.stats.local_mapping.percentiles();
    report.timing_ms.pose_prediction = system.tracker.t_prediction.percentiles();
    report.timing_ms.local_map_tracking = system.tracker.t_local_map.percentiles();
    report.timing_ms.relocalisation = system.tracker.t_relocalisation.percentiles();
    report.timing_ms.keyframe_insertion = system.stats.keyframe_insertion.percentiles();
    report.timing_ms.map_lock_wait = system.stats.map_lock_wait.percentiles();
    report.tracked_frames = system.stats.tracked_frames;
    report.backfilled_frames = system.stats.backfilled_frames;
    report.map_resets = system.stats.resets;
    report.poses_discarded_by_reset = system.stats.poses_discarded_by_reset;
    report.lost_episodes = system.tracker.lost_episodes;
    report.relocalisations = system.tracker.relocalisations;
    report.loops_closed = system.stats.loops_closed;
    report.loops_closed_by_revisit = system.stats.loops_closed_by_revisit;
    report.loop_closures.clone_from(&system.stats.loop_closures);
    report.final_ba_ms = system.stats.final_ba_ms;
    report.timing_ms.loop_closing = system.stats.loop_closing.percentiles();
    (report.keyframes, report.map_points) = system.map_size();
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
