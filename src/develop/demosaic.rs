//! Demosaicing: the two colours each Bayer sample lacks.
//!
//! Done on sRGB-encoded samples, not in linear light: shading and shadows scale all three
//! colours together, which in linear light changes their differences in proportion but in an
//! encoded signal hardly at all, and the filters below assume smooth colour differences. On the
//! simulator's scenes this alone is worth several dB for the same filters (the tests print
//! the figures).
//!
//! Minimised-Laplacian residual interpolation (Kiku, Monno, Tanaka and Okutomi, "Residual
//! interpolation for color image demosaicking", ICIP 2013, and "Minimized-Laplacian residual
//! interpolation for color image demosaicking", SPIE Electronic Imaging 2014): green first, from
//! colour differences estimated along the rows and down the columns and weighted by how little
//! they change on each side of the pixel (the gradient-based threshold-free weighting of
//! Pekkucuksen and Altunbasak, ICASSP 2010; see [`directional_green`]); then red and blue each
//! from a local linear fit a·G + b to the colour's own samples with the green as guide (a guided
//! filter), the fit's residuals at those samples interpolated bilinearly and added back.
//! Residuals are far smoother than colours or colour differences, so bilinear interpolation of
//! them loses little; the slope a is chosen to make the residuals' Laplacian small rather than
//! the residuals themselves, since the Laplacian is what bilinear interpolation gets wrong. Green
//! is then fitted again the same way with red and blue as guides, and red and blue once more
//! from that green. Every fit, the directional ones included, averages the overlapping windows'
//! coefficients with weights the inverse of each window's fitting error (weighted residual
//! interpolation: Kiku, Monno, Tanaka and Okutomi, "Beyond color difference", IEEE TIP 2016;
//! see [`residual_fill`]), so that windows straddling an edge count little.
//!
//! The tests measure it against Malvar, He and Cutler's linear filters (the baseline, which it
//! beats by several dB on the simulator's scenes) and print the figures; `benches/tools/demosaic.rs`
//! gives them all. The directional green, the refit of green and the weighted averages each
//! earn their place there and on real phone frames; a second round of refitting does not.
//!
//! Written here: the crates that demosaic (`bayer`, `rawloader`'s companions) are unmaintained,
//! bring a whole raw-file stack, or offer only bilinear and Malvar–He–Cutler.
//!
//! A frame is developed in strips of rows, in parallel; each strip reads a halo of `PAD` rows
//! above and below, as far as any output pixel's value reaches, so strips give exactly the
//! whole frame's result (a test checks it) while the working planes stay a strip's size.

use super::{BayerOrder, Mosaic};
use crate::stack::image::{Image, Sample};
use crate::stack::srgb;
use crate::stack::Rect;
use rayon::prelude::*;
use std::sync::{Mutex, PoisonError};

/// Half the side of the guided filter's square window: its statistics, and the average of its
/// coefficients, are taken over (2·RADIUS + 1)² pixels. 3 is the best of 2 to 4 on the
/// simulator's scenes and the real frames.
const RADIUS: usize = 3;

/// Regularisation of the fit's slope, per sample, in squared encoded units of the Laplacian:
/// keeps it finite where the guide is flat. Larger values suit the simulator's scenes but leave
/// the guide unused on smooth real frames, where the Laplacians are small; smaller ones leave
/// more false colour on soft 45° edges. 1e-4 beats Malvar-He-Cutler on every real frame.
const EPS: f32 = 1e-4;

/// Half the length of the one-dimensional windows in which the green's directional colour
/// differences are fitted; shorter windows lose on the simulator's scenes.
const DIR_RADIUS: usize = 5;

/// [`EPS`] of the directional fits: 1e-3 rather than 1e-4 does as well on the simulator's
/// scenes and better on the real frames.
const DIR_EPS: f32 = 1e-3;

/// The least mean squared residual a window's fit is credited with, in squared encoded units,
/// when its coefficients are averaged with weights the inverse of that residual (see
/// [`residual_fill`]): below it a window counts as fitting exactly, which keeps the weights
/// finite and lets the windows of a smooth region share the work evenly. Nearby values do as
/// well; much smaller ones double the false colour on 45° grey edges.
const FLOOR: f32 = 1e-4;

/// [`FLOOR`] of the directional fits, whose windows hold 5-6 samples of a guide that is itself
/// interpolated, so that hardly any fits closer. 1e-3 helps the real frames and cuts false
/// colour on 45° edges; smaller values lose on the simulator.
const DIR_FLOOR: f32 = 1e-3;

/// How far the green's value reaches into the mosaic: the differences 2·DIR_RADIUS + 4 (the
/// colours' means, their Laplacians, statistics, averaged coefficients, the residuals'
/// interpolation), their gradients one more and the windows summing them 4 beyond that.
const GREEN_REACH: usize = 2 * DIR_RADIUS + 9;

/// How far a residual fill's value reaches into its guide and mosaic: the Laplacians (two
/// pixels on the grid, one diagonally in the quincunx), the statistics' windows and the
/// coefficients' averages (RADIUS each) and the residuals' interpolation (one).
const GRID_REACH: usize = 2 * RADIUS + 3;
const QUINCUNX_REACH: usize = 2 * RADIUS + 2;

/// How far an output pixel's value reaches into the mosaic: the green's reach, then the
/// three residual fills', one of them on the quincunx.
const REACH: usize = GREEN_REACH + 2 * GRID_REACH + QUINCUNX_REACH;

/// The mirrored border around the mosaic, and the halo above and below each strip: the reach,
/// made even so that padded coordinates keep the colour pattern's phase.
const PAD: usize = REACH + REACH % 2;

/// Output rows per strip (even, for the pattern's phase): eight strips on a 3 MP frame, for the
/// cores of a phone, while the halo (2·PAD rows) adds two fifths to the work.
const STRIP_ROWS: usize = 192;

/// The mosaic with `PAD` samples of mirrored border on each side (mirrored about the edge
/// sample, which keeps the colour pattern's phase), the samples mapped through `f`.
pub(super) struct Padded {
    width: usize,
    data: Vec<f32>,
}

impl Padded {
    /// The sample at (x + dx, y + dy) of the unpadded mosaic (|dx|, |dy| at most `PAD`).
    #[cfg(test)]
    pub(super) fn at(&self, x: usize, y: usize, dx: isize, dy: isize) -> f32 {
        let px = (x + PAD) as isize + dx;
        let py = (y + PAD) as isize + dy;
        self.data[py as usize * self.width + px as usize]
    }

