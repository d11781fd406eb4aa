//! `sdslam config`: print every setting with its default (a starting point for a TOML file),
//! or check a file.

use std::path::PathBuf;

use clap::Args;

use sdslam::{Config, Error, Result};

#[derive(Args, Debug)]
pub struct ConfigArgs {
    /// Print the whole configuration tree with its defaults (TOML; every key may be left out).
    #[arg(long, conflicts_with = "check")]
    defaults: bool,
    /// Check FILE: parse and validate it, report the first problem with its line and field.
    #[arg(long, value_name = "FILE")]
    check: Option<PathBuf>,
}

pub fn config(a: ConfigArgs) -> Result<()> {
    if let Some(p) = &a.check {
        Config::load(p)?;
        out!("{}: valid", p.display());
        return Ok(());
    }
    let _ = a.defaults; // the default action
    let text = toml::to_string_pretty(&Config::default())
        .map_err(|e| Error::Invalid(format!("cannot print the defaults: {e}")))?;
    out!(
        "# sdslam {} configuration: every key with its default. Keys may be left out; unknown\n# keys are errors. The names are the papers' (see the doc comments in src/config/).\n\n{text}",
        env!("CARGO_PKG_VERSION")
    );
    Ok(())
}
