//! Subcommands of `sdslam`.

mod bench;
mod calibrate;
mod cameras;
mod densify;
mod eval;
mod features;
mod plots;
mod record;
mod run;
mod signal;
mod source;
mod synth;
mod vocab;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

use sdslam::Result;

/// Real-time monocular ORB SLAM with probabilistic semi-dense mapping.
///
/// With no subcommand, `sdslam` runs on the built-in synthetic sequence (same as
/// `sdslam run synthetic`).
#[derive(Parser, Debug)]
#[command(name = "sdslam", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run SLAM on a source and write trajectory.txt, keyframes.txt, semidense.ply and report.json.
    Run(run::RunArgs),
    /// Calibrate a camera from chessboard views (a folder of images or a live camera).
    Calibrate(calibrate::CalibrateArgs),
    /// List cameras (V4L2, and libcamera when built with it) with their formats, sizes and rates.
    Cameras,
    /// Save a camera's frames as a TUM RGB-D folder (rgb/, rgb.txt) that replays in `sdslam run`.
    Record(record::RecordArgs),
    /// Semi-dense reconstruction from given poses (offline): semidense.ply, depth maps, report.
    Densify(densify::DensifyArgs),
    /// Measure the pipeline: `bench latency [SOURCE] [--cores 0,1]`.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Evaluate results against ground truth.
    #[command(subcommand)]
    Eval(eval::EvalCommand),
    /// Train or import place-recognition vocabularies.
    #[command(subcommand)]
    Vocab(vocab::VocabCommand),
    /// Time ORB extraction on images (one thread): median time and feature count.
    Features(features::FeaturesArgs),
    /// Render the built-in synthetic sequence to a TUM RGB-D folder (images, depth, ground truth).
    Synth(synth::SynthArgs),
}

pub fn dispatch(cli: Cli) -> Result<()> {
    match cli.command {
        None => run::run(run::RunArgs::default_synthetic()),
        Some(Command::Run(a)) => run::run(a),
        Some(Command::Cameras) => cameras::cameras(),
        Some(Command::Calibrate(a)) => calibrate::calibrate(a),
        Some(Command::Record(a)) => record::record(a),
        Some(Command::Eval(e)) => eval::eval(e),
        Some(Command::Densify(a)) => densify::densify(a),
        Some(Command::Bench(b)) => bench::bench(b),
        Some(Command::Synth(a)) => synth::synth(a),
        Some(Command::Features(a)) => features::features(a),
        Some(Command::Vocab(v)) => vocab::vocab(v),
    }
}

/// Default output folder.
fn default_out() -> PathBuf {
    PathBuf::from("out")
}
