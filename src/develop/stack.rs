//! A stack of raw frames developed lazily for the fuse ([`Develop`]): each frame cheaply in
//! whole ([`linear::cheap`], full size, a twentieth of the full demosaic's work), and with the
//! full demosaic only over the regions the fuse asks for; one white balance for the stack.

use super::demosaic::demosaic_regions;
use super::{encode, grey_world, linear, Developer, RawFrame};
use crate::stack::image::Image;
use crate::stack::{Develop, Rect};

pub struct RawStack {
    frames: Vec<RawFrame>,
    developer: Developer,
}

impl RawStack {
    /// The stack of `frames`, developed with one white balance: the first frame's own
    /// ([`RawFrame::white_balance`]), or grey-world measured on it where it has none, as a
    /// sweep's developer measures it. Every frame is given that balance, so what they say (a
    /// DNG's AsShotNeutral) is what they were developed with. The frames must share one
    /// geometry; the fuse checks it on the cheap developments.
    pub fn new(mut frames: Vec<RawFrame>) -> Result<RawStack, String> {
        let first = frames.first().ok_or("no raw frames to develop")?;
        let mut developer = Developer::new(first.black_level, first.matrix);
        let gains = match first.white_balance {
            Some(g) => g,
            None => grey_world(&[&first.mosaic()?]),
        };
        developer.white_balance = Some(gains);
        for f in &mut frames {
            f.white_balance = Some(gains);
        }
        Ok(RawStack { frames, developer })
    }

    /// The raw frames, with the stack's white balance.
    pub fn takes(&self) -> &[RawFrame] {
        &self.frames
    }

    /// Frame `i`'s samples in linear light, white-balanced: what both developments start from.
    fn balanced(&self, i: usize) -> Result<super::Mosaic, String> {
        let mut m = self.frames[i].mosaic()?;
        m.balance(self.developer.locked());
        Ok(m)
    }
}

/// Bytes developing one `width`×`height` raw frame takes while it runs: its samples in linear
/// light and encoded with the demosaic's border (4 bytes each), and the cheap development in
/// linear light (12 bytes a pixel) or the full one's rectangles and their working planes,
/// whichever is more.
pub fn working_bytes(width: usize, height: usize) -> usize {
    24 * width * height
}

impl Develop<u8> for RawStack {
    fn frames(&self) -> usize {
        self.frames.len()
    }

    fn cheap(&self, i: usize) -> Result<Image<u8>, String> {
        let mut rgb = linear::cheap(&self.balanced(i)?);
        self.developer.to_srgb(&mut rgb, [1.0; 3]);
        Ok(encode(&rgb))
    }

    fn full(&self, i: usize, rects: &[Rect]) -> Result<Vec<Image<u8>>, String> {
        Ok(demosaic_regions(&self.balanced(i)?, rects)
            .into_iter()
            .map(|mut rgb| {
                self.developer.to_srgb(&mut rgb, [1.0; 3]);
                encode(&rgb)
            })
            .collect())
    }

    fn held_bytes(&self) -> usize {
        self.frames.iter().map(|f| f.bytes.len()).sum()
    }

    fn working_bytes(&self) -> usize {
        let f = &self.frames[0];
        working_bytes(f.width, f.height)
    }
}
