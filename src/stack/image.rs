//! In-memory frames, generic over the sample type so 8- and 16-bit stacks keep their depth.

/// Luma from red, green and blue with the Rec. 601 weights, in whatever scale and light the
/// three come in: the one place the weights are written.
pub fn luma_of(r: f32, g: f32, b: f32) -> f32 {
    0.299 * r + 0.587 * g + 0.114 * b
}

/// A pixel sample type: `u8`, `u16` or `f32` (normalised to 0..=1).
pub trait Sample: Copy + PartialEq + Send + Sync + Default + 'static {
    /// The value that stands for full scale.
    const MAX: f32;
    fn to_f32(self) -> f32;
    /// Converts a value in sample units (0..=MAX), rounding and clamping.
    fn from_f32(v: f32) -> Self;
    /// |self − other| in sample units, truncated to an integer: the seam cost's colour term.
    /// Integer samples take it exactly in integers; through floats it was the labelling's
    /// hottest line.
    fn abs_diff_i32(self, other: Self) -> i32;
}

impl Sample for u8 {
    const MAX: f32 = 255.0;
    #[inline]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline]
    fn from_f32(v: f32) -> Self {
        // Truncating v + ½ rounds half away from zero like `round` on the clamped range, without
        // `round`'s libm call (baseline x86-64 has no rounding instruction).
        (v.clamp(0.0, 255.0) + 0.5) as u8
    }
    #[inline]
    fn abs_diff_i32(self, other: Self) -> i32 {
        self.abs_diff(other) as i32
    }
}

impl Sample for u16 {
    const MAX: f32 = 65535.0;
    #[inline]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline]
    fn from_f32(v: f32) -> Self {
        (v.clamp(0.0, 65535.0) + 0.5) as u16
    }
    #[inline]
    fn abs_diff_i32(self, other: Self) -> i32 {
        self.abs_diff(other) as i32
    }
}

impl Sample for f32 {
    const MAX: f32 = 1.0;
    #[inline]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline]
    fn from_f32(v: f32) -> Self {
        v
    }
    #[inline]
    fn abs_diff_i32(self, other: Self) -> i32 {
        (self - other).abs() as i32
    }
}

/// An interleaved image: `channels` samples per pixel, rows top to bottom. The fields are
/// private so the buffer always holds exactly `width · height · channels` samples.
#[derive(Debug, PartialEq)]
pub struct Image<T> {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<T>,
}

/// Why a buffer cannot be an image of the given size.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("image buffer holds {len} samples, {width}x{height}x{channels} needs {needed}")]
pub struct ImageSizeError {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub len: usize,
    pub needed: usize,
}

impl<T> Image<T> {
    #[inline]
    pub fn width(&self) -> usize {
        self.width
    }
    #[inline]
    pub fn height(&self) -> usize {
        self.height
    }
    #[inline]
    pub fn channels(&self) -> usize {
        self.channels
    }
    /// The samples, interleaved, rows top to bottom.
    #[inline]
    pub fn data(&self) -> &[T] {
        &self.data
    }
    /// The samples to write in place; the length cannot change.
    #[inline]
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
    /// The buffer, giving the image up.
    pub fn into_data(self) -> Vec<T> {
        self.data
    }
    /// An image over `data`, or why its length does not fit the size.
    pub fn from_raw(
        width: usize,
        height: usize,
        channels: usize,
        data: Vec<T>,
    ) -> Result<Self, ImageSizeError> {
        let needed = width
            .checked_mul(height)
            .and_then(|p| p.checked_mul(channels));
        match needed {
            Some(n) if n == data.len() => Ok(Self {
                width,
                height,
                channels,
                data,
            }),
            _ => Err(ImageSizeError {
                width,
                height,
                channels,
                len: data.len(),
                needed: needed.unwrap_or(usize::MAX),
            }),
        }
    }
}

impl<T: Clone> Clone for Image<T> {
    fn clone(&self) -> Self {
        Self {
            data: self.data.clone(),
            ..*self
        }
    }

