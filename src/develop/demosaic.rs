//! Demosaicing: the two colours each Bayer sample lacks.
//!
//! Done on sRGB-encoded samples, not in linear light: shading and shadows scale all three
//! colours together, which in linear light changes their differences in proportion but in an
//! encoded signal hardly at all, and the filters below assume smooth colour differences. On the
//! simulator's scenes this alone is worth about 3.5 dB for the same filters (measured by the
//! tests, which print the figures).
//!
//! Residual interpolation (Kiku, Monno, Tanaka and Okutomi, "Residual interpolation for color
//! image demosaicking", ICIP 2013): green first (Hamilton and Adams' edge-directed estimate),
//! then red and blue each from a guided filter with the green as guide (a local linear fit
//! a·G + b to the colour's own samples), the fit's residuals at those samples interpolated
//! bilinearly and added back. Residuals are far smoother than colour differences, so bilinear
//! interpolation of them loses little. Green is then fitted again the same way with red and
//! blue as guides, and red and blue once more from that green. Malvar, He and Cutler's linear
//! filters, which focusd used before, are kept by the tests as the baseline this must beat.
//!
//! Written here: the crates that demosaic (`bayer`, `rawloader`'s companions) are unmaintained,
//! bring a whole raw-file stack, or offer only bilinear and Malvar–He–Cutler.
//!
//! A frame is developed in strips of rows, in parallel; each strip reads a halo of `PAD` rows
//! above and below, as far as any output pixel's value reaches, so strips give exactly the
//! whole frame's result (a test checks it) while the working planes stay a strip's size.

use super::{BayerOrder, Mosaic};
use crate::stack::image::Image;
use crate::stack::srgb;
use rayon::prelude::*;

/// Half the side of the guided filter's square window: its statistics, and the average of its
/// coefficients, are taken over (2·RADIUS + 1)² pixels.
const RADIUS: usize = 2;

/// Guided filter regularisation, in squared encoded units: keeps the fit's slope finite on flat
/// patches, where the guide has no variance.
const EPS: f32 = 1e-5;

/// How far an output pixel's value reaches into the mosaic: two samples for the green, then
/// 2·RADIUS + 1 for each of the three residual fills (statistics, averaged coefficients, the
/// residuals' interpolation).
const REACH: usize = 2 + 3 * (2 * RADIUS + 1);

/// The mirrored border around the mosaic, and the halo above and below each strip: the reach,
/// made even so that padded coordinates keep the colour pattern's phase.
const PAD: usize = REACH + REACH % 2;

/// Output rows per strip (even, for the pattern's phase): several strips per core on a phone
/// frame, while the halo adds at most a quarter to the work.
const STRIP_ROWS: usize = 144;

/// The mosaic with `PAD` samples of mirrored border on each side (mirrored about the edge
/// sample, which keeps the colour pattern's phase), the samples mapped through `f`.
struct Padded {
    width: usize,
    data: Vec<f32>,
}