    pub(super) fn new(m: &Mosaic, f: impl Fn(f32) -> f32) -> Padded {
        let (w, h) = (m.width, m.height);
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

/// The sample of a line of `n` that index `i` of the line padded by `PAD` on each side stands
/// for: reflections about the first and the last sample, repeated, so that even a mosaic
/// smaller than the border is extended with the right colours.
fn mirror(i: usize, n: usize) -> usize {
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
}

/// The sample of a line of `n` that index `i`, at most `PAD` beyond either end, stands for: the
/// border [`Padded`] gives the demosaic, for filters that mirror the mosaic themselves.
pub fn mirrored(i: isize, n: usize) -> usize {
    mirror((i + PAD as isize) as usize, n)
}

/// Linear RGB, three channels, from a linear mosaic: residual interpolation on its encoded
/// samples.
pub fn demosaic(m: &Mosaic) -> Image<f32> {
    in_strips(m, STRIP_ROWS)
}

/// A frame's regions for [`demosaic_regions`]: a `size` mosaic of Bayer `order` whose samples,
/// sRGB-encoded, `fill(y, x0, row)` gives (mosaic row `y` from column `x0` on, as many as `row`
/// holds, all inside the mosaic), and the rectangles of it wanted.
pub struct Regions<'a, F> {
    pub size: (usize, usize),
    pub order: BayerOrder,
    pub fill: &'a F,
    pub rects: &'a [Rect],
}

/// [`demosaic`] over each frame's rectangles only, exactly as the whole frame's development
/// gives them before it decodes them: each rectangle is developed with the mosaic around it as
/// far as an output pixel's value reaches (`REACH`, the border mirrored here), rectangles close
/// together in one window ([`windows`]), the windows of every frame in one parallel run, the
/// largest first, so that cores share unequal windows evenly. `pixels` writes a row of output
/// pixels from their encoded red, green and blue rows, three samples a pixel (decoded, through a
/// colour matrix, to 8 bits: whatever the caller keeps), in the window's task, so that no float
/// copy of the regions is made. Only the windows are ever encoded, so a frame's samples need no frame-sized float
/// copy; a window's working planes are reused by the next, so at most one per core is made.
pub fn demosaic_regions<T: Sample, F: Fn(usize, usize, &mut [f32]) + Sync>(
    frames: &[Regions<F>],
    pixels: &(impl Fn([&[f32]; 3], &mut [T]) + Sync),
) -> Vec<Vec<Image<T>>> {
    let spare = Mutex::new(Vec::<Workspace>::new());
    let mut tasks: Vec<(usize, Rect, Vec<usize>)> = frames
        .iter()
        .enumerate()
        .flat_map(|(f, regions)| {
            windows(regions.rects, regions.size.0)
                .into_iter()
                .map(move |(window, members)| (f, window, members))
        })
        .collect();
    tasks.sort_by_key(|(_, r, _)| std::cmp::Reverse(r.width * r.height));
    let pieces: Vec<Vec<(usize, usize, Image<T>)>> = tasks
        .par_iter()
        .with_max_len(1)
        .map(|&(f, window, ref members)| {
            let Regions {
                size: (width, height),
                order,
                fill,
                rects,
            } = frames[f];
            let Rect {
                x,
                y,
                width: mw,
                height: mh,
            } = window;
            assert!(
                x + mw <= width && y + mh <= height,
                "region outside the mosaic"
            );
            // REACH beyond the rectangles on every side, its pattern the one read from its
            // corner; in the coordinates of the mosaic padded by PAD (even, so a padded
            // coordinate has the phase of the one it stands for), so its rows and columns are
            // mirrored where they reach beyond the mosaic.
            let (x0, y0) = (x + PAD - REACH, y + PAD - REACH);
            let (ww, wh) = (mw + 2 * REACH, mh + 2 * REACH);
            let inside = PAD.saturating_sub(x0).min(ww)..(PAD + width).saturating_sub(x0).min(ww);
            let taken = spare.lock().unwrap_or_else(PoisonError::into_inner).pop();
            let mut ws: Workspace = taken.unwrap_or_default();
            let mut samples = std::mem::take(&mut ws.samples);
            samples.resize(ww * wh, 0.0);
            for (j, line) in samples.chunks_exact_mut(ww).enumerate() {
                let row = mirror(y0 + j, height);
                if !inside.is_empty() {
                    fill(row, x0 + inside.start - PAD, &mut line[inside.clone()]);
                }
                for k in (0..inside.start).chain(inside.end..ww) {
                    fill(row, mirror(x0 + k, width), &mut line[k..k + 1]);
                }
            }
            let phase = order.read_from(x0, y0);
            residual_interpolation(&samples, ww, phase, REACH, &mut ws);
            ws.samples = samples;
            let planes = [&ws.planes[0], &ws.planes[3], &ws.planes[2]];
            let cut = members
                .iter()
                .map(|&k| {
                    let r = rects[k];
                    let (dx, dy) = (r.x + PAD - x0, r.y + PAD - y0);
                    let mut out = vec![T::default(); r.width * r.height * 3];
                    for (yy, row) in out.chunks_exact_mut(r.width * 3).enumerate() {
                        let at = (yy + dy) * ww + dx;
                        pixels(planes.map(|p| &p[at..at + r.width]), row);
                    }
                    (f, k, Image::from_vec(r.width, r.height, 3, out))
                })
                .collect();
            spare
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push(ws);
            cut
        })
        .collect();
    let mut out: Vec<Vec<Option<Image<T>>>> = frames
        .iter()
        .map(|regions| regions.rects.iter().map(|_| None).collect())
        .collect();
    for (f, k, img) in pieces.into_iter().flatten() {
        out[f][k] = Some(img);
    }
    out.into_iter()
        .map(|frame| {
            frame
                .into_iter()
                .map(|img| img.expect("every rectangle is in a window"))
                .collect()
        })
        .collect()
}

/// `rects` grouped into windows, each developed once: two become one where the window around
/// both, with its halo of `REACH` on every side, costs no more than their two, and no more than a
/// strip of a `width`-wide frame's whole development (so no more memory). Each window with the
/// indices of the rectangles it holds.
fn windows(rects: &[Rect], width: usize) -> Vec<(Rect, Vec<usize>)> {
    let cost = |r: Rect| (r.width + 2 * REACH) * (r.height + 2 * REACH);
    let cap = (width + 2 * PAD) * (STRIP_ROWS + 2 * PAD);
    let union = |a: Rect, b: Rect| {
        let (x, y) = (a.x.min(b.x), a.y.min(b.y));
        Rect {
            x,
            y,
            width: (a.x + a.width).max(b.x + b.width) - x,
            height: (a.y + a.height).max(b.y + b.height) - y,
        }
    };
    let mut groups: Vec<(Rect, Vec<usize>)> = rects
        .iter()
        .enumerate()
        .map(|(k, &r)| (r, vec![k]))
        .collect();
    let mut merged = true;
    while merged {
        merged = false;
        let mut i = 0;
        while i < groups.len() {
            let mut j = i + 1;
            while j < groups.len() {
                let u = union(groups[i].0, groups[j].0);
                if cost(u) <= (cost(groups[i].0) + cost(groups[j].0)).min(cap) {
                    let (_, members) = groups.swap_remove(j);
                    groups[i].0 = u;
                    groups[i].1.extend(members);
                    merged = true;
                } else {
                    j += 1;
                }
            }
            i += 1;
        }
    }
    groups
}

/// [`demosaic`] computed `rows` output rows at a time.
fn in_strips(m: &Mosaic, rows: usize) -> Image<f32> {
    debug_assert!(rows > 0 && rows.is_multiple_of(2));
    let (w, h) = (m.width, m.height);
    let mut out = vec![0.0f32; w * h * 3];
    if out.is_empty() {
        return Image::from_vec(w, h, 3, out);
    }
    let srgb::Tabulated { encode, decode } = srgb::tabulated();
    let p = Padded::new(m, |v| encode.at(v));
    let pw = p.width;
    // One workspace for each strip being developed at once, taken by the next strip.
    let spare = Mutex::new(Vec::<Workspace>::new());
    out.par_chunks_mut(rows * w * 3)
        .enumerate()
        .for_each(|(i, chunk)| {
            let n = chunk.len() / (w * 3);
            let strip = &p.data[i * rows * pw..(i * rows + n + 2 * PAD) * pw];
            let taken = spare.lock().unwrap_or_else(PoisonError::into_inner).pop();
            let mut ws = taken.unwrap_or_default();
            residual_interpolation(strip, pw, m.order, PAD, &mut ws);
            let rgb = [&ws.planes[0], &ws.planes[3], &ws.planes[2]];
            for (y, row) in chunk.chunks_exact_mut(w * 3).enumerate() {
                let at = (y + PAD) * pw + PAD;
                for (x, px) in row.chunks_exact_mut(3).enumerate() {
                    for (v, plane) in px.iter_mut().zip(rgb) {
                        *v = decode.at(plane[at + x]);
                    }
                }
            }
            spare
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push(ws);
        });
    Image::from_vec(w, h, 3, out)
}

/// The planes one strip is developed in, handed on to the next strip: with `malloc::tune`'s
/// setting every plane of a strip's size is a mapping of its own, whose fresh pages cost more to
/// fault in and clear than to fill.
#[derive(Default)]
struct Workspace {
    /// A region's window of the mosaic ([`demosaic_regions`]).
    samples: Vec<f32>,
    /// Working planes of the green and the fills: differences, gradients, Laplacians,
    /// coefficients, residuals.
    scratch: [Vec<f32>; 5],
    /// The results: red, a green in the making, blue, the green.
    planes: [Vec<f32>; 4],
}

impl Workspace {
    /// Every plane `n` samples long, not cleared: each pass writes what the next reads, and
    /// what a strip before left in the margins reaches no output value.
    fn prepare(&mut self, n: usize) {
        for p in self.scratch.iter_mut().chain(&mut self.planes) {
            p.resize(n, 0.0);
        }
    }
}

/// Red, green and blue planes from the `w`-wide mosaic `m` of Bayer `order` (a strip of the
/// padded frame, or a region's window), left in `ws.planes` 0, 3 and 2: their values `margin`
/// (at least `REACH`) or more inside the edges.
fn residual_interpolation(
    m: &[f32],
    w: usize,
    order: BayerOrder,
    margin: usize,
    ws: &mut Workspace,
) {
    // Where each colour has samples, as 0 or 1 along even rows and along odd ones.
    let sites = |c: usize| {
        [0, 1].map(|y| {
            (0..w)
                .map(|x| f32::from(u8::from(order.channel(x, y) == c)))
                .collect::<Vec<f32>>()
        })
    };
    let (red, green, blue) = (sites(0), sites(1), sites(2));
    ws.prepare(m.len());
    let Workspace {
        scratch, planes, ..
    } = ws;
    let [r, g, b, g2] = planes;
    // Each pass only as far into the halo as the next one reads.
    let (last, refit) = (margin, margin - GRID_REACH);
    let first = refit - QUINCUNX_REACH;
    directional_green(m, w, order, first - GRID_REACH, scratch, g);
    residual_fill(g, m, w, &red, Lattice::Grid, first, scratch, r);
    residual_fill(g, m, w, &blue, Lattice::Grid, first, scratch, b);
    // Green again, at red samples with red as the guide, at blue ones with blue.
    residual_fill(r, m, w, &green, Lattice::Quincunx, refit, scratch, g2);
    residual_fill(b, m, w, &green, Lattice::Quincunx, refit, scratch, g);
    for (y, (row, other)) in g2.chunks_exact_mut(w).zip(g.chunks_exact(w)).enumerate() {
        for ((v, o), &on) in row.iter_mut().zip(other).zip(&blue[y % 2]) {
            if on > 0.0 {
                *v = *o;
            }
        }
    }
    residual_fill(g2, m, w, &red, Lattice::Grid, last, scratch, r);
    residual_fill(g2, m, w, &blue, Lattice::Grid, last, scratch, b);
}

/// Green at red and blue samples from colour differences estimated along the rows and along
/// the columns and weighted by direction, as in Pekkucuksen and Altunbasak's gradient-based
/// threshold-free demosaicking (GBTF, ICASSP 2010) with the differences estimated by
/// minimised-Laplacian residual interpolation in one dimension (Kiku et al. 2014): along each
/// row, green at the other colour's samples and that colour at green's, each fitted to its
/// samples with the other, linearly interpolated, as the guide; their difference G − C at every
/// pixel; the same down the columns. At a red or blue sample the four one-sided averages of
/// those differences (west, east, north, south, weighted by distance) are weighted by the
/// inverse square of how much the differences change on that side, and added to the sample.
/// Only the values `margin` or more inside the edges are computed. `scratch` is overwritten.
fn directional_green(
    m: &[f32],
    w: usize,
    order: BayerOrder,
    margin: usize,
    scratch: &mut [Vec<f32>; 5],
    g: &mut [f32],
) {
    let h = m.len() / w;
    assert!(
        margin >= GREEN_REACH && 2 * margin < w.min(h),
        "margin {margin} outside {w}x{h}"
    );
    let [dh, dv, bh, bv, t] = scratch;
    // Only what the green `margin` inside the edges takes: the differences along the rows on
    // its rows and 2 more (the gradients' windows), those down the columns on its columns and
    // 2 more and on its rows and 5 more (the gradients' windows, their offset, the gradient).
    differences_along_rows(
        m,
        w,
        margin - 2..h - margin + 2,
        |y| order.channel(0, y) == 1,
        dh,
    );
    // Down the columns: along the rows of the transposed strip.
    transpose(m, w, dv);
    let columns = margin - 2..w - margin + 2;
    differences_along_rows(dv, h, columns, |x| order.channel(x, 0) == 1, bh);
    transpose(bh, h, dv);
    // How much the differences change across each pixel, summed over 5×5 windows: on the
    // rows `margin` in for the differences along the rows, 2 rows further for those down the
    // columns (the side windows' offset).
    for (d, grad, step, rim) in [(&*dh, &mut *bh, 1, margin), (&*dv, &mut *bv, w, margin - 2)] {
        let (r0, r1) = (rim - 2, h - rim + 2);
        for i in r0 * w..r1 * w {
            grad[i] = (d[i - step] - d[i + step]).abs();
        }
        for y in r0..r1 {
            window_sum::<2>(&grad[y * w..(y + 1) * w], &mut t[y * w..(y + 1) * w]);
        }
        grad[rim * w..(h - rim) * w].fill(0.0);
        for y in rim..h - rim {
            let out = &mut grad[y * w..(y + 1) * w];
            for j in y - 2..=y + 2 {
                out.iter_mut()
                    .zip(&t[j * w..(j + 1) * w])
                    .for_each(|(o, v)| *o += v);
            }
        }
    }
    // Weights of the differences 0-3 samples away on one side.
    const NEAR: [f32; 4] = [0.56, 0.35, 0.08, 0.01];
    g.copy_from_slice(m);
    for y in margin..h - margin {
        for x in margin..w - margin {
            if order.channel(x, y) == 1 {
                continue;
            }
            let i = y * w + x;
            // Each side's window lies two pixels off-centre: from the pixel outwards, 5 wide.
            let weight = |v: f32| 1.0 / ((v + 1e-6) * (v + 1e-6));
            let (ww, we) = (weight(bh[i - 2]), weight(bh[i + 2]));
            let (wn, ws) = (weight(bv[i - 2 * w]), weight(bv[i + 2 * w]));
            let (mut dw, mut de, mut dn, mut ds) = (0.0, 0.0, 0.0, 0.0);
            for (k, f) in NEAR.iter().enumerate() {
                dw += f * dh[i - k];
                de += f * dh[i + k];
                dn += f * dv[i - k * w];
                ds += f * dv[i + k * w];
            }
            g[i] = m[i] + (ww * dw + we * de + wn * dn + ws * ds) / (ww + we + wn + ws);
        }
    }
}

/// `m` (`w` wide) transposed into `out`.
fn transpose(m: &[f32], w: usize, out: &mut [f32]) {
    const BLOCK: usize = 32;
    let h = m.len() / w;
    for y0 in (0..h).step_by(BLOCK) {
        for x0 in (0..w).step_by(BLOCK) {
            for y in y0..(y0 + BLOCK).min(h) {
                for x in x0..(x0 + BLOCK).min(w) {
                    out[x * h + y] = m[y * w + x];
                }
            }
        }
    }
}

/// Along each `w`-wide row of `m`, the colour difference G − C at every pixel, C being the
/// row's other colour: green estimated at C's samples and C at green's by one-dimensional
/// minimised-Laplacian residual interpolation. `green_first(y)`: whether row y's green samples
/// are at even x.
fn differences_along_rows(
    m: &[f32],
    w: usize,
    rows_of: std::ops::Range<usize>,
    green_first: impl Fn(usize) -> bool,
    out: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX, checked just above.
        return unsafe { differences_along_rows_avx(m, w, rows_of, green_first, out) };
    }
    differences_along_rows_body(m, w, rows_of, green_first, out)
}

