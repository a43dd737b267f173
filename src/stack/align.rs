//! Bringing registered frames into the reference frame's geometry and exposure.
//!
//! Each frame is resampled through its [`Warp`] onto the reference's pixel grid and corrected
//! for exposure and white balance. A reference pixel the frame does not cover takes the
//! reference's own value, so later filters see real image content there (not black, not
//! smeared edge pixels), and [`Coverage`] records where the frame is genuine, so labelling never
//! picks it outside.

use super::image::{Image, Sample};
use super::transform::{Affine, Raster, Warp};
use rayon::prelude::*;

/// Per row, the half-open span of pixels a warped frame covers: an affine footprint is convex,
/// so one span per row describes it (and a smooth field bends it too little to matter).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Coverage {
    pub width: usize,
    pub spans: Vec<(u32, u32)>,
}

/// An axis-aligned rectangle of pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl Coverage {
    pub fn full(width: usize, height: usize) -> Coverage {
        Coverage {
            width,
            spans: vec![(0, width as u32); height],
        }
    }

    #[inline]
    pub fn covers(&self, x: usize, y: usize) -> bool {
        let (lo, hi) = self.spans[y];
        (lo as usize..hi as usize).contains(&x)
    }

    /// The pixels every one of `all` covers (all of one size, at least one).
    pub fn intersection(all: &[Coverage]) -> Coverage {
        let mut out = all[0].clone();
        for c in &all[1..] {
            for (o, s) in out.spans.iter_mut().zip(&c.spans) {
                *o = (o.0.max(s.0), o.1.min(s.1));
            }
        }
        out
    }

    /// The largest-area rectangle inside the covered pixels; `None` when nothing is covered.
    /// Quadratic in the height, which is a few million steps for a phone frame.
    pub fn largest_rect(&self) -> Option<Rect> {
        let h = self.spans.len();
        let mut best: Option<(usize, Rect)> = None;
        for top in 0..h {
            let (mut lo, mut hi) = (0u32, u32::MAX);
            for bottom in top..h {
                let s = self.spans[bottom];
                (lo, hi) = (lo.max(s.0), hi.min(s.1));
                if hi <= lo {
                    break;
                }
                let r = Rect {
                    x: lo as usize,
                    y: top,
                    width: (hi - lo) as usize,
                    height: bottom + 1 - top,
                };
                let area = r.width * r.height;
                if best.is_none_or(|(a, _)| area > a) {
                    best = Some((area, r));
                }
            }
        }
        best.map(|(_, r)| r)
    }
}

/// A frame's exposure against the reference in one channel: frame ≈ gain · reference + offset,
/// values scaled to 0..1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exposure {
    pub gain: f32,
    pub offset: f32,
}

impl Exposure {
    pub const SAME: Exposure = Exposure {
        gain: 1.0,
        offset: 0.0,
    };
}

/// Blocks across and down the reference over which exposure is compared. Means over large
/// blocks hardly change with defocus (a blur only moves light across a block's edge), so block
/// means of a sharp and a blurred frame line up; the spread of the blocks' brightness is what
/// separates gain from offset.
const BLOCKS: (usize, usize) = (12, 9);
/// Samples per frame the block means are taken from, at most: the grid's step is rounded up, so
/// a small frame is not sampled at every pixel; more samples change the exposure estimate by
/// nothing the output shows.
const SAMPLES: usize = 100_000;
/// Values at or above this fraction of full scale may be clipped and say nothing about gain.
const CLIPPED: f32 = 0.98;
/// Blocks whose brightness spreads less than this (0..1 units) cannot separate gain from offset:
/// below it the offset is taken as 0.
const MIN_SPREAD: f64 = 0.03;
/// An offset is fitted only where gain and offset leave less than this fraction of the squared
/// error the gain alone leaves.
const OFFSET_EVIDENCE: f64 = 0.25;

/// Estimates each channel's exposure of `frame` against `reference` through `warp`
/// (reference pixel → frame pixel). Falls back to [`Exposure::SAME`] for a channel where the
/// frames share too little to judge or the fit is implausible.
pub fn estimate_exposure<T: Sample>(
    frame: &Image<T>,
    reference: &Image<T>,
    warp: &Warp,
) -> Vec<Exposure> {
    let (w, h, ch) = (reference.width(), reference.height(), reference.channels());
    let stride = ((w * h) as f64 / SAMPLES as f64).sqrt().ceil().max(1.0) as usize;
    let (bx, by) = BLOCKS;
    let nb = bx * by;
    // Per block: samples, then per channel Σ reference and Σ frame.
    let mut count = vec![0u32; nb];
    let mut sums = vec![(0.0f64, 0.0f64); nb * ch];
    let clip = CLIPPED * T::MAX;
    let (fw, fh) = (frame.width() as f64, frame.height() as f64);
    // Each sampled column's block, worked out once rather than by a division per sample.
    let columns: Vec<(usize, usize)> = (stride / 2..w)
        .step_by(stride)
        .map(|x| (x, x * bx / w))
        .collect();
    let raster = warp.raster(w);
    for y in (stride / 2..h).step_by(stride) {
        let (at, row_block) = (raster.row(y), (y * by / h) * bx);
        for &(x, column_block) in &columns {
            // The nearest frame pixel: u + ½ truncated is u rounded wherever it is in the frame
            // (u > −½), without the library call `round` is on baseline x86-64.
            let (u, v) = at(x);
            let (u, v) = (u + 0.5, v + 0.5);
            if !(u > 0.0 && u < fw && v > 0.0 && v < fh) {
                continue;
            }
            let r = &reference.data()[(y * w + x) * ch..][..ch];
            let f = &frame.data()[(v as usize * frame.width() + u as usize) * ch..][..ch];
            if r.iter().chain(f).any(|s| s.to_f32() >= clip) {
                continue;
            }
            let b = row_block + column_block;
            count[b] += 1;
            for c in 0..ch {
                let s = &mut sums[b * ch + c];
                s.0 += r[c].to_f32() as f64;
                s.1 += f[c].to_f32() as f64;
            }
        }
    }
    let full = count.iter().copied().max().unwrap_or(0);
    let blocks: Vec<usize> = (0..nb)
        .filter(|&b| full > 0 && count[b] * 2 >= full)
        .collect();
    (0..ch)
        .map(|c| {
            let points: Vec<(f64, f64, f64)> = blocks
                .iter()
                .map(|&b| {
                    let (n, (sr, sf)) = (count[b] as f64, sums[b * ch + c]);
                    let m = T::MAX as f64 * n;
                    (sr / m, sf / m, n)
                })
                .collect();
            fit_exposure(&points).unwrap_or(Exposure::SAME)
        })
        .collect()
}

