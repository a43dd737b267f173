//! Faults injected into a replay, so that the service's failure paths (a camera that vanishes,
//! a frame that never comes, an IMU that stops or reads garbage) run end to end in tests,
//! exactly where a phone would hit them: at a given plane of the sweep, or at a frame of the
//! development after it.

use crate::capture::{Camera, CaptureError, Imu, ImuSample, Nanos, Take};
use crate::stack::image::Image;
use crate::stack::{Develop, Piece, Progress, Rect};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// Moving the lens to this plane fails as an unplugged device does (ENODEV).
    CameraGone(usize),
    /// No frame arrives at this plane.
    FrameTimeout(usize),
    /// The IMU stops delivering once the sweep reaches this plane.
    ImuStops(usize),
    /// From this plane on, the IMU reads NaN.
    ImuNan(usize),
    /// Moving the lens to this plane panics, as a bug would.
    Panic(usize),
    /// Developing this raw frame (its cheap development, the first the job does of it) waits
    /// until the job is cancelled: a job held in the `developing` stage, for tests of what a
    /// client sees and may do then.
    DevelopHold(usize),
}

impl std::str::FromStr for Fault {
    type Err = String;

    /// `camera-gone:P`, `frame-timeout:P`, `imu-stops:P`, `imu-nan:P`, `panic:P` or
    /// `develop-hold:P`, P a plane index.
    fn from_str(s: &str) -> Result<Fault, String> {
        let usage = "expected camera-gone:P, frame-timeout:P, imu-stops:P, imu-nan:P, panic:P \
                     or develop-hold:P";
        let (kind, plane) = s
            .split_once(':')
            .ok_or_else(|| format!("fault {s:?}: {usage}"))?;
        let p: usize = plane
            .parse()
            .map_err(|_| format!("fault {s:?}: plane {plane:?} is not a plane index"))?;
        Ok(match kind {
            "camera-gone" => Fault::CameraGone(p),
            "frame-timeout" => Fault::FrameTimeout(p),
            "imu-stops" => Fault::ImuStops(p),
            "imu-nan" => Fault::ImuNan(p),
            "panic" => Fault::Panic(p),
            "develop-hold" => Fault::DevelopHold(p),
            _ => return Err(format!("fault {s:?}: {usage}")),
        })
    }
}

/// A raw stack whose development of frame `i` waits where `faults` say so
/// ([`Fault::DevelopHold`]): until `progress` says the job is cancelled, asking every few
/// milliseconds (which also beats its heartbeat).
pub struct HeldDevelopment<'a, T> {
    pub stack: &'a dyn Develop<T>,
    pub faults: &'a [Fault],
    pub progress: &'a dyn Progress,
}

impl<T> Develop<T> for HeldDevelopment<'_, T> {
    fn frames(&self) -> usize {
        self.stack.frames()
    }

    fn cheap(&self, i: usize) -> Result<Image<T>, String> {
        if self.faults.contains(&Fault::DevelopHold(i)) {
            while !self.progress.cancelled() {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
        }
        self.stack.cheap(i)
    }

    fn full(&self, asked: &[(usize, &[Rect])]) -> Result<Vec<Vec<Piece<T>>>, (usize, String)> {
        self.stack.full(asked)
    }

    fn held_bytes(&self) -> usize {
        self.stack.held_bytes()
    }

    fn working_bytes(&self) -> usize {
        self.stack.working_bytes()
    }
}

/// The plane the sweep is at, shared by the faulty camera (which sets it) and IMU.
const NO_PLANE: usize = usize::MAX;

pub struct FaultyCamera<C> {
    inner: C,
    faults: Vec<Fault>,
    plane: Arc<AtomicUsize>,
}

pub struct FaultyImu<I> {
    inner: I,
    faults: Vec<Fault>,
    plane: Arc<AtomicUsize>,
}

/// Wraps a replay's camera and IMU with `faults`.
pub fn inject<C: Camera, I: Imu>(
    camera: C,
    imu: I,
    faults: &[Fault],
) -> (FaultyCamera<C>, FaultyImu<I>) {
    let plane = Arc::new(AtomicUsize::new(NO_PLANE));
    (
        FaultyCamera {
            inner: camera,
            faults: faults.to_vec(),
            plane: plane.clone(),
        },
        FaultyImu {
            inner: imu,
            faults: faults.to_vec(),
            plane,
        },
    )
}

impl<C: Camera> Camera for FaultyCamera<C> {
    fn lens_range(&self) -> (i32, i32) {
        self.inner.lens_range()
    }

    fn focus(&mut self, plane: usize, position: i32) -> Result<(), CaptureError> {
        if self.faults.contains(&Fault::Panic(plane)) {
            panic!("injected fault at plane {plane}");
        }
        if self.faults.contains(&Fault::CameraGone(plane)) {
            return Err(CaptureError::device(
                "replay camera",
                "No such device (os error 19): the camera vanished (injected fault)",
            ));
        }
        self.inner.focus(plane, position)?;
        self.plane.store(plane, Ordering::SeqCst);
        Ok(())
    }

    fn capture(&mut self) -> Result<Take, CaptureError> {
        let plane = self.plane.load(Ordering::SeqCst);
        if self.faults.contains(&Fault::FrameTimeout(plane)) {
            return Err(CaptureError::Timeout {
                what: format!("waiting for a frame of plane {plane} from the replay camera"),
                ms: 2000,
            });
        }
        self.inner.capture()
    }

    fn release(&mut self) -> Result<(), CaptureError> {
        self.inner.release()
    }
}

impl<I: Imu> Imu for FaultyImu<I> {
    fn samples(&mut self, from: Nanos, to: Nanos) -> Result<Vec<ImuSample>, CaptureError> {
        let plane = self.plane.load(Ordering::SeqCst);
        let reached = |p: usize| plane != NO_PLANE && plane >= p;
        let mut samples = self.inner.samples(from, to)?;
        for f in &self.faults {
            match *f {
                Fault::ImuStops(p) if reached(p) => {
                    return Err(CaptureError::device(
                        "replay IMU",
                        format!("no samples after {from} ns: the sensor stopped delivering (injected fault)"),
                    ))
                }
                Fault::ImuNan(p) if reached(p) => {
                    for s in &mut samples {
                        s.v = [f64::NAN; 3];
                    }
                }
                _ => {}
            }
        }
        Ok(samples)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_and_bad_ones_say_why() {
        assert_eq!("camera-gone:2".parse(), Ok(Fault::CameraGone(2)));
        assert_eq!("imu-nan:0".parse(), Ok(Fault::ImuNan(0)));
        assert_eq!("develop-hold:3".parse(), Ok(Fault::DevelopHold(3)));
        assert!("imu-nan"
            .parse::<Fault>()
            .unwrap_err()
            .contains("expected camera-gone:P"));
        assert!("imu-nan:x"
            .parse::<Fault>()
            .unwrap_err()
            .contains("not a plane index"));
        assert!("disk-full:1"
            .parse::<Fault>()
            .unwrap_err()
            .contains("expected"));
    }
}
