//! Demosaicing: the two colours each Bayer sample lacks.
//!
//! Done on sRGB-encoded samples, not in linear light: shading and shadows scale all three
//! colours together, which in linear light changes their differences in proportion but in an
//! encoded signal hardly at all, and the filters below assume smooth colour differences. On the
//! simulator's scenes this alone is worth about 3.5 dB for the same filters (measured by the
//! tests, which print the figures).
//!
//! Malvar, He and Cutler's gradient-corrected linear interpolation ("High-quality linear
//! interpolation for demosaicing of Bayer-patterned color images", ICASSP 2004): the bilinear
//! estimate of a missing colour plus a fraction of the Laplacian of the colour the pixel has,
//! which puts back the detail bilinear interpolation blurs and cancels most of its colour
//! fringes and zipper along edges. Fixed 5×5 filters, so it costs little more than bilinear.
//! Written here: the crates that demosaic (`bayer`, `rawloader`'s companions) are unmaintained
//! or bring a whole raw-file stack; this is forty lines.

use super::Mosaic;
use crate::stack::image::Image;
use crate::stack::srgb;

/// The mosaic with two samples of mirrored border on each side (mirrored about the edge sample,
/// which keeps the colour pattern's phase), so the 5×5 filters need no bounds checks.
struct Padded {
    width: usize,
    data: Vec<f32>,
}

const PAD: usize = 2;

impl Padded {
    fn new(m: &Mosaic) -> Padded {
        let (w, h) = (m.width, m.height);
        let mirror = |i: isize, n: usize| -> usize {
            let n = n as isize;
            let i = if i < 0 { -i } else { i };
            (if i >= n { 2 * (n - 1) - i } else { i }).clamp(0, n - 1) as usize
        };
        let pw = w + 2 * PAD;
        let mut data = Vec::with_capacity(pw * (h + 2 * PAD));
        for y in 0..h + 2 * PAD {
            let sy = mirror(y as isize - PAD as isize, h);
            for x in 0..pw {
                let sx = mirror(x as isize - PAD as isize, w);
                data.push(m.data[sy * w + sx]);
            }
        }
        Padded { width: pw, data }
    }

    /// The sample at (x + dx, y + dy) of the unpadded mosaic.
    #[inline]
    fn at(&self, x: usize, y: usize, dx: isize, dy: isize) -> f32 {
        let px = (x + PAD) as isize + dx;
        let py = (y + PAD) as isize + dy;
        self.data[py as usize * self.width + px as usize]
    }
}

/// The sRGB curve (or its inverse) extended oddly below 0 and on above 1, so that noise
/// around black and balanced highlights keep their values through the round trip. Tabulated
/// on 0..2 and interpolated: a `powf` per sample took most of a frame's development.
struct Curve {
    f: fn(f32) -> f32,
    table: Vec<f32>,
}

const CURVE_RANGE: f32 = 2.0;
const CURVE_STEPS: usize = 8192;

impl Curve {
    fn new(f: fn(f32) -> f32) -> Curve {
        let table = (0..=CURVE_STEPS)
            .map(|i| f(i as f32 * CURVE_RANGE / CURVE_STEPS as f32))
            .collect();
        Curve { f, table }
    }

    #[inline]
    fn at(&self, v: f32) -> f32 {
        let a = v.abs();
        if a >= CURVE_RANGE {
            return v.signum() * (self.f)(a);
        }
        let x = a * (CURVE_STEPS as f32 / CURVE_RANGE);
        let i = x as usize;
        let (lo, hi) = (self.table[i], self.table[i + 1]);
        v.signum() * (lo + (x - i as f32) * (hi - lo))
    }
}

/// Linear RGB, three channels, from a linear mosaic: Malvar–He–Cutler on its encoded samples.
pub fn demosaic(m: &Mosaic) -> Image<f32> {
    encoded(m, malvar)
}

/// `filter` run on the mosaic's sRGB-encoded samples, its output decoded to linear light.
fn encoded(m: &Mosaic, filter: fn(&Mosaic) -> Image<f32>) -> Image<f32> {
    let encode = Curve::new(srgb::curve);
    let decode = Curve::new(srgb::curve_inverse);
    let encoded = Mosaic {
        data: m.data.iter().map(|&v| encode.at(v)).collect(),
        ..m.clone()
    };
    let mut rgb = filter(&encoded);
    for v in &mut rgb.data {
        *v = decode.at(*v);
    }
    rgb
}

