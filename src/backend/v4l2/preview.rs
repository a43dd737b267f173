//! The camera opened for the live preview: the capture's settings with a stream no larger than
//! a preview frame asked for, so the driver scales (or bins) instead of the preview shrinking
//! every frame. The driver picks its nearest size; a device profile's pipeline keeps its own.

use super::{camera, V4l2Camera, V4l2Config};
use crate::capture::preview::{MAX_HEIGHT, MAX_WIDTH};
use crate::capture::CaptureError;

/// `cfg` asking for its own aspect ratio fitted into the preview's size (even sides, as YUV
/// formats need); a size already inside is kept.
pub fn preview_config(cfg: &V4l2Config) -> V4l2Config {
    let (w, h) = (f64::from(cfg.width.max(1)), f64::from(cfg.height.max(1)));
    let scale = (MAX_WIDTH as f64 / w).min(MAX_HEIGHT as f64 / h);
    if scale >= 1.0 {
        return cfg.clone();
    }
    let even = |v: f64| ((v * scale / 2.0).round() as u32 * 2).max(2);
    V4l2Config {
        width: even(w),
        height: even(h),
        ..cfg.clone()
    }
}

/// Opens the camera for the preview.
pub fn open_preview(cfg: &V4l2Config) -> Result<V4l2Camera, CaptureError> {
    camera::open(&preview_config(cfg))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_preview_asks_for_the_aspect_fitted_into_its_size() {
        let size = |width, height| {
            let c = preview_config(&V4l2Config {
                width,
                height,
                ..V4l2Config::default()
            });
            (c.width, c.height)
        };
        assert_eq!(size(1280, 720), (640, 360));
        assert_eq!(size(4208, 3120), (640, 474));
        assert_eq!(size(1080, 1920), (540, 960));
        assert_eq!(size(320, 240), (320, 240));
    }
}
