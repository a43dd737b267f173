//! A replay's preview: the bundle's reference frame (the middle plane's first take, the frame
//! a fuse registers onto), shrunk and turned upright once and served again and again.

use super::Bundle;
use crate::capture::preview::{fit, upright, FrameSource};
use crate::capture::{CaptureError, Frame};
use crate::develop::StackDeveloper;
use crate::stack::image::Image;
use crate::stack::middle_frame;

pub struct ReplayPreview {
    frame: Image<u8>,
}

impl ReplayPreview {
    pub fn open(bundle: &Bundle) -> Result<Self, CaptureError> {
        let error = |reason: String| CaptureError::Bundle {
            path: bundle.dir.join("bundle.toml").display().to_string(),
            reason,
        };
        let plane = middle_frame(bundle.planes());
        let take = bundle
            .manifest
            .takes
            .iter()
            .find(|t| t.plane == plane)
            .ok_or_else(|| error(format!("plane {plane} has no take to preview")))?;
        let path = bundle.file(&take.image).map_err(|e| error(e.to_string()))?;
        // A raw take is shown as the camera's preview shows raw frames: cheaply developed.
        let image = match super::take::load(&path).map_err(error)? {
            Frame::Picture(image) => image,
            Frame::Raw(raw) => StackDeveloper::default()
                .develop_half(&raw)
                .map_err(error)?,
        };
        Ok(Self {
            frame: fit(&image, upright(bundle.manifest.rotation)?),
        })
    }
}

impl FrameSource for ReplayPreview {
    fn next_frame(&mut self) -> Result<&Image<u8>, CaptureError> {
        Ok(&self.frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::psnr;
    use std::path::Path;

    #[test]
    fn a_raw_bundle_previews_its_reference_take_cheaply_developed() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("sim-data/bundles/raw");
        let mut p = ReplayPreview::open(&Bundle::open(&dir).unwrap()).unwrap();
        let frame = p.next_frame().unwrap();
        // One pixel a 2×2 cell of the 480×360 takes, against the picture averaged likewise.
        assert_eq!((frame.width(), frame.height()), (240, 180));
        let picture = crate::files::imageio::load_rgb8(&dir.join("frame_02.jpg")).unwrap();
        let halved = Image::from_fn(240, 180, 3, |x, y, c| {
            let s: u32 = [(0, 0), (0, 1), (1, 0), (1, 1)]
                .iter()
                .map(|(dx, dy)| u32::from(picture.at(2 * x + dx, 2 * y + dy, c)))
                .sum();
            ((s + 2) / 4) as u8
        });
        let db = psnr(frame, &halved, 0);
        assert!(db > 30.0, "{db:.2} dB against the picture halved");
    }
}
