//! `focusd capture`: sweep the focus (or replay a recorded sweep), register, fuse, and report
//! every take the motion gate saw. `focusd record`: sweep and write every take and the IMU
//! trace as a replay bundle, to replay and debug later.

use super::progress::Bar;
use anyhow::{Context, Result};
use focusd::backend::replay::BundleWriter;
use focusd::capture::record::{take_dng, Recording};
use focusd::capture::sweep::{sweep_takes, PlaneReport, Unmonitored};
use focusd::capture::Frame;
use focusd::files::imageio as io;
use focusd::files::orientation::Orientation;
use focusd::service::config::Config;
use focusd::service::fuse_settings::QUALITY;
use focusd::service::job::{self, Rig, Source};
use std::path::{Path, PathBuf};

/// Where the frames come from, and how.
#[derive(clap::Args, Debug)]
pub struct SourceArgs {
    /// Configuration file (TOML, see config/focusd.toml); built-in defaults without it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Replay a recorded bundle directory instead of using the camera and the IMU.
    #[arg(long, value_name = "DIR")]
    pub replay: Option<PathBuf>,
}

impl SourceArgs {
    fn open(&self) -> Result<(Config, Rig)> {
        let config = match &self.config {
            Some(p) => Config::load(p)?,
            None => Config::default(),
        };
        let source = match &self.replay {
            Some(dir) => Source::Replay {
                dir: dir.clone(),
                paced: false,
                faults: Vec::new(),
            },
            None => Source::Device,
        };
        let rig = Rig::open(&config, &source)?;
        for line in &rig.description {
            eprintln!("focusd: {line}");
        }
        Ok((config, rig))
    }
}

#[derive(clap::Args, Debug)]
pub struct CaptureArgs {
    /// Output image (.jpg, .png or .tif).
    #[arg(short, long, value_name = "OUT")]
    pub output: PathBuf,
    #[command(flatten)]
    pub source: SourceArgs,
    /// Write a JSON report: every take of every plane with its motion, and stage timings.
    #[arg(long, value_name = "R.json")]
    pub report: Option<PathBuf>,
    /// JPEG quality, 1..=100 (default: the config's [fuse] quality).
    #[arg(long, value_parser = QUALITY.parser())]
    pub quality: Option<u8>,
}

pub fn run(a: &CaptureArgs) -> Result<()> {
    io::format_for(&a.output)?;
    let (config, mut rig) = a.source.open()?;
    let mut fuse_cfg = config.fuse.clone();
    if let Some(q) = a.quality {
        fuse_cfg.quality = q;
    }
    let bar = Bar::stderr();
    let report = job::run(
        &mut rig,
        &fuse_cfg,
        &a.output,
        a.report.as_deref(),
        config.output.keep_raw,
        &Unmonitored,
        &bar,
    );
    bar.finish();
    let report = report?;
    print_planes(&report.planes);
    eprintln!("  order {}", report.focus_order);
    if let Some(d) = &report.developed_in_full {
        eprintln!(
            "  develop {} px in full ({:.2} frames' worth)",
            d.pixels, d.frames
        );
    }
    let m = &report.memory;
    let raise = "raise [fuse] memory_mb";
    eprintln!(
        "  {}",
        super::fuse::memory_line(m.within_budget, &m.plan, raise)
    );
    eprintln!(
        "focusd: captured {} planes, fused into {}",
        report.planes.len(),
        a.output.display()
    );
    Ok(())
}

fn print_planes(planes: &[PlaneReport]) {
    for p in planes {
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
}

/// IMU trace recorded past the sweep's end, ms.
const TRACE_TAIL_MS: i64 = 50;

#[derive(clap::Args, Debug)]
pub struct RecordArgs {
    /// The bundle directory to write (created; must be empty if it exists).
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
    #[command(flatten)]
    pub source: SourceArgs,
}

pub fn record(a: &RecordArgs) -> Result<()> {
    check_empty(&a.output)?;
    let (_, mut rig) = a.source.open()?;
    let begin = rig.clock.now();
    let mut recording = Recording::new(rig.camera.as_mut());
    // The takes are written as they came: nothing here is developed.
    let swept = sweep_takes(
        &mut recording,
        rig.imu.as_mut(),
        rig.clock.as_ref(),
        &rig.sweep,
        &Unmonitored,
    );
    // A failed sweep is worth replaying too: write what it took before saying why it failed.
    let takes = std::mem::take(&mut recording.takes);
    // A replay of the bundle asks for samples up to the last exposure's end, and a sensor
    // counts as delivering up to its last sample: keep a little beyond, where there is any.
    let (now, tail) = (rig.clock.now(), TRACE_TAIL_MS * 1_000_000);
    rig.clock.sleep_until(now + tail);
    let imu = rig
        .imu
        .samples(begin, now + tail)
        .or_else(|_| rig.imu.samples(begin, now))
        .context("reading back the IMU trace of the sweep")?;
    let mut w = BundleWriter::create_new(&a.output, rig.camera.lens_range())
        .with_context(|| format!("{}: cannot create the bundle", a.output.display()))?
        .with_rotation(rig.camera.sensor_rotation());
    // Raw takes stay raw (DNG, written now that the sweep is done), so a replay develops
    // them as the camera's; pictures are written as PNG.
    let placed = takes.len();
    for t in takes {
        let exposure = (t.take.exposure_start, t.take.exposure_end);
        let (extension, bytes) = match &t.take.frame {
            Frame::Picture(p) => ("png", io::encode(p, image::ImageFormat::Png, 100)?),
            Frame::Raw(r) => (
                "dng",
                take_dng(r, exposure, "focusd record", Orientation::UPRIGHT)?,
            ),
        };
        w.add_take(t.plane, t.lens, exposure, extension, &bytes)
            .with_context(|| format!("{}: cannot write a take", a.output.display()))?;
    }
    w.finish(&imu)
        .with_context(|| format!("{}: cannot write the bundle", a.output.display()))?;
    eprintln!(
        "focusd: recorded {} takes and {} IMU samples into {}",
        placed,
        imu.len(),
        a.output.display()
    );
    let (_, swept) = swept?;
    print_planes(&swept.planes);
    Ok(())
}

/// A bundle goes into a new or empty directory, so takes of two sweeps never mix.
fn check_empty(dir: &Path) -> Result<()> {
    let used = std::fs::read_dir(dir).is_ok_and(|mut e| e.next().is_some());
    if used {
        anyhow::bail!(
            "{}: the directory is not empty; record into a new one",
            dir.display()
        );
    }
    Ok(())
}
