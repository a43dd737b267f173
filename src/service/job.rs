//! One capture job, as `focusd capture` and the daemon run it: open the camera and the IMU (or
//! a replay of a recorded bundle), sweep, register and fuse, and write the image and its
//! report atomically.

use super::config::Config;
use super::fuse_settings::FuseSettings;
use super::output_dir;
use super::ServiceError;
use crate::backend::iio::IioImu;
use crate::backend::replay::faults::{self, Fault, HeldDevelopment};
use crate::backend::replay::{self, Bundle};
use crate::backend::sys::MonotonicClock;
use crate::backend::v4l2;
use crate::capture::hold::Hold;
use crate::capture::record::take_dng;
use crate::capture::sweep::{sweep_takes, Monitor, PlaneReport, Sweep, SweepConfig};
use crate::capture::{Camera, CaptureError, Clock, Frame, Imu, Nanos};
use crate::develop::{RawFrame, RawStack};
use crate::files::orientation::{tag_jpeg, Orientation};
use crate::files::outputs::Outputs;
use crate::stack::fuse::{fuse, fuse_developing, FuseError};
use crate::stack::image::Image;
use crate::stack::memory::{mib, Plan};
use crate::stack::{Developed, Progress, Stage};
use image::ImageFormat;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

type Result<T> = std::result::Result<T, ServiceError>;

/// Where the frames come from.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// The phone's camera and IMU, as the config names them.
    Device,
    /// A recorded bundle, on simulated time; `paced`: as slow as it was recorded; `faults`:
    /// failures injected at given planes (for tests of the failure paths).
    Replay {
        dir: PathBuf,
        paced: bool,
        faults: Vec<Fault>,
    },
}

/// The hardware (or its replay) a job sweeps with, and the sweep settings for it.
pub struct Rig {
    pub camera: Box<dyn Camera>,
    pub imu: Box<dyn Imu>,
    pub clock: Box<dyn Clock>,
    pub sweep: SweepConfig,
    /// What was opened, one line each (for the log).
    pub description: Vec<String>,
    /// The faults a replay injects (the development's; the camera and the IMU have theirs).
    pub faults: Vec<Fault>,
}

impl Rig {
    pub fn open(config: &Config, source: &Source) -> Result<Rig> {
        match source {
            Source::Replay { dir, paced, faults } => {
                let bundle = Bundle::open(dir)?;
                let sweep = config
                    .sweep
                    .clone()
                    .unwrap_or_else(|| defaults_for(&bundle));
                let description = vec![format!(
                    "replaying {} ({} takes of {} planes)",
                    dir.display(),
                    bundle.manifest.takes.len(),
                    bundle.planes()
                )];
                let (camera, imu, clock) = replay::open_paced(bundle, *paced);
                let (camera, imu): (Box<dyn Camera>, Box<dyn Imu>) = if faults.is_empty() {
                    (Box::new(camera), Box::new(imu))
                } else {
                    let (c, i) = faults::inject(camera, imu, faults);
                    (Box::new(c), Box::new(i))
                };
                Ok(Rig {
                    camera,
                    imu,
                    clock: Box::new(clock),
                    sweep,
                    description,
                    faults: faults.clone(),
                })
            }
            Source::Device => {
                // The IMU first: it reads in the background, so the still wait has history.
                let imu = IioImu::open(&config.imu)?;
                let camera = v4l2::open(&config.camera)?;
                let mut description = vec![camera.describe()];
                description.extend(imu.description.iter().cloned());
                Ok(Rig {
                    camera: Box::new(camera),
                    imu: Box::new(imu),
                    clock: Box::new(MonotonicClock),
                    sweep: config.sweep.clone().unwrap_or_default(),
                    description,
                    faults: Vec::new(),
                })
            }
        }
    }
}

/// Built-in sweep settings for a bundle: its planes and lens positions.
pub fn defaults_for(bundle: &Bundle) -> SweepConfig {
    let lens = bundle.lens_positions();
    SweepConfig {
        planes: bundle.planes(),
        lens_near: lens.first().copied(),
        lens_far: lens.last().copied(),
        ..SweepConfig::default()
    }
}