/// Fits frame = gain · reference (+ offset) to block means `(reference, frame, weight)`;
/// `None` when there is nothing to fit or the result is no plausible exposure change.
///
/// The gain alone, a ratio of sums, is what defocus leaves least biased (measured on hand-held
/// synthetic stacks with ±5% gain and ±3% white balance: 0.0003 mean error, against 0.007 when
/// gain and offset are always fitted together, as the pair trades off along the blocks' narrow
/// brightness range). So an offset is fitted only when it explains most of what the gain leaves.
fn fit_exposure(points: &[(f64, f64, f64)]) -> Option<Exposure> {
    let sw: f64 = points.iter().map(|p| p.2).sum();
    if points.len() < 4 || sw <= 0.0 {
        return None;
    }
    let mean =
        |f: &dyn Fn(&(f64, f64, f64)) -> f64| points.iter().map(|p| p.2 * f(p)).sum::<f64>() / sw;
    let (mr, mf) = (mean(&|p| p.0), mean(&|p| p.1));
    if mr <= 0.0 {
        return None;
    }
    let ratio = mf / mr;
    let srr = mean(&|p| (p.0 - mr).powi(2));
    let srf = mean(&|p| (p.0 - mr) * (p.1 - mf));
    let (g, o) = (srf / srr, mf - srf / srr * mr);
    let residual = |g: f64, o: f64| mean(&|p| (p.1 - g * p.0 - o).powi(2));
    let (gain, offset) =
        if srr.sqrt() >= MIN_SPREAD && residual(g, o) < OFFSET_EVIDENCE * residual(ratio, 0.0) {
            (g, o)
        } else {
            (ratio, 0.0)
        };
    ((0.5..=2.0).contains(&gain) && offset.abs() <= 0.1).then_some(Exposure {
        gain: gain as f32,
        offset: offset as f32,
    })
}

/// Keys' cubic convolution weights (a = −½) of the four taps around a point `t` past the second.
/// Bilinear resampling would soften every frame once more.
pub(super) fn keys(t: f32) -> [f32; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    ]
}

/// Sub-pixel positions [`keys`] is tabulated at: 1/256 px is far below registration error, and
/// the table lookup costs a fifth of computing the weights per pixel.
const PHASES: usize = 256;

/// [`keys`] at each of the [`PHASES`] positions past a pixel.
fn keys_table() -> [[f32; 4]; PHASES] {
    std::array::from_fn(|i| keys(i as f32 / PHASES as f32))
}

/// A coordinate `u` ≥ 0 rounded to 1/[`PHASES`] px: the pixel at or before it and its phase
/// past that pixel. One float-to-integer conversion gives both: as a pixel (`floor`) and a
/// phase each, the two were a fifth of the warp's time. Where the fraction rounds up to a whole
/// pixel this gives the next pixel at phase 0, the same taps with the same weights (0 and 1)
/// as the pixel before at phase 1.
#[inline]
fn tap(u: f64) -> (usize, usize) {
    // Signed: one conversion instruction, where an unsigned one takes several. It saturates
    // only beyond 2^55 px, so any side the decoders accept (`imageio::MAX_PIXELS`) fits.
    let fixed = (u * PHASES as f64 + 0.5) as i64 as usize;
    (fixed / PHASES, fixed % PHASES)
}

/// Resamples `frame` onto the reference's grid through `warp` (bicubic), undoing `exposure`;
/// pixels the frame does not cover take `reference`'s values.
pub fn warp_frame<T: Sample>(
    frame: &Image<T>,
    reference: &Image<T>,
    warp: &Warp,
    exposure: &[Exposure],
) -> (Image<T>, Coverage) {
    let mut out = reference.clone();
    let cov = warp_frame_into(frame, reference, warp, exposure, &mut out, &mut Vec::new());
    (out, cov)
}

/// [`warp_frame`] into `out` (the reference's geometry), with `scratch` for the frame's samples
/// as floats: a stack is warped through the same two buffers, not two fresh ones per frame.
pub fn warp_frame_into<T: Sample>(
    frame: &Image<T>,
    reference: &Image<T>,
    warp: &Warp,
    exposure: &[Exposure],
    out: &mut Image<T>,
    scratch: &mut Vec<f32>,
) -> Coverage {
    assert!(
        out.same_geometry(reference),
        "output is not the reference's geometry"
    );
    let fallback = Some(reference.data());
    warp_source(Source::Frame(frame), fallback, warp, exposure, out, scratch)
}

/// A difference between two images of parts of a frame: over `.0`, `.1` − `.2` (each `.0`'s
/// size), zero elsewhere.
pub type Patch<'a, T> = (Rect, &'a Image<T>, &'a Image<T>);

/// Row `y` of a patch (counted from its own top) as its differences `.1` − `.2`, sample by
/// sample.
pub fn patch_row<'a, T: Sample>(patch: &Patch<'a, T>, y: usize) -> impl Iterator<Item = f32> + 'a {
    let (r, a, b) = *patch;
    let row = y * r.width * a.channels()..(y + 1) * r.width * a.channels();
    let pairs = a.data()[row.clone()].iter().zip(&b.data()[row]);
    pairs.map(|(a, b)| a.to_f32() - b.to_f32())
}

/// Brings a frame's full development into `out` (the reference's geometry), which holds the
/// frame's cheap development warped (`exposure` undone and rounded), perhaps changed since:
/// `patches` give both developments over parts of a `width`×`height` frame. Where an output
/// pixel is still the cheap warp's value, it takes the full development's warp, rounded once,
/// as warping the full development would give it; where it was changed since (the spill
/// removal), the warp of the difference is added, keeping the change. Only the output rows
/// whose taps reach a patch are resampled; pixels the frame does not cover are left as they are.
pub fn warp_refine_into<T: Sample>(
    patches: &[Patch<T>],
    (width, height): (usize, usize),
    warp: &Warp,
    exposure: &[Exposure],
    out: &mut Image<T>,
    scratch: &mut Vec<f32>,
) {
    let source = Source::Patches {
        size: (width, height),
        patches,
    };
    warp_source(source, None, warp, exposure, out, scratch);
}

/// What a warp resamples.
#[derive(Clone, Copy)]
enum Source<'a, T> {
    Frame(&'a Image<T>),
    /// A frame of this size, zero but over the patches ([`warp_refine_into`]): a pixel's first
    /// half of lanes the difference full − cheap, its second half the cheap development.
    Patches {
        size: (usize, usize),
        patches: &'a [Patch<'a, T>],
    },
}

