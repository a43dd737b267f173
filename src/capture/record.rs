//! Recording a sweep: a camera that keeps a copy of every take it hands out, so `focusd
//! record` can write the whole sweep, rejected takes included, as a replay bundle.

use super::{Camera, CaptureError, Nanos, Take};
use crate::develop::RawFrame;
use crate::files::dng::{self, DngInfo};
use crate::files::orientation::Orientation;
use crate::files::FileError;

/// One recorded take: its plane, lens position and frame.
pub struct Recorded {
    pub plane: usize,
    pub lens: i32,
    pub take: Take,
}

/// Wraps a camera and records what passes through it.
pub struct Recording<'a> {
    inner: &'a mut dyn Camera,
    at: Option<(usize, i32)>,
    pub takes: Vec<Recorded>,
}

impl<'a> Recording<'a> {
    pub fn new(inner: &'a mut dyn Camera) -> Self {
        Self {
            inner,
            at: None,
            takes: Vec::new(),
        }
    }
}

impl Camera for Recording<'_> {
    fn lens_range(&self) -> (i32, i32) {
        self.inner.lens_range()
    }

    fn focus(&mut self, plane: usize, position: i32) -> Result<(), CaptureError> {
        self.inner.focus(plane, position)?;
        self.at = Some((plane, position));
        Ok(())
    }

    fn capture(&mut self) -> Result<Take, CaptureError> {
        let take = self.inner.capture()?;
        if let Some((plane, lens)) = self.at {
            self.takes.push(Recorded {
                plane,
                lens,
                take: take.clone(),
            });
        }
        Ok(take)
    }

    fn sensor_rotation(&self) -> i64 {
        self.inner.sensor_rotation()
    }

    fn release(&mut self) -> Result<(), CaptureError> {
        self.inner.release()
    }
}

/// The DNG of a raw take as focusd keeps it (`focusd record`, `[output] keep_raw`): the
/// exposure's length from its start and end, the time now, the camera `model`, and the turn
/// that makes the picture upright.
pub fn take_dng(
    raw: &RawFrame,
    exposure: (Nanos, Nanos),
    model: &str,
    orientation: Orientation,
) -> Result<Vec<u8>, FileError> {
    let taken = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .ok()
        .map(|d| d.as_secs());
    let info = DngInfo {
        orientation,
        model: model.into(),
        exposure: u64::try_from(exposure.1 - exposure.0)
            .ok()
            .map(std::time::Duration::from_nanos),
        taken,
        ..DngInfo::default()
    };
    dng::encode(raw, &info)
}