    /// Copies `src` into `self`'s buffer: a stage that makes a plane of the same size for every
    /// frame can keep one, rather than map and fault in fresh memory each time.
    fn clone_from(&mut self, src: &Self) {
        (self.width, self.height, self.channels) = (src.width, src.height, src.channels);
        self.data.clone_from(&src.data);
    }
}

/// A single-channel working plane in f32.
pub type Plane = Image<f32>;

impl<T: Sample> Image<T> {
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        Self::from_vec(
            width,
            height,
            channels,
            vec![T::default(); width * height * channels],
        )
    }

    /// Panics when the buffer length does not match: for buffers the caller sized itself
    /// (a programming error, not bad input); [`Image::from_raw`] is the fallible form.
    pub fn from_vec(width: usize, height: usize, channels: usize, data: Vec<T>) -> Self {
        match Self::from_raw(width, height, channels, data) {
            Ok(image) => image,
            Err(e) => panic!("{e}"),
        }
    }

    /// Gives the image another size in place, keeping its allocation where it is large
    /// enough: the samples already there stay, new ones are the default (as `Vec::resize`).
    pub fn resize(&mut self, width: usize, height: usize, channels: usize) {
        (self.width, self.height, self.channels) = (width, height, channels);
        self.data.resize(width * height * channels, T::default());
    }

    pub fn from_fn(
        width: usize,
        height: usize,
        channels: usize,
        mut f: impl FnMut(usize, usize, usize) -> T,
    ) -> Self {
        let mut data = Vec::with_capacity(width * height * channels);
        for y in 0..height {
            for x in 0..width {
                for c in 0..channels {
                    data.push(f(x, y, c));
                }
            }
        }
        Self::from_vec(width, height, channels, data)
    }

    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    #[inline]
    pub fn at(&self, x: usize, y: usize, c: usize) -> T {
        self.data[(y * self.width + x) * self.channels + c]
    }

    pub fn same_geometry<U>(&self, other: &Image<U>) -> bool {
        self.width == other.width && self.height == other.height && self.channels == other.channels
    }

    /// Luma (Rec. 601 weights) normalised to 0..=1: the signal every focus measure works on.
    pub fn luma(&self) -> Plane {
        self.luma_rows(0..self.height)
    }

    /// The luma of rows `rows` only, as a plane of that many rows.
    pub fn luma_rows(&self, rows: std::ops::Range<usize>) -> Plane {
        let w = self.width;
        let mut data = vec![0.0; w * rows.len()];
        if w > 0 {
            for (out, y) in data.chunks_exact_mut(w).zip(rows.clone()) {
                self.luma_row(y, out);
            }
        }
        Plane::from_vec(w, rows.len(), 1, data)
    }

    /// The luma of row `y` into `out`, `width` values: for a pass that streams rows and needs
    /// no luma plane.
    pub fn luma_row(&self, y: usize, out: &mut [f32]) {
        let scale = 1.0 / T::MAX;
        let n = self.width * self.channels;
        let samples = &self.data[y * n..(y + 1) * n];
        match self.channels {
            1 => out
                .iter_mut()
                .zip(samples)
                .for_each(|(o, v)| *o = v.to_f32() * scale),
            _ => out
                .iter_mut()
                .zip(samples.chunks_exact(self.channels))
                .for_each(|(o, p)| {
                    *o = luma_of(p[0].to_f32(), p[1].to_f32(), p[2].to_f32()) * scale
                }),
        }
    }

    /// Splits into f32 planes normalised to 0..=1, one per channel.
    pub fn to_planes(&self) -> Vec<Plane> {
        let scale = 1.0 / T::MAX;
        (0..self.channels)
            .map(|c| {
                let data = self
                    .data
                    .iter()
                    .skip(c)
                    .step_by(self.channels)
                    .map(|v| v.to_f32() * scale)
                    .collect();
                Plane::from_vec(self.width, self.height, 1, data)
            })
            .collect()
    }

    /// Interleaves normalised planes back into samples of this type.
    pub fn from_planes(planes: &[Plane]) -> Self {
        let (w, h, n) = (planes[0].width, planes[0].height, planes.len());
        let mut data = Vec::with_capacity(w * h * n);
        for i in 0..w * h {
            for p in planes {
                data.push(T::from_f32(p.data[i] * T::MAX));
            }
        }
        Self::from_vec(w, h, n, data)
    }

    /// Converts to another sample type, rescaling full scale to full scale.
    pub fn convert<U: Sample>(&self) -> Image<U> {
        let k = U::MAX / T::MAX;
        Image::from_vec(
            self.width,
            self.height,
            self.channels,
            self.data
                .iter()
                .map(|v| U::from_f32(v.to_f32() * k))
                .collect(),
        )
    }
}

