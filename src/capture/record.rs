//! Recording a sweep: a camera that keeps a copy of every take it hands out, so `focusd
//! record` can write the whole sweep, rejected takes included, as a replay bundle.

use super::{Camera, CaptureError, Take};

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