/// `differences_along_rows_body` compiled for AVX, as [`residual_fill_avx`]: the fits' row
/// loops and window sums eight lanes wide, the same operations in the same order.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn differences_along_rows_avx(
    m: &[f32],
    w: usize,
    rows_of: std::ops::Range<usize>,
    green_first: impl Fn(usize) -> bool,
    out: &mut [f32],
) {
    differences_along_rows_body(m, w, rows_of, green_first, out)
}

/// [`differences_along_rows`], inlined so that each caller compiles it (and [`fit_along`]) for
/// its own target features.
#[inline(always)]
fn differences_along_rows_body(
    m: &[f32],
    w: usize,
    rows_of: std::ops::Range<usize>,
    green_first: impl Fn(usize) -> bool,
    out: &mut [f32],
) {
    let mut rows = Rows::new(w);
    let (mut g, mut c) = (vec![0.0f32; w], vec![0.0f32; w]);
    let (mut g_at_c, mut c_at_g) = (vec![0.0f32; w], vec![0.0f32; w]);
    for y in rows_of {
        let (row, out) = (&m[y * w..(y + 1) * w], &mut out[y * w..(y + 1) * w]);
        let phase = usize::from(!green_first(y));
        // Each colour at every pixel, its samples' neighbours' mean where it has none.
        for x in 1..w - 1 {
            let mean = 0.5 * (row[x - 1] + row[x + 1]);
            let (own, other) = if x % 2 == phase {
                (&mut g, &mut c)
            } else {
                (&mut c, &mut g)
            };
            own[x] = row[x];
            other[x] = mean;
        }
        fit_along(&c, &g, phase, &mut rows, &mut g_at_c);
        fit_along(&g, &c, 1 - phase, &mut rows, &mut c_at_g);
        for x in 0..w {
            out[x] = if x % 2 == phase {
                row[x] - c_at_g[x]
            } else {
                g_at_c[x] - row[x]
            };
        }
    }
}