/// Where a bilinear sample reads along one axis: the two neighbouring pixels (clamped to the
/// edge) and the weight of the second. A regular grid of samples, such as a reduced map read at
/// every full-resolution pixel, computes each row's and each column's taps once instead of at
/// every sample of every plane.
#[derive(Clone, Copy, Debug)]
pub struct Tap {
    lo: usize,
    hi: usize,
    frac: f32,
}

impl Tap {
    /// The taps of coordinate `v` (pixel-centre) on an axis of `n` pixels.
    #[inline]
    pub fn new(v: f32, n: usize) -> Tap {
        let n = n as isize;
        let f = v.floor();
        Tap {
            lo: (f as isize).clamp(0, n - 1) as usize,
            hi: (f as isize + 1).clamp(0, n - 1) as usize,
            frac: v - f,
        }
    }

    /// The pixel at or before the coordinate, clamped to the axis.
    #[inline]
    pub fn cell(self) -> usize {
        self.lo
    }

    /// The taps of full-resolution pixel `i`'s centre on an axis reduced by `factor` to
    /// `reduced` pixels.
    pub fn reduced(i: usize, factor: usize, reduced: usize) -> Tap {
        Tap::new((i as f32 + 0.5) * (1.0 / factor as f32) - 0.5, reduced)
    }

    /// [`Self::reduced`] of each of `full` pixels: a frame's columns read the same taps on
    /// every row and in every plane.
    pub fn all_reduced(full: usize, factor: usize, reduced: usize) -> Vec<Tap> {
        (0..full)
            .map(|x| Tap::reduced(x, factor, reduced))
            .collect()
    }
}

impl Plane {
    /// Bilinear sample with edge clamping; (x, y) in pixel-centre coordinates.
    #[inline]
    pub fn sample_bilinear(&self, x: f32, y: f32) -> f32 {
        self.sample_taps(Tap::new(x, self.width), Tap::new(y, self.height))
    }

    /// Bilinear sample at the taps of a column and a row (made for this plane's size).
    #[inline]
    pub fn sample_taps(&self, tx: Tap, ty: Tap) -> f32 {
        let (r0, r1) = (ty.lo * self.width, ty.hi * self.width);
        let (fx, fy) = (tx.frac, ty.frac);
        let top = self.data[r0 + tx.lo] * (1.0 - fx) + self.data[r0 + tx.hi] * fx;
        let bot = self.data[r1 + tx.lo] * (1.0 - fx) + self.data[r1 + tx.hi] * fx;
        top * (1.0 - fy) + bot * fy
    }
}

#[cfg(test)]
mod tests {
    use super::Sample;

    /// The integer seam term must equal the float one it replaced, |a − b| truncated, or the
    /// labels (and every output) would change.
    #[test]
    fn integer_abs_diff_matches_the_float_definition() {
        let float = |a: f32, b: f32| (a - b).abs() as i32;
        for a in 0..=255u8 {
            for b in 0..=255u8 {
                assert_eq!(a.abs_diff_i32(b), float(a.to_f32(), b.to_f32()), "{a} {b}");
            }
        }
        for (a, b) in [
            (0u16, 65535u16),
            (65535, 0),
            (40000, 39999),
            (7, 7),
            (1, 30000),
        ] {
            assert_eq!(a.abs_diff_i32(b), float(a.to_f32(), b.to_f32()), "{a} {b}");
        }
        assert_eq!(0.25f32.abs_diff_i32(3.75), 3);
    }
}
