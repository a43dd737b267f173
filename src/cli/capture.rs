//! `focusd capture`: sweep the focus (or replay a recorded sweep), register, fuse, and report
//! every take the motion gate saw.

use super::io;
use super::progress::Bar;
use crate::backend::replay::{self, Bundle};
use crate::capture::sweep::{sweep, PlaneReport, Sweep, SweepConfig, Unmonitored};
use crate::capture::{Camera, Clock, Imu};
use crate::stack::fuse::{fuse, FuseParams};
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct CaptureArgs {
    /// Output image (.jpg, .png or .tif).
    #[arg(short, long, value_name = "OUT")]
    pub output: PathBuf,
    /// Configuration file (TOML); built-in defaults without it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Replay a recorded bundle directory instead of using the camera and the IMU.
    #[arg(long, value_name = "DIR")]
    pub replay: Option<PathBuf>,
    /// Write a JSON report: every take of every plane with its motion, and stage timings.
    #[arg(long, value_name = "R.json")]
    pub report: Option<PathBuf>,
    /// JPEG quality, 1..=100.
    #[arg(long, default_value_t = 92, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub quality: u8,
}

/// The parts of the configuration file `capture` reads.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct ConfigFile {
    sweep: Option<SweepConfig>,
}

fn load_config(path: &Path) -> Result<ConfigFile> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    toml::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: {}", path.display(), e.to_string().trim()))
}

#[derive(Serialize)]
struct Report<'a> {
    planes: &'a [PlaneReport],
    /// Sweep duration on the capture clock (simulated time in a replay), ms.
    sweep_ms: f64,
    timings_ms: BTreeMap<&'static str, f64>,
    output: String,
}

pub fn run(a: &CaptureArgs) -> Result<()> {
    io::format_for(&a.output)?;
    let config = match &a.config {
        Some(p) => load_config(p)?,
        None => ConfigFile::default(),
    };
    let Some(dir) = &a.replay else {
        bail!(
            "capturing from the camera is not wired up yet; replay a recorded bundle with \
             --replay DIR (e.g. --replay sim-data/bundles/shaken)"
        );
    };
    let bundle = Bundle::open(dir)?;
    let cfg = config.sweep.unwrap_or_else(|| defaults_for(&bundle));
    let (mut camera, mut imu, clock) = replay::open(bundle);
    capture(a, &cfg, &mut camera, &mut imu, &clock)
}

/// Built-in sweep settings for a bundle: its planes and lens positions.
fn defaults_for(bundle: &Bundle) -> SweepConfig {
    let lens = bundle.lens_positions();
    SweepConfig {
        planes: bundle.planes(),
        lens_near: lens.first().copied(),
        lens_far: lens.last().copied(),
        ..SweepConfig::default()
    }
}

fn capture(
    a: &CaptureArgs,
    cfg: &SweepConfig,
    camera: &mut dyn Camera,
    imu: &mut dyn Imu,
    clock: &dyn Clock,
) -> Result<()> {
    let t0 = Instant::now();
    let Sweep {
        frames,
        planes,
        started,
        ended,
    } = sweep(camera, imu, clock, cfg, &Unmonitored)?;
    let capture_ms = t0.elapsed().as_secs_f64() * 1e3;
    for p in &planes {
        let rejected = p.takes.iter().filter(|t| !t.accepted).count();
        let kept = p.takes.iter().find(|t| t.kept_shaken).map(|t| t.take);
        eprintln!(
            "  plane {:>2}  lens {:>4}  {} take(s), {rejected} rejected{}",
            p.plane,
            p.lens,
            p.takes.len(),
            kept.map_or(String::new(), |k| format!(
                ", kept take {k} although shaken"
            ))
        );
    }
    let reference = (frames.len() - 1) / 2;
    let images = frames.into_iter().map(|t| t.image).collect();
    let params = FuseParams {
        reference,
        ..FuseParams::default()
    };
    let bar = Bar::stderr();
    let fused = fuse(images, &params, &bar);
    bar.finish();
    let fused = fused?;
    let t = Instant::now();
    let bytes = io::encode(&fused.image, io::format_for(&a.output)?, a.quality)?;
    io::write_atomic(&a.output, &bytes)?;
    let mut timings = BTreeMap::from([("capture", capture_ms)]);
    for (stage, d) in &fused.timings {
        let key = match *stage {
            "register" | "warp" => "register",
            _ => "fuse",
        };
        *timings.entry(key).or_default() += d.as_secs_f64() * 1e3;
    }
    timings.insert("save", t.elapsed().as_secs_f64() * 1e3);
    if let Some(path) = &a.report {
        let report = Report {
            planes: &planes,
            sweep_ms: (ended - started) as f64 * 1e-6,
            timings_ms: timings,
            output: a.output.display().to_string(),
        };
        let mut json = serde_json::to_vec_pretty(&report).context("encoding the report")?;
        json.push(b'\n');
        io::write_atomic(path, &json)?;
    }
    eprintln!(
        "focusd: captured {} planes, fused into {}",
        planes.len(),
        a.output.display()
    );
    Ok(())
}