impl<T: Sample> Source<'_, T> {
    fn size(&self) -> (usize, usize) {
        match self {
            Source::Frame(f) => (f.width(), f.height()),
            Source::Patches { size, .. } => *size,
        }
    }

    /// Whether any of frame rows `rows` may be other than zero.
    fn reaches(&self, rows: std::ops::Range<usize>) -> bool {
        match self {
            Source::Frame(_) => true,
            Source::Patches { patches, .. } => patches
                .iter()
                .any(|(r, ..)| r.y < rows.end && r.y + r.height > rows.start),
        }
    }

    /// Frame rows `first..` as floats into `dst`, `L` lanes a pixel, `C` channels and unused
    /// lanes zero.
    fn rows_into<const C: usize, const L: usize>(&self, first: usize, dst: &mut [f32]) {
        let fw = self.size().0;
        match self {
            Source::Frame(frame) => {
                let end = first + dst.len() / (fw * L);
                dst.par_chunks_mut(L << 14)
                    .zip(frame.data()[first * fw * C..end * fw * C].par_chunks(C << 14))
                    .for_each(|(d, s)| {
                        for (d, s) in d.chunks_exact_mut(L).zip(s.chunks_exact(C)) {
                            let (d, pad) = d.split_at_mut(C);
                            d.iter_mut().zip(s).for_each(|(d, s)| *d = s.to_f32());
                            pad.fill(0.0);
                        }
                    });
            }
            // Row by row in parallel: the band is some megabytes of mostly zeros.
            Source::Patches { patches, .. } => {
                dst.par_chunks_mut(fw * L)
                    .enumerate()
                    .for_each(|(k, line)| {
                        line.fill(0.0);
                        let y = first + k;
                        for patch in patches.iter() {
                            let (r, cheap) = (patch.0, patch.2.data());
                            if !(r.y..r.y + r.height).contains(&y) {
                                continue;
                            }
                            let pixels = &mut line[r.x * L..(r.x + r.width) * L];
                            let diffs = pixels.chunks_exact_mut(L).flat_map(|d| &mut d[..C]);
                            for (d, v) in diffs.zip(patch_row(patch, y - r.y)) {
                                *d = v;
                            }
                            let cheap = cheap[(y - r.y) * r.width * C..][..r.width * C].chunks(C);
                            for (d, v) in pixels.chunks_exact_mut(L).zip(cheap) {
                                for (d, v) in d[L / 2..].iter_mut().zip(v) {
                                    *d = v.to_f32();
                                }
                            }
                        }
                    });
            }
        }
    }
}

/// Resamples `source` into `out` through `warp`, undoing `exposure`: where `fallback` (the
/// reference's samples) is given, replacing `out`'s pixels and taking the fallback's where the
/// frame does not cover them; where it is not, adding to them.
fn warp_source<T: Sample>(
    source: Source<T>,
    fallback: Option<&[T]>,
    warp: &Warp,
    exposure: &[Exposure],
    out: &mut Image<T>,
    scratch: &mut Vec<f32>,
) -> Coverage {
    const GREY: usize = warp_lanes(1);
    const COLOUR: usize = warp_lanes(3);
    let (w, ch) = (out.width(), out.channels());
    const GREY2: usize = refine_lanes(1);
    const COLOUR2: usize = refine_lanes(3);
    let data = out.data_mut();
    let patches = matches!(source, Source::Patches { .. });
    match (ch, patches) {
        (1, false) => {
            warp_channels::<T, 1, GREY>(source, fallback, w, warp, exposure, data, scratch)
        }
        (3, false) => {
            warp_channels::<T, 3, COLOUR>(source, fallback, w, warp, exposure, data, scratch)
        }
        (1, true) => {
            warp_channels::<T, 1, GREY2>(source, fallback, w, warp, exposure, data, scratch)
        }
        (3, true) => {
            warp_channels::<T, 3, COLOUR2>(source, fallback, w, warp, exposure, data, scratch)
        }
        (n, _) => panic!("frames have 1 or 3 channels, not {n}"),
    }
}

/// Float lanes a pixel the warp holds a frame in (see [`warp_channels`]): one for grey, four
/// for colour. The memory plan counts its scratch with this.
pub const fn warp_lanes(channels: usize) -> usize {
    if channels == 1 {
        1
    } else {
        4
    }
}

/// Float lanes a pixel [`warp_refine_into`] holds its patches in: the difference and the cheap
/// development, each in the warp's lanes. The memory plan counts its scratch with this.
pub const fn refine_lanes(channels: usize) -> usize {
    2 * warp_lanes(channels)
}

/// `warp_frame_into` for `C` channels, so the tap loops unroll. The frame's samples are held as
/// floats in `L` lanes a pixel, `C` and unused ones after: three channels in four lanes make
/// every tap one vector multiply-add instead of three scalar ones, each lane summing in the same
/// order as the scalar loop did, so the output is the same, for a third more scratch memory.
fn warp_channels<T: Sample, const C: usize, const L: usize>(
    source: Source<T>,
    fallback: Option<&[T]>,
    w: usize,
    warp: &Warp,
    exposure: &[Exposure],
    data: &mut [T],
    src: &mut Vec<f32>,
) -> Coverage {
    let (fw, fh) = source.size();
    let scale = T::MAX;
    // v' = (v − offset·MAX) / gain as one multiply-add.
    let correct: [(f32, f32); C] = std::array::from_fn(|c| {
        let e = exposure[c];
        (1.0 / e.gain, -e.offset * scale / e.gain)
    });
    // Output rows in bands, each band's frame rows converted to floats just before it is
    // resampled: a scalar integer-to-float conversion per tap would cost more than the
    // interpolation (16 taps per pixel and channel), and the whole frame as floats would be 16
    // bytes a pixel of fresh memory where a band's rows are a few megabytes. A
    // band is at least as tall as the rows a roll spreads one output row over, so no frame row
    // is converted more than about twice.
    let reach = warp.field.as_ref().map_or(0.0, |f| f.reach(1.0));
    let band = band_rows(w as f64 * warp.affine.0[1][0].abs() + 2.0 * reach);
    let (table, raster) = (keys_table(), warp.raster(w));
    let cells = match source {
        Source::Patches { size, patches } => Some(Cells::of(patches, size, &warp.affine, reach)),
        Source::Frame(_) => None,
    };
    let h = data.len() / (w * C);
    let mut spans = Vec::with_capacity(h);
    for y0 in (0..h).step_by(band) {
        let y1 = (y0 + band).min(h);
        let (lo, hi) = warp.frame_rows(y0..y1, w, reach);
        // Every row a tap of the band reads: from the row before the lowest coordinate to three
        // after the highest (a coordinate may round up to the next pixel), and one more each
        // side for rounding.
        let first = (lo.floor() - 2.0).clamp(0.0, fh as f64) as usize;
        let end = ((hi.floor() + 5.0).clamp(0.0, fh as f64) as usize).max(first);
        if fallback.is_none() && !source.reaches(first..end) {
            // Adding a warp of zeros changes nothing.
            spans.extend((y0..y1).map(|_| (0, 0)));
            continue;
        }
        // Sized in one allocation, reused by every band and frame: a parallel collect would
        // build it from pieces allocated in the worker threads' malloc arenas, which keep the
        // memory after it is freed.
        src.resize((end - first) * fw * L, 0.0);
        source.rows_into::<C, L>(first, &mut src[..(end - first) * fw * L]);
        let rows = Rows {
            src,
            first,
            size: (fw, fh),
            table: &table,
            raster: &raster,
            correct,
            refine: cells.as_ref(),
        };
        spans.par_extend(
            data[y0 * w * C..y1 * w * C]
                .par_chunks_mut(w * C)
                .enumerate()
                .map(|(k, row)| {
                    let y = y0 + k;
                    let fallback = fallback.map_or(&[][..], |f| &f[y * w * C..][..w * C]);
                    rows.warp::<T, L>(y, row, fallback)
                }),
        );
    }
    Coverage { width: w, spans }
}

