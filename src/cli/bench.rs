//! `sdslam bench latency`: replays a source in real time, pinned to the given cores, with
//! every thread running, and prints the tracking latency histogram and the deadline misses.

use clap::{Args, Subcommand};

use sdslam::{Error, Result};

use super::run::{run_with, RunArgs};

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Frame-arrival-to-pose latency of a real-time replay.
    Latency(LatencyArgs),
}

#[derive(Args, Debug)]
pub struct LatencyArgs {
    /// A source as for `sdslam run` (default: the built-in sequence).
    source: Option<String>,
    /// CPUs to run on, e.g. `0,1` (the whole process, all threads).
    #[arg(long, value_delimiter = ',')]
    cores: Vec<usize>,
    /// Configuration file (TOML).
    #[arg(long)]
    config: Option<std::path::PathBuf>,
    /// Use only the first N frames.
    #[arg(long)]
    frames: Option<usize>,
    /// Without the semi-dense thread.
    #[arg(long)]
    no_semidense: bool,
    /// Where the run's outputs go.
    #[arg(long, default_value = "out-latency")]
    out: std::path::PathBuf,
}

pub fn bench(cmd: BenchCommand) -> Result<()> {
    let BenchCommand::Latency(a) = cmd;
    // Pin before any thread starts: every thread inherits the set.
    if !a.cores.is_empty() && !sdslam::runtime::pin_current_thread(&a.cores) {
        return Err(Error::Invalid(format!(
            "--cores {:?}: cannot run on these CPUs",
            a.cores
        )));
    }
    let mut run = RunArgs::default_synthetic();
    run.source = a.source;
    run.config = a.config;
    run.frames = a.frames;
    run.no_semidense = a.no_semidense;
    run.realtime = true;
    run.out = a.out;
    let outcome = run_with(run)?;
    let r = &outcome.report;
    let deadline = r.deadline_ms;
    let edges = [
        2.5,
        5.0,
        7.5,
        10.0,
        12.5,
        15.0,
        20.0,
        25.0,
        deadline,
        f64::INFINITY,
    ];
    let mut counts = vec![0usize; edges.len()];
    for &l in &outcome.latencies_ms {
        let i = edges
            .iter()
            .position(|&e| (l as f64) <= e)
            .unwrap_or(edges.len() - 1);
        counts[i] += 1;
    }
    let n = outcome.latencies_ms.len().max(1);
    out!(
        "tracking latency (frame arrival -> pose), {} frames, deadline {:.1} ms, cores {:?}",
        r.frames,
        deadline,
        a.cores
    );
    let mut lo = 0.0;
    for (e, c) in edges.iter().zip(&counts) {
        let label = if e.is_finite() {
            format!("{lo:5.1} - {e:5.1} ms")
        } else {
            format!("    > {lo:5.1} ms")
        };
        let bar = "#".repeat((60 * c).div_ceil(n));
        out!("{label} {c:6} {bar}");
        lo = *e;
    }
    let t = &r.timing_ms.tracking;
    out!(
        "p50 {:.1} ms, p90 {:.1} ms, p99 {:.1} ms, max {:.1} ms",
        t.p50,
        t.p90,
        t.p99,
        t.max
    );
    out!(
        "deadline misses {}, dropped frames {}, peak RSS {:.0} MB",
        r.deadline_misses,
        r.dropped_frames,
        r.peak_rss_mb
    );
    Ok(())
}
