//! `sdslam eval`: trajectory accuracy by the project's protocol.

use std::path::PathBuf;

use clap::{Args, Subcommand};

use sdslam::eval::ate;
use sdslam::io::read_tum_trajectory;
use sdslam::{Error, Result};

#[derive(Subcommand, Debug)]
pub enum EvalCommand {
    /// Absolute trajectory error after Sim3 (Umeyama) alignment, poses matched by timestamp.
    Ate(AteArgs),
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
                println!(
                    "{}",
                    serde_json::to_string(&r).map_err(|e| Error::Invalid(e.to_string()))?
                );
            } else {
                println!("matched    {} poses ({} unmatched)", r.matched, r.unmatched);
                println!("ATE rmse   {:.6} m", r.rmse_m);
                println!("    mean   {:.6} m", r.mean_m);
                println!("    median {:.6} m", r.median_m);
                println!("    max    {:.6} m", r.max_m);
                println!("scale      {:.6}", r.scale);
            }
            Ok(())
        }
    }
}