/// What a job did: every take of every plane, and how long each stage took.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub planes: Vec<PlaneReport>,
    /// Sweep duration on the capture clock (simulated time in a replay), ms.
    pub sweep_ms: f64,
    /// Wall time of `capture` (the sweep), `develop` (its raw takes, cheaply in whole and in
    /// full where the picture keeps them; 0 for a camera that delivers pictures), `register`,
    /// `fuse` and `save` (the picture, the report and any raw takes kept), ms.
    pub timings_ms: BTreeMap<&'static str, f64>,
    /// What of the raw takes was developed at full quality (`None` for pictures).
    pub developed_in_full: Option<DevelopedReport>,
    pub memory: MemoryReport,
    /// Which way the frames were focused, as the occlusion edges tell (`OrderEvidence`'s line).
    pub focus_order: String,
    /// Which way the picture is turned upright, and from what.
    pub orientation: OrientationReport,
    pub output: String,
}

/// The pixels developed at full quality over all frames, and how many frames' worth that is.
#[derive(Clone, Debug, Serialize)]
pub struct DevelopedReport {
    pub pixels: usize,
    pub frames: f64,
}

impl From<&Developed> for DevelopedReport {
    fn from(d: &Developed) -> Self {
        Self {
            pixels: d.pixels,
            frames: d.frames(),
        }
    }
}

/// A sweep's frames: all pictures, or all raw takes.
enum Frames {
    Pictures(Vec<Image<u8>>),
    Raw(Vec<RawFrame>),
}

impl Frames {
    /// The frames sorted by kind; a sweep that mixes them is an error (no camera delivers both
    /// in one stream, and a stack of both would be developed two ways).
    fn of(frames: Vec<Frame>) -> std::result::Result<Frames, CaptureError> {
        let raw = |f: &Frame| matches!(f, Frame::Raw(_));
        if let (Some(r), Some(p)) = (
            frames.iter().position(raw),
            frames.iter().position(|f| !raw(f)),
        ) {
            return Err(CaptureError::device(
                "camera",
                format!(
                    "plane {r} is a raw frame but plane {p} a picture: a stack is developed one \
                     way, so its frames must be all raw or all pictures"
                ),
            ));
        }
        let mut pictures = Vec::new();
        let mut raws = Vec::new();
        for f in frames {
            match f {
                Frame::Picture(p) => pictures.push(p),
                Frame::Raw(r) => raws.push(r),
            }
        }
        Ok(if raws.is_empty() {
            Frames::Pictures(pictures)
        } else {
            Frames::Raw(raws)
        })
    }
}

/// The picture's turn: its EXIF Orientation (written into a JPEG, applied to PNG and TIFF
/// pixels), the sensor's rotation and the hold it combines.
#[derive(Clone, Debug, Serialize)]
pub struct OrientationReport {
    pub exif: u16,
    pub sensor_rotation: i64,
    pub hold: Hold,
}

/// How the fuse fitted its memory budget (`stack::memory::Plan`).
#[derive(Clone, Debug, Serialize)]
pub struct MemoryReport {
    pub budget_mib: usize,
    /// The plan's estimated peak, or what the stack needs at least when that is over budget.
    pub estimated_peak_mib: usize,
    pub within_budget: bool,
    /// The plan in words.
    pub plan: String,
}

impl From<&Plan> for MemoryReport {
    fn from(p: &Plan) -> Self {
        Self {
            budget_mib: mib(p.budget),
            estimated_peak_mib: mib(if p.fits() { p.peak } else { p.floor }),
            within_budget: p.fits(),
            plan: p.to_string(),
        }
    }
}