/// Row buffers of [`fit_along`].
struct Rows {
    /// At each sample (every other pixel): its guide, its value, the guide's Laplacian squared,
    /// the product of the two Laplacians, the guide squared, guide times value, value squared.
    stats: [Vec<f32>; 7],
    /// Those over every window of HALF · 2 + 1 samples.
    sums: [Vec<f32>; 7],
    /// Slope, offset and weight of the windows on samples, and of those between two.
    fits: [Vec<f32>; 6],
    /// The fit's coefficients at every pixel times their weights, the weights, and the sums of
    /// the three over windows.
    coef: [Vec<f32>; 6],
    res: Vec<f32>,
}

impl Rows {
    fn new(w: usize) -> Rows {
        let row = |n: usize| vec![0.0f32; n];
        Rows {
            // One more than a row's samples: a zero after the last.
            stats: std::array::from_fn(|_| row(w.div_ceil(2) + 1)),
            sums: std::array::from_fn(|_| row(w.div_ceil(2))),
            fits: std::array::from_fn(|_| row(w.div_ceil(2))),
            coef: std::array::from_fn(|_| row(w)),
            res: row(w),
        }
    }
}

/// Samples on either side of a sample within its window of 2·DIR_RADIUS + 1 pixels.
const HALF: usize = (DIR_RADIUS - 1) / 2;
const _: () = assert!(DIR_RADIUS % 2 == 1);

