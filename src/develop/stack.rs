//! A stack of raw frames developed lazily for the fuse ([`Develop`]): each frame cheaply in
//! whole (Malvar–He–Cutler with a directional green on encoded samples, [`linear::cheap_over`],
//! about a twentieth of the full demosaic's work), and with the full demosaic only over the regions the fuse asks for;
//! one white balance for the stack.

use super::demosaic::{demosaic_regions, Regions};
use super::pixels::Pixels;
use super::{grey_world, linear, raw, Developer, Mosaic, RawFrame};
use crate::stack::image::Image;
use crate::stack::srgb;
use crate::stack::{Develop, Piece, Rect};
use rayon::prelude::*;

pub struct RawStack {
    frames: Vec<RawFrame>,
    developer: Developer,
    /// Per frame, every value its samples take (one more than the largest; a 16-bit word may
    /// hold more than its depth says): the length of its tables ([`RawStack::encoded_rows`]),
    /// found once rather than by a scan of the frame at every development.
    values: Vec<usize>,
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
        let values = frames.par_iter().map(values).collect();
        Ok(RawStack {
            frames,
            developer,
            values,
        })
    }

    /// The raw frames, with the stack's white balance.
    pub fn takes(&self) -> &[RawFrame] {
        &self.frames
    }

    /// Frame `i`'s samples as both developments read them, row by row (see
    /// [`linear::cheap_over`]): each sample read from the frame's bytes and through a table
    /// per colour to its balanced, sRGB-encoded value. The same values as unpacking to linear
    /// light, balancing and encoding the whole frame, without a frame-sized buffer between the
    /// steps. An error if the bytes do not hold the frame.
    fn encoded_rows(
        &self,
        i: usize,
    ) -> Result<impl Fn(usize, usize, &mut [f32]) + Sync + '_, String> {
        let f = &self.frames[i];
        let (packing, order) = (f.packing, f.order);
        let (stride, _) = raw::layout(packing, f.width, f.height, f.stride, f.bytes.len())?;
        let row_bytes = packing.row_bytes(f.width);
        let line = move |y: usize| &f.bytes[y * stride..][..row_bytes];
        let values = self.values[i];
        let encode = &srgb::tabulated().encode;
        let linear = Mosaic::linear(f.bits(), f.black_level);
        let gains = self.developer.locked();
        let tables: [Vec<f32>; 3] = std::array::from_fn(|c| {
            (0..values)
                .map(|v| encode.at(linear(v as u16) * gains[c]))
                .collect()
        });
        Ok(move |y: usize, x0: usize, row: &mut [f32]| {
            let pair = [
                &tables[order.channel(x0, y)][..],
                &tables[order.channel(x0 + 1, y)][..],
            ];
            // A few samples at a time through a buffer on the stack.
            const RUN: usize = 64;
            let mut samples = [0u16; RUN];
            for (j, run) in row.chunks_mut(RUN).enumerate() {
                let samples = &mut samples[..run.len()];
                raw::read_row(packing, line(y), x0 + j * RUN, samples);
                for (k, (v, &s)) in run.iter_mut().zip(samples.iter()).enumerate() {
                    *v = pair[k & 1][usize::from(s)];
                }
            }
        })
    }

    /// What both developments make of a row of pixels' encoded red, green and blue: decoded,
    /// through the colour matrix and to 8-bit sRGB ([`Pixels`]).
    fn pixels(&self) -> impl Fn([&[f32]; 3], &mut [u8]) + Sync + '_ {
        let pixels = Pixels::new(&self.developer);
        move |rgb: [&[f32]; 3], out: &mut [u8]| pixels.row(rgb, out)
    }

    /// The cheap development of frame `i` over each of `rects`, from its encoded rows
    /// ([`RawStack::encoded_rows`]): Malvar–He–Cutler, each pixel through
    /// [`RawStack::pixels`].
    fn cheap_over(
        &self,
        i: usize,
        fill: &(impl Fn(usize, usize, &mut [f32]) + Sync),
        rects: &[Rect],
    ) -> Vec<Image<u8>> {
        let f = &self.frames[i];
        let pixels = self.pixels();
        rects
            .par_iter()
            .map(|&r| {
                let mut out = vec![0u8; r.width * r.height * 3];
                linear::cheap_over((f.width, f.height), f.order, r, fill, &pixels, &mut out);
                Image::from_vec(r.width, r.height, 3, out)
            })
            .collect()
    }
}

/// One more than the largest of frame `f`'s samples; 0 where its bytes do not hold it.
fn values(f: &RawFrame) -> usize {
    let Ok((stride, _)) = raw::layout(f.packing, f.width, f.height, f.stride, f.bytes.len()) else {
        return 0;
    };
    let row_bytes = f.packing.row_bytes(f.width);
    let mut buffer = vec![0u16; f.width];
    (0..f.height)
        .map(|y| {
            raw::read_row(
                f.packing,
                &f.bytes[y * stride..][..row_bytes],
                0,
                &mut buffer,
            );
            buffer.iter().max().map_or(0, |&m| usize::from(m) + 1)
        })
        .max()
        .unwrap_or(0)
}

