//! A raw take kept as it came: the frame buffer's bytes with their packing and stride, the
//! Bayer order and the black level, and the colour matrix to develop it with. A sweep only
//! copies these; developing them waits until the lens is done ([`StackDeveloper`]).

use super::raw::{self, Packing};
use super::{encode, BayerOrder, Developer, Mosaic};
use crate::files::orientation::Orientation;
use crate::stack::image::Image;

#[derive(Clone, Debug, PartialEq)]
pub struct RawFrame {
    /// The buffer as the driver wrote it, up to the frame's last sample.
    pub bytes: Vec<u8>,
    pub packing: Packing,
    /// Bytes a row in `bytes`.
    pub stride: usize,
    pub width: usize,
    pub height: usize,
    pub order: BayerOrder,
    /// The pedestal in sample values at the packing's depth.
    pub black_level: u32,
    /// Camera RGB (balanced) to linear sRGB, row by row.
    pub matrix: [[f32; 3]; 3],
    /// The gains for red, green and blue (green 1) that make a grey of the scene grey, as the
    /// take knew them when it was made (a DNG's AsShotNeutral; the simulator's takes, whose
    /// camera RGB is linear sRGB, have 1); `None` for a camera that says nothing (then the
    /// stack's development measures grey-world).
    pub white_balance: Option<[f32; 3]>,
}

/// How a raw frame sits in its buffer and what develops it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawLayout {
    pub packing: Packing,
    pub width: usize,
    pub height: usize,
    /// The driver's bytes per line (0: rows unpadded).
    pub stride: usize,
    pub order: BayerOrder,
    pub black_level: u32,
    pub matrix: [[f32; 3]; 3],
}

impl RawFrame {
    /// A copy of the frame in `buffer`, after checking the buffer holds it (the error names
    /// the geometry and the sizes).
    pub fn copy(buffer: &[u8], l: RawLayout) -> Result<RawFrame, String> {
        if l.width < 2 || l.height < 2 {
            return Err(format!(
                "frame {}x{} is smaller than 2x2",
                l.width, l.height
            ));
        }
        let (stride, needed) = raw::layout(l.packing, l.width, l.height, l.stride, buffer.len())?;
        Ok(RawFrame {
            bytes: buffer[..needed].to_vec(),
            packing: l.packing,
            stride,
            width: l.width,
            height: l.height,
            order: l.order,
            black_level: l.black_level,
            matrix: l.matrix,
            white_balance: None,
        })
    }

    /// Bits a sample.
    pub fn bits(&self) -> u32 {
        self.packing.bits()
    }

    /// The samples as integers, row by row, unpacked.
    pub fn samples(&self) -> Result<Vec<u16>, String> {
        raw::unpack(
            self.packing,
            self.width,
            self.height,
            self.stride,
            &self.bytes,
        )
    }

    /// The frame turned by `o`: its samples turned as a picture's pixels are, the Bayer order
    /// the one now at the top left, packed as before.
    pub fn upright(self, o: Orientation) -> Result<RawFrame, String> {
        if o == Orientation::UPRIGHT {
            return Ok(self);
        }
        let samples = self.samples()?;
        let turned = o.turn(&Image::from_vec(self.width, self.height, 1, samples));
        let colours = o.turn(&Image::from_fn(self.width, self.height, 1, |x, y, _| {
            self.order.channel(x, y) as u8
        }));
        let order = [
            BayerOrder::Rggb,
            BayerOrder::Bggr,
            BayerOrder::Grbg,
            BayerOrder::Gbrg,
        ]
        .into_iter()
        .find(|b| (0..4).all(|k| b.channel(k % 2, k / 2) == colours.at(k % 2, k / 2, 0) as usize))
        .expect("a Bayer pattern turned is a Bayer pattern");
        Ok(RawFrame {
            stride: self.packing.row_bytes(turned.width()),
            bytes: raw::pack(self.packing, turned.width(), turned.data()),
            width: turned.width(),
            height: turned.height(),
            order,
            ..self
        })
    }

    /// The samples in linear light, black level off.
    pub fn mosaic(&self) -> Result<Mosaic, String> {
        let samples = self.samples()?;
        Ok(Mosaic::from_samples(
            &samples,
            self.width,
            self.height,
            self.order,
            self.bits(),
            self.black_level,
        ))
    }
}

/// Develops the raw frames of one stack: the white balance measured on the first and kept
/// for the rest, so the planes' colours match.
#[derive(Default)]
pub struct StackDeveloper {
    developer: Option<Developer>,
}

