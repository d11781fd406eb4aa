//! `sdslam eval`: trajectory and semi-dense accuracy by the project's protocol.

use std::path::PathBuf;

use clap::{Args, Subcommand};

use sdslam::eval::{ate, cloud_accuracy, rpe};
use sdslam::io::{decode_ply, load_calibration, load_tum_depth_frames, read_tum_trajectory};
use sdslam::{Error, Result};

#[derive(Subcommand, Debug)]
pub enum EvalCommand {
    /// Absolute trajectory error after Sim3 (Umeyama) alignment, poses matched by timestamp.
    Ate(AteArgs),
    /// Semi-dense cloud accuracy against a TUM folder's ground-truth depth: the cloud is
    /// aligned by a Sim3 fitted to the keyframe centres plus one point 0.5 m along each camera
    /// axis per keyframe, each point compared with the best of the 3x3 ground-truth depths
    /// around its projection in the depth map nearest its keyframe.
    Cloud(CloudArgs),
    /// Relative pose error over a time interval (drift), after scaling a monocular estimate
    /// by its Sim3 alignment.
    Rpe(RpeArgs),
    /// A one-page RUN/report.html: the run's figures (report.json), ATE and RPE when
    /// RUN/groundtruth.txt exists, and the pictures.
    Report(ReportArgs),
}

#[derive(Args, Debug)]
pub struct RpeArgs {
    gt: PathBuf,
    est: PathBuf,
    /// Interval, seconds.
    #[arg(long, default_value_t = 1.0)]
    delta: f64,
    #[arg(long, default_value_t = 0.02)]
    max_dt: f64,
    /// Do not rescale the estimate (metric estimates).
    #[arg(long)]
    no_scale: bool,
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Output folder of `sdslam run`.
    run: PathBuf,
}

