//! Capturing a focus stack: the hardware traits, the motion gate and the sweep.
//!
//! The sweep is written once against [`Camera`], [`Imu`] and [`Clock`]; the V4L2 and IIO
//! backends drive a phone, the replay backends a recorded bundle, so tests run the same
//! sweep-and-reshoot logic the phone runs.

pub mod gate;
pub mod hold;
pub mod preview;
pub mod record;
pub mod sweep;
pub mod trigger;

use crate::develop::RawFrame;
use crate::stack::image::Image;
use serde::{Deserialize, Serialize};

/// Every stage of a capture job: the sweep's, then the engine's. The names are the daemon's
/// `Progress` stages and the CLI's progress text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Waiting until the gyroscope has been still long enough.
    WaitingStill,
    /// Taking the planes.
    Sweeping,
    /// Developing the raw takes, once the lens is done (in a job, the engine's
    /// `stack::Stage::Develop`).
    Developing,
    /// The engine's work on the frames.
    Fuse(crate::stack::Stage),
}

impl Stage {
    pub const fn name(self) -> &'static str {
        match self {
            Stage::WaitingStill => "waiting-still",
            Stage::Sweeping => "sweeping",
            Stage::Developing => "developing",
            Stage::Fuse(s) => s.name(),
        }
    }
}

/// The engine's stages as a job's; its development of raw frames (cheap before the fuse, in
/// full before the compose) is the job's one `Developing` stage.
impl From<crate::stack::Stage> for Stage {
    fn from(s: crate::stack::Stage) -> Self {
        match s {
            crate::stack::Stage::Develop => Stage::Developing,
            s => Stage::Fuse(s),
        }
    }
}

/// Nanoseconds on CLOCK_MONOTONIC: the clock of V4L2 buffer timestamps and of IIO timestamps
/// once `current_timestamp_clock` is set to `monotonic`.
pub type Nanos = i64;

/// Time as the sweep sees it: the real monotonic clock on a phone, simulated time in replay.
pub trait Clock: Send {
    fn now(&self) -> Nanos;
    /// Returns once `now() >= t`.
    fn sleep_until(&self, t: Nanos);
}

/// One captured frame and when it was exposed.
#[derive(Clone, Debug)]
pub struct Take {
    pub frame: Frame,
    pub exposure_start: Nanos,
    pub exposure_end: Nanos,
}

/// A take's pixels: a picture, or a raw mosaic kept as it came, developed once the sweep is
/// done so that the lens never waits for a demosaic.
#[derive(Clone, Debug)]
pub enum Frame {
    Picture(Image<u8>),
    Raw(RawFrame),
}

/// Develops raw frame `i` into a picture; the error says why not.
pub type DevelopOne<'a> = dyn FnMut(usize, &RawFrame) -> Result<Image<u8>, String> + 'a;

/// Pictures from a sweep's frames, in order: raw ones developed by `develop` (called with the
/// frame's index, one call each, each mosaic freed as soon as it is developed), pictures as
/// they are. The raw ones are reported to `monitor` as the `Developing` stage, frame by frame;
/// a cancel between two frames stops the work and frees the mosaics left.
pub fn develop(
    frames: Vec<Frame>,
    monitor: &dyn sweep::Monitor,
    develop: &mut DevelopOne,
) -> Result<Vec<Image<u8>>, CaptureError> {
    let total = frames.iter().filter(|f| matches!(f, Frame::Raw(_))).count();
    let mut done = 0;
    let mut pictures = Vec::with_capacity(frames.len());
    for (i, f) in frames.into_iter().enumerate() {
        pictures.push(match f {
            Frame::Picture(img) => img,
            Frame::Raw(raw) => {
                if monitor.cancelled() {
                    return Err(CaptureError::Cancelled);
                }
                monitor.progress(Stage::Developing, done, total);
                done += 1;
                develop(i, &raw).map_err(|e| CaptureError::device(format!("raw frame {i}"), e))?
            }
        });
    }
    if total > 0 {
        monitor.progress(Stage::Developing, total, total);
    }
    Ok(pictures)
}

/// A camera with a lens that can be moved to an absolute position.
pub trait Camera: Send {
    /// The positions the absolute focus control accepts, inclusive (the dw9714: 0..=1023).
    fn lens_range(&self) -> (i32, i32);
    /// Moves the lens to `position` for focus plane `plane` (0 = nearest) and waits for it to
    /// settle. Replay cameras serve the recorded takes of `plane`.
    fn focus(&mut self, plane: usize, position: i32) -> Result<(), CaptureError>;
    /// The next frame exposed entirely after the last `focus` returned.
    fn capture(&mut self) -> Result<Take, CaptureError>;
    /// The counter-clockwise turn, in degrees, that makes the sensor's pictures upright
    /// (`V4L2_CID_CAMERA_SENSOR_ROTATION`, a bundle's `rotation`); 0 when unknown.
    fn sensor_rotation(&self) -> i64 {
        0
    }
    /// Puts the lens back where it was found and stops streaming. Called on every way out of a
    /// sweep (success, error, cancel); must be safe to call twice.
    fn release(&mut self) -> Result<(), CaptureError>;
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sensor {
    /// Angular velocity, rad/s.
    Gyro,
    /// Acceleration including gravity, m/s².
    Accel,
}

/// One IMU reading in SI units, in the device frame (mount matrix applied).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    pub t: Nanos,
    pub sensor: Sensor,
    pub v: [f64; 3],
}

