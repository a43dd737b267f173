//! The live preview's frames: the trait a preview reads from, the size a preview frame may
//! have, and the source that previews any [`Camera`] (the phone's, between captures).

use super::{Camera, CaptureError, Frame};
use crate::develop::StackDeveloper;
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

/// `image` shrunk by the smallest whole factor that fits it in the preview's size, averaging
/// each block of pixels (a whole factor keeps the pixels square and the work a single pass).
pub fn shrink(image: &Image<u8>) -> Image<u8> {
    let factor = image
        .width()
        .div_ceil(MAX_WIDTH)
        .max(image.height().div_ceil(MAX_HEIGHT));
    if factor <= 1 {
        return image.clone();
    }
    crate::stack::blur::downsample_area(image, factor)
}

/// A camera's stream, shrunk: the preview of a phone's camera. The lens stays where it is.
pub struct CameraPreview<C: Camera> {
    camera: C,
    frame: Image<u8>,
    /// Raw frames are developed as a capture's are, one white balance for the stream.
    developer: StackDeveloper,
}

impl<C: Camera> CameraPreview<C> {
    pub fn new(camera: C) -> Self {
        Self {
            camera,
            frame: Image::new(0, 0, 3),
            developer: StackDeveloper::default(),
        }
    }
}

impl<C: Camera> FrameSource for CameraPreview<C> {
    fn next_frame(&mut self) -> Result<&Image<u8>, CaptureError> {
        let picture = match self.camera.capture()?.frame {
            Frame::Picture(picture) => picture,
            Frame::Raw(raw) => self
                .developer
                .develop(&raw)
                .map_err(|e| CaptureError::device("preview", e))?,
        };
        self.frame = shrink(&picture);
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
    fn shrink_fits_the_preview_box_by_a_whole_factor_and_averages() {
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
}