/// The colour `v` holds at the pixels of parity `phase` along a row, at every pixel: fitted as
/// a·guide + b over windows of 2·DIR_RADIUS + 1 pixels (the slope minimising the residuals'
/// Laplacian), the windows' coefficients averaged with weights as in [`residual_fill`] (floored
/// at [`DIR_FLOOR`]), plus the residuals interpolated linearly.
#[inline(always)]
fn fit_along(guide: &[f32], v: &[f32], phase: usize, rows: &mut Rows, out: &mut [f32]) {
    let w = v.len();
    out.fill(0.0);
    if w <= 4 * DIR_RADIUS + 2 {
        return;
    }
    let Rows {
        stats,
        sums,
        fits,
        coef,
        res,
    } = rows;
    // Sample j is at x = phase + 2j. A window of 2·DIR_RADIUS + 1 pixels centred on sample j
    // holds samples j - HALF ..= j + HALF; one centred between samples j and j + 1 holds those
    // and sample j + HALF + 1.
    let n = (w - phase).div_ceil(2);
    let (on_sample, between) = ((2 * HALF + 1) as f32, (2 * HALF + 2) as f32);
    {
        let [sg, sv, sll, slv, sgg, sgv, svv] = stats.each_mut().map(|s| &mut s[..n]);
        for (j, (g, v)) in guide[phase..]
            .iter()
            .zip(&v[phase..])
            .step_by(2)
            .enumerate()
        {
            sg[j] = *g;
            sv[j] = *v;
            sgg[j] = g * g;
            sgv[j] = g * v;
            svv[j] = v * v;
        }
        // The Laplacians where both neighbours are in the row, zero at the ends.
        sll.fill(0.0);
        slv.fill(0.0);
        for j in (2usize.saturating_sub(phase)).div_ceil(2)..n {
            let x = phase + 2 * j;
            if x + 2 >= w {
                break;
            }
            let lg = 2.0 * guide[x] - guide[x - 2] - guide[x + 2];
            let lv = 2.0 * v[x] - v[x - 2] - v[x + 2];
            sll[j] = lg * lg;
            slv[j] = lg * lv;
        }
    }
    for s in stats.iter_mut() {
        s[n] = 0.0;
    }
    for (s, d) in stats.iter().zip(sums.iter_mut()) {
        window_sum::<HALF>(&s[..n], &mut d[..n]);
    }
    // A window of `k` samples' slope, offset and weight (as in `residual_fill`) from its sums
    // (in `stats`' order), the first two times the weight.
    let fit = |k: f32, [g, v, ll, lv, gg, gv, vv]: [f32; 7]| {
        let a = lv / (ll + DIR_EPS * k).max(f32::MIN_POSITIVE);
        let (mg, mv) = (g / k, v / k);
        let e = (vv / k - mv * mv) - 2.0 * a * (gv / k - mg * mv) + a * a * (gg / k - mg * mg);
        let u = 1.0 / e.max(DIR_FLOOR);
        (a * u, (mv - a * mg) * u, u)
    };
    // The windows on samples j0..j1 and between each and the next: those whose pixels have
    // whole windows.
    let (j0, j1) = (
        (DIR_RADIUS - phase) / 2,
        (w - DIR_RADIUS - 1 - phase) / 2 + 1,
    );
    let len = j1 - j0;
    {
        let own = sums.each_ref().map(|s| &s[j0..j1]);
        let next = stats.each_ref().map(|s| &s[j0 + HALF + 1..j1 + HALF + 1]);
        let [a0, b0, u0, a1, b1, u1] = fits.each_mut().map(|f| &mut f[..len]);
        for j in 0..len {
            let o: [f32; 7] = std::array::from_fn(|i| own[i][j]);
            (a0[j], b0[j], u0[j]) = fit(on_sample, o);
            let both = std::array::from_fn(|i| o[i] + next[i][j]);
            (a1[j], b1[j], u1[j]) = fit(between, both);
        }
    }
    let [a, b, u, sa, sb, su] = coef;
    let x0 = phase + 2 * j0;
    for (c, (on, off)) in [&mut *a, &mut *b, &mut *u]
        .into_iter()
        .zip([(0, 3), (1, 4), (2, 5)])
    {
        c.fill(0.0);
        let pairs = c[x0..x0 + 2 * len].chunks_exact_mut(2);
        for (p, (x, y)) in pairs.zip(fits[on][..len].iter().zip(&fits[off][..len])) {
            p[0] = *x;
            p[1] = *y;
        }
    }
    window_sum::<DIR_RADIUS>(a, sa);
    window_sum::<DIR_RADIUS>(b, sb);
    window_sum::<DIR_RADIUS>(u, su);
    let inner = 2 * DIR_RADIUS..w - 2 * DIR_RADIUS;
    let o = &mut out[inner.clone()];
    let (sa, sb, su, g) = (
        &sa[inner.clone()],
        &sb[inner.clone()],
        &su[inner.clone()],
        &guide[inner],
    );
    for x in 0..o.len() {
        o[x] = (sa[x] * g[x] + sb[x]) / su[x];
    }
    res.fill(0.0);
    let first = 2 * DIR_RADIUS + phase;
    for x in (first..w - 2 * DIR_RADIUS).step_by(2) {
        res[x] = v[x] - out[x];
    }
    // Each sample's own residual, each pixel between two samples the mean of theirs.
    let first = 2 - phase % 2;
    for x in (first..w - 1).step_by(2) {
        out[x] += res[x];
    }
    for x in (3 - first..w - 1).step_by(2) {
        out[x] += 0.5 * (res[x - 1] + res[x + 1]);
    }
}

