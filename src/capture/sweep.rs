//! The focus sweep: wait for stillness, then visit the planes from nearest to farthest,
//! reshooting every take the motion gate rejects.

use super::gate::{measure, Motion, Rest, Thresholds};
use super::hold::{Hold, HoldTracker};
use super::{Camera, CaptureError, Clock, Imu, Nanos, Sensor, Stage, Take};
use crate::base::setting::{Bounds, Invalid};
use crate::develop::StackDeveloper;
use crate::stack::image::Image;
use serde::{Deserialize, Serialize};

/// What to do when every take of a plane was shaken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnExhausted {
    /// Fail the capture with an error naming the plane.
    Fail,
    /// Keep the least shaken take and mark it in the report.
    KeepLeastShaken,
}

/// The sweep's settings (the `[sweep]` table of the config).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SweepConfig {
    /// Focus planes, nearest first.
    pub planes: usize,
    /// Lens positions of the nearest and the farthest plane; `None`: the ends of the lens
    /// range, nearest at the top (a voice-coil lens focuses nearer the more current it gets).
    pub lens_near: Option<i32>,
    pub lens_far: Option<i32>,
    /// How long the gyroscope must be still before the sweep starts, and how long to wait for
    /// that at most.
    pub still_ms: u64,
    pub still_timeout_ms: u64,
    /// RMS angular rate (rad/s, per axis, about its mean) below which the phone counts as still.
    pub still_gyro_rms: f64,
    pub thresholds: Thresholds,
    /// Extra takes of a plane after a rejected one.
    pub max_reshoots: usize,
    pub on_exhausted: OnExhausted,
    /// Focal length in pixels, for the blur estimate (PinePhone Pro: ≈ 2100).
    pub focal_px: f64,
}

impl Default for SweepConfig {
    fn default() -> Self {
        Self {
            planes: 6,
            lens_near: None,
            lens_far: None,
            still_ms: 300,
            still_timeout_ms: 5000,
            still_gyro_rms: 0.02,
            thresholds: Thresholds::default(),
            max_reshoots: 2,
            on_exhausted: OnExhausted::Fail,
            focal_px: 2100.0,
        }
    }
}

impl SweepConfig {
    /// Lens position of each plane, nearest first, evenly spaced.
    pub fn positions(&self, range: (i32, i32)) -> Vec<i32> {
        let near = self.lens_near.unwrap_or(range.1) as f64;
        let far = self.lens_far.unwrap_or(range.0) as f64;
        let n = self.planes.max(1);
        (0..n)
            .map(|i| {
                let t = if n == 1 {
                    0.0
                } else {
                    i as f64 / (n - 1) as f64
                };
                (near + (far - near) * t).round() as i32
            })
            .collect()
    }

    /// Checks the values a sweep cannot run with; the message names the key and the range.
    pub fn validate(&self, range: (i32, i32)) -> Result<(), Invalid> {
        Bounds::new(2, 64).check("planes", self.planes)?;
        // Long enough to hold the two gyroscope readings a stillness test needs at the IMU
        // rates of phones (100 Hz and up; 0 could never be still), short enough that its
        // nanoseconds cannot overflow.
        Bounds::new(20, 10_000).check("still_ms", self.still_ms)?;
        Bounds::new(self.still_ms, 600_000).check("still_timeout_ms", self.still_timeout_ms)?;
        for (key, v) in [("lens_near", self.lens_near), ("lens_far", self.lens_far)] {
            if let Some(v) = v.filter(|v| !(range.0..=range.1).contains(v)) {
                return Err(Invalid::new(
                    key,
                    format!(
                        "{key} = {v} is outside the lens range {}..={}",
                        range.0, range.1
                    ),
                ));
            }
        }
        // Wide enough for any phone's sensors and lenses, narrow enough that the products and
        // sums the gate and the blur estimate form stay finite.
        Bounds::new(1e-9, 10.0).check("thresholds.gyro", self.thresholds.gyro)?;
        Bounds::new(1e-6, 1e3).check("thresholds.accel", self.thresholds.accel)?;
        Bounds::new(1e-4, 10.0).check("still_gyro_rms", self.still_gyro_rms)?;
        Bounds::new(10.0, 100_000.0).check("focal_px", self.focal_px)?;
        Bounds::new(0, 20).check("max_reshoots", self.max_reshoots)
    }
}

