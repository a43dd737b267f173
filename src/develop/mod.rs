//! Raw Bayer frames to a picture, as an ISP would: the samples unpacked ([`raw`]), the black
//! level taken off, white balance, demosaic ([`demosaic`]), the camera's colour matrix, sRGB.
//!
//! Pure pixel work, no I/O: the V4L2 backend hands it buffers and a device profile's values.
//!
//! White balance is grey-world, measured once and then locked: a focus sweep changes what is
//! sharp, not the light, and gains re-measured per frame would make the planes' colours flicker,
//! which the fusion would then stitch together as visible seams.

pub mod demosaic;
pub mod frame;
pub mod half;
pub mod linear;
mod pixels;
pub mod raw;
pub mod stack;

use crate::stack::image::Image;
pub use frame::{RawFrame, RawLayout, StackDeveloper};
pub use stack::RawStack;

/// The colour of the top-left 2×2 cell of a Bayer mosaic, by its V4L2 name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BayerOrder {
    Bggr,
    Gbrg,
    Grbg,
    Rggb,
}

impl BayerOrder {
    /// The channel (0 red, 1 green, 2 blue) of the sample at (x, y).
    pub fn channel(self, x: usize, y: usize) -> usize {
        let cell = match self {
            BayerOrder::Bggr => [[2, 1], [1, 0]],
            BayerOrder::Gbrg => [[1, 2], [0, 1]],
            BayerOrder::Grbg => [[1, 0], [2, 1]],
            BayerOrder::Rggb => [[0, 1], [1, 2]],
        };
        cell[y & 1][x & 1]
    }

    /// The order of the pattern read from (x, y) on.
    pub fn read_from(self, x: usize, y: usize) -> BayerOrder {
        let orders = [
            BayerOrder::Bggr,
            BayerOrder::Gbrg,
            BayerOrder::Grbg,
            BayerOrder::Rggb,
        ];
        let same = |o: &BayerOrder| {
            (0..4).all(|k| o.channel(k % 2, k / 2) == self.channel(x + k % 2, y + k / 2))
        };
        orders.into_iter().find(same).unwrap_or(self)
    }
}

/// A Bayer frame in linear light: 0 at the black level, 1 at the sensor's white (noise may go
/// a little below 0; it is kept so that averages stay unbiased).
#[derive(Clone, Debug, PartialEq)]
pub struct Mosaic {
    pub width: usize,
    pub height: usize,
    pub order: BayerOrder,
    pub data: Vec<f32>,
}

impl Mosaic {
    /// Integer samples of `bits` bits with the black level `black` (in the same units) taken
    /// off and scaled so that the largest code is 1.
    pub fn from_samples(
        samples: &[u16],
        width: usize,
        height: usize,
        order: BayerOrder,
        bits: u32,
        black: u32,
    ) -> Mosaic {
        let linear = Mosaic::linear(bits, black);
        Mosaic {
            width,
            height,
            order,
            data: samples.iter().map(|&v| linear(v)).collect(),
        }
    }

    /// A sample of `bits` bits in linear light, black level `black` off, as
    /// [`Mosaic::from_samples`] takes it.
    pub fn linear(bits: u32, black: u32) -> impl Fn(u16) -> f32 {
        let white = ((1u32 << bits) - 1) as f32;
        let black = black as f32;
        let scale = 1.0 / (white - black).max(1.0);
        move |v| (f32::from(v) - black) * scale
    }

    /// The mosaic a sensor with this pattern would record of linear RGB `rgb` (three channels):
    /// each pixel keeps its own colour. For simulations and tests.
    pub fn sample(rgb: &Image<f32>, order: BayerOrder) -> Mosaic {
        let data = (0..rgb.height())
            .flat_map(|y| (0..rgb.width()).map(move |x| (x, y)))
            .map(|(x, y)| rgb.at(x, y, order.channel(x, y)))
            .collect();
        Mosaic {
            width: rgb.width(),
            height: rgb.height(),
            order,
            data,
        }
    }

    /// Multiplies each sample by its colour's gain.
    fn balance(&mut self, gains: [f32; 3]) {
        for y in 0..self.height {
            for x in 0..self.width {
                self.data[y * self.width + x] *= gains[self.order.channel(x, y)];
            }
        }
    }
}

/// Grey-world white balance over `frames`: gains for red, green and blue making the three
/// colours' means over all frames equal, green's gain 1. Samples near clipping are left out (a
/// clipped highlight is white whatever the light, and would pull the estimate towards no
/// correction); a colour with no usable sample gets gain 1.
pub fn grey_world(frames: &[&Mosaic]) -> [f32; 3] {
    let mut sum = [0f64; 3];
    let mut n = [0u64; 3];
    for m in frames {
        for y in 0..m.height {
            for x in 0..m.width {
                let v = m.data[y * m.width + x];
                if v < 0.95 {
                    let c = m.order.channel(x, y);
                    sum[c] += f64::from(v.max(0.0));
                    n[c] += 1;
                }
            }
        }
    }
    let mean = |c: usize| sum[c] / n[c].max(1) as f64;
    let g = mean(1);
    let gain = |c: usize| {
        let m = mean(c);
        if m > 1e-6 && g > 1e-6 {
            (g / m) as f32
        } else {
            1.0
        }
    };
    [gain(0), 1.0, gain(2)]
}

