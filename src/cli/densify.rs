//! `sdslam densify`: semi-dense reconstruction from given poses (offline, after full BA or
//! from ground truth), and the depth-map writer shared with `sdslam run --depth-maps`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use sdslam::camera::{Frame, FrameStatus};
use sdslam::camera_model::FrameRectifier;
use sdslam::eval::TimedPose;
use sdslam::io::{self, read_tum_trajectory, write_json_atomic, write_ply};
use sdslam::runtime::TimingReport;
use sdslam::semidense::{Densifier, SemiDenseMapper};
use sdslam::{Config, Error, Result};

use super::source;

#[derive(Args, Debug)]
pub struct DensifyArgs {
    /// A TUM RGB-D folder, a EuRoC folder, an image folder with `times.txt`, or `synthetic`.
    source: String,
    /// Poses (TUM format, `T_wc`): a refined trajectory or the ground truth. Optional with
    /// `--keyframes` (whose poses are then used).
    #[arg(long, required_unless_present = "keyframes")]
    poses: Option<PathBuf>,
    /// Make every K-th frame with a pose a keyframe.
    #[arg(long, default_value_t = 10, conflicts_with = "keyframes")]
    every: usize,
    /// The keyframes (TUM format, e.g. a run's keyframes.txt): the frames at these times, in
    /// this order, are the keyframes (instead of every K-th).
    #[arg(long, value_name = "FILE")]
    keyframes: Option<PathBuf>,
    /// Also write OUT/depth/<timestamp>.png per keyframe (depth x 5000 in pose units).
    #[arg(long)]
    depth_maps: bool,
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Calibration file (default: the folder's camera.yaml / sensor.yaml).
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Configuration file (TOML).
    #[arg(long)]
    config: Option<PathBuf>,
}

/// `densify` report: what was reconstructed, how fast, how accurate.
#[derive(serde::Serialize, Default)]
struct DensifyReport {
    keyframes: usize,
    semidense_keyframes: usize,
    semidense_skipped_keyframes: usize,
    semidense_points: usize,
    /// Pixels through each stage (what each check removes).
    semidense_pixels: sdslam::semidense::PixelCounts,
    semidense_accuracy: Option<sdslam::eval::CloudAccuracy>,
    wall_time_s: f64,
    timing_ms: TimingReport,
    /// Why the input was not read to its end (Ctrl-C, an unreadable source), if it was not.
    stopped_early: Option<String>,
}

pub fn densify(a: DensifyArgs) -> Result<()> {
    let started = Instant::now();
    if a.every == 0 {
        return Err(Error::Invalid("--every must be at least 1".into()));
    }
    let config = match &a.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    io::prepare_output_dir(&a.out)?;
    let chosen = match &a.keyframes {
        Some(p) => {
            let k = read_tum_trajectory(p)?;
            if k.is_empty() {
                return Err(Error::Invalid(format!("{}: no keyframes", p.display())));
            }
            Some(k)
        }
        None => None,
    };
    let poses_path = a
        .poses
        .as_ref()
        .or(a.keyframes.as_ref())
        .cloned()
        .unwrap_or_default();
    let poses = read_tum_trajectory(&poses_path)?;
    if poses.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no poses",
            poses_path.display()
        )));
    }
    let mut opened = source::open(
        Some(&a.source),
        a.calib.as_deref(),
        None,
        &source::CameraArgs::default(),
    )?;
    let calib = opened.calibration.clone();
    let info = opened.source.info().clone();
    let camera = calib.camera.undistorted();
    let mut rectifier = FrameRectifier::new(&calib);
    let max_kf = match &chosen {
        Some(k) => k.len() + 2,
        None => info.len.unwrap_or(100_000) / a.every + 2,
    };
    let mut densifier = Densifier::new(&camera, &config, max_kf);
    let mut frame = Frame::new(info.width, info.height);
    let (mut with_pose, mut keyframes) = (0usize, 0usize);
    let mut stopped_early = None;
    super::signal::install();
    loop {
        if super::signal::interrupted() {
            note!("sdslam densify: interrupted; writing the keyframes reconstructed so far");
            stopped_early = Some("interrupted (Ctrl-C)".to_string());
            break;
        }
        match opened.source.next_frame(&mut frame) {
            Ok(FrameStatus::Ready) => {}
            Ok(FrameStatus::Skipped { index, reason }) => {
                note!("warning: skipping unreadable frame {index}: {reason}");
                continue;
            }
            Ok(FrameStatus::End) => break,
            Err(e) => {
                note!("error: {e}; writing the keyframes reconstructed so far");
                stopped_early = Some(e.to_string());
                break;
            }
        }
        let Some(pose) = pose_at(&poses, frame.timestamp, 0.02) else {
            continue;
        };
        with_pose += 1;
        let is_keyframe = match &chosen {
            Some(k) => pose_at(k, frame.timestamp, 0.02).is_some(),
            None => (with_pose - 1) % a.every == 0,
        };
        if !is_keyframe {
            continue;
        }
        let input = rectifier.apply(&frame);
        let rgb = input.has_color.then_some(&input.rgb[..]);
        if densifier.add_keyframe(&input.gray, rgb, frame.timestamp, frame.index, &pose.t_wc) {
            keyframes += 1;
        }
    }
    if keyframes == 0 {
        return Err(Error::Invalid(format!(
            "{}: no frame of {} has a pose within 20 ms",
            poses_path.display(),
            a.source
        )));
    }
    let sd = densifier.finish();
    let mut report = DensifyReport {
        keyframes,
        semidense_keyframes: sd.stats.keyframes_reconstructed,
        semidense_skipped_keyframes: sd.stats.keyframes_skipped,
        semidense_pixels: sd.stats.pixels.clone(),
        stopped_early,
        ..Default::default()
    };
    report.timing_ms.semidense_keyframe = sd.t_keyframe.percentiles();
    report.timing_ms.semidense_depth = sd.t_depth.percentiles();
    report.timing_ms.semidense_intra = sd.t_intra.percentiles();
    report.timing_ms.semidense_inter = sd.t_inter.percentiles();
    if a.depth_maps {
        write_depth_maps(&a.out, sd, info.width, info.height)?;
    }
    let stamps: Vec<f64> = sd.entries().iter().map(|e| e.timestamp).collect();
    let mut cloud = Vec::new();
    densifier.cloud(&mut cloud);
    report.semidense_points = cloud.len();
    write_ply(&a.out.join("semidense.ply"), &cloud)?;
    // Accuracy against ground-truth depth, aligned with the given poses' own alignment to the
    // ground truth (identity when the poses are the ground truth).
    if let Some(gt) = &opened.groundtruth {
        let kf_poses: Vec<TimedPose> = stamps
            .iter()
            .filter_map(|&t| pose_at(&poses, t, 0.02).copied())
            .collect();
        if let Some(alignment) = sdslam::eval::pose_alignment(gt, &kf_poses, 0.02) {
            let depth_truth = std::mem::replace(&mut opened.depth_truth, source::DepthTruth::None);
            let frames = depth_truth.load(&stamps, gt, info.width, info.height)?;
            if !frames.is_empty() {
                report.semidense_accuracy = Some(sdslam::eval::cloud_accuracy(
                    &cloud,
                    &alignment,
                    &calib.lens(),
                    &frames,
                ));
            }
        }
    }
    report.wall_time_s = started.elapsed().as_secs_f64();
    write_json_atomic(&a.out.join("report.json"), &report)?;
    let acc = report
        .semidense_accuracy
        .as_ref()
        .map(|a| {
            format!(
                "; median relative depth error {}, {:.1}% within 2%, {:.2}% off by > 10%",
                super::percent(a.median_relative_error),
                a.within_2pct * 100.0,
                a.outliers_10pct * 100.0
            )
        })
        .unwrap_or_default();
    note!(
        "sdslam densify: {} keyframes, {} reconstructed, {} points ({:.0} per keyframe){acc}; {:.1} s; outputs in {}",
        keyframes,
        report.semidense_keyframes,
        report.semidense_points,
        report.semidense_points as f64 / report.semidense_keyframes.max(1) as f64,
        report.wall_time_s,
        a.out.display()
    );
    Ok(())
}

/// The pose nearest in time to `t`, within `max_dt` (poses sorted by time).
fn pose_at(poses: &[TimedPose], t: f64, max_dt: f64) -> Option<&TimedPose> {
    let i = poses.partition_point(|p| p.timestamp < t);
    [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter_map(|j| poses.get(j))
        .filter(|p| (p.timestamp - t).abs() <= max_dt)
        .min_by(|a, b| (a.timestamp - t).abs().total_cmp(&(b.timestamp - t).abs()))
}

/// One 16-bit PNG per reconstructed keyframe: OUT/depth/<timestamp>.png, depth x 5000.
pub fn write_depth_maps(out: &Path, sd: &SemiDenseMapper, width: u32, height: u32) -> Result<()> {
    let dir = out.join("depth");
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let mut depth = vec![0.0f32; (width * height) as usize];
    for (i, e) in sd.entries().iter().enumerate() {
        sd.depth_map(i, &mut depth);
        let path = dir.join(format!("{:.6}.png", e.timestamp));
        io::write_depth_png(&path, width, height, &depth, 5000.0)?;
    }
    Ok(())
}