impl Padded {
    fn new(m: &Mosaic, f: impl Fn(f32) -> f32) -> Padded {
        let (w, h) = (m.width, m.height);
        // Reflections about the first and the last sample, repeated, so that even a mosaic
        // smaller than the border is extended with the right colours.
        let mirror = |i: usize, n: usize| -> usize {
            if n == 1 {
                return 0;
            }
            let period = 2 * (n - 1);
            let i = (i + period * PAD - PAD) % period;
            if i >= n {
                period - i
            } else {
                i
            }
        };
        let pw = w + 2 * PAD;
        let cols: Vec<usize> = (0..pw).map(|x| mirror(x, w)).collect();
        let mut data = Vec::with_capacity(pw * (h + 2 * PAD));
        for y in 0..h + 2 * PAD {
            let row = &m.data[mirror(y, h) * w..][..w];
            data.extend(cols.iter().map(|&sx| f(row[sx])));
        }
        Padded { width: pw, data }
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

/// Linear RGB, three channels, from a linear mosaic: residual interpolation on its encoded
/// samples.
pub fn demosaic(m: &Mosaic) -> Image<f32> {
    in_strips(m, STRIP_ROWS)
}

/// [`demosaic`] computed `rows` output rows at a time.
fn in_strips(m: &Mosaic, rows: usize) -> Image<f32> {
    debug_assert!(rows > 0 && rows % 2 == 0);
    let (w, h) = (m.width, m.height);
    let mut out = vec![0.0f32; w * h * 3];
    if out.is_empty() {
        return Image::from_vec(w, h, 3, out);
    }
    let encode = Curve::new(srgb::curve);
    let decode = Curve::new(srgb::curve_inverse);
    let p = Padded::new(m, |v| encode.at(v));
    let pw = p.width;
    out.par_chunks_mut(rows * w * 3)
        .enumerate()
        .for_each(|(i, chunk)| {
            let n = chunk.len() / (w * 3);
            let strip = &p.data[i * rows * pw..(i * rows + n + 2 * PAD) * pw];
            let rgb = residual_interpolation(strip, pw, m.order);
            for (y, row) in chunk.chunks_exact_mut(w * 3).enumerate() {
                let at = (y + PAD) * pw + PAD;
                for (x, px) in row.chunks_exact_mut(3).enumerate() {
                    for (v, plane) in px.iter_mut().zip(&rgb) {
                        *v = decode.at(plane[at + x]);
                    }
                }
            }
        });
    Image::from_vec(w, h, 3, out)
}

/// Red, green and blue planes from the `w`-wide mosaic `m` (a strip of the padded frame, whose
/// first row has the pattern's phase). Values within `REACH` of the strip's edges are not
/// meaningful.
fn residual_interpolation(m: &[f32], w: usize, order: BayerOrder) -> [Vec<f32>; 3] {
    let is = |c: usize| move |x: usize, y: usize| order.channel(x, y) == c;
    let g = hamilton_adams(m, w, order);
    let r = residual_fill(&g, m, w, is(0), Sites::Grid);
    let b = residual_fill(&g, m, w, is(2), Sites::Grid);
    // Green again, at red samples with red as the guide, at blue ones with blue.
    let from_r = residual_fill(&r, m, w, is(1), Sites::Quincunx);
    let from_b = residual_fill(&b, m, w, is(1), Sites::Quincunx);
    let mut g = from_r;
    for (y, (row, other)) in g
        .chunks_exact_mut(w)
        .zip(from_b.chunks_exact(w))
        .enumerate()
    {
        for (x, (v, o)) in row.iter_mut().zip(other).enumerate() {
            if order.channel(x, y) == 2 {
                *v = *o;
            }
        }
    }
    let r = residual_fill(&g, m, w, is(0), Sites::Grid);
    let b = residual_fill(&g, m, w, is(2), Sites::Grid);
    [r, g, b]
}

/// Green at red and blue samples by Hamilton and Adams' rule: along the row or the column,
/// whichever changes less, the mean of the two green neighbours corrected by the second
/// difference of the sample's own colour.
fn hamilton_adams(m: &[f32], w: usize, order: BayerOrder) -> Vec<f32> {
    let h = m.len() / w;
    let mut g = m.to_vec();
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            if order.channel(x, y) == 1 {
                continue;
            }
            let i = y * w + x;
            let c2 = 2.0 * m[i];
            let (l, r, across) = (m[i - 1], m[i + 1], c2 - m[i - 2] - m[i + 2]);
            let (u, d, down) = (m[i - w], m[i + w], c2 - m[i - 2 * w] - m[i + 2 * w]);
            let dh = (l - r).abs() + across.abs();
            let dv = (u - d).abs() + down.abs();
            let gh = (l + r) / 2.0 + across / 4.0;
            let gv = (u + d) / 2.0 + down / 4.0;
            g[i] = if dh < dv {
                gh
            } else if dv < dh {
                gv
            } else {
                (gh + gv) / 2.0
            };
        }
    }
    g
}

/// Where a colour's samples lie: red and blue every other row and column, green in a quincunx.
#[derive(Clone, Copy)]
enum Sites {
    Grid,
    Quincunx,
}