/// How a colour's samples lie: red and blue every other row and column, green in a quincunx.
#[derive(Clone, Copy)]
enum Lattice {
    Grid,
    Quincunx,
}

/// The colour whose samples lie where `sites` (by row parity, as from `residual_interpolation`)
/// is 1 in `m`, at every pixel: the guided filter's fit to those samples with `guide` as the
/// guide, plus the fit's residuals at the samples interpolated bilinearly.
///
/// Each pixel lies in (2·RADIUS + 1)² windows and takes the average of their fits, weighted by
/// the inverse of each window's mean squared residual at its samples (floored at [`FLOOR`]), as
/// in Kiku, Monno, Tanaka and Okutomi's weighted residual interpolation ("Beyond color
/// difference: residual interpolation for color image demosaicking", IEEE TIP 2016): near an
/// edge the windows that straddle it fit neither side, and the plain average let them blur the
/// colour across it.
///
/// Each pass goes a row at a time through row buffers, so that only the coefficients, their
/// weights (in the residuals' plane until the residuals are taken), the fit and the residuals
/// are whole planes. Only `fit`'s values `margin` or more inside the edges are computed, from
/// the guide's `margin - GRID_REACH` or more inside.
#[allow(clippy::too_many_arguments)]
fn residual_fill(
    guide: &[f32],
    m: &[f32],
    w: usize,
    sites: &[Vec<f32>; 2],
    lattice: Lattice,
    margin: usize,
    scratch: &mut [Vec<f32>; 5],
    fit: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX, checked just above.
        return unsafe { residual_fill_avx(guide, m, w, sites, lattice, margin, scratch, fit) };
    }
    residual_fill_body(guide, m, w, sites, lattice, margin, scratch, fit)
}

/// `residual_fill_body` compiled for AVX: its row loops run eight lanes wide instead of the
/// x86-64 baseline's four, the same operations in the same order, so the same values (a fifth
/// less time; the directional green, whose loops go by pairs of pixels, gains nothing so).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[allow(clippy::too_many_arguments)]
unsafe fn residual_fill_avx(
    guide: &[f32],
    m: &[f32],
    w: usize,
    sites: &[Vec<f32>; 2],
    lattice: Lattice,
    margin: usize,
    scratch: &mut [Vec<f32>; 5],
    fit: &mut [f32],
) {
    residual_fill_body(guide, m, w, sites, lattice, margin, scratch, fit)
}