impl StackDeveloper {
    pub fn develop(&mut self, raw: &RawFrame) -> Result<Image<u8>, String> {
        let m = raw.mosaic()?;
        Ok(self.developer(raw).develop(m))
    }

    /// The cheap development of `raw` at half size ([`Developer::develop_half_linear`]), with
    /// the stack's white balance.
    pub fn develop_half(&mut self, raw: &RawFrame) -> Result<Image<u8>, String> {
        let m = raw.mosaic()?;
        Ok(encode(&self.developer(raw).develop_half_linear(&m)))
    }

    /// The stack's developer, made for `raw`'s camera if this is the first frame.
    fn developer(&mut self, raw: &RawFrame) -> &mut Developer {
        self.developer
            .get_or_insert_with(|| Developer::new(raw.black_level, raw.matrix))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::develop::IDENTITY;

    fn layout(width: usize, height: usize, stride: usize) -> RawLayout {
        RawLayout {
            packing: Packing::Bits8,
            width,
            height,
            stride,
            order: BayerOrder::Grbg,
            black_level: 16,
            matrix: IDENTITY,
        }
    }

    #[test]
    fn a_copy_keeps_the_frame_and_drops_the_buffers_tail() {
        // Two rows of 4 samples at a stride of 6, then padding the driver left.
        let buffer = [1, 2, 3, 4, 0, 0, 5, 6, 7, 8, 9, 9, 9];
        let f = RawFrame::copy(&buffer, layout(4, 2, 6)).expect("fits");
        assert_eq!(f.bytes, &buffer[..10]);
        assert_eq!((f.stride, f.bits(), f.order), (6, 8, BayerOrder::Grbg));
        let m = f.mosaic().expect("unpacks");
        assert_eq!(m.data.len(), 8);
        assert!(m.data[0] < 0.0, "1 is below the black level of 16");
        let e = RawFrame::copy(&buffer[..9], layout(4, 2, 6)).expect_err("short");
        assert_eq!(e, "4x2 frame: buffer of 9 bytes is too short, 10 needed");
        let e = RawFrame::copy(&buffer, layout(1, 2, 0)).expect_err("tiny");
        assert_eq!(e, "frame 1x2 is smaller than 2x2");
    }

    #[test]
    fn a_turned_frame_keeps_each_sample_and_its_colour() {
        // 4×2 GRBG, samples 0..8 row by row; a quarter turn clockwise makes it 2×4.
        let bytes: Vec<u8> = (0..8).collect();
        let f = RawFrame::copy(&bytes, layout(4, 2, 0)).expect("fits");
        let t = f.clone().upright(Orientation::clockwise(1)).expect("turns");
        assert_eq!((t.width, t.height, t.stride), (2, 4, 2));
        // The old bottom-left sample (4, blue in GRBG) is now at the top left.
        assert_eq!(t.bytes, [4, 0, 5, 1, 6, 2, 7, 3]);
        assert_eq!(t.order, BayerOrder::Bggr);
        let back = (0..3).try_fold(t, |t, _| t.upright(Orientation::clockwise(1)));
        assert_eq!(back.expect("turns"), f);
    }

    #[test]
    fn a_stack_keeps_the_first_frames_white_balance() {
        // A grey frame, then a reddish one: the second keeps the grey frame's gains (1), so
        // it develops reddish rather than balanced back to grey.
        let grey = vec![100u8; 16];
        let red: Vec<u8> = (0..16)
            .map(|i| {
                if (i / 4) % 2 == 0 && i % 2 == 1 {
                    200
                } else {
                    100
                }
            })
            .collect();
        let mut s = StackDeveloper::default();
        let l = layout(4, 4, 0);
        let a = s
            .develop(&RawFrame::copy(&grey, l).expect("g"))
            .expect("dev");
        let b = s
            .develop(&RawFrame::copy(&red, l).expect("r"))
            .expect("dev");
        let mean = |img: &Image<u8>, c: usize| {
            img.data().chunks(3).map(|p| f64::from(p[c])).sum::<f64>() / 16.0
        };
        assert!((mean(&a, 0) - mean(&a, 1)).abs() < 1.0);
        assert!(mean(&b, 0) > mean(&b, 1) + 10.0, "red kept");
        let alone = StackDeveloper::default()
            .develop(&RawFrame::copy(&red, l).expect("r"))
            .expect("dev");
        assert!(
            (mean(&alone, 0) - mean(&alone, 1)).abs() < 2.0,
            "balanced alone"
        );
    }
}
