//! Replay of a recorded bundle: takes and an IMU trace, on simulated time.
//!
//! The camera serves, for the plane asked for, that plane's next unused take, so a reshoot gets
//! the next take; the IMU serves the trace; the clock jumps to whatever the sweep waits for.
//! Replays are therefore fast and deterministic, and run the sweep's real logic.

pub mod bundle;
pub mod faults;
pub mod preview;
mod take;

use crate::capture::{Camera, CaptureError, Clock, Imu, ImuSample, Nanos, Take};
pub use bundle::{Bundle, BundleError, BundleWriteError, BundleWriter};
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;

/// Simulated monotonic time shared by a replay camera and IMU.
#[derive(Debug, Default)]
pub struct SimClock {
    now: AtomicI64,
    /// Also wait out every step in real time, so a replay takes as long as the sweep it
    /// recorded (for exercising a service's progress, busy and cancel paths).
    paced: bool,
}

impl SimClock {
    pub fn starting_at(t: Nanos, paced: bool) -> Arc<SimClock> {
        Arc::new(SimClock {
            now: AtomicI64::new(t),
            paced,
        })
    }

    fn advance_to(&self, t: Nanos) {
        let before = self.now.fetch_max(t, Ordering::SeqCst);
        if self.paced && t > before {
            std::thread::sleep(std::time::Duration::from_nanos((t - before) as u64));
        }
    }
}

impl Clock for Arc<SimClock> {
    fn now(&self) -> Nanos {
        self.now.load(Ordering::SeqCst)
    }

    fn sleep_until(&self, t: Nanos) {
        self.advance_to(t);
    }
}

/// The camera, the IMU and the clock of one bundle; the clock starts at the trace's first
/// sample.
pub fn open(bundle: Bundle) -> (ReplayCamera, ReplayImu, Arc<SimClock>) {
    open_paced(bundle, false)
}

/// [`open`], with the clock also waiting in real time when `paced`.
pub fn open_paced(bundle: Bundle, paced: bool) -> (ReplayCamera, ReplayImu, Arc<SimClock>) {
    let bundle = Arc::new(bundle);
    let clock = SimClock::starting_at(bundle.imu.first().map_or(0, |s| s.t), paced);
    let camera = ReplayCamera {
        next: vec![0; bundle.planes()],
        bundle: bundle.clone(),
        clock: clock.clone(),
        plane: None,
    };
    let imu = ReplayImu {
        bundle,
        clock: clock.clone(),
    };
    (camera, imu, clock)
}

pub struct ReplayCamera {
    bundle: Arc<Bundle>,
    clock: Arc<SimClock>,
    plane: Option<usize>,
    /// Per plane, how many of its takes have been served.
    next: Vec<usize>,
}

impl ReplayCamera {
    fn bundle_error(&self, reason: String) -> CaptureError {
        CaptureError::Bundle {
            path: self.bundle.dir.display().to_string(),
            reason,
        }
    }
}

impl Camera for ReplayCamera {
    fn lens_range(&self) -> (i32, i32) {
        (self.bundle.manifest.lens_min, self.bundle.manifest.lens_max)
    }

    fn sensor_rotation(&self) -> i64 {
        self.bundle.manifest.rotation
    }

    fn focus(&mut self, plane: usize, _position: i32) -> Result<(), CaptureError> {
        if plane >= self.next.len() {
            return Err(self.bundle_error(format!(
                "the sweep asks for plane {plane}, the bundle has {} planes; set [sweep] planes \
                 to match",
                self.next.len()
            )));
        }
        self.plane = Some(plane);
        Ok(())
    }

    fn capture(&mut self) -> Result<Take, CaptureError> {
        let plane = self
            .plane
            .ok_or_else(|| self.bundle_error("capture before any focus".into()))?;
        let k = self.next[plane];
        let Some(entry) = self
            .bundle
            .manifest
            .takes
            .iter()
            .filter(|t| t.plane == plane)
            .nth(k)
        else {
            return Err(self.bundle_error(format!(
                "plane {plane} has no more takes ({k} recorded, all used)"
            )));
        };
        self.next[plane] += 1;
        let bundle_error = |e: String| CaptureError::Bundle {
            path: self.bundle.dir.join("bundle.toml").display().to_string(),
            reason: format!("take {k} of plane {plane}: {e}"),
        };
        // The errors name the file already.
        let path = self
            .bundle
            .file(&entry.image)
            .map_err(|e| bundle_error(e.to_string()))?;
        let frame = take::load(&path).map_err(bundle_error)?;
        let now = self.clock.now();
        if entry.exposure_start_ns < now {
            tracing::warn!(
                "take {k} of plane {plane} ({}) was exposed from {} ns, before the replay's \
                 clock ({now} ns: the still wait, the lens settling or an earlier take); its \
                 motion is read from the trace as recorded",
                entry.image,
                entry.exposure_start_ns
            );
        }
        self.clock.advance_to(entry.exposure_end_ns);
        Ok(Take {
            frame,
            exposure_start: entry.exposure_start_ns,
            exposure_end: entry.exposure_end_ns,
        })
    }

    fn release(&mut self) -> Result<(), CaptureError> {
        if self.plane.take().is_some() {
            tracing::info!("replay camera released, lens back at its start position");
        }
        Ok(())
    }
}

pub struct ReplayImu {
    bundle: Arc<Bundle>,
    clock: Arc<SimClock>,
}

impl Imu for ReplayImu {
    fn samples(&mut self, from: Nanos, to: Nanos) -> Result<Vec<ImuSample>, CaptureError> {
        let trace = &self.bundle.imu;
        let end = trace.last().map_or(Nanos::MIN, |s| s.t);
        if to > end {
            return Err(CaptureError::device(
                "replay IMU",
                format!(
                    "the trace in {} ends at {end} ns, before {to} ns: the sensor stopped \
                     delivering",
                    self.bundle.dir.join("imu.csv").display()
                ),
            ));
        }
        self.clock.advance_to(to);
        let lo = trace.partition_point(|s| s.t < from);
        let hi = trace.partition_point(|s| s.t <= to);
        Ok(trace[lo..hi].to_vec())
    }
}