#[derive(Args, Debug)]
pub struct CloudArgs {
    /// Output folder of `sdslam run` or `sdslam densify` (semidense.ply, keyframes.txt).
    run: PathBuf,
    /// TUM folder with groundtruth.txt, depth.txt and camera.yaml.
    #[arg(long)]
    gt: PathBuf,
    /// Keyframe trajectory used for the alignment (default RUN/keyframes.txt; for densify
    /// from ground truth, pass the poses given).
    #[arg(long)]
    keyframes: Option<PathBuf>,
    /// Evaluate only points whose inverse-depth sigma is below this fraction of their
    /// inverse depth (explores a variance threshold).
    #[arg(long)]
    max_rel_sigma: Option<f64>,
    /// Also print the figures of each keyframe's points.
    #[arg(long)]
    per_keyframe: bool,
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
pub struct AteArgs {
    /// Ground-truth trajectory (TUM format: timestamp tx ty tz qx qy qz qw).
    gt: PathBuf,
    /// Estimated trajectory (TUM format).
    est: PathBuf,
    /// Maximum timestamp difference for a match, seconds.
    #[arg(long, default_value_t = 0.02)]
    max_dt: f64,
    /// Align with SE3 only (no scale), for metric estimates.
    #[arg(long)]
    no_scale: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

pub fn eval(cmd: EvalCommand) -> Result<()> {
    match cmd {
        EvalCommand::Ate(a) => {
            let gt = read_tum_trajectory(&a.gt)?;
            let est = read_tum_trajectory(&a.est)?;
            let r = ate(&gt, &est, a.max_dt, !a.no_scale).ok_or_else(|| {
                Error::Invalid(format!(
                    "fewer than 3 non-collinear poses of {} match {} within {} s",
                    a.est.display(),
                    a.gt.display(),
                    a.max_dt
                ))
            })?;
            if a.json {
                print_json(&r)?;
            } else {
                out!("matched    {} poses ({} unmatched)", r.matched, r.unmatched);
                out!("ATE rmse   {:.6} m", r.rmse_m);
                out!("    mean   {:.6} m", r.mean_m);
                out!("    median {:.6} m", r.median_m);
                out!("    max    {:.6} m", r.max_m);
                out!("scale      {:.6}", r.scale);
            }
            Ok(())
        }
        EvalCommand::Cloud(a) => cloud(a),
        EvalCommand::Rpe(a) => {
            if !(a.delta.is_finite() && a.delta > 0.0) {
                return Err(Error::Invalid(format!(
                    "--delta {}: must be a positive number of seconds",
                    a.delta
                )));
            }
            let gt = read_tum_trajectory(&a.gt)?;
            let est = read_tum_trajectory(&a.est)?;
            let r = rpe(&gt, &est, a.max_dt, a.delta, !a.no_scale).ok_or_else(|| {
                Error::Invalid(format!(
                    "no pose pair {} s apart in {} matches {} within {} s",
                    a.delta,
                    a.est.display(),
                    a.gt.display(),
                    a.max_dt
                ))
            })?;
            if a.json {
                print_json(&r)?;
            } else {
                out!("pairs      {} ({} s apart)", r.pairs, r.delta_s);
                out!(
                    "RPE trans  rmse {:.6} m, mean {:.6} m, max {:.6} m",
                    r.trans_rmse,
                    r.trans_mean,
                    r.trans_max
                );
                out!(
                    "RPE rot    rmse {:.4} deg, mean {:.4} deg",
                    r.rot_rmse_deg,
                    r.rot_mean_deg
                );
                out!("scale      {:.6}", r.scale);
            }
            Ok(())
        }
        EvalCommand::Report(a) => super::html::write_report(&a.run),
    }
}

fn cloud(a: CloudArgs) -> Result<()> {
    let gt = read_tum_trajectory(&a.gt.join("groundtruth.txt"))?;
    let kf_path = a.keyframes.unwrap_or_else(|| a.run.join("keyframes.txt"));
    let est = read_tum_trajectory(&kf_path)?;
    let ply_path = a.run.join("semidense.ply");
    let bytes = sdslam_camera::capped::read_capped(&ply_path, sdslam_camera::capped::BULK_CAP)
        .map_err(|e| Error::io(&ply_path, e))?;
    let mut points = decode_ply(&bytes, &ply_path)?;
    let calib = load_calibration(&a.gt.join("camera.yaml"))?;
    let cam = &calib.camera;
    let align = ate(&gt, &est, 0.02, true).ok_or_else(|| {
        Error::Invalid(format!(
            "{}: fewer than 3 keyframes match the ground truth",
            kf_path.display()
        ))
    })?;
    if let Some(max) = a.max_rel_sigma {
        // sigma is of the inverse depth: relative to rho = 1 / depth along the optical axis,
        // which needs the keyframe pose; use the distance to the keyframe centre instead.
        let centres: Vec<(f64, nalgebra::Vector3<f64>)> = est
            .iter()
            .map(|p| (p.timestamp, p.t_wc.position()))
            .collect();
        points.retain(|p| {
            let i = centres.partition_point(|c| c.0 < p.timestamp - 1e-6);
            let Some((_, c)) = centres.get(i) else {
                return false;
            };
            let d = (nalgebra::Vector3::new(
                p.position[0] as f64,
                p.position[1] as f64,
                p.position[2] as f64,
            ) - c)
                .norm();
            (p.sigma as f64) * d < max
        });
    }
    let mut stamps: Vec<f64> = points.iter().map(|p| p.timestamp).collect();
    stamps.sort_by(f64::total_cmp);
    stamps.dedup();
    let frames = load_tum_depth_frames(&a.gt, &gt, cam.width, cam.height, 5000.0, Some(&stamps))?;
    // The evaluation protocol's alignment: keyframe centres plus axis points (positions alone
    // leave the rotation about a near-straight path free).
    let align = sdslam::eval::pose_alignment(&gt, &est, 0.02).unwrap_or(align.alignment);
    let lens = calib.lens();
    let r = cloud_accuracy(&points, &align, &lens, &frames);
    if a.per_keyframe {
        let mut start = 0;
        while start < points.len() {
            let t = points[start].timestamp;
            let end = start + points[start..].partition_point(|p| p.timestamp == t);
            let k = cloud_accuracy(&points[start..end], &align, &lens, &frames);
            out!(
                "keyframe {t:.6}: {:6} points, median {}, within 2% {:.1}%, beyond 10% {:.2}%",
                k.points,
                super::percent(k.median_relative_error),
                k.within_2pct * 100.0,
                k.outliers_10pct * 100.0
            );
            start = end;
        }
    }
    if a.json {
        print_json(&r)?;
    } else {
        out!(
            "points     {} ({} evaluated, {} keyframes, {:.0} per keyframe)",
            r.points,
            r.evaluated,
            r.keyframes,
            r.points_per_keyframe
        );
        out!(
            "median relative depth error {}",
            super::percent(r.median_relative_error)
        );
        out!("within 2%  {:.2}%", r.within_2pct * 100.0);
        out!("beyond 10% {:.3}% (outliers)", r.outliers_10pct * 100.0);
    }
    Ok(())
}

/// Prints `value` as one line of JSON (the `--json` output of the evaluation commands).
fn print_json<T: serde::Serialize>(value: &T) -> Result<()> {
    let line = serde_json::to_string(value).map_err(|e| Error::Invalid(e.to_string()))?;
    out!("{line}");
    Ok(())
}