/// The colour whose samples lie where `on_site` holds in `m`, at every pixel: the guided
/// filter's fit to those samples with `guide` as the guide, plus the fit's residuals at the
/// samples interpolated bilinearly.
fn residual_fill(
    guide: &[f32],
    m: &[f32],
    w: usize,
    on_site: impl Fn(usize, usize) -> bool,
    sites: Sites,
) -> Vec<f32> {
    let n = m.len();
    // Count, sums of guide and samples, of the guide squared and of their product, over the
    // samples in each window.
    let mut q: [Vec<f32>; 5] = std::array::from_fn(|_| vec![0.0; n]);
    for (y, (g, v)) in guide.chunks_exact(w).zip(m.chunks_exact(w)).enumerate() {
        for x in 0..w {
            if on_site(x, y) {
                let (g, v, i) = (g[x], v[x], y * w + x);
                q[0][i] = 1.0;
                q[1][i] = g;
                q[2][i] = v;
                q[3][i] = g * g;
                q[4][i] = g * v;
            }
        }
    }
    let s = q.map(|p| window_sum(&p, w));
    let mut a = vec![0.0f32; n];
    let mut b = vec![0.0f32; n];
    for i in 0..n {
        let k = s[0][i];
        if k > 0.0 {
            let (mg, mv) = (s[1][i] / k, s[2][i] / k);
            let var = s[3][i] / k - mg * mg;
            let cov = s[4][i] / k - mg * mv;
            a[i] = cov / (var + EPS);
            b[i] = mv - a[i] * mg;
        }
    }
    let (a, b) = (window_sum(&a, w), window_sum(&b, w));
    let area = ((2 * RADIUS + 1) * (2 * RADIUS + 1)) as f32;
    let mut fit: Vec<f32> = guide
        .iter()
        .zip(a.iter().zip(&b))
        .map(|(g, (a, b))| (a * g + b) / area)
        .collect();
    let mut res = vec![0.0f32; n];
    for (y, (r, (f, v))) in res
        .chunks_exact_mut(w)
        .zip(fit.chunks_exact(w).zip(m.chunks_exact(w)))
        .enumerate()
    {
        for x in 0..w {
            if on_site(x, y) {
                r[x] = v[x] - f[x];
            }
        }
    }
    // Bilinear interpolation of samples on the sites, zero elsewhere: each pixel gets its own
    // sample or the mean of its two or four nearest.
    match sites {
        Sites::Grid => {
            let mut across = vec![0.0f32; n];
            for i in 1..n - 1 {
                across[i] = res[i] + 0.5 * (res[i - 1] + res[i + 1]);
            }
            for i in w..n - w {
                fit[i] += across[i] + 0.5 * (across[i - w] + across[i + w]);
            }
        }
        Sites::Quincunx => {
            for i in w..n - w {
                fit[i] += res[i] + 0.25 * (res[i - 1] + res[i + 1] + res[i - w] + res[i + w]);
            }
        }
    }
    fit
}