/// A gyroscope and an accelerometer.
pub trait Imu: Send {
    /// Every sample with `from <= t <= to`, in time order, both sensors. Blocks until samples
    /// up to `to` have arrived; fails if the sensor stops delivering.
    fn samples(&mut self, from: Nanos, to: Nanos) -> Result<Vec<ImuSample>, CaptureError>;
}

/// Why a capture failed. Messages name the device or file and, where there is one, the fix.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A device is missing, refused an operation, or vanished.
    #[error("{device}: {reason}")]
    Device { device: String, reason: String },
    /// The camera has no absolute focus control, so the lens cannot be swept.
    #[error(
        "{device} has no absolute focus control (V4L2_CID_FOCUS_ABSOLUTE){detail}: a manual \
         focus sweep is not possible with this camera"
    )]
    NoFocusControl { device: String, detail: String },
    /// Nothing arrived in time.
    #[error("{what} timed out after {ms} ms")]
    Timeout { what: String, ms: u64 },
    /// The phone never held still long enough to start.
    #[error(
        "the phone did not hold still for {still_ms} ms within {timeout_ms} ms; rest it on \
         something or raise [sweep] still_timeout_ms"
    )]
    NotStill { still_ms: u64, timeout_ms: u64 },
    /// Every take of a plane was shaken and the config says to fail.
    #[error(
        "plane {plane}: all {takes} takes were shaken (worst axis {axis} at {ratio:.1}x its \
         threshold); hold the phone steadier, or set [sweep] on_exhausted = \"keep-least-shaken\""
    )]
    Shaken {
        plane: usize,
        takes: usize,
        axis: String,
        ratio: f64,
    },
    /// A replay bundle is malformed or ran out of takes.
    #[error("{path}: {reason}")]
    Bundle { path: String, reason: String },
    #[error("cancelled")]
    Cancelled,
}

impl CaptureError {
    pub fn device(device: impl Into<String>, reason: impl Into<String>) -> Self {
        CaptureError::Device {
            device: device.into(),
            reason: reason.into(),
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::sweep::Monitor;
    use super::*;
    use crate::develop::{BayerOrder, RawLayout, IDENTITY};
    use std::cell::{Cell, RefCell};

    /// Records the progress reported and cancels once `cancel_at` frames were developed.
    struct Watch {
        seen: RefCell<Vec<(Stage, usize, usize)>>,
        developed: Cell<usize>,
        cancel_at: usize,
    }

    impl Monitor for Watch {
        fn progress(&self, stage: Stage, done: usize, total: usize) {
            self.seen.borrow_mut().push((stage, done, total));
        }
        fn cancelled(&self) -> bool {
            self.developed.get() >= self.cancel_at
        }
    }

    /// A 4×4 RGGB mosaic of grey.
    pub(crate) fn raw_frame() -> RawFrame {
        let layout = RawLayout {
            packing: crate::develop::raw::Packing::Bits8,
            width: 4,
            height: 4,
            stride: 0,
            order: BayerOrder::Rggb,
            black_level: 0,
            matrix: IDENTITY,
        };
        RawFrame::copy(&[90; 16], layout).expect("raw")
    }

    fn raw() -> Frame {
        Frame::Raw(raw_frame())
    }

    #[test]
    fn raw_frames_are_reported_one_by_one_and_a_cancel_stops_between_two() {
        let watch = Watch {
            seen: RefCell::default(),
            developed: Cell::new(0),
            cancel_at: usize::MAX,
        };
        let mut stack = crate::develop::StackDeveloper::default();
        let mut one = |_: usize, r: &RawFrame| {
            watch.developed.set(watch.developed.get() + 1);
            stack.develop(r)
        };
        let frames = vec![raw(), raw(), raw()];
        assert_eq!(develop(frames, &watch, &mut one).unwrap().len(), 3);
        let developing = |n| {
            (0..=n)
                .map(|i| (Stage::Developing, i, n))
                .collect::<Vec<_>>()
        };
        assert_eq!(*watch.seen.borrow(), developing(3));

        // Cancelled once two are developed: the third is never started.
        let watch = Watch {
            seen: RefCell::default(),
            developed: Cell::new(0),
            cancel_at: 2,
        };
        let mut calls = 0;
        let mut stack = crate::develop::StackDeveloper::default();
        let e = develop(vec![raw(), raw(), raw(), raw()], &watch, &mut |_, r| {
            calls += 1;
            watch.developed.set(calls);
            stack.develop(r)
        })
        .unwrap_err();
        assert!(matches!(e, CaptureError::Cancelled), "{e}");
        assert_eq!(calls, 2);
        assert_eq!(watch.seen.borrow().len(), 2);

        // Pictures are no development: no stage reported.
        let watch = Watch {
            seen: RefCell::default(),
            developed: Cell::new(0),
            cancel_at: 0,
        };
        let picture = Frame::Picture(Image::from_fn(4, 4, 3, |_, _, _| 7u8));
        let out = develop(vec![picture], &watch, &mut |_, _| unreachable!()).unwrap();
        assert_eq!(out.len(), 1);
        assert!(watch.seen.borrow().is_empty());
    }
}