/// Where a frame point's 4×4 bicubic taps fall ([`Rows::taps`]): outside the frame, wholly
/// inside it (from frame float `at` on, a run of four pixels on each of four rows), or partly
/// beyond its edge (clamped taps around pixel `(x0, y0)`); with the weights along x and y.
#[derive(Clone, Copy)]
enum Taps {
    Outside,
    Inside {
        at: usize,
        kx: [f32; 4],
        ky: [f32; 4],
    },
    Edge {
        x0: usize,
        y0: usize,
        kx: [f32; 4],
        ky: [f32; 4],
    },
}

/// Output rows a band of the warp has at least (see [`warp_channels`]).
const BAND_ROWS: usize = 64;

/// Output rows of a band of the warp where one output row spreads over `spread` frame rows (a
/// roll across the width, and a field's reach up and down): at least [`BAND_ROWS`] and at least
/// the spread, so that no frame row is converted more than about twice.
fn band_rows(spread: f64) -> usize {
    BAND_ROWS.max(spread.ceil() as usize)
}

/// Frame rows the warp of a `width`×`height` stack holds as floats at once, for the memory
/// plan: a band and the rows it reaches under a roll of up to about 3° (a twentieth of the
/// width across it) and local offsets of up to 16 px; a steeper roll takes more.
pub fn warp_scratch_rows(width: usize, height: usize) -> usize {
    let band = band_rows((width / 20 + 32) as f64);
    (2 * band + 8).min(height)
}

/// What [`warp_channels`] resamples a row of the output from.
struct Rows<'a, const C: usize> {
    /// The frame's rows from `first` on as floats, `L` lanes a pixel: every row the band's
    /// taps read.
    src: &'a [f32],
    first: usize,
    /// The frame's width and height.
    size: (usize, usize),
    table: &'a [[f32; 4]; PHASES],
    raster: &'a Raster<'a>,
    /// Per channel, the exposure correction as a multiply-add.
    correct: [(f32, f32); C],
    /// Where the source is [`warp_refine_into`]'s patches (no fallback), the cells near them:
    /// the output is refined there, not replaced, and left as it is elsewhere.
    refine: Option<&'a Cells>,
}

/// Which cells of a frame lie within a bicubic tap's reach of [`warp_refine_into`]'s patches:
/// an output pixel whose frame point falls in none reads only zeros, and refining leaves it as
/// it is, so it is not resampled (a frame's regions are a small part of the rows they span).
/// Runs of [`Cells::BLOCK`] output pixels are first tested together ([`Cells::may_reach`]),
/// so that the rows' long stretches far from every patch cost a test a run, not a warp of each
/// pixel's coordinates.
struct Cells {
    cols: usize,
    rows: usize,
    near: Vec<bool>,
    /// `near` widened by how far the frame points of a run's pixels may lie from the affine
    /// point of its first pixel.
    wide: Vec<bool>,
    affine: Affine,
}

impl Cells {
    const SIZE: usize = 8;
    const BLOCK: usize = 8;

    /// The cells near `patches` of a `w`×`h` frame, warped onto by `affine` plus a field whose
    /// offsets reach at most `reach` pixels.
    fn of<T: Sample>(
        patches: &[Patch<T>],
        (w, h): (usize, usize),
        affine: &Affine,
        reach: f64,
    ) -> Cells {
        // A point's taps reach from the column before its own to three after (see `tap`).
        const REACH: usize = 4;
        let (cols, rows) = (w.div_ceil(Self::SIZE), h.div_ceil(Self::SIZE));
        let mut near = vec![false; cols * rows];
        for (r, ..) in patches {
            let span = |from: usize, n: usize, cells: usize| {
                from.saturating_sub(REACH) / Self::SIZE
                    ..((from + n + REACH) / Self::SIZE + 1).min(cells)
            };
            let xs = span(r.x, r.width, cols);
            for cy in span(r.y, r.height, rows) {
                near[cy * cols + xs.start..cy * cols + xs.end].fill(true);
            }
        }
        // Along a run the affine point moves by its x step each pixel; the field adds at most
        // its reach; a pixel more for rounding. A point d pixels from another lies at most
        // ⌊d / SIZE⌋ + 1 cells from it.
        let cells = |step: f64| {
            let d = (Self::BLOCK - 1) as f64 * step.abs() + reach + 1.0;
            (d / Self::SIZE as f64) as usize + 1
        };
        let (sx, sy) = (cells(affine.0[0][0]), cells(affine.0[1][0]));
        let mut across = vec![false; cols * rows];
        for (cy, line) in near.chunks_exact(cols).enumerate() {
            for cx in (0..cols).filter(|&cx| line[cx]) {
                across[cy * cols + cx.saturating_sub(sx)..cy * cols + (cx + sx + 1).min(cols)]
                    .fill(true);
            }
        }
        let mut wide = vec![false; cols * rows];
        for cy in 0..rows {
            for dy in cy.saturating_sub(sy)..(cy + sy + 1).min(rows) {
                for (w, &a) in wide[cy * cols..][..cols]
                    .iter_mut()
                    .zip(&across[dy * cols..])
                {
                    *w |= a;
                }
            }
        }
        Cells {
            cols,
            rows,
            near,
            wide,
            affine: *affine,
        }
    }

    fn near(&self, (u, v): (f64, f64)) -> bool {
        let (cx, cy) = (
            u.max(0.0) as usize / Self::SIZE,
            v.max(0.0) as usize / Self::SIZE,
        );
        cx < self.cols && cy < self.rows && self.near[cy * self.cols + cx]
    }

    /// Whether any of the [`Cells::BLOCK`] output pixels from `(x, y)` on may be
    /// [`Cells::near`]: false only where none is. A point off the frame is taken to the
    /// nearest cell, which the widening covers as well.
    fn may_reach(&self, x: usize, y: usize) -> bool {
        let (u, v) = self.affine.apply(x as f64, y as f64);
        let cell = |a: f64, n: usize| ((a.max(0.0) / Self::SIZE as f64) as usize).min(n - 1);
        self.wide[cell(v, self.rows) * self.cols + cell(u, self.cols)]
    }
}

