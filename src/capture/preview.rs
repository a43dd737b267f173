//! The live preview's frames: the trait a preview reads from, the size a preview frame may
//! have, and the source that previews any [`Camera`] (the phone's, between captures).
//!
//! Preview frames are upright for the phone held in portrait: turned by the sensor's rotation
//! as a capture's picture is (a capture adds the hold's turn, which a viewfinder on a screen
//! that turns with the phone does not need).

use super::{Camera, CaptureError, Frame};
use crate::develop::StackDeveloper;
use crate::files::orientation::Orientation;
use crate::stack::image::Image;

/// The widest preview frame, in pixels.
pub const MAX_WIDTH: usize = 640;
/// The tallest preview frame (a 2:3 portrait frame at full width).
pub const MAX_HEIGHT: usize = 960;
/// Preview frames a second.
pub const FPS: u32 = 15;

/// Where preview frames come from. Each call returns the next frame, RGB with 8 bits a
/// channel and at most [`MAX_WIDTH`] × [`MAX_HEIGHT`] pixels; pacing is the caller's.
/// Dropping the source releases the camera.
pub trait FrameSource: Send {
    fn next_frame(&mut self) -> Result<&Image<u8>, CaptureError>;
}

/// `image` shrunk by the smallest whole factor that fits it, once turned `upright`, in the
/// preview's size (averaging each block of pixels: a whole factor keeps the pixels square and
/// the work a single pass), then turned.
pub fn fit(image: &Image<u8>, upright: Orientation) -> Image<u8> {
    let (w, h) = if upright.quarter_turns() % 2 == 1 {
        (image.height(), image.width())
    } else {
        (image.width(), image.height())
    };
    let factor = w.div_ceil(MAX_WIDTH).max(h.div_ceil(MAX_HEIGHT));
    let shrunk = if factor <= 1 {
        image.clone()
    } else {
        crate::stack::blur::downsample_area(image, factor)
    };
    if upright == Orientation::UPRIGHT {
        shrunk
    } else {
        upright.turn(&shrunk)
    }
}

/// The turn a sensor's frames need (its `V4L2_CID_CAMERA_SENSOR_ROTATION`, a bundle's
/// `rotation`).
pub fn upright(sensor_rotation: i64) -> Result<Orientation, CaptureError> {
    Orientation::from_sensor_rotation(sensor_rotation)
        .map_err(|e| CaptureError::device("camera", e))
}

/// A camera's stream, shrunk and upright: the preview of a phone's camera. The lens stays
/// where it is.
pub struct CameraPreview<C: Camera> {
    camera: C,
    upright: Orientation,
    frame: Image<u8>,
    /// Raw frames get the cheap half-size development, one white balance for the stream.
    developer: StackDeveloper,
}

impl<C: Camera> CameraPreview<C> {
    pub fn new(camera: C) -> Result<Self, CaptureError> {
        Ok(Self {
            upright: upright(camera.sensor_rotation())?,
            camera,
            frame: Image::new(0, 0, 3),
            developer: StackDeveloper::default(),
        })
    }
}

impl<C: Camera> FrameSource for CameraPreview<C> {
    fn next_frame(&mut self) -> Result<&Image<u8>, CaptureError> {
        let picture = match self.camera.capture()?.frame {
            Frame::Picture(picture) => picture,
            Frame::Raw(raw) => self
                .developer
                .develop_half(&raw)
                .map_err(|e| CaptureError::device("preview", e))?,
        };
        self.frame = fit(&picture, self.upright);
        Ok(&self.frame)
    }
}

impl<C: Camera> Drop for CameraPreview<C> {
    fn drop(&mut self) {
        if let Err(e) = self.camera.release() {
            tracing::warn!("preview: releasing the camera: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_shrinks_into_the_preview_box_by_a_whole_factor_and_averages() {
        let shrink = |img: &Image<u8>| fit(img, Orientation::UPRIGHT);
        // 4000x3000 landscape: factor 7 (4000/640 = 6.25, rounded up).
        let big = Image::from_fn(4000, 3000, 3, |x, _, c| ((x / 7) % 2 * 200 + c) as u8);
        let s = shrink(&big);
        assert_eq!((s.width(), s.height()), (572, 429));
        assert!(s.width() <= MAX_WIDTH && s.height() <= MAX_HEIGHT);
        // Blocks of 7 columns alternate 0 and 200: the average keeps them.
        assert_eq!(s.at(0, 0, 0), 0);
        assert_eq!(s.at(1, 0, 1), 201);
        // A tall portrait frame is bound by its height.
        let tall = Image::<u8>::new(1000, 3000, 3);
        let s = shrink(&tall);
        assert_eq!((s.width(), s.height()), (250, 750));
        // A small frame is kept.
        let small = Image::<u8>::new(480, 360, 3);
        assert_eq!(shrink(&small).width(), 480);
    }

    #[test]
    fn fit_turns_after_fitting_the_turned_frame() {
        // A 1280x720 landscape sensor mounted at 270 degrees (the PinePhone Pro's rear camera):
        // one clockwise turn, fitted as 720x1280 into 640x960, factor 2, then turned.
        let turn = upright(270).expect("270 is a quarter turn");
        assert_eq!(turn.quarter_turns(), 1);
        let img = Image::from_fn(1280, 720, 3, |x, y, _| if x < 2 && y < 2 { 255 } else { 0 });
        let s = fit(&img, turn);
        assert_eq!((s.width(), s.height()), (360, 640));
        // The top-left corner turns clockwise to the top-right.
        assert_eq!(s.at(359, 0, 0), 255);
        assert_eq!(s.at(0, 0, 0), 0);
        assert!(upright(45).is_err());
    }
}