/// Malvar–He–Cutler: three channels from a mosaic, in the mosaic's own encoding.
fn malvar(m: &Mosaic) -> Image<f32> {
    let p = Padded::new(m);
    let mut out = Vec::with_capacity(m.width * m.height * 3);
    for y in 0..m.height {
        for x in 0..m.width {
            let s = |dx: isize, dy: isize| p.at(x, y, dx, dy);
            let c = s(0, 0);
            // The filters of the paper's figure 2, each times 8.
            let cross = s(-1, 0) + s(1, 0) + s(0, -1) + s(0, 1);
            let far = s(-2, 0) + s(2, 0) + s(0, -2) + s(0, 2);
            let diag = s(-1, -1) + s(1, -1) + s(-1, 1) + s(1, 1);
            let far_h = s(-2, 0) + s(2, 0);
            let far_v = s(0, -2) + s(0, 2);
            // Green at a red or blue sample.
            let g_at_rb = (4.0 * c + 2.0 * cross - far) / 8.0;
            // Red (blue) at a green sample whose row holds red (blue): from the left and right.
            let from_row =
                (5.0 * c + 4.0 * (s(-1, 0) + s(1, 0)) - diag - far_h + 0.5 * far_v) / 8.0;
            // ... whose column holds it: from above and below.
            let from_col =
                (5.0 * c + 4.0 * (s(0, -1) + s(0, 1)) - diag - far_v + 0.5 * far_h) / 8.0;
            // Red at blue, blue at red: from the diagonals.
            let from_diag = (6.0 * c + 2.0 * diag - 1.5 * far) / 8.0;
            let rgb = match m.order.channel(x, y) {
                0 => [c, g_at_rb, from_diag],
                2 => [from_diag, g_at_rb, c],
                _ if m.order.channel(x + 1, y) == 0 => [from_row, c, from_col],
                _ => [from_col, c, from_row],
            };
            out.extend_from_slice(&rgb);
        }
    }
    Image::from_vec(m.width, m.height, 3, out)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::develop::BayerOrder;

    /// Bilinear interpolation: each missing colour the mean of its samples among the 3×3
    /// neighbours, what focusd did before and the baseline the quality tests compare with.
    pub fn bilinear(m: &Mosaic) -> Image<f32> {
        let p = Padded::new(m);
        let mut out = Vec::with_capacity(m.width * m.height * 3);
        for y in 0..m.height {
            for x in 0..m.width {
                let mut sum = [0f32; 3];
                let mut n = [0f32; 3];
                for dy in -1..=1isize {
                    for dx in -1..=1isize {
                        // The padding mirrors, so the colour at (x+dx, y+dy) is the pattern's.
                        let c = m.order.channel(
                            (x + 2).wrapping_add_signed(dx),
                            (y + 2).wrapping_add_signed(dy),
                        );
                        sum[c] += p.at(x, y, dx, dy);
                        n[c] += 1.0;
                    }
                }
                let own = m.order.channel(x, y);
                for c in 0..3 {
                    out.push(if c == own {
                        p.at(x, y, 0, 0)
                    } else {
                        sum[c] / n[c]
                    });
                }
            }
        }
        Image::from_vec(m.width, m.height, 3, out)
    }

    /// Bilinear on sRGB-encoded samples: the same domain as `demosaic`, so that comparing the
    /// two credits the filters, not only the encoding.
    pub fn bilinear_encoded(m: &Mosaic) -> Image<f32> {
        encoded(m, bilinear)
    }

    #[test]
    fn the_tabulated_curves_follow_the_formulas() {
        for f in [srgb::curve, srgb::curve_inverse] {
            let c = Curve::new(f);
            for i in -3000..=3000 {
                let v = i as f32 / 1000.0;
                let exact = v.signum() * f(v.abs());
                assert!(
                    (c.at(v) - exact).abs() < 2e-5,
                    "{v}: {} against {exact}",
                    c.at(v)
                );
            }
        }
    }

    #[test]
    fn flat_colours_and_ramps_come_back_exactly() {
        // A linear ramp in each channel is reproduced by both filters (their Laplacian terms
        // vanish), away from the mirrored border.
        for order in [
            BayerOrder::Rggb,
            BayerOrder::Bggr,
            BayerOrder::Grbg,
            BayerOrder::Gbrg,
        ] {
            let rgb = Image::from_fn(12, 10, 3, |x, y, c| {
                0.1 + 0.02 * x as f32 + 0.01 * y as f32 + 0.1 * c as f32
            });
            let m = Mosaic::sample(&rgb, order);
            for out in [malvar(&m), bilinear(&m)] {
                for y in 2..8 {
                    for x in 2..10 {
                        for c in 0..3 {
                            let (got, want) = (out.at(x, y, c), rgb.at(x, y, c));
                            assert!(
                                (got - want).abs() < 1e-5,
                                "{order:?} ({x},{y},{c}): {got} {want}"
                            );
                        }
                    }
                }
            }
        }
    }
}
