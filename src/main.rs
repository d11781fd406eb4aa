//! The `sdslam` command-line tool: argument parsing and wiring only.

use std::process::ExitCode;

use clap::Parser;

#[macro_use]
mod cli;

fn main() -> ExitCode {
    let args = cli::Cli::parse();
    match cli::dispatch(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            note!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