/// Bytes developing one `width`×`height` raw frame takes while it runs, whichever way is more:
/// cheaply, its samples unpacked (2 bytes each) and a few rows of them encoded; in full, the
/// samples and the regions' windows with their working planes, up to a strip of the frame's.
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
        let mut pieces = self.cheap_over(i, &self.encoded_rows(i)?, &[whole]);
        Ok(pieces.pop().expect("one rectangle asked for"))
    }

    fn full(&self, asked: &[(usize, &[Rect])]) -> Result<Vec<Vec<Piece<u8>>>, (usize, String)> {
        let rows = asked
            .iter()
            .map(|&(i, _)| self.encoded_rows(i).map_err(|e| (i, e)))
            .collect::<Result<Vec<_>, _>>()?;
        let regions: Vec<Regions<_>> = asked
            .iter()
            .zip(&rows)
            .map(|(&(i, rects), fill)| {
                let f = &self.frames[i];
                Regions {
                    size: (f.width, f.height),
                    order: f.order,
                    fill,
                    rects,
                }
            })
            .collect();
        let full = demosaic_regions(&regions, &self.pixels());
        let cheap: Vec<Vec<Image<u8>>> = asked
            .par_iter()
            .zip(&rows)
            .map(|(&(i, rects), fill)| self.cheap_over(i, fill, rects))
            .collect();
        Ok(full
            .into_iter()
            .zip(cheap)
            .map(|(full, cheap)| {
                full.into_iter()
                    .zip(cheap)
                    .map(|(full, cheap)| Piece { full, cheap })
                    .collect()
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
    use crate::develop::{decode, encode, BayerOrder};
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
            (Packing::Le10, BayerOrder::Gbrg, 5),
        ] {
            let stack = RawStack::new(frames(packing, order, seed)).expect("a stack");
            let got = stack.cheap(0).expect("develops");
            // Unpacked, balanced, encoded, filtered, decoded, through the matrix, to 8 bits.
            let mut m = stack.frames[0].mosaic().expect("unpacks");
            m.balance(stack.developer.locked());
            let mut rgb = linear::encoded(&m, linear::cheap);
            stack.developer.to_srgb(&mut rgb, [1.0; 3]);
            let want = encode(&rgb);
            assert!(got == want, "{packing:?} {order:?}: not the same pixels");
        }
    }

    #[test]
    fn regions_asked_together_are_each_frames_whole_development_cut() {
        for (packing, order, seed) in [
            (Packing::Mipi10, BayerOrder::Grbg, 3),
            (Packing::Le16, BayerOrder::Bggr, 11),
        ] {
            let takes = [seed, seed + 1].map(|s| frames(packing, order, s).remove(0));
            let stack = RawStack::new(takes.to_vec()).expect("a stack");
            let w = stack.frames[0].width;
            // One inside on odd coordinates, one against the top left corner; the second
            // frame's elsewhere.
            let rect = |(x, y, width, height)| Rect {
                x,
                y,
                width,
                height,
            };
            let rects = [
                [(37, 21, 50, 19), (0, 0, 30, 12)].map(rect),
                [(5, 40, 64, 24), (90, 3, 17, 30)].map(rect),
            ];
            let asked = [(0, &rects[0][..]), (1, &rects[1][..])];
            let developed = stack.full(&asked).expect("develops");
            for (i, pieces) in developed.iter().enumerate() {
                // Unpacked, balanced, demosaiced whole, through the matrix, to 8 bits.
                let mut m = stack.frames[i].mosaic().expect("unpacks");
                m.balance(stack.developer.locked());
                let mut rgb = super::super::demosaic::demosaic(&m);
                stack.developer.to_srgb(&mut rgb, [1.0; 3]);
                let want = encode(&rgb);
                let cheap = stack.cheap(i).expect("develops");
                for (piece, r) in pieces.iter().zip(rects[i]) {
                    for yy in 0..r.height {
                        let row = yy * r.width * 3..(yy + 1) * r.width * 3;
                        let at = ((r.y + yy) * w + r.x) * 3..((r.y + yy) * w + r.x + r.width) * 3;
                        let what = format!("frame {i} {order:?} {r:?}");
                        assert_eq!(
                            &piece.full.data()[row.clone()],
                            &want.data()[at.clone()],
                            "{what}"
                        );
                        assert_eq!(&piece.cheap.data()[row], &cheap.data()[at], "{what}");
                    }
                }
            }
        }
    }
}