/// [`residual_fill`], inlined so that each caller compiles it for its own target features.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn residual_fill_body(
    guide: &[f32],
    m: &[f32],
    w: usize,
    sites: &[Vec<f32>; 2],
    lattice: Lattice,
    margin: usize,
    scratch: &mut [Vec<f32>; 5],
    fit: &mut [f32],
) {
    let h = m.len() / w;
    fn row(p: &[f32], w: usize, y: usize) -> &[f32] {
        &p[y * w..(y + 1) * w]
    }
    // Only what the output `margin` inside the edges takes: the fit one pixel further out
    // (the residuals' interpolation), the coefficients RADIUS further (their averages), the
    // statistics RADIUS further again (the windows), the Laplacians one sample step beyond.
    assert!(
        margin >= GRID_REACH && 2 * margin < w.min(h),
        "margin {margin} outside {w}x{h}"
    );
    let ca = margin - RADIUS - 1;
    // The statistics' rows and columns: x0 even, to keep the pattern's phase.
    let (s0, s1) = (ca - RADIUS, h - ca + RADIUS);
    let (x0, x1) = ((ca - RADIUS) & !1, w - ca + RADIUS);
    let lw = x1 - x0;
    // The slope of the fit in each window from the colour's and the guide's Laplacians (taken
    // among the colour's samples, which are two apart on the grid and diagonal neighbours in
    // the quincunx), its offset from their means, its weight from the residuals' variance:
    // count, sums of guide and samples, of the guide's Laplacian squared, of the product of the
    // two Laplacians, and of the guide squared, guide times sample and sample squared, over the
    // window's samples.
    let [lg, lv, a, b, res] = scratch;
    let (s, d) = match lattice {
        Lattice::Grid => (2, 2 * w),
        Lattice::Quincunx => (w - 1, w + 1),
    };
    for (l, p) in [(&mut *lg, guide), (&mut *lv, m)] {
        for i in s0 * w..s1 * w {
            l[i] = 4.0 * p[i] - p[i - s] - p[i + s] - p[i - d] - p[i + d];
        }
    }
    // A column's samples lie every other row, the same rows for every column of one parity
    // (none for the grid's columns without samples), and a row's in the columns of one parity.
    let has = |rp: usize, cp: usize| sites[rp].get(cp).is_some_and(|&s| s > 0.0);
    let rows_of: [Option<usize>; 2] = [0, 1].map(|cp| (0..2).find(|&rp| has(rp, cp)));
    let cols_of: [Option<usize>; 2] = [0, 1].map(|rp| (0..2).find(|&cp| has(rp, cp)));
    let half = |cp: usize| (lw - cp).div_ceil(2);
    // The window's sums are taken down the columns, then along the row, in that order and
    // ascending, as the sums of every pixel's figures (zero where there is no sample) would be:
    // leaving the zeros out changes no bit. A column's sums over the 3 sample rows centred on
    // a sample row are those over 4 rows centred between two, less their last row.
    //
    // The eight figures at each sample of the last 8 rows (a ring, by row modulo 8), each row's
    // samples side by side: 1, guide, sample, guide's Laplacian squared, product of the
    // Laplacians, guide squared, guide times sample, sample squared.
    let mut ring: [[Vec<f32>; 8]; 8] =
        std::array::from_fn(|_| std::array::from_fn(|_| vec![0.0; lw.div_ceil(2)]));
    // Per column parity, the sums over 3 sample rows (kept for the next row) and over 4, with
    // a zero after the last column.
    let mut three: [[Vec<f32>; 8]; 2] =
        std::array::from_fn(|_| std::array::from_fn(|_| vec![0.0; lw.div_ceil(2) + 1]));
    let mut four = three.clone();
    let mut full: [Vec<f32>; 8] = std::array::from_fn(|_| vec![0.0; lw.max(w)]);
    let mut win: [Vec<f32>; 8] = std::array::from_fn(|_| vec![0.0; lw]);
    let mut filled = s0;
    for y in ca - 1..h - ca {
        for j in filled..=y + 3 {
            let Some(cp) = cols_of[j % 2] else {
                continue;
            };
            let n = half(cp);
            let at = j * w + x0 + cp;
            let (g, v) = (&guide[at..][..2 * n - 1], &m[at..][..2 * n - 1]);
            let (l, lm) = (&lg[at..][..2 * n - 1], &lv[at..][..2 * n - 1]);
            let [p0, p1, p2, p3, p4, p5, p6, p7] = ring[j % 8].each_mut().map(|p| &mut p[..n]);
            for i in 0..n {
                let (g, v, l, lm) = (g[2 * i], v[2 * i], l[2 * i], lm[2 * i]);
                p0[i] = 1.0;
                p1[i] = g;
                p2[i] = v;
                p3[i] = l * l;
                p4[i] = l * lm;
                p5[i] = g * g;
                p6[i] = g * v;
                p7[i] = v * v;
            }
        }
        filled = filled.max(y + 4);
        // Each column parity's sums down the window's rows: `three` on rows of the samples'
        // parity, `four` on the others.
        let mut sums: [Option<&[Vec<f32>; 8]>; 2] = [None, None];
        for (cp, (t3, t4)) in three.iter_mut().zip(&mut four).enumerate() {
            let Some(rp) = rows_of[cp] else {
                continue;
            };
            let n = half(cp);
            if y % 2 == rp {
                for (k, t) in t3.iter_mut().enumerate() {
                    let [a, b, c] = [y - 2, y, y + 2].map(|j| &ring[j % 8][k][..n]);
                    let t = &mut t[..n];
                    for i in 0..n {
                        t[i] = 0.0 + a[i] + b[i] + c[i];
                    }
                }
                sums[cp] = Some(t3);
            } else if y >= ca {
                for (k, (t, s)) in t4.iter_mut().zip(&*t3).enumerate() {
                    let (t, s, d) = (&mut t[..n], &s[..n], &ring[(y + 3) % 8][k][..n]);
                    for i in 0..n {
                        t[i] = s[i] + d[i];
                    }
                }
                sums[cp] = Some(t4);
            }
        }
        if y < ca {
            continue;
        }
        // Along the row: every column's sums in the quincunx, every other column's on the grid
        // (3 of them centred on a sample column, 4 between two).
        match sums {
            [Some(even), Some(odd)] => {
                for (k, (f, s)) in full.iter_mut().zip(&mut win).enumerate() {
                    let f = &mut f[..lw];
                    for (pair, (e, o)) in f.chunks_exact_mut(2).zip(even[k].iter().zip(&odd[k])) {
                        pair[0] = *e;
                        pair[1] = *o;
                    }
                    if lw % 2 == 1 {
                        f[lw - 1] = even[k][lw / 2];
                    }
                    window_sum::<RADIUS>(f, s);
                }
            }
            [Some(c), None] | [None, Some(c)] => {
                // Sample column i is at x = 2i + s; from i = 1 (columns 0 to 2 hold no window)
                // up to the zero after the last sample.
                let s = usize::from(sums[0].is_none());
                for (c, out) in c.iter().zip(&mut win) {
                    let c = &c[..half(s) + 1];
                    let next = c.iter().zip(&c[1..]).zip(&c[2..]).zip(&c[3..]);
                    for (pair, (((l, m), r), after)) in out[s + 2..].chunks_exact_mut(2).zip(next) {
                        let t = l + m + r;
                        pair[0] = t;
                        pair[1] = t + after;
                    }
                }
            }
            [None, None] => unreachable!("a colour without samples"),
        }
        // Without branches or bounds checks, so that it vectorises: every window of the strip
        // holds samples, and one without (k = 0) would give a = b = 0.
        let inner = RADIUS..lw - RADIUS;
        let [k, sg, sv, sll, slv, sgg, sgv, svv] = win.each_ref().map(|s| &s[inner.clone()]);
        let a = &mut a[y * w + x0..][..lw][inner.clone()];
        let b = &mut b[y * w + x0..][..lw][inner.clone()];
        let wt = &mut res[y * w + x0..][..lw][inner];
        for x in 0..a.len() {
            let n = k[x].max(1.0);
            // The mean squared residual v - a·g - b over the window's samples, b making their
            // mean zero: var(v) - 2a·cov(g, v) + a²·var(g).
            let (aa, mg, mv) = (
                slv[x] / (sll[x] + EPS * k[x]).max(f32::MIN_POSITIVE),
                sg[x] / n,
                sv[x] / n,
            );
            let bb = mv - aa * mg;
            let var_g = sgg[x] / n - mg * mg;
            let cov = sgv[x] / n - mg * mv;
            let var_v = svv[x] / n - mv * mv;
            let e = var_v - 2.0 * aa * cov + aa * aa * var_g;
            let u = 1.0 / e.max(FLOOR);
            wt[x] = u;
            a[x] = aa * u;
            b[x] = bb * u;
        }
    }
    // The coefficients averaged over each window, weighted, applied to the guide.
    // Over the rows and columns margin - 1 ..; the coefficients' from `ca`.
    let [da, db, dw, wa, wb, ww, _, _] = full.each_mut().map(|v| &mut v[ca..w - ca]);
    let (f0, f1) = (margin - 1, w - margin + 1);
    for y in margin - 1..h - margin + 1 {
        // Down the window's rows from zero, in order.
        for (d, p) in [(&mut *da, &*a), (&mut *db, &*b), (&mut *dw, &*res)] {
            let top = &row(p, w, y - RADIUS)[ca..w - ca];
            for x in 0..d.len() {
                d[x] = 0.0 + top[x];
            }
            for j in y - RADIUS + 1..=y + RADIUS {
                let r = &row(p, w, j)[ca..w - ca];
                for x in 0..d.len() {
                    d[x] += r[x];
                }
            }
        }
        window_sum::<RADIUS>(da, wa);
        window_sum::<RADIUS>(db, wb);
        window_sum::<RADIUS>(dw, ww);
        let inner = RADIUS..w - 2 * ca - RADIUS;
        let (wa, wb, ww) = (&wa[inner.clone()], &wb[inner.clone()], &ww[inner]);
        let (g, f) = (&row(guide, w, y)[f0..f1], &mut fit[y * w + f0..y * w + f1]);
        for x in 0..f.len() {
            f[x] = (wa[x] * g[x] + wb[x]) / ww[x];
        }
    }
    // The residuals at the samples, zero elsewhere, interpolated bilinearly: each pixel gets
    // its own sample's or the mean of its two or four nearest.
    for y in margin - 1..h - margin + 1 {
        let r = &mut res[y * w + f0..y * w + f1];
        let (on, f, v) = (
            &sites[y % 2][f0..f1],
            &row(fit, w, y)[f0..f1],
            &row(m, w, y)[f0..f1],
        );
        for x in 0..r.len() {
            r[x] = on[x] * (v[x] - f[x]);
        }
    }
    for y in margin..h - margin {
        let (up, mid, down) = (row(res, w, y - 1), row(res, w, y), row(res, w, y + 1));
        let f = &mut fit[y * w..(y + 1) * w];
        match lattice {
            Lattice::Grid => {
                for x in margin..w - margin {
                    let cross = mid[x - 1] + mid[x + 1] + up[x] + down[x];
                    let diagonal = up[x - 1] + up[x + 1] + down[x - 1] + down[x + 1];
                    f[x] += mid[x] + 0.5 * cross + 0.25 * diagonal;
                }
            }
            Lattice::Quincunx => {
                for x in margin..w - margin {
                    f[x] += mid[x] + 0.25 * (mid[x - 1] + mid[x + 1] + up[x] + down[x]);
                }
            }
        }
    }
}