/// One take of a plane and its verdict.
#[derive(Clone, Debug, Serialize)]
pub struct TakeReport {
    pub take: usize,
    pub exposure_start_ns: Nanos,
    pub exposure_end_ns: Nanos,
    pub gyro_sum: [f64; 3],
    pub accel_sum: [f64; 3],
    pub blur_px: f64,
    pub accepted: bool,
    /// Kept although shaken: the retries ran out and the config said to keep the least shaken.
    pub kept_shaken: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct PlaneReport {
    pub plane: usize,
    pub lens: i32,
    pub takes: Vec<TakeReport>,
}

/// The sweep's result: one picture per plane, nearest first, and what happened.
pub struct Sweep {
    pub frames: Vec<Image<u8>>,
    pub planes: Vec<PlaneReport>,
    /// Which way the phone was held while it was found still.
    pub hold: Hold,
    /// When the phone was found still, and when the sweep ended.
    pub started: Nanos,
    pub ended: Nanos,
}

/// Reports the sweep's progress and asks whether to go on.
pub trait Monitor {
    /// Steps done of `total` (planes, or raw frames developed), and the stage (`WaitingStill`,
    /// `Sweeping`, `Developing`).
    fn progress(&self, stage: Stage, done: usize, total: usize);
    fn cancelled(&self) -> bool;
}

/// Reports nothing, never cancels.
pub struct Unmonitored;

impl Monitor for Unmonitored {
    fn progress(&self, _: Stage, _: usize, _: usize) {}
    fn cancelled(&self) -> bool {
        false
    }
}

/// Runs a sweep. The camera is released on every way out, and its release error is reported
/// only when the sweep itself succeeded. Raw takes are developed after the release, with one
/// white balance for the stack.
pub fn sweep(
    camera: &mut dyn Camera,
    imu: &mut dyn Imu,
    clock: &dyn Clock,
    cfg: &SweepConfig,
    monitor: &dyn Monitor,
) -> Result<Sweep, CaptureError> {
    let (takes, sweep) = sweep_takes(camera, imu, clock, cfg, monitor)?;
    let mut stack = StackDeveloper::default();
    let frames = takes.into_iter().map(|t| t.frame).collect();
    let frames = super::develop(frames, monitor, &mut |_, raw| stack.develop(raw))?;
    Ok(Sweep { frames, ..sweep })
}

/// [`sweep`] without the development: the chosen take of each plane as it came (raw ones
/// still mosaics), and the sweep's report with no frames.
pub fn sweep_takes(
    camera: &mut dyn Camera,
    imu: &mut dyn Imu,
    clock: &dyn Clock,
    cfg: &SweepConfig,
    monitor: &dyn Monitor,
) -> Result<(Vec<Take>, Sweep), CaptureError> {
    let result = run(camera, imu, clock, cfg, monitor);
    let released = camera.release();
    let (takes, sweep) = result?;
    released?;
    Ok((takes, sweep))
}

fn run(
    camera: &mut dyn Camera,
    imu: &mut dyn Imu,
    clock: &dyn Clock,
    cfg: &SweepConfig,
    monitor: &dyn Monitor,
) -> Result<(Vec<Take>, Sweep), CaptureError> {
    let range = camera.lens_range();
    cfg.validate(range)
        .map_err(|e| CaptureError::device("sweep config", e.to_string()))?;
    monitor.progress(Stage::WaitingStill, 0, cfg.planes);
    let (rest, started, hold) = wait_still(imu, clock, cfg, monitor)?;
    let mut frames = Vec::with_capacity(cfg.planes);
    let mut planes = Vec::with_capacity(cfg.planes);
    for (plane, lens) in cfg.positions(range).into_iter().enumerate() {
        monitor.progress(Stage::Sweeping, plane, cfg.planes);
        camera.focus(plane, lens)?;
        let mut report = PlaneReport {
            plane,
            lens,
            takes: Vec::new(),
        };
        let mut tried: Vec<(Take, Motion)> = Vec::new();
        let mut chosen = None;
        for take in 0..=cfg.max_reshoots {
            if monitor.cancelled() {
                return Err(CaptureError::Cancelled);
            }
            let t = camera.capture()?;
            let window = (t.exposure_start, t.exposure_end);
            let samples = imu.samples(window.0, window.1)?;
            let m = measure(&samples, window, &rest, &cfg.thresholds, cfg.focal_px)?;
            report.takes.push(take_report(take, &t, &m));
            tried.push((t, m));
            if m.accepted() {
                chosen = Some(take);
                break;
            }
        }
        let chosen = match (chosen, cfg.on_exhausted) {
            (Some(k), _) => k,
            (None, OnExhausted::KeepLeastShaken) => {
                let k = (0..tried.len())
                    .min_by(|&a, &b| tried[a].1.worst_ratio.total_cmp(&tried[b].1.worst_ratio))
                    .expect("at least one take");
                report.takes[k].kept_shaken = true;
                k
            }
            (None, OnExhausted::Fail) => {
                let least = tried
                    .iter()
                    .map(|(_, m)| m)
                    .min_by(|a, b| a.worst_ratio.total_cmp(&b.worst_ratio))
                    .expect("at least one take");
                return Err(CaptureError::Shaken {
                    plane,
                    takes: tried.len(),
                    axis: least.worst_axis.to_string(),
                    ratio: least.worst_ratio,
                });
            }
        };
        frames.push(tried.swap_remove(chosen).0);
        planes.push(report);
    }
    monitor.progress(Stage::Sweeping, cfg.planes, cfg.planes);
    let sweep = Sweep {
        frames: Vec::new(),
        planes,
        hold,
        started,
        ended: clock.now(),
    };
    Ok((frames, sweep))
}

fn take_report(take: usize, t: &Take, m: &Motion) -> TakeReport {
    TakeReport {
        take,
        exposure_start_ns: t.exposure_start,
        exposure_end_ns: t.exposure_end,
        gyro_sum: m.gyro_sum,
        accel_sum: m.accel_sum,
        blur_px: m.blur_px,
        accepted: m.accepted(),
        kept_shaken: false,
    }
}

/// Waits until the gyroscope has been still for `still_ms`, stepping a quarter of that at a
/// time; returns what rest looks like then, when, and the hold (each window's gravity seen).
fn wait_still(
    imu: &mut dyn Imu,
    clock: &dyn Clock,
    cfg: &SweepConfig,
    monitor: &dyn Monitor,
) -> Result<(Rest, Nanos, Hold), CaptureError> {
    let span = cfg.still_ms as Nanos * 1_000_000;
    let step = (span / 4).max(1_000_000);
    let begin = clock.now();
    let mut end = begin + span;
    let mut hold = HoldTracker::default();
    loop {
        if monitor.cancelled() {
            return Err(CaptureError::Cancelled);
        }
        clock.sleep_until(end);
        let samples = imu.samples(end - span, end)?;
        let rest = Rest::from_samples(&samples);
        if let Some(r) = &rest {
            hold.see(r.gravity);
        }
        if let Some(rest) = rest.filter(|_| is_still(&samples, cfg.still_gyro_rms)) {
            return Ok((rest, end, hold.hold()));
        }
        if end - begin >= cfg.still_timeout_ms as Nanos * 1_000_000 {
            return Err(CaptureError::NotStill {
                still_ms: cfg.still_ms,
                timeout_ms: cfg.still_timeout_ms,
            });
        }
        end += step;
    }
}

/// Whether the gyroscope's readings stay within `rms` of their mean on every axis (a constant
/// offset is bias, not motion).
fn is_still(samples: &[super::ImuSample], rms: f64) -> bool {
    let gyro: Vec<[f64; 3]> = samples
        .iter()
        .filter(|s| s.sensor == Sensor::Gyro)
        .map(|s| s.v)
        .collect();
    if gyro.len() < 2 {
        return false;
    }
    let n = gyro.len() as f64;
    (0..3).all(|a| {
        let mean = gyro.iter().map(|v| v[a]).sum::<f64>() / n;
        let var = gyro.iter().map(|v| (v[a] - mean).powi(2)).sum::<f64>() / n;
        var.is_finite() && var.sqrt() <= rms
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::{Frame, ImuSample};
    use std::sync::{Arc, Mutex};

    /// What happened, in order: lens moves, takes and developments.
    type Log = Arc<Mutex<Vec<&'static str>>>;

    /// A camera handing out raw takes, logging each move and take.
    struct RawCamera {
        log: Log,
        t: Nanos,
    }

    impl Camera for RawCamera {
        fn lens_range(&self) -> (i32, i32) {
            (0, 1023)
        }
        fn focus(&mut self, _plane: usize, _position: i32) -> Result<(), CaptureError> {
            self.log.lock().expect("log").push("move");
            Ok(())
        }
        fn capture(&mut self) -> Result<Take, CaptureError> {
            self.log.lock().expect("log").push("take");
            self.t += 40_000_000;
            let raw = crate::capture::tests::raw_frame();
            Ok(Take {
                frame: Frame::Raw(raw),
                exposure_start: self.t,
                exposure_end: self.t + 10_000_000,
            })
        }
        fn release(&mut self) -> Result<(), CaptureError> {
            Ok(())
        }
    }

    /// A phone at rest: gyro 0, gravity along y, a sample a millisecond.
    struct Resting;

    impl Imu for Resting {
        fn samples(&mut self, from: Nanos, to: Nanos) -> Result<Vec<ImuSample>, CaptureError> {
            let ms = 1_000_000;
            Ok((from / ms..=to / ms)
                .flat_map(|i| {
                    [
                        ImuSample {
                            t: i * ms,
                            sensor: Sensor::Gyro,
                            v: [0.0; 3],
                        },
                        ImuSample {
                            t: i * ms,
                            sensor: Sensor::Accel,
                            v: [0.0, 9.81, 0.0],
                        },
                    ]
                })
                .filter(|s| (from..=to).contains(&s.t))
                .collect())
        }
    }

    /// Logs each raw frame the development starts.
    struct Logging(Log);

    impl Monitor for Logging {
        fn progress(&self, stage: Stage, done: usize, total: usize) {
            if stage == Stage::Developing && done < total {
                self.0.lock().expect("log").push("develop");
            }
        }
        fn cancelled(&self) -> bool {
            false
        }
    }

    struct Frozen(std::sync::atomic::AtomicI64);

    impl Clock for Frozen {
        fn now(&self) -> Nanos {
            self.0.load(std::sync::atomic::Ordering::SeqCst)
        }
        fn sleep_until(&self, t: Nanos) {
            self.0.fetch_max(t, std::sync::atomic::Ordering::SeqCst);
        }
    }

    #[test]
    fn raw_takes_are_developed_after_the_last_move_not_between_planes() {
        let log: Log = Arc::default();
        let mut camera = RawCamera {
            log: log.clone(),
            t: 1_000_000_000,
        };
        let clock = Frozen(1_000_000_000.into());
        let cfg = SweepConfig {
            planes: 4,
            ..SweepConfig::default()
        };
        let s = sweep(
            &mut camera,
            &mut Resting,
            &clock,
            &cfg,
            &Logging(log.clone()),
        )
        .expect("sweeps");
        assert_eq!(s.frames.len(), 4);
        assert_eq!((s.frames[0].width(), s.frames[0].channels()), (4, 3));
        let log = log.lock().expect("log").clone();
        let last_move = log.iter().rposition(|&e| e == "move").expect("moves");
        let first_develop = log.iter().position(|&e| e == "develop").expect("develops");
        assert!(first_develop > last_move, "{log:?}");
        // Between any two moves: takes only.
        assert_eq!(
            log,
            ["move", "take", "move", "take", "move", "take", "move", "take"]
                .into_iter()
                .chain(["develop"; 4])
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_stack_of_held_13_mp_mosaics_fits_the_default_budget() {
        // Ten 4208x3120 takes held until the sweep ends, at 10 bits in 16-bit words (the
        // largest packing a phone profile captures) and at 8 bits.
        let frame = |packing| {
            crate::develop::raw::layout(packing, 4208, 3120, 0, usize::MAX)
                .expect("layout")
                .1
        };
        let ten = 10 * frame(crate::develop::raw::Packing::Le10);
        let eight = 10 * frame(crate::develop::raw::Packing::Bits8);
        assert_eq!((ten, eight), (262_579_200, 131_289_600));
        assert!(ten < crate::stack::DEFAULT_BUDGET, "{ten}");
        // While developing, the mosaics not yet developed and the pictures made so far are
        // held together: at most all of both. At the 8 bits both phone profiles capture, that
        // is within the budget too.
        let pictures = 10 * 4208 * 3120 * 3;
        assert!(
            eight + pictures < crate::stack::DEFAULT_BUDGET,
            "{}",
            eight + pictures
        );
    }
}
