//! Per-pixel focus measure: local energy of a difference of Gaussians (the paper's unary term).

use super::blur::{
    gaussian_half, par_strips, Cached, LumaRows, PlaneRows, RowBlur, RowCache, Rows,
};
use super::image::{Image, Plane, Sample};
use rayon::prelude::*;
use std::cell::RefCell;
use std::ops::Range;

/// Focus measure settings, in pixels of the frame.
#[derive(Clone, Debug)]
pub struct FocusParams {
    /// The DoG band: blur at `sigma_fine` minus blur at `sigma_coarse`.
    pub sigma_fine: f32,
    pub sigma_coarse: f32,
    /// Gaussian window over which the squared DoG response is aggregated.
    pub window: f32,
}

impl Default for FocusParams {
    fn default() -> Self {
        Self {
            sigma_fine: 0.7,
            sigma_coarse: 2.0,
            window: 2.0,
        }
    }
}

/// Rows beyond a pixel that its amplitude depends on: the wider DoG blur, then the window.
pub fn focus_reach(p: &FocusParams) -> usize {
    let r = |sigma: f32| gaussian_half(sigma).len() - 1;
    r(p.sigma_fine).max(r(p.sigma_coarse)) + r(p.window)
}

/// Amplitudes are stored as u16 with this full scale (luma is 0..=1, a DoG amplitude ≲ 0.5),
/// which halves memory against f32 and keeps 1.5e-5 resolution, far below sensor noise.
pub const AMP_SCALE: f32 = 65535.0;

/// RMS DoG response around each pixel, quantised to u16 (see `AMP_SCALE`).
///
/// One streaming pass: the two blurs feed DoG² rows straight into the window blur, whose rows
/// are quantised as they come, so the only full-size buffer is the result.
pub fn focus_amplitude(luma: &Plane, p: &FocusParams) -> Vec<u16> {
    amplitude(PlaneRows(luma), luma.width(), luma.height(), p)
}

/// [`focus_amplitude`] of the luma of `frame`'s rows `rows`, each luma row made as the blurs
/// read it: a whole float luma plane a frame was a tenth of a fuse's freshly faulted memory.
pub fn frame_focus_amplitude<T: Sample>(
    frame: &Image<T>,
    rows: Range<usize>,
    p: &FocusParams,
) -> Vec<u16> {
    let source = LumaRows {
        image: frame,
        first: rows.start,
    };
    amplitude(source, frame.width(), rows.len(), p)
}

/// [`focus_amplitude`] of the `w`×`h` rows of `src`.
fn amplitude<S: Rows + Copy + Sync>(src: S, w: usize, h: usize, p: &FocusParams) -> Vec<u16> {
    let (fine, coarse, window) = (
        gaussian_half(p.sigma_fine),
        gaussian_half(p.sigma_coarse),
        gaussian_half(p.window),
    );
    let mut amp = vec![0u16; w * h];
    par_strips(&mut amp, w, h, |y0, strip| {
        // Both blurs read each source row: the coarse (wider) one first, which asks for the
        // rows in order, the fine one at most `slots` − 1 rows later (at a strip's first row,
        // all within the coarse blur's reach at once).
        let slots = 2 * fine.len().max(coarse.len()) - 1;
        let rows = RefCell::new(RowCache::new(src, w, slots));
        let dog = DogSquared {
            fine: RowBlur::new(Cached(&rows), w, h, &fine),
            coarse: RowBlur::new(Cached(&rows), w, h, &coarse),
            tmp: vec![0.0; w],
        };
        let mut energy = RowBlur::new(dog, w, h, &window);
        let mut row = vec![0.0; w];
        for (y, out) in (y0..).zip(strip.chunks_exact_mut(w)) {
            energy.row(y, &mut row);
            for (a, e) in out.iter_mut().zip(&row) {
                *a = quantise(e.max(0.0).sqrt() * AMP_SCALE);
            }
        }
    });
    amp
}

/// `v.round().min(65535.0) as u16` for v ≥ 0, exactly, in operations that vectorise
/// (`f32::round` is a libm call on baseline x86-64, and float-to-int casts saturate lane by
/// lane): adding 2²³ leaves the integer nearest v, ties to even, in the mantissa; ties that went
/// down are then moved up, as `round` takes them away from zero.
#[inline(always)]
fn quantise(v: f32) -> u16 {
    const TWO_23: f32 = 8_388_608.0;
    let v = v.min(65535.0);
    let r = v + TWO_23;
    let tie_down = (v - (r - TWO_23) == 0.5) as u32;
    ((r.to_bits() & 0x7f_ffff) + tie_down) as u16
}