pub use crate::stack::srgb::{
    decode as srgb_decode, encode as srgb_encode, tabulated as srgb_tabulated,
};

/// 8-bit sRGB to linear RGB: the inverse of [`encode`], for truths and frames made as pictures
/// that a test or measurement mosaics as a sensor would see them.
pub fn decode(img: &Image<u8>) -> Image<f32> {
    let data = img
        .data()
        .iter()
        .map(|&v| srgb_decode(f32::from(v) / 255.0))
        .collect();
    Image::from_vec(img.width(), img.height(), img.channels(), data)
}

/// Linear RGB to 8-bit sRGB.
pub fn encode(rgb: &Image<f32>) -> Image<u8> {
    let to8 = Encode8::table();
    let data = rgb.data().iter().map(|&v| to8.at(v)).collect();
    Image::from_vec(rgb.width(), rgb.height(), rgb.channels(), data)
}

/// Linear values as 8-bit sRGB, through a table over 12 bits of linear light made once (the
/// curve's libm `powf` per sample would dominate), fetched once per loop.
#[derive(Clone, Copy)]
pub struct Encode8(&'static [u8]);

impl Encode8 {
    pub const STEPS: usize = 4096;

    /// The table, made on first use.
    pub fn table() -> Encode8 {
        static TABLE: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
        Encode8(TABLE.get_or_init(|| {
            // Three bytes of padding, so that a four-byte read at the last step stays inside
            // (`pixels`' vector code).
            (0..=Self::STEPS)
                .map(|i| (srgb_encode(i as f32 / Self::STEPS as f32) * 255.0 + 0.5) as u8)
                .chain([0; 3])
                .collect()
        }))
    }

    /// The table, [`Encode8::STEPS`] + 1 values and three bytes of padding.
    pub fn bytes(self) -> &'static [u8] {
        self.0
    }

    /// The linear value `v` as 8-bit sRGB.
    #[inline]
    pub fn at(self, v: f32) -> u8 {
        // Not `clamp`, which keeps NaN: NaN goes to 0 here, where the cast of a clamped NaN put it.
        #[allow(clippy::manual_clamp)]
        let step = v.max(0.0).min(1.0) * Self::STEPS as f32 + 0.5;
        // SAFETY: 0.5 <= step <= STEPS + 0.5, inside i32 (a saturating `as` costs several
        // instructions a sample).
        let i: i32 = unsafe { step.to_int_unchecked() };
        self.0[i as usize]
    }
}

/// How one camera's raw frames are developed, with its white balance once measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Developer {
    /// The sensor's pedestal in its samples' units, for [`Mosaic::from_samples`].
    pub black_level: u32,
    /// Camera RGB (balanced) to linear sRGB, row by row.
    pub matrix: [[f32; 3]; 3],
    /// The gains in use; `None` until the first frame measures them.
    pub white_balance: Option<[f32; 3]>,
}

impl Developer {
    pub fn new(black_level: u32, matrix: [[f32; 3]; 3]) -> Developer {
        Developer {
            black_level,
            matrix,
            white_balance: None,
        }
    }

    /// Linear sRGB from a mosaic: white balance (measured on this frame if none is locked yet,
    /// then locked), demosaic, colour matrix.
    pub fn develop_linear(&mut self, mut m: Mosaic) -> Image<f32> {
        m.balance(self.gains(&m));
        let mut rgb = demosaic::demosaic(&m);
        self.to_srgb(&mut rgb, [1.0; 3]);
        rgb
    }

    /// Linear sRGB at half size from a mosaic ([`half::half_size`]), with the same white
    /// balance (measured and locked as by [`Developer::develop_linear`]) and colour matrix as
    /// the full development: the cheap development, for previews and for registering and
    /// labelling a stack.
    pub fn develop_half_linear(&mut self, m: &Mosaic) -> Image<f32> {
        let gains = self.gains(m);
        let mut rgb = half::half_size(m);
        self.to_srgb(&mut rgb, gains);
        rgb
    }

    /// The locked white balance, gains of 1 if none is.
    fn locked(&self) -> [f32; 3] {
        self.white_balance.unwrap_or([1.0; 3])
    }

    /// The locked white balance, measured on `m` if none is yet.
    fn gains(&mut self, m: &Mosaic) -> [f32; 3] {
        *self.white_balance.get_or_insert_with(|| grey_world(&[m]))
    }

    /// Camera RGB, each channel times its `gains`, through the colour matrix, in place.
    fn to_srgb(&self, rgb: &mut Image<f32>, gains: [f32; 3]) {
        for px in rgb.data_mut().chunks_exact_mut(3) {
            let v = self.srgb([px[0] * gains[0], px[1] * gains[1], px[2] * gains[2]]);
            px.copy_from_slice(&v);
        }
    }

    /// One pixel of balanced camera RGB through the colour matrix.
    #[inline]
    fn srgb(&self, v: [f32; 3]) -> [f32; 3] {
        self.matrix
            .map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
    }

    /// 8-bit sRGB from a mosaic.
    pub fn develop(&mut self, m: Mosaic) -> Image<u8> {
        encode(&self.develop_linear(m))
    }
}

/// The identity colour matrix.
pub const IDENTITY: [[f32; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

#[cfg(test)]
mod tests;