/// Sums of 2·R + 1 neighbours along `row`, into `out` but for `R` at each end. In a fixed
/// order rather than as a running sum, whose rounding would depend on where it started: strips
/// must give the whole frame's values exactly. The order is that of adding whole shifted rows
/// one after another, left to right, but a block of sums is held in registers meanwhile rather
/// than stored and reloaded at every step: 32 at a time (four independent chains of AVX
/// additions, so that no addition waits for the one before), then 8, then one.
#[inline(always)]
fn window_sum<const R: usize>(row: &[f32], out: &mut [f32]) {
    let Some(n) = row.len().checked_sub(2 * R) else {
        return;
    };
    let out = &mut out[R..R + n];
    let done = sums_in_blocks::<R, 32>(row, out, 0);
    let done = sums_in_blocks::<R, 8>(row, out, done);
    sums_in_blocks::<R, 1>(row, out, done);
}

/// [`window_sum`]'s sums `out[from..]` in whole blocks of `B`, up to the last whole block;
/// where they stopped.
#[inline(always)]
fn sums_in_blocks<const R: usize, const B: usize>(
    row: &[f32],
    out: &mut [f32],
    from: usize,
) -> usize {
    let len = out.len();
    let mut chunks = out[from..].chunks_exact_mut(B);
    for (c, o) in (&mut chunks).enumerate() {
        let taps = &row[from + c * B..][..B + 2 * R];
        let mut s: [f32; B] = std::array::from_fn(|l| taps[l]);
        for k in 1..=2 * R {
            let t = &taps[k..k + B];
            for l in 0..B {
                s[l] += t[l];
            }
        }
        o.copy_from_slice(&s);
    }
    len - chunks.into_remainder().len()
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::develop::linear::{bilinear, malvar};

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
            let mut ws = Workspace::default();
            residual_interpolation(&padded.data, padded.width, order, PAD, &mut ws);
            let planes = [&ws.planes[0], &ws.planes[3], &ws.planes[2]];
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

    /// `demosaic_regions`'s rows of a mosaic in linear light: its samples encoded.
    fn encoded_rows(m: &Mosaic) -> impl Fn(usize, usize, &mut [f32]) + Sync + '_ {
        let encode = &srgb::tabulated().encode;
        move |y, x0, row| {
            for (v, s) in row.iter_mut().zip(&m.data[y * m.width + x0..]) {
                *v = encode.at(*s);
            }
        }
    }

    /// `demosaic_regions`'s pixels as [`demosaic`] gives them: decoded to linear light.
    fn decoded(rgb: [&[f32]; 3], out: &mut [f32]) {
        let decode = &srgb::tabulated().decode;
        for (k, px) in out.chunks_exact_mut(3).enumerate() {
            for (o, c) in px.iter_mut().zip(rgb) {
                *o = decode.at(c[k]);
            }
        }
    }

    #[test]
    fn a_region_of_a_mosaic_smaller_than_the_border_is_its_whole_development() {
        for order in ORDERS {
            let rgb = Image::from_fn(9, 5, 3, |x, y, c| {
                ((x * 7 + y * 3 + c * 5) % 11) as f32 / 11.0
            });
            let m = Mosaic::sample(&rgb, order);
            let r = Rect {
                x: 1,
                y: 1,
                width: 7,
                height: 3,
            };
            let fill = encoded_rows(&m);
            let regions = Regions {
                size: (9, 5),
                order,
                fill: &fill,
                rects: &[r],
            };
            let part = &demosaic_regions(&[regions], &decoded)[0][0];
            let whole = demosaic(&m);
            for yy in 0..3 {
                assert_eq!(
                    &part.data()[yy * 21..][..21],
                    &whole.data()[((1 + yy) * 9 + 1) * 3..][..21],
                    "{order:?} row {yy}"
                );
            }
        }
    }

    #[test]
    fn regions_are_developed_exactly_as_in_the_whole_frame() {
        let scene = crate::sim::SimParams::demosaic_scene(11);
        let truth = crate::develop::decode(&crate::sim::render(&scene).truth);
        let m = Mosaic::sample(&truth, BayerOrder::Gbrg);
        let whole = demosaic(&m);
        // Inside, on odd coordinates, and against each edge of the frame.
        let (w, h) = (m.width, m.height);
        // Two just below the first, developed in one window with it.
        let rects = [
            (101, 77, 60, 33),
            (0, 0, 50, 40),
            (w - 31, h - 20, 31, 20),
            (3, 1, w - 5, 9),
            (99, 110, 64, 32),
            (120, 142, 9, 7),
        ]
        .map(|(x, y, width, height)| Rect {
            x,
            y,
            width,
            height,
        });
        let grouped = windows(&rects, w);
        assert!(grouped.len() < rects.len(), "{grouped:?}");
        let first = grouped.iter().find(|(_, k)| k.contains(&0)).expect("held");
        assert!(first.1.contains(&4) && first.1.contains(&5), "{grouped:?}");
        let fill = encoded_rows(&m);
        let asked = Regions {
            size: (w, h),
            order: m.order,
            fill: &fill,
            rects: &rects,
        };
        let regions = demosaic_regions(&[asked], &decoded).remove(0);
        for (part, r) in regions.iter().zip(rects) {
            let Rect {
                x,
                y,
                width: rw,
                height: rh,
            } = r;
            assert_eq!((part.width(), part.height()), (rw, rh));
            for yy in 0..rh {
                let got = &part.data()[yy * rw * 3..][..rw * 3];
                let want = &whole.data()[((y + yy) * w + x) * 3..][..rw * 3];
                assert_eq!(got, want, "region {r:?} row {yy}");
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
