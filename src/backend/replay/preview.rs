//! A replay's preview: the bundle's reference frame (the middle plane's first take, the frame
//! a fuse registers onto), shrunk and turned upright once and served again and again.

use super::Bundle;
use crate::capture::preview::{fit, upright, FrameSource};
use crate::capture::CaptureError;
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
        let image = crate::files::imageio::load_rgb8(&path)
            .map_err(|e| error(crate::base::clip::chain(&e)))?;
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