/// Rows of the squared difference of two blurs of the same source. The coarse blur reads each
/// row first (see [`amplitude`]'s cache).
struct DogSquared<'k, S> {
    fine: RowBlur<'k, S>,
    coarse: RowBlur<'k, S>,
    tmp: Vec<f32>,
}

impl<S: Rows> Rows for DogSquared<'_, S> {
    fn row(&mut self, y: usize, out: &mut [f32]) {
        self.coarse.row(y, &mut self.tmp);
        self.fine.row(y, out);
        for (f, c) in out.iter_mut().zip(&self.tmp) {
            *f = (*f - c) * (*f - c);
        }
    }
}

/// Per-pixel maximum over the stack.
pub fn max_amplitude(amps: &[Vec<u16>]) -> Vec<u16> {
    let mut m = amps[0].clone();
    for a in &amps[1..] {
        m.par_iter_mut().zip(a).for_each(|(m, &v)| *m = (*m).max(v));
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::blur::gaussian_blur;

    #[test]
    fn sharper_texture_has_higher_amplitude() {
        let sharp = Plane::from_fn(64, 64, 1, |x, y, _| ((x / 2 + y / 2) % 2) as f32);
        let soft = gaussian_blur(&sharp, 2.0);
        let flat = Plane::from_fn(64, 64, 1, |_, _, _| 0.5);
        let p = FocusParams::default();
        let mean = |v: Vec<u16>| v.iter().map(|&a| a as f64).sum::<f64>() / v.len() as f64;
        let (a, b, c) = (
            mean(focus_amplitude(&sharp, &p)),
            mean(focus_amplitude(&soft, &p)),
            mean(focus_amplitude(&flat, &p)),
        );
        assert!(a > 3.0 * b, "sharp {a} vs soft {b}");
        assert!(b > c && c == 0.0);
    }

    #[test]
    fn quantise_rounds_half_away_like_round() {
        // Neighbouring floats by their bits (positive floats order like their bit patterns).
        let step = |x: f32, d: i32| f32::from_bits(x.to_bits().wrapping_add_signed(d));
        let mut v = 0.0f32;
        while v < 70000.0 {
            for x in [v, v + 0.5, step(v, 1), step(v + 0.5, -1), step(v + 0.5, 1)] {
                assert_eq!(quantise(x), x.round().min(65535.0) as u16, "{x}");
            }
            v += 0.75;
        }
        assert_eq!(quantise(f32::INFINITY), 65535);
    }

    /// A frame's rows measured straight from its samples give the amplitudes of its luma
    /// plane's rows, to the bit, in colour and grey.
    #[test]
    fn frame_rows_measure_as_their_luma_plane() {
        let p = FocusParams::default();
        let colour =
            Image::<u8>::from_fn(57, 90, 3, |x, y, c| ((x * 7 + y * y + c * 50) % 251) as u8);
        let grey = Image::<u16>::from_fn(40, 33, 1, |x, y, _| ((x * y * 977) % 65521) as u16);
        for rows in [0..90, 20..61, 89..90] {
            let plane = focus_amplitude(&colour.luma_rows(rows.clone()), &p);
            assert_eq!(frame_focus_amplitude(&colour, rows, &p), plane);
        }
        let plane = focus_amplitude(&grey.luma(), &p);
        assert_eq!(frame_focus_amplitude(&grey, 0..33, &p), plane);
    }

    #[test]
    fn streamed_amplitude_matches_blur_composition() {
        let luma = Plane::from_fn(83, 141, 1, |x, y, _| ((x * x + 3 * y) % 17) as f32 / 17.0);
        for p in [
            FocusParams::default(),
            FocusParams {
                sigma_fine: 0.0,
                sigma_coarse: 1.3,
                window: 0.0,
            },
        ] {
            let (fine, coarse) = (
                gaussian_blur(&luma, p.sigma_fine),
                gaussian_blur(&luma, p.sigma_coarse),
            );
            let dog: Vec<f32> = fine
                .data()
                .iter()
                .zip(coarse.data())
                .map(|(f, c)| (f - c) * (f - c))
                .collect();
            let energy = gaussian_blur(&Plane::from_vec(83, 141, 1, dog), p.window);
            let want = energy
                .data()
                .iter()
                .map(|e| (e.max(0.0).sqrt() * AMP_SCALE).round() as i32);
            let err = focus_amplitude(&luma, &p)
                .iter()
                .zip(want)
                .map(|(&a, b)| (a as i32 - b).abs())
                .max();
            assert!(err <= Some(1), "max error {err:?}");
        }
    }
}
