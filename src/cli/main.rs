//! The `sdslam` command-line tool: argument parsing, subcommands and the files they write.
//! Everything that computes lives in the `sdslam` library; this crate holds what only a
//! command line needs (clap, plots, the progress bar, log output, the Rerun viewer), so a
//! robot embedding the library does not pull them in.

// Doc comments of the argument structs are clap's --help text (`OUT/depth/<timestamp>.png`
// reads right there), not rustdoc HTML.
#![allow(rustdoc::invalid_html_tags)]

/// A line to stderr that never panics: a closed or full stderr (`2>/dev/full`, `| head -1`)
/// must not cost a run its outputs.
macro_rules! note {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($t)*);
    }};
}

/// A line of a command's result to stdout; a failed write (full disk, closed pipe) is that
/// command's error, not a panic.
macro_rules! out {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout(), $($t)*)
            .map_err(|e| sdslam::Error::io("<standard output>", e))?;
    }};
}

mod bag;
mod bench;
mod calibrate;
mod cameras;
mod config_cmd;
mod densify;
mod eval;
mod features;
mod foxglove_out;
mod html;
mod plots;
mod record;
mod run;
mod signal;
mod source;
mod synth;
#[cfg(feature = "rerun")]
mod viewer;
mod vocab;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use sdslam::Result;

/// Real-time monocular ORB SLAM with probabilistic semi-dense mapping.
///
/// With no subcommand, `sdslam` runs on the built-in synthetic sequence (same as
/// `sdslam run synthetic`).
#[derive(Parser, Debug)]
#[command(name = "sdslam", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// More log lines on stderr: -v events (map initialised, lost, relocalised, loop closed),
    /// -vv debug, -vvv trace.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// No progress bar and only warnings and errors.
    #[arg(short, long, global = true)]
    quiet: bool,
    /// Widest SIMD the kernels may use: 128 (the SSE4.2 baseline, the width an ARM robot's
    /// NEON has), 256 (AVX2), 512 or auto (what the CPU has; default). Also `SDSLAM_SIMD`.
    #[arg(long, global = true, value_name = "BITS", value_parser = sdslam::simd::parse_width)]
    simd: Option<sdslam::simd::Width>,
}

static QUIET: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// True with `--quiet`: no progress bar.
fn quiet() -> bool {
    QUIET.load(std::sync::atomic::Ordering::Relaxed)
}

/// Log lines (`tracing`) to stderr at the level `-v` asks for (warnings by default).
fn init_logging(verbose: u8) {
    let level = match verbose {
        0 => tracing::Level::WARN,
        1 => tracing::Level::INFO,
        2 => tracing::Level::DEBUG,
        _ => tracing::Level::TRACE,
    };
    let _ = tracing_subscriber::fmt()
        .with_max_level(level)
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        // A closed or full stderr must not panic (the default reports the failed write with
        // eprintln!, which itself panics).
        .log_internal_errors(false)
        .try_init();
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
    /// Print every setting with its default (`--defaults`), or check a file (`--check FILE`).
    Config(config_cmd::ConfigArgs),
    /// Write a source's frames (default: the built-in sequence) as a ROS 2 bag in MCAP.
    Bag(bag::BagArgs),
    /// Render the built-in synthetic sequence to a TUM RGB-D folder (images, depth, ground truth).
    Synth(synth::SynthArgs),
}

fn main() -> ExitCode {
    sdslam::io::limit_allocator_arenas(sdslam::io::ALLOCATOR_ARENAS);
    match dispatch(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            note!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn dispatch(cli: Cli) -> Result<()> {
    init_logging(cli.verbose);
    QUIET.store(cli.quiet, std::sync::atomic::Ordering::Relaxed);
    sdslam::simd::cap_from_env().map_err(sdslam::Error::Invalid)?;
    if let Some(w) = cli.simd {
        sdslam::simd::set_max_width(w);
    }
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
        Some(Command::Bag(a)) => bag::bag(a),
        Some(Command::Features(a)) => features::features(a),
        Some(Command::Vocab(v)) => vocab::vocab(v),
        Some(Command::Config(a)) => config_cmd::config(a),
    }
}

/// Refuses a configuration whose preallocated map and semi-dense store would not fit in this
/// machine's memory (a full map would be killed mid-run, or allocation aborts at the start).
fn check_memory(calib: &sdslam::camera_model::Calibration, config: &sdslam::Config) -> Result<()> {
    let need = sdslam::runtime::System::reserved_memory(calib, config);
    let Some(have) = sdslam::io::machine_memory_bytes() else {
        return Ok(());
    };
    // Leave a quarter of the machine to the rest of the process and the system.
    let limit = have / 4 * 3;
    if need.total() > limit {
        let gb = |b: u64| b as f64 / 1e9;
        return Err(sdslam::Error::Invalid(format!(
            "the configuration reserves {:.1} GB (keyframes {:.1}, map points {:.1}, semi-dense store {:.1}) but this machine has {:.1} GB; the limit is {:.1} GB (3/4 of it): lower {}",
            gb(need.total()),
            gb(need.keyframes),
            gb(need.map_points),
            gb(need.semidense_store),
            gb(have),
            gb(limit),
            need.largest_field()
        )));
    }
    Ok(())
}

/// `x` as a percentage, or "n/a" when there was nothing to measure (a NaN median).
fn percent(x: f64) -> String {
    if x.is_finite() {
        format!("{:.2}%", x * 100.0)
    } else {
        "n/a (no point could be evaluated)".into()
    }
}

/// Default output folder.
fn default_out() -> PathBuf {
    PathBuf::from("out")
}