impl<const C: usize> Rows<'_, C> {
    /// Resamples output row `y` into `row`, taking `fallback`'s values where the frame does not
    /// cover it; returns the span it covers. Compiled for AVX where the CPU has it: the same
    /// arithmetic in the same order (no fused multiply-add), so the same output, in less time.
    fn warp<T: Sample, const L: usize>(
        &self,
        y: usize,
        row: &mut [T],
        fallback: &[T],
    ) -> (u32, u32) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the CPU has AVX, checked just above.
            return unsafe {
                match L {
                    4 => self.warp_pairs_avx(y, row, fallback),
                    8 => self.warp_octets_avx(y, row, fallback),
                    _ => self.warp_avx::<T, L>(y, row, fallback),
                }
            };
        }
        self.warp_body::<T, L>(y, row, fallback)
    }

    /// `warp_body` compiled for AVX.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn warp_avx<T: Sample, const L: usize>(
        &self,
        y: usize,
        row: &mut [T],
        fallback: &[T],
    ) -> (u32, u32) {
        self.warp_body::<T, L>(y, row, fallback)
    }

    #[inline(always)]
    fn warp_body<T: Sample, const L: usize>(
        &self,
        y: usize,
        row: &mut [T],
        fallback: &[T],
    ) -> (u32, u32) {
        let w = row.len() / C;
        let mut span = (w, 0);
        // The unused lane's sum, kept: a compiler that sees the lane unused splits every four-lane
        // tap into a two-lane and a one-lane one, which is slower.
        let mut pad = 0.0f32;
        let at = self.raster.row(y);
        let mut x = 0;
        while x < w {
            if let Some(run) = self.far_run(x, y) {
                x += run;
                continue;
            }
            let (point, out) = (at(x), &mut row[x * C..][..C]);
            x += 1;
            if self.refine.is_some_and(|cells| !cells.near(point)) {
                continue;
            }
            let acc = self.pixel::<T, L>(self.taps(point), x - 1, &mut span, out, fallback);
            if let Some(acc) = acc {
                pad += acc[L - 1];
                self.store(&acc, out);
            }
        }
        std::hint::black_box(pad);
        Self::covered(span)
    }

    /// Refining, the pixels from `x` on (at the start of a run) that no patch reaches, to be
    /// passed over.
    #[inline(always)]
    fn far_run(&self, x: usize, y: usize) -> Option<usize> {
        let cells = self.refine?;
        (x.is_multiple_of(Cells::BLOCK) && !cells.may_reach(x, y)).then_some(Cells::BLOCK)
    }

    /// The span a row covers, from its lowest and one past its highest covered pixel.
    fn covered((lo, hi): (usize, usize)) -> (u32, u32) {
        if hi <= lo {
            (0, 0)
        } else {
            (lo as u32, hi as u32)
        }
    }

    /// Where the 4×4 taps of frame point `(u, v)` fall, and their weights.
    #[inline(always)]
    fn taps(&self, (u, v): (f64, f64)) -> Taps {
        let (fw, fh) = self.size;
        if !(0.0..=fw as f64 - 1.0).contains(&u) || !(0.0..=fh as f64 - 1.0).contains(&v) {
            return Taps::Outside;
        }
        let ((x0, px), (y0, py)) = (tap(u), tap(v));
        let (kx, ky) = (self.table[px], self.table[py]);
        if x0 >= 1 && y0 >= 1 && x0 + 2 < fw && y0 + 2 < fh {
            Taps::Inside {
                at: (y0 - 1 - self.first) * fw + x0 - 1,
                kx,
                ky,
            }
        } else {
            Taps::Edge { x0, y0, kx, ky }
        }
    }

    /// Output pixel `x` from its `taps`: its `L` lanes' bicubic sums, or `None` where it is
    /// outside the frame (then `out` takes `fallback`'s pixel). Widens `span` to the pixel
    /// where it is covered.
    #[inline(always)]
    fn pixel<T: Sample, const L: usize>(
        &self,
        taps: Taps,
        x: usize,
        span: &mut (usize, usize),
        out: &mut [T],
        fallback: &[T],
    ) -> Option<[f32; L]> {
        let (src, first, (fw, fh)) = (self.src, self.first, self.size);
        let mut acc = [0.0f32; L];
        match taps {
            Taps::Outside => {
                if self.refine.is_none() {
                    out.copy_from_slice(&fallback[x * C..][..C]);
                }
                return None;
            }
            // Inside: the 4×4 taps are contiguous runs of rows, each summed along x and then
            // weighted for y (separable: 20 multiply-adds a lane, not 16 and 16 products of
            // weights, faster; a few pixels in a hundred thousand round one level apart).
            Taps::Inside { at, kx, ky } => {
                let base = at * L;
                for (r, &wy) in ky.iter().enumerate() {
                    let taps = &src[base + r * fw * L..][..4 * L];
                    let mut along = [0.0f32; L];
                    for (px, &wx) in taps.chunks_exact(L).zip(&kx) {
                        let px: &[f32; L] = px.try_into().expect("L lanes");
                        for (a, s) in along.iter_mut().zip(px) {
                            *a += wx * s;
                        }
                    }
                    for (a, s) in acc.iter_mut().zip(along) {
                        *a += wy * s;
                    }
                }
            }
            Taps::Edge { x0, y0, kx, ky } => {
                let tap = |o: usize, k: usize, n: usize| (o + k).saturating_sub(1).min(n - 1);
                for (r, &wy) in ky.iter().enumerate() {
                    let yy = tap(y0, r, fh) - first;
                    for (k, &wx) in kx.iter().enumerate() {
                        let px = &src[(yy * fw + tap(x0, k, fw)) * L..][..L];
                        for (a, s) in acc.iter_mut().zip(px) {
                            *a += wx * wy * s;
                        }
                    }
                }
            }
        }
        *span = (span.0.min(x), x + 1);
        Some(acc)
    }

    /// A pixel's channels from its lanes' sums, exposure corrected; refining (see
    /// [`warp_refine_into`]), the full development's value where the output is still the cheap
    /// one's, else the output plus the difference.
    #[inline(always)]
    fn store<T: Sample>(&self, acc: &[f32], out: &mut [T]) {
        let half = acc.len() / 2;
        for (c, (o, &(m, b))) in out.iter_mut().zip(&self.correct).enumerate() {
            *o = match self.refine {
                None => T::from_f32(acc[c] * m + b),
                Some(_) => {
                    let (cheap, diff) = (acc[half + c] * m + b, acc[c] * m);
                    match *o == T::from_f32(cheap) {
                        true => T::from_f32(cheap + diff),
                        false => T::from_f32(o.to_f32() + diff),
                    }
                }
            };
        }
    }

    /// [`Self::warp`] of frames held in four lanes a pixel (colour), with AVX: two output pixels
    /// a step, each pixel's four lanes one half of an eight-lane register, where
    /// [`Self::warp_body`] fills a four-lane register a pixel. The same multiplies and adds in
    /// the same order lane by lane (no fused multiply-add), so the same output.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn warp_pairs_avx<T: Sample>(
        &self,
        y: usize,
        row: &mut [T],
        fallback: &[T],
    ) -> (u32, u32) {
        use std::arch::x86_64::*;
        const L: usize = 4;
        let (src, fw) = (self.src, self.size.0);
        let w = row.len() / C;
        let mut span = (w, 0);
        let at = self.raster.row(y);
        let mut x = 0;
        // The second pixel's taps when it was not taken with the first: the next step's first.
        let mut carried = None;
        while x < w {
            let a = carried.take().unwrap_or_else(|| self.taps(at(x)));
            let b = match x + 1 < w {
                true => self.taps(at(x + 1)),
                false => Taps::Outside,
            };
            let (
                Taps::Inside {
                    at: ba,
                    kx: kxa,
                    ky: kya,
                },
                Taps::Inside {
                    at: bb,
                    kx: kxb,
                    ky: kyb,
                },
            ) = (a, b)
            else {
                let out = &mut row[x * C..][..C];
                if let Some(acc) = self.pixel::<T, L>(a, x, &mut span, out, fallback) {
                    self.store(&acc, out);
                }
                carried = Some(b);
                x += 1;
                continue;
            };
            let (ba, bb) = (ba * L, bb * L);
            let mut acc = _mm256_setzero_ps();
            for r in 0..4 {
                let (ta, tb) = (
                    &src[ba + r * fw * L..][..4 * L],
                    &src[bb + r * fw * L..][..4 * L],
                );
                let mut along = _mm256_setzero_ps();
                for k in 0..4 {
                    // SAFETY: each slice holds 4·L floats, so lanes k·L..k·L + 4 are in bounds.
                    let (hi, lo) = unsafe {
                        (
                            _mm_loadu_ps(tb[k * L..].as_ptr()),
                            _mm_loadu_ps(ta[k * L..].as_ptr()),
                        )
                    };
                    let taps = _mm256_set_m128(hi, lo);
                    let wx = _mm256_set_m128(_mm_set1_ps(kxb[k]), _mm_set1_ps(kxa[k]));
                    along = _mm256_add_ps(along, _mm256_mul_ps(wx, taps));
                }
                let wy = _mm256_set_m128(_mm_set1_ps(kyb[r]), _mm_set1_ps(kya[r]));
                acc = _mm256_add_ps(acc, _mm256_mul_ps(wy, along));
            }
            let mut sums = [0.0f32; 2 * L];
            // SAFETY: `sums` holds 2·L floats, the register's eight lanes.
            unsafe { _mm256_storeu_ps(sums.as_mut_ptr(), acc) };
            self.store(&sums[..C], &mut row[x * C..][..C]);
            self.store(&sums[L..L + C], &mut row[(x + 1) * C..][..C]);
            span = (span.0.min(x), x + 2);
            x += 2;
        }
        Self::covered(span)
    }

    /// [`Self::warp`] of colour held in eight lanes a pixel ([`warp_refine_into`]'s difference
    /// and cheap development, four each), with AVX: a pixel's lanes one register, where
    /// [`Self::warp_body`] compiled for eight lanes goes four or one at a time. The same
    /// multiplies and adds in the same order lane by lane, so the same output.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn warp_octets_avx<T: Sample>(
        &self,
        y: usize,
        row: &mut [T],
        fallback: &[T],
    ) -> (u32, u32) {
        use std::arch::x86_64::*;
        const L: usize = 8;
        let (src, fw) = (self.src, self.size.0);
        let w = row.len() / C;
        let mut span = (w, 0);
        let at = self.raster.row(y);
        let mut x = 0;
        while x < w {
            if let Some(run) = self.far_run(x, y) {
                x += run;
                continue;
            }
            let point = at(x);
            x += 1;
            if self.refine.is_some_and(|cells| !cells.near(point)) {
                continue;
            }
            let x = x - 1;
            let out = &mut row[x * C..][..C];
            let taps = self.taps(point);
            let Taps::Inside { at: base, kx, ky } = taps else {
                if let Some(acc) = self.pixel::<T, L>(taps, x, &mut span, out, fallback) {
                    self.store(&acc, out);
                }
                continue;
            };
            let base = base * L;
            let mut acc = _mm256_setzero_ps();
            for (r, &wy) in ky.iter().enumerate() {
                let taps = &src[base + r * fw * L..][..4 * L];
                let mut along = _mm256_setzero_ps();
                for (k, &wx) in kx.iter().enumerate() {
                    // SAFETY: `taps` holds 4·L floats, so lanes k·L..k·L + 8 are in bounds.
                    let px = unsafe { _mm256_loadu_ps(taps[k * L..].as_ptr()) };
                    along = _mm256_add_ps(along, _mm256_mul_ps(_mm256_set1_ps(wx), px));
                }
                acc = _mm256_add_ps(acc, _mm256_mul_ps(_mm256_set1_ps(wy), along));
            }
            let mut sums = [0.0f32; L];
            // SAFETY: `sums` holds the register's eight lanes.
            unsafe { _mm256_storeu_ps(sums.as_mut_ptr(), acc) };
            self.store(&sums, out);
            span = (span.0.min(x), x + 1);
        }
        Self::covered(span)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::transform::{Affine, OffsetField};

    /// The pixel and phase of a coordinate; a fraction that rounds up to a whole pixel is the
    /// next pixel at phase 0, which [`keys`] weighs as the pixel before at phase 1.
    #[test]
    fn tap_splits_a_coordinate_into_pixel_and_phase() {
        assert_eq!(tap(0.0), (0, 0));
        assert_eq!(tap(3.0), (3, 0));
        assert_eq!(tap(2.5), (2, PHASES / 2));
        assert_eq!(tap(7.25 + 0.4 / PHASES as f64), (7, PHASES / 4));
        assert_eq!(tap(4.0 - 0.4 / PHASES as f64), (4, 0));
        // A side past 2^24 px, which the decoders accept in a long, thin frame.
        assert_eq!(tap(20_000_000.5), (20_000_000, PHASES / 2));
        let (before, after) = (keys(1.0), keys(0.0));
        assert_eq!((before[2], after[1]), (1.0, 1.0));
        assert_eq!([before[0], before[1], before[3]], [0.0; 3]);
        assert_eq!([after[0], after[2], after[3]], [0.0; 3]);
    }

    /// Two developments of a frame, `full` and `cheap`, differing over two rectangles, their
    /// pieces there, and a warp through a roll and a field with gains and an offset.
    struct Refining<T> {
        full: Image<T>,
        cheap: Image<T>,
        rects: [Rect; 2],
        pieces: Vec<(Image<T>, Image<T>)>,
        warp: Warp,
        exposure: [Exposure; 3],
    }

    fn refining<T: Sample>() -> Refining<T> {
        let (w, h) = (160, 400);
        let level = |v: f32| T::from_f32(v * T::MAX);
        let cheap = Image::from_fn(w, h, 3, |x, y, c| {
            level(((x * 7 + y * 13 + c * 5) % 97) as f32 / 97.0 * 0.5 + 0.1)
        });
        let rects = [
            Rect {
                x: 20,
                y: 30,
                width: 40,
                height: 25,
            },
            Rect {
                x: 100,
                y: 150,
                width: 60,
                height: 20,
            },
        ];
        let full = Image::from_fn(w, h, 3, |x, y, c| {
            let inside =
                |r: &Rect| (r.x..r.x + r.width).contains(&x) && (r.y..r.y + r.height).contains(&y);
            let k = rects.iter().position(inside).map_or(0, |k| k + 1);
            let v = cheap.at(x, y, c).to_f32() / T::MAX;
            level(v + 0.1 * k as f32 * ((x + c) % 3) as f32 / 3.0)
        });
        let crop = |img: &Image<T>, r: Rect| {
            Image::from_fn(r.width, r.height, 3, |x, y, c| img.at(r.x + x, r.y + y, c))
        };
        let pieces = rects
            .iter()
            .map(|&r| (crop(&full, r), crop(&cheap, r)))
            .collect();
        let field = OffsetField {
            step: 40.0,
            cols: 5,
            rows: 11,
            offsets: (0..55).map(|i| (0.05 * i as f32 - 1.0, 0.7)).collect(),
        };
        let warp = Warp {
            affine: Affine::similarity(1.01, 0.03, (80.0, 200.0), (2.5, -1.25)),
            field: Some(field),
        };
        let exposure = [
            Exposure {
                gain: 0.9,
                offset: 0.02,
            },
            Exposure::SAME,
            Exposure {
                gain: 1.2,
                offset: -0.01,
            },
        ];
        Refining {
            full,
            cheap,
            rects,
            pieces,
            warp,
            exposure,
        }
    }

    impl<T: Sample> Refining<T> {
        /// The full and the cheap development warped onto a grey reference, and the cheap one
        /// refined with `changed` applied to it first.
        fn run(&self, changed: impl Fn(&mut Image<T>)) -> [Image<T>; 3] {
            let (w, h) = (self.full.width(), self.full.height());
            let reference = Image::from_fn(w, h, 3, |_, _, _| T::from_f32(0.5 * T::MAX));
            let (want, _) = warp_frame(&self.full, &reference, &self.warp, &self.exposure);
            let (mut got, _) = warp_frame(&self.cheap, &reference, &self.warp, &self.exposure);
            changed(&mut got);
            let before = got.clone();
            let patches: Vec<Patch<T>> = (self.rects.iter().zip(&self.pieces))
                .map(|(&r, (full, cheap))| (r, full, cheap))
                .collect();
            let (size, scratch) = ((w, h), &mut Vec::new());
            warp_refine_into(
                &patches,
                size,
                &self.warp,
                &self.exposure,
                &mut got,
                scratch,
            );
            [want, before, got]
        }
    }

    #[test]
    fn a_run_passed_over_holds_no_pixel_near_a_patch() {
        // Rolled, scaled either way, with a field of offsets up to 9 px: every output pixel whose
        // frame point is near a patch lies in a run `may_reach` keeps.
        let (w, h) = (203, 157);
        let piece = Image::from_fn(9, 5, 3, |_, _, _| 0u8);
        let rects = [(0, 0), (60, 70), (190, 150), (120, 3)].map(|(x, y)| Rect {
            x,
            y,
            width: 9.min(w - x),
            height: 5.min(h - y),
        });
        let patches: Vec<Patch<u8>> = rects.iter().map(|&r| (r, &piece, &piece)).collect();
        for (scale, roll, shift) in [(1.0, 0.0, 0.0), (0.9, 0.2, 7.5), (1.12, -0.3, -30.0)] {
            let field = OffsetField {
                step: 32.0,
                cols: 8,
                rows: 6,
                offsets: (0..48)
                    .map(|i| (9.0 * ((i * 7) % 5) as f32 / 4.0 - 4.5, (i % 3) as f32 * 3.0))
                    .collect(),
            };
            let warp = Warp {
                affine: Affine::similarity(scale, roll, (100.0, 80.0), (shift, -shift)),
                field: Some(field),
            };
            let reach = warp.field.as_ref().map_or(0.0, |f| f.reach(1.0));
            let cells = Cells::of(&patches, (w, h), &warp.affine, reach);
            let raster = warp.raster(w);
            let (mut near, mut kept) = (0, 0);
            for y in 0..h {
                let at = raster.row(y);
                for x in (0..w).filter(|&x| cells.near(at(x))) {
                    near += 1;
                    let start = x - x % Cells::BLOCK;
                    assert!(
                        cells.may_reach(start, y),
                        "({x}, {y}) passed over, {scale} {roll}"
                    );
                }
                kept += (0..w)
                    .step_by(Cells::BLOCK)
                    .filter(|&x| cells.may_reach(x, y))
                    .count();
            }
            // Something to find, and runs passed over.
            assert!(
                near > 0 && kept * Cells::BLOCK < w * h,
                "{near} near, {kept} runs kept"
            );
        }
    }

    #[test]
    fn refining_gives_the_full_developments_warp() {
        // In floats: refined, the cheap development's warp is the full one's, and rows no
        // rectangle reaches are not touched.
        let case = refining::<f32>();
        let [want, before, got] = case.run(|_| ());
        let worst = got
            .data()
            .iter()
            .zip(want.data())
            .map(|(g, w)| (g - w).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "off by {worst}");
        assert!(got != before, "nothing refined");
        let h = got.height();
        let last =
            (340..h).all(|y| (0..got.width()).all(|x| got.at(x, y, 1) == before.at(x, y, 1)));
        assert!(last, "rows beyond every rectangle's reach changed");
    }

    #[test]
    fn refining_rounds_once_and_keeps_what_was_changed() {
        // In 8 bits: a pixel whose taps all fall inside a rectangle takes the full development's
        // warp as warping it gives it, rounded once (not the cheap warp's rounding plus the
        // difference's); a pixel changed after the warp keeps its change, the difference added.
        let case = refining::<u8>();
        let changed = |x: usize, y: usize| (x + y).is_multiple_of(7);
        let [want, before, got] = case.run(|img| {
            for y in 0..img.height() {
                for x in (0..img.width()).filter(|&x| changed(x, y)) {
                    let (v, at) = (img.at(x, y, 0), (y * img.width() + x) * 3);
                    img.data_mut()[at] = v.wrapping_add(9);
                }
            }
        });
        let [r0, r1] = case.rects;
        // Output pixels whose 4×4 taps all lie inside a rectangle.
        let inside = |x: usize, y: usize| {
            let (u, v) = case.warp.apply(x as f64, y as f64);
            let within = |a: f64, from: usize, n: usize| {
                a - 2.0 >= from as f64 && a + 3.0 < (from + n) as f64
            };
            [r0, r1]
                .iter()
                .any(|r| within(u, r.x, r.width) && within(v, r.y, r.height))
        };
        let (mut exact, mut kept, mut unrounded) = (0, 0, 0);
        for y in 0..got.height() {
            for x in (0..got.width()).filter(|&x| inside(x, y)) {
                if changed(x, y) {
                    // The change (9 levels) survives: the full development's value is not
                    // taken over it.
                    let with_change = i32::from(got.at(x, y, 0)) - i32::from(want.at(x, y, 0));
                    assert!((8..=10).contains(&with_change), "({x}, {y}): {with_change}");
                    kept += 1;
                } else {
                    for c in 0..3 {
                        let (g, w) = (got.at(x, y, c), want.at(x, y, c));
                        assert!(g.abs_diff(w) <= 1, "({x}, {y}, {c}): {g} against {w}");
                        exact += usize::from(g == w);
                        unrounded += 1;
                    }
                }
            }
        }
        // Adding the rounded difference to the rounded cheap warp leaves about a third of the
        // values a level off; rounded once, all but float noise match.
        assert!(kept > 0 && unrounded > 1000);
        assert!(
            exact * 1000 >= unrounded * 999,
            "{exact} of {unrounded} exact"
        );
        assert!(got != before, "nothing refined");
    }

    #[test]
    fn largest_rect_of_a_tilted_footprint() {
        // A diamond-ish region: rows widen then narrow.
        let spans = vec![(4, 6), (2, 8), (1, 9), (1, 9), (2, 8), (4, 6)];
        let c = Coverage { width: 10, spans };
        assert_eq!(
            c.largest_rect(),
            Some(Rect {
                x: 2,
                y: 1,
                width: 6,
                height: 4
            })
        );
        let none = Coverage {
            width: 3,
            spans: vec![(0, 0); 2],
        };
        assert_eq!(none.largest_rect(), None);
        let both = Coverage::intersection(&[Coverage::full(10, 6), none.clone()]);
        assert_eq!(both.spans[0], (0, 0));
    }

    /// Smooth texture with a wide brightness range, `gain`·v + `offset` per channel.
    fn textured(w: usize, h: usize, gain: [f32; 3], offset: f32, dx: f64) -> Image<u8> {
        Image::from_fn(w, h, 3, |x, y, c| {
            let (x, y) = (x as f64 + dx, y as f64);
            let v = 0.45 + 0.3 * (x / 37.0).sin() * (y / 23.0).cos() + 0.1 * (x / 5.0).sin();
            ((v as f32 * gain[c] + offset) * 255.0).round() as u8
        })
    }

    #[test]
    fn exposure_recovers_gain_white_balance_and_offset() {
        let reference = textured(320, 240, [1.0; 3], 0.0, 0.0);
        let frame = textured(320, 240, [1.05, 0.97, 1.02], 0.02, 3.0);
        let warp = Warp::affine(Affine([[1.0, 0.0, -3.0], [0.0, 1.0, 0.0]]));
        let e = estimate_exposure(&frame, &reference, &warp);
        for (e, g) in e.iter().zip([1.05, 0.97, 1.02]) {
            assert!((e.gain - g).abs() < 0.01, "{e:?} vs gain {g}");
            assert!((e.offset - 0.02).abs() < 0.005, "{e:?}");
        }
    }

    /// The warp converts the frame to floats a band of output rows at a time: every band must
    /// hold every frame row its taps read, under a slight roll with a local field pulling rows
    /// up and down, and under a roll steep enough to spread one output row over more rows than
    /// a band has. Checked against bicubic resampling straight from the frame through
    /// `Warp::apply`, pixel by pixel.
    #[test]
    fn each_band_of_the_warp_holds_every_frame_row_its_taps_read() {
        let (w, h) = (200, 260);
        let reference = textured(w, h, [1.0; 3], 0.0, 0.0);
        let frame = textured(w, h, [1.0; 3], 0.0, 2.0);
        let centre = (w as f64 / 2.0, h as f64 / 2.0);
        let field = OffsetField {
            step: 50.0,
            cols: 5,
            rows: 7,
            offsets: (0..35)
                .map(|i| (0.5, if i % 3 == 0 { 6.0 } else { -4.5 }))
                .collect(),
        };
        let warps = [
            Warp {
                affine: Affine::similarity(1.0, 0.03, centre, (1.5, -2.0)),
                field: Some(field),
            },
            Warp::affine(Affine::similarity(1.0, 0.45, centre, (0.0, 0.0))),
        ];
        let kx = |t: f64| keys(t as f32);
        for warp in &warps {
            let (out, _) = warp_frame(&frame, &reference, warp, &[Exposure::SAME; 3]);
            for y in 0..h {
                for x in 0..w {
                    let (u, v) = warp.apply(x as f64, y as f64);
                    let inside =
                        (0.0..=(w - 1) as f64).contains(&u) && (0.0..=(h - 1) as f64).contains(&v);
                    for c in 0..3 {
                        let want = if inside {
                            let (x0, y0) = (u.floor(), v.floor());
                            let (wx, wy) = (kx(u - x0), kx(v - y0));
                            let mut sum = 0.0f32;
                            for (r, wy) in wy.iter().enumerate() {
                                for (k, wx) in wx.iter().enumerate() {
                                    let at = |o: f64, d: usize, n: usize| {
                                        (o as isize + d as isize - 1).clamp(0, n as isize - 1)
                                            as usize
                                    };
                                    let px = frame.at(at(x0, k, w), at(y0, r, h), c);
                                    sum += wx * wy * px as f32;
                                }
                            }
                            u8::from_f32(sum)
                        } else {
                            reference.at(x, y, c)
                        };
                        let got = out.at(x, y, c);
                        assert!(got.abs_diff(want) <= 1, "({x}, {y}, {c}): {got} vs {want}");
                    }
                }
            }
        }
    }

    /// The AVX colour warp, two pixels a step, gives what the one-pixel warp gives, to the
    /// bit: pixels outside the frame, at its edges (clamped taps) and inside, alone or in pairs,
    /// with exposure corrected, under a roll and a local field.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx_pairs_warp_as_the_one_pixel_warp_does() {
        if !std::arch::is_x86_feature_detected!("avx") {
            return;
        }
        let (w, h) = (97, 61);
        let reference = textured(w, h, [1.0; 3], 0.0, 0.0);
        let frame = textured(w, h, [1.0; 3], 0.0, 3.0);
        let src: Vec<f32> = frame
            .data()
            .chunks_exact(3)
            .flat_map(|p| [p[0] as f32, p[1] as f32, p[2] as f32, 0.0])
            .collect();
        let field = OffsetField {
            step: 24.0,
            cols: 5,
            rows: 4,
            offsets: (0..20).map(|i| (0.3 * i as f32 - 2.0, 1.5)).collect(),
        };
        let centre = (w as f64 / 2.0, h as f64 / 2.0);
        let warp = Warp {
            affine: Affine::similarity(1.02, 0.08, centre, (4.5, -3.25)),
            field: Some(field),
        };
        let (table, raster) = (keys_table(), warp.raster(w));
        let rows = Rows::<3> {
            src: &src,
            first: 0,
            size: (w, h),
            table: &table,
            raster: &raster,
            correct: [(0.9, 2.0), (1.0, 0.0), (1.1, -3.0)],
            refine: None,
        };
        let (mut one, mut pairs) = (vec![0u8; w * 3], vec![0u8; w * 3]);
        for y in 0..h {
            let fallback = &reference.data()[y * w * 3..][..w * 3];
            let a = rows.warp_body::<u8, 4>(y, &mut one, fallback);
            // SAFETY: the CPU has AVX, checked above.
            let b = unsafe { rows.warp_pairs_avx(y, &mut pairs, fallback) };
            assert_eq!((a, &one), (b, &pairs), "row {y}");
        }
    }

    #[test]
    fn warp_fills_uncovered_pixels_from_the_reference_and_undoes_exposure() {
        let reference = textured(64, 48, [1.0; 3], 0.0, 0.0);
        let frame = textured(64, 48, [1.1; 3], 0.0, 5.0);
        // Reference pixel x is frame pixel x − 5: the frame lacks the reference's left 5 columns.
        let warp = Warp::affine(Affine([[1.0, 0.0, -5.0], [0.0, 1.0, 0.0]]));
        let e = [Exposure {
            gain: 1.1,
            offset: 0.0,
        }; 3];
        let (out, cov) = warp_frame(&frame, &reference, &warp, &e);
        assert_eq!(cov.spans[10], (5, 64));
        assert!(!cov.covers(4, 10) && cov.covers(5, 10));
        for y in 0..48 {
            for x in 0..64 {
                let (o, r) = (out.at(x, y, 1) as i32, reference.at(x, y, 1) as i32);
                assert!((o - r).abs() <= 2, "({x}, {y}): {o} vs {r}");
            }
        }
        assert_eq!(out.at(2, 7, 0), reference.at(2, 7, 0));
    }
}
