//! A stack of raw frames developed lazily for the fuse ([`Develop`]): each frame cheaply in
//! whole (Malvar–He–Cutler on encoded samples, [`linear::malvar_over`], a twentieth of the
//! full demosaic's work), and with the full demosaic only over the regions the fuse asks for;
//! one white balance for the stack.

use super::demosaic::demosaic_regions;
use super::{encode, encode8, grey_world, linear, Developer, Mosaic, RawFrame};
use crate::stack::image::Image;
use crate::stack::srgb;
use crate::stack::{Develop, Piece, Rect};

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

    /// The cheap development of frame `i` over each of `rects`, from its `samples`: each
    /// sample through a table per colour to its balanced, encoded value, Malvar–He–Cutler, and
    /// per pixel decoded, through the colour matrix and to 8-bit sRGB. The same values as
    /// taking those steps one at a time over the whole frame, without a frame-sized buffer
    /// between them.
    fn cheap_over(&self, i: usize, samples: &[u16], rects: &[Rect]) -> Vec<Image<u8>> {
        let f = &self.frames[i];
        let srgb::Tabulated { encode, decode } = srgb::tabulated();
        let linear = Mosaic::linear(f.bits(), f.black_level);
        let gains = self.developer.locked();
        // Every value the samples take (a 16-bit word may hold more than its depth says).
        let values = samples.iter().max().map_or(0, |&m| usize::from(m) + 1);
        let tables: [Vec<f32>; 3] = std::array::from_fn(|c| {
            (0..values)
                .map(|v| encode.at(linear(v as u16) * gains[c]))
                .collect()
        });
        let fill = |y: usize, x0: usize, row: &mut [f32]| {
            let pair = [
                &tables[f.order.channel(x0, y)],
                &tables[f.order.channel(x0 + 1, y)],
            ];
            let from = &samples[y * f.width + x0..][..row.len()];
            for (k, (v, &s)) in row.iter_mut().zip(from).enumerate() {
                *v = pair[k & 1][usize::from(s)];
            }
        };
        let pixel = |rgb: [f32; 3], out: &mut [u8]| {
            let v = self.developer.srgb(rgb.map(|v| decode.at(v)));
            for (o, v) in out.iter_mut().zip(v) {
                *o = encode8(v);
            }
        };
        rects
            .iter()
            .map(|&r| {
                let mut out = vec![0u8; r.width * r.height * 3];
                linear::malvar_over((f.width, f.height), f.order, r, &fill, &pixel, &mut out);
                Image::from_vec(r.width, r.height, 3, out)
            })
            .collect()
    }
}

/// Bytes developing one `width`×`height` raw frame takes while it runs, whichever way is more:
/// cheaply, its samples unpacked (2 bytes each) and a few rows of them encoded; in full, the
/// samples, in linear light and encoded with the demosaic's border (4 bytes each), and the
/// regions' windows with their working planes, up to a strip of the frame's.
pub fn working_bytes(width: usize, height: usize) -> usize {
    24 * width * height
}

impl Develop<u8> for RawStack {
    fn frames(&self) -> usize {
        self.frames.len()
    }

    fn cheap(&self, i: usize) -> Result<Image<u8>, String> {
        let f = &self.frames[i];
        let whole = Rect {
            x: 0,
            y: 0,
            width: f.width,
            height: f.height,
        };
        let mut pieces = self.cheap_over(i, &f.samples()?, &[whole]);
        Ok(pieces.pop().expect("one rectangle asked for"))
    }

    fn full(&self, i: usize, rects: &[Rect]) -> Result<Vec<Piece<u8>>, String> {
        let f = &self.frames[i];
        let samples = f.samples()?;
        let mut m = Mosaic::from_samples(
            &samples,
            f.width,
            f.height,
            f.order,
            f.bits(),
            f.black_level,
        );
        m.balance(self.developer.locked());
        let full = demosaic_regions(&m, rects);
        drop(m);
        let cheap = self.cheap_over(i, &samples, rects);
        Ok(full
            .into_iter()
            .zip(cheap)
            .map(|(mut rgb, cheap)| {
                self.developer.to_srgb(&mut rgb, [1.0; 3]);
                Piece {
                    full: encode(&rgb),
                    cheap,
                }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::develop::raw::{pack, Packing};
    use crate::develop::{decode, BayerOrder};
    use crate::sim::{self, SimParams};

    /// Raw frames of a simulated scene: its truth mosaicked, at `bits` bits over a black level,
    /// with a colour matrix and gains far from 1, so that every step counts.
    fn frames(packing: Packing, order: BayerOrder, seed: u64) -> Vec<RawFrame> {
        let truth = decode(&sim::render(&SimParams::demosaic_scene(seed)).truth);
        let m = Mosaic::sample(&truth, order);
        let (bits, black) = (packing.bits(), 64u32.min((1 << packing.bits()) / 16));
        let top = ((1u32 << bits) - 1 - black) as f32;
        let samples: Vec<u16> = m
            .data
            .iter()
            .map(|&v| (black as f32 + v * 0.8 * top) as u16)
            .collect();
        vec![RawFrame {
            bytes: pack(packing, m.width, &samples),
            packing,
            stride: packing.row_bytes(m.width),
            width: m.width,
            height: m.height,
            order,
            black_level: black,
            matrix: [[1.3, -0.2, -0.1], [-0.1, 1.2, -0.1], [0.0, -0.3, 1.3]],
            white_balance: Some([1.6, 1.0, 1.3]),
        }]
    }

    #[test]
    fn the_cheap_development_is_its_steps_taken_one_by_one() {
        for (packing, order, seed) in [
            (Packing::Mipi10, BayerOrder::Grbg, 3),
            (Packing::Le16, BayerOrder::Bggr, 11),
            (Packing::Bits8, BayerOrder::Rggb, 29),
        ] {
            let stack = RawStack::new(frames(packing, order, seed)).expect("a stack");
            let got = stack.cheap(0).expect("develops");
            // Unpacked, balanced, encoded, filtered, decoded, through the matrix, to 8 bits.
            let mut m = stack.frames[0].mosaic().expect("unpacks");
            m.balance(stack.developer.locked());
            let mut rgb = linear::encoded(&m, linear::malvar);
            stack.developer.to_srgb(&mut rgb, [1.0; 3]);
            let want = encode(&rgb);
            assert!(got == want, "{packing:?} {order:?}: not the same pixels");
        }
    }
}