/// Sums over the (2·RADIUS + 1)² window around each pixel of the `w`-wide plane `p`; zero
/// within `RADIUS` of the edges. Direct sums rather than running ones: a running sum's
/// rounding would depend on where it started, and strips must give the whole frame's values
/// exactly.
fn window_sum(p: &[f32], w: usize) -> Vec<f32> {
    let h = p.len() / w;
    let span = 2 * RADIUS + 1;
    let mut across = vec![0.0f32; p.len()];
    for (out, row) in across.chunks_exact_mut(w).zip(p.chunks_exact(w)) {
        let out = &mut out[RADIUS..w - RADIUS];
        for k in 0..span {
            out.iter_mut().zip(&row[k..]).for_each(|(o, v)| *o += v);
        }
    }
    let mut out = vec![0.0f32; p.len()];
    for y in RADIUS..h - RADIUS {
        let o = &mut out[y * w..(y + 1) * w];
        for row in across[(y - RADIUS) * w..].chunks_exact(w).take(span) {
            o.iter_mut().zip(row).for_each(|(o, v)| *o += v);
        }
    }
    out
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    impl Padded {
        /// The sample at (x + dx, y + dy) of the unpadded mosaic.
        fn at(&self, x: usize, y: usize, dx: isize, dy: isize) -> f32 {
            let px = (x + PAD) as isize + dx;
            let py = (y + PAD) as isize + dy;
            self.data[py as usize * self.width + px as usize]
        }
    }

    /// `filter` run on the mosaic's sRGB-encoded samples, its output decoded to linear light:
    /// what [`demosaic`] does, for the baselines.
    pub fn encoded(m: &Mosaic, filter: fn(&Mosaic) -> Image<f32>) -> Image<f32> {
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

    /// Bilinear interpolation: each missing colour the mean of its samples among the 3×3
    /// neighbours, what focusd did first and the baseline the quality tests compare with.
    pub fn bilinear(m: &Mosaic) -> Image<f32> {
        let p = Padded::new(m, |v| v);
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

    /// Malvar, He and Cutler's gradient-corrected linear interpolation ("High-quality linear
    /// interpolation for demosaicing of Bayer-patterned color images", ICASSP 2004), what
    /// focusd used before residual interpolation: the bilinear estimate of a missing colour
    /// plus a fraction of the Laplacian of the colour the pixel has. In the mosaic's own
    /// encoding.
    pub fn malvar(m: &Mosaic) -> Image<f32> {
        let p = Padded::new(m, |v| v);
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
                // Red (blue) at a green sample whose row holds red (blue): from left and right.
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

    const ORDERS: [BayerOrder; 4] = [
        BayerOrder::Rggb,
        BayerOrder::Bggr,
        BayerOrder::Grbg,
        BayerOrder::Gbrg,
    ];

    #[test]
    fn flat_colours_and_ramps_come_back_exactly() {
        // A linear ramp in each channel is reproduced by all three filters (the Laplacian
        // terms vanish, the guided filter fits a ramp by a ramp and the residuals left by its
        // regularisation are a ramp too), away from the mirrored border.
        for order in ORDERS {
            let (w, h) = (2 * REACH + 12, 2 * REACH + 10);
            let rgb = Image::from_fn(w, h, 3, |x, y, c| {
                0.1 + 0.004 * x as f32 + 0.003 * y as f32 + 0.1 * c as f32
            });
            let m = Mosaic::sample(&rgb, order);
            let padded = Padded::new(&m, |v| v);
            let planes = residual_interpolation(&padded.data, padded.width, order);
            let ri = Image::from_fn(w, h, 3, |x, y, c| {
                planes[c][(y + PAD) * padded.width + x + PAD]
            });
            // Near the border the mirrored ramp is a ridge: residual interpolation reaches
            // `REACH` pixels, the others two.
            for (out, margin) in [(ri, REACH), (malvar(&m), 2), (bilinear(&m), 2)] {
                for y in margin..h - margin {
                    for x in margin..w - margin {
                        for c in 0..3 {
                            let (got, want) = (out.at(x, y, c), rgb.at(x, y, c));
                            assert!(
                                (got - want).abs() < 1e-4,
                                "{order:?} ({x},{y},{c}): {got} {want}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn strips_give_the_whole_frame_exactly() {
        // A frame of texture and edges, not a multiple of the strip height, mosaics of every
        // order; and one smaller than the border.
        for order in ORDERS {
            for (w, h) in [(70, 61), (9, 5)] {
                let rgb = Image::from_fn(w, h, 3, |x, y, c| {
                    let t = ((x * 7 + y * 3 + c * 5) % 11) as f32 / 11.0;
                    let edge = if 3 * x + y > 2 * w { 0.6 } else { 0.1 };
                    0.3 * t + edge
                });
                let m = Mosaic::sample(&rgb, order);
                let whole = in_strips(&m, h + h % 2);
                for rows in [2, 8, 24] {
                    assert!(
                        in_strips(&m, rows) == whole,
                        "{order:?} {w}x{h}, {rows} rows"
                    );
                }
            }
        }
    }
}
