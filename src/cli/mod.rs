//! Command-line front ends over the library.
pub mod capture;
pub mod fuse;
pub mod interrupt;
pub mod progress;
pub mod serve;
pub mod simulate;

use focusd::service::config::Config;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct CheckConfigArgs {
    /// The TOML file to check.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
}

/// `focusd check-config`: the file's first problem, or that it is fine.
pub fn check_config(a: &CheckConfigArgs) -> anyhow::Result<()> {
    Config::load(&a.file)?;
    println!("{}: ok", a.file.display());
    Ok(())
}