/// Sweeps, fuses and writes `output` (and `report` when given), both atomically; with
/// `keep_raw`, the raw takes too, as DNGs beside `output` (`output_dir::raw_path`), landing with it. The
/// sweep and the development report to `monitor`, the fusion to `progress`; all can cancel.
pub fn run(
    rig: &mut Rig,
    fuse_cfg: &FuseSettings,
    output: &Path,
    report: Option<&Path>,
    keep_raw: bool,
    monitor: &dyn Monitor,
    progress: &dyn Progress,
) -> Result<Report> {
    let format = crate::files::imageio::format_for(output)?;
    let mut outs = Outputs::check(
        &[Some(output), report]
            .into_iter()
            .flatten()
            .collect::<Vec<_>>(),
        &[],
    )?;
    let t0 = Instant::now();
    let (takes, swept) = sweep_takes(
        rig.camera.as_mut(),
        rig.imu.as_mut(),
        rig.clock.as_ref(),
        &rig.sweep,
        monitor,
    )?;
    let Sweep {
        planes,
        hold,
        started,
        ended,
        ..
    } = swept;
    let rotation = rig.camera.sensor_rotation();
    let upright = Orientation::from_sensor_rotation(rotation)
        .map_err(|e| CaptureError::device("camera", e))?
        .then(Orientation::clockwise(hold.quarter_turns));
    // The raw takes to keep, by frame: where each goes, and its exposure.
    let mut kept: Vec<Option<(PathBuf, (Nanos, Nanos))>> = Vec::with_capacity(takes.len());
    for (plane, t) in takes.iter().enumerate() {
        let path = (keep_raw && matches!(t.frame, Frame::Raw(_)))
            .then(|| output_dir::raw_path(output, plane));
        if let Some(p) = &path {
            outs.add(p)?;
        }
        kept.push(path.map(|p| (p, (t.exposure_start, t.exposure_end))));
    }
    let capture_ms = t0.elapsed().as_secs_f64() * 1e3;
    let frames = Frames::of(takes.into_iter().map(|t| t.frame).collect())?;
    let mut kept_ms = 0.0;
    let fused = match frames {
        Frames::Pictures(frames) => {
            let params = fuse_cfg.params(frames.len());
            fuse(frames, &params, progress)?
        }
        Frames::Raw(raws) => {
            let params = fuse_cfg.params(raws.len());
            let stack = RawStack::new(raws).map_err(|e| CaptureError::device("raw frame 0", e))?;
            // The raw takes to keep are written first, with the stack's white balance: from
            // here on the engine develops them, and they land with the picture or not at all.
            let t = Instant::now();
            for (raw, kept) in stack.takes().iter().zip(&kept) {
                if let Some((path, exposure)) = kept {
                    if monitor.cancelled() {
                        return Err(CaptureError::Cancelled.into());
                    }
                    outs.write(path, &take_dng(raw, *exposure, "focusd capture", upright)?)?;
                }
            }
            kept_ms = t.elapsed().as_secs_f64() * 1e3;
            let held = HeldDevelopment {
                stack: &stack,
                faults: &rig.faults,
                progress,
            };
            let fused = fuse_developing(&held, &params, progress)?;
            if let Some(d) = &fused.developed {
                tracing::info!("develop: {d}");
            }
            fused
        }
    };
    if !fused.memory.fits() {
        tracing::warn!("{}; raise [fuse] memory_mb", fused.memory);
    }
    tracing::info!("focus order: {}", fused.order);
    if let Some(s) = &fused.spill {
        if let Some(r) = &s.repaired {
            tracing::info!("repair: {r}");
        }
        tracing::info!("spill: {s}");
    }
    if progress.cancelled() {
        return Err(FuseError::Cancelled.into());
    }
    let t = Instant::now();
    // JPEG says the turn in its EXIF tag; PNG and TIFF get the pixels turned.
    let bytes = if format == ImageFormat::Jpeg {
        let plain = crate::files::imageio::encode(&fused.image, format, fuse_cfg.quality)?;
        tag_jpeg(&plain, upright).map_err(|e| CaptureError::device("output", e))?
    } else {
        let turned = upright.turn(&fused.image);
        crate::files::imageio::encode(&turned, format, fuse_cfg.quality)?
    };
    outs.write(output, &bytes)?;
    let mut timings = BTreeMap::from([("capture", capture_ms), ("develop", 0.0)]);
    for (stage, d) in &fused.timings {
        let key = match stage {
            Stage::Develop => "develop",
            s if s.registers() => "register",
            _ => "fuse",
        };
        *timings.entry(key).or_default() += d.as_secs_f64() * 1e3;
    }
    timings.insert("save", kept_ms + t.elapsed().as_secs_f64() * 1e3);
    let r = Report {
        planes,
        sweep_ms: (ended - started) as f64 * 1e-6,
        timings_ms: timings,
        developed_in_full: fused.developed.as_ref().map(DevelopedReport::from),
        memory: MemoryReport::from(&fused.memory),
        focus_order: fused.order.to_string(),
        orientation: OrientationReport {
            exif: upright.exif(),
            sensor_rotation: rotation,
            hold,
        },
        output: output.display().to_string(),
    };
    if let Some(path) = report {
        let mut json = serde_json::to_vec_pretty(&r).map_err(ServiceError::Report)?;
        json.push(b'\n');
        outs.write(path, &json)?;
    }
    // A cancel that came during the encoding and the writes still wins: nothing lands (the
    // temporary files go with `outs`), and the job ends Failed("cancelled"), not Finished.
    if progress.cancelled() {
        return Err(FuseError::Cancelled.into());
    }
    outs.commit()?;
    Ok(r)
}
