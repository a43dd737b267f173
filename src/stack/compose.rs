//! Composes the output from the frames' Laplacian pyramids.
//!
//! Both fusion methods are one compositor with different rules for which frame a band
//! coefficient comes from:
//! - `Select::MaxContrast` (the classic baseline): every band from the frame with the most local
//!   band energy, the low-pass residual averaged.
//! - `Select::Labels` (graph cut): each band from the highest-contrast frame among the labels
//!   present within that band's reach, the residual weighted by the blurred label masks. Inside a
//!   label region this is a plain copy of the labelled frame (no noise picked from other frames);
//!   across a seam the transition is multiband, so no seam shows, and at an occlusion edge the
//!   crisp edge's coefficients win over the other frame's defocus spill. Given the stack's focus
//!   order, a frame focused farther than a pixel's label never gives that pixel its finest band
//!   where that label tells depth (see [`KeepOut`]):
//!   there it shows the near object defocused and the background through its edge, texture that
//!   would win the contrast choice over the near object's own clean edge. Nor does a frame
//!   give its finest band where it does not reach: it holds the reference's pixels there (see
//!   `align`), and its band next to its coverage's edge shows the step between the two.

use super::align::Coverage;
use super::blur::{blur_rows_into, gaussian_half, strip_rows, PlaneRows, RowBlur, Rows};
use super::image::{luma_of, Image, Plane, Sample};
use super::order::Order;
use super::pyramid::{
    collapse_of, fill_gaussian, fill_laplacian, levels_for, with_levels, zeros_like,
};
use super::{Progress, Stage};
use rayon::prelude::*;
use std::ops::Range;

/// A label counts as present at a level where its blurred mask exceeds this: anywhere within
/// the level's kernel reach, so every seam is crossed by a contrast choice.
const PRESENT: f32 = 1e-3;
/// Reach of the finest band beyond a label region, in pixels (σ of the mask blur).
const FINE_REACH: f32 = 1.5;

#[derive(Clone, Copy)]
pub enum Select<'a> {
    MaxContrast,
    /// Per-pixel frame index, the most pyramid levels to use, the frames' focus order if
    /// farther frames are to be kept out of nearer labels' finest band (see the module's note):
    /// only an order the occlusion edges told, since on a guessed one the rule would keep the
    /// nearer frame out instead, and a stack without such edges has no spill to keep out; and
    /// where each frame reaches (`None`: everywhere).
    Labels(&'a [u8], usize, Option<KeepOut<'a>>, Option<Reached<'a>>),
}

/// The focus order by which farther frames are kept out of a nearer label's finest band, and
/// where a label says something of depth (`None`: everywhere). A label that says nothing of
/// depth (a plain patch given the tie's frame, a pixel not every frame reaches) keeps no frame
/// out: there the rule would only take the sharper frame's edge away, where the spill removal
/// found no near object to keep a halo of out.
#[derive(Clone, Copy)]
pub struct KeepOut<'a> {
    pub order: Order,
    pub told: Option<&'a [bool]>,
}

/// Where each frame reaches, for the rows composed.
#[derive(Clone, Copy)]
pub struct Reached<'a> {
    pub coverage: &'a [Coverage],
    /// The image row the labels composed start at.
    pub row: usize,
}

/// One frame's pyramids. The buffers are refilled for every frame, so only the first frame pays
/// for allocating and page-faulting them.
struct FrameBuffers {
    /// The Laplacian pyramid of each channel.
    bands: Vec<Vec<Plane>>,
    /// `Select::Labels` only (else empty): the Gaussian pyramid of the frame's label mask, and
    /// its level 0 blurred to the finest band's reach.
    mask: Vec<Plane>,
    reach: Plane,
}

impl FrameBuffers {
    fn new(w: usize, h: usize, channels: usize, levels: usize, labels: bool) -> Self {
        let pyramid = || with_levels(Plane::new(w, h, 1), levels);
        let bands: Vec<Vec<Plane>> = (0..channels).map(|_| pyramid()).collect();
        let (mask, reach) = match labels {
            true => (pyramid(), Plane::new(w, h, 1)),
            false => (Vec::new(), Plane::new(0, 0, 1)),
        };
        Self { bands, mask, reach }
    }

    /// Builds the pyramids of `samples` (frame `i`'s rows of the band, interleaved) and, for
    /// `Select::Labels`, where it may be chosen.
    fn fill<T: Sample>(&mut self, samples: &[T], select: &Select, i: usize, frames: usize) {
        // `Image::to_planes` in one parallel pass.
        let (n, scale) = (self.bands.len(), 1.0 / T::MAX);
        let (width, height) = (self.bands[0][0].width(), self.bands[0][0].height());
        let (levels0, strip) = (
            self.bands.iter_mut().map(|b| &mut b[0].data_mut()[..]),
            strip_rows(height) * width,
        );
        chunk_groups(levels0, strip)
            .into_par_iter()
            .zip(samples.par_chunks(strip * n))
            .for_each(|(planes, px)| {
                for (c, plane) in planes.into_iter().enumerate() {
                    for (o, px) in plane.iter_mut().zip(px.chunks_exact(n)) {
                        *o = px[c].to_f32() * scale;
                    }
                }
            });
        // Channels in parallel too: the coarse levels are too small to occupy every thread.
        self.bands.par_iter_mut().for_each(|b| fill_laplacian(b));
        if let Select::Labels(labels, _, order, reached) = select {
            let m0 = self.mask[0].data_mut();
            m0.par_iter_mut()
                .zip(*labels)
                .for_each(|(m, &l)| *m = (l as usize == i) as u8 as f32);
            fill_gaussian(&mut self.mask);
            if self.mask.len() > 1 {
                let (r, m0) = (&mut self.reach, &self.mask[0]);
                let half = gaussian_half(FINE_REACH);
                let (w, h) = (r.width(), r.height());
                blur_rows_into(r.data_mut(), w, h, &half, || PlaneRows(m0));
                if let Some(reached) = reached {
                    out_of_reach(r.data_mut(), w, labels, reached, i);
                }
                if let Some(keep) = order.filter(|k| k.order != Order::Unknown) {
                    keep_out_of_nearer(r.data_mut(), labels, keep, i, frames);
                }
            }
        }
    }

    /// Where the frame may be chosen at band level `l` (`None`: everywhere).
    fn present(&self, l: usize) -> Option<&[f32]> {
        match (l, self.mask.is_empty()) {
            (_, true) => None,
            (0, false) => Some(self.reach.data()),
            (_, false) => Some(self.mask[l].data()),
        }
    }

    /// The weight of the frame's residual (`None`: the plain average, 1/n).
    fn residual_weight(&self) -> Option<&[f32]> {
        self.mask.last().map(|m| m.data())
    }
}

/// Zeroes `reach` (rows `w` wide), where frame `frame` may give the finest band, at pixels it
/// does not cover, but for those labelled with it.
fn out_of_reach(reach: &mut [f32], w: usize, labels: &[u8], reached: &Reached, frame: usize) {
    let covers = &reached.coverage[frame];
    reach
        .par_chunks_mut(w)
        .zip(labels.par_chunks(w))
        .enumerate()
        .for_each(|(y, (reach, labels))| {
            // Only the pixels left and right of the row's covered span.
            let (lo, hi) = covers.spans[reached.row + y];
            let lo = (lo as usize).min(w);
            let hi = (hi as usize).clamp(lo, w);
            for x in (0..lo).chain(hi..w) {
                if labels[x] as usize != frame {
                    reach[x] = 0.0;
                }
            }
        });
}

/// Zeroes `reach`, where frame `frame` may give the finest band, at pixels labelled with a frame
/// focused nearer than it, where that label tells depth. Only the finest band: the coarser
/// bands, shared by the pixels on both sides of a step, are better taken from whichever frame
/// has the most contrast.
fn keep_out_of_nearer(reach: &mut [f32], labels: &[u8], keep: KeepOut, frame: usize, n: usize) {
    let depth = keep.order.depth_of(frame, n);
    let nearer: Vec<bool> = (0..n).map(|l| keep.order.depth_of(l, n) < depth).collect();
    reach
        .par_iter_mut()
        .enumerate()
        .zip(labels)
        .for_each(|((p, r), &l)| {
            if nearer[l as usize] && keep.told.is_none_or(|t| t[p]) {
                *r = 0.0;
            }
        });
}

/// The fused image and, per pixel, the frame its finest band came from.
///
/// Composed in row bands of at most `rows` output rows (rounded to the pyramid's grid), so
/// the pyramids of a band, not of the whole image, are in memory: see [`bands`].
pub fn compose<T: Sample>(
    frames: &[Image<T>],
    select: Select,
    rows: usize,
    progress: &dyn Progress,
) -> (Image<T>, Vec<u8>) {
    let (w, h, channels) = (frames[0].width(), frames[0].height(), frames[0].channels());
    let levels = pyramid_levels(
        w,
        h,
        match select {
            Select::MaxContrast => None,
            Select::Labels(_, max, _, _) => Some(max),
        },
    );
    let bands = bands(h, levels, rows);
    // Per band, the frames it takes anything from.
    let used: Vec<Vec<usize>> = bands
        .iter()
        .map(|b| match select {
            Select::MaxContrast => (0..frames.len()).collect(),
            Select::Labels(labels, _, _, _) => {
                let mut seen = vec![false; frames.len()];
                labels[b.ext.start * w..b.ext.end * w]
                    .iter()
                    .for_each(|&l| seen[l as usize] = true);
                (0..frames.len()).filter(|&i| seen[i]).collect()
            }
        })
        .collect();
    progress.stage(Stage::Compose, used.iter().map(Vec::len).sum());
    let mut image = Image::new(w, h, channels);
    let mut choice = vec![0u8; w * h];
    for (band, used) in bands.iter().zip(&used) {
        let (e0, e1) = (band.ext.start, band.ext.end);
        let select = match select {
            Select::MaxContrast => Select::MaxContrast,
            Select::Labels(labels, _, order, reached) => Select::Labels(
                &labels[e0 * w..e1 * w],
                levels,
                order.map(|k| KeepOut {
                    told: k.told.map(|t| &t[e0 * w..e1 * w]),
                    ..k
                }),
                reached.map(|r| Reached { row: e0, ..r }),
            ),
        };
        let (part, part_choice) = compose_band(
            frames
                .iter()
                .map(|f| &f.data()[e0 * w * channels..e1 * w * channels])
                .collect(),
            (w, e1 - e0, channels),
            &select,
            levels,
            used,
            progress,
        );
        let (keep, skip) = (band.keep.len() * w, (band.keep.start - e0) * w);
        image.data_mut()[band.keep.start * w * channels..][..keep * channels]
            .copy_from_slice(&part.data()[skip * channels..][..keep * channels]);
        choice[band.keep.start * w..][..keep].copy_from_slice(&part_choice[skip..][..keep]);
    }
    (image, choice)
}

/// A band of output rows, `keep`, and the rows its pyramids are built on, `ext`.
#[derive(Clone, Debug, PartialEq)]
pub struct Band {
    pub ext: Range<usize>,
    pub keep: Range<usize>,
}

/// Splits `h` rows into bands of at most `rows` kept rows for a pyramid of `levels`.
///
/// Each band starts on the coarsest level's grid and is widened by a margin beyond the reach of
/// every kernel on its kept rows (band and residual pyramids 2^(levels+1), the band-energy
/// blur 3·2^(levels−2), the collapse 2^levels rows, all under 8·2^(levels−1)): the band's own
/// edges then never touch the kept rows, so the bands join exactly as one image would.
pub fn bands(h: usize, levels: usize, rows: usize) -> Vec<Band> {
    let (grid, margin) = band_grid(levels);
    let rows = (rows / grid).max(1) * grid;
    if rows.saturating_add(2 * margin) >= h {
        return vec![Band {
            ext: 0..h,
            keep: 0..h,
        }];
    }
    (0..h)
        .step_by(rows)
        .map(|b0| {
            let b1 = (b0 + rows).min(h);
            Band {
                ext: b0.saturating_sub(margin)..(b1 + margin).min(h),
                keep: b0..b1,
            }
        })
        .collect()
}

/// Pyramid levels of a compose of `w`×`h`: as many as the size allows, at most `max`.
pub fn pyramid_levels(w: usize, h: usize, max: Option<usize>) -> usize {
    levels_for(w, h).min(max.unwrap_or(usize::MAX).max(1))
}

/// The row grid bands start on, and the margin each is widened by, for `levels`.
pub fn band_grid(levels: usize) -> (usize, usize) {
    let grid = 1usize << (levels - 1);
    (grid, 8 * grid)
}

/// Bytes of working memory per row of a band `width` wide: one frame's pyramids and its mask's,
/// the output's pyramids, the band energies (a pyramid is 4/3 of its base), the band's image.
pub fn bytes_per_row(width: usize, channels: usize, sample_bytes: usize) -> usize {
    let pyramid = width * 4 * 4 / 3;
    width * (sample_bytes * channels + 1 + 4) + pyramid * (2 * channels + 2)
}

/// Composes one band: `frames` are every frame's rows of it, `(w, h, channels)` its size.
fn compose_band<T: Sample>(
    frames: Vec<&[T]>,
    (w, h, channels): (usize, usize, usize),
    select: &Select,
    levels: usize,
    used: &[usize],
    progress: &dyn Progress,
) -> (Image<T>, Vec<u8>) {
    let top = levels - 1;
    let n = frames.len();
    let labels = matches!(select, Select::Labels(..));
    let mut frame = FrameBuffers::new(w, h, channels, levels, labels);
    let mut out: Vec<Vec<Plane>> = frame.bands.iter().map(|b| zeros_like(b)).collect();
    let mut best: Vec<Plane> = frame.bands[0][..top]
        .iter()
        .map(|b| Plane::from_vec(b.width(), b.height(), 1, vec![-1.0; b.pixels()]))
        .collect();
    let mut choice = vec![0u8; w * h];
    for &i in used {
        frame.fill(frames[i], select, i, n);
        for (l, best) in best.iter_mut().enumerate() {
            let out = out.iter_mut().map(|o| &mut o[l].data_mut()[..]).collect();
            let choice = (l == 0).then_some(&mut choice[..]);
            select_level(&frame, l, best, out, choice, i as u8);
        }
        for (o, b) in out.iter_mut().zip(&frame.bands) {
            let (o, v) = (o[top].data_mut(), b[top].data());
            match frame.residual_weight() {
                Some(m) => (o, v, m).into_par_iter().for_each(|(o, v, m)| *o += v * m),
                None => {
                    let m = 1.0 / n as f32;
                    o.par_iter_mut().zip(v).for_each(|(o, v)| *o += v * m);
                }
            }
        }
        progress.advance(1);
    }
    let planes: Vec<Plane> = out.into_par_iter().map(collapse_of).collect();
    (interleave(&planes), choice)
}

/// Takes each coefficient of band level `l` from `frame` into `out` where its band energy
/// (blurred |luma band|) beats the `best` so far and the frame is present, and records `label`
/// in `choice`. The energy streams strip by strip instead of being stored, and blocks of
/// pixels the frame does not win are neither read nor written. Rows where the frame is nowhere
/// present are passed over, their energy not computed: most frames hold a few percent of the
/// labels.
fn select_level(
    frame: &FrameBuffers,
    l: usize,
    best: &mut Plane,
    out: Vec<&mut [f32]>,
    choice: Option<&mut [u8]>,
    label: u8,
) {
    let (w, h) = (best.width(), best.height());
    let strip = strip_rows(h) * w;
    let bands: Vec<&[f32]> = frame.bands.iter().map(|b| b[l].data()).collect();
    let present = frame.present(l);
    let half = gaussian_half(1.0);
    let outs = chunk_groups(out, strip);
    let choices: Vec<Option<&mut [u8]>> = match choice {
        Some(c) => c.chunks_mut(strip).map(Some).collect(),
        None => outs.iter().map(|_| None).collect(),
    };
    (outs, choices, best.data_mut().par_chunks_mut(strip))
        .into_par_iter()
        .enumerate()
        .for_each(|(s, (mut outs, mut choice, best))| {
            let mut energy = RowBlur::new(AbsLuma(bands.clone()), w, h, &half);
            let (mut e, mut take) = (vec![0.0f32; w], vec![0u32; w]);
            for (r, best) in best.chunks_exact_mut(w).enumerate() {
                let y = s * strip / w + r;
                if present.is_some_and(|g| g[y * w..][..w].iter().all(|&g| g <= PRESENT)) {
                    continue;
                }
                energy.row(y, &mut e);
                // All ones where this frame's coefficient is taken.
                let wins = take.iter_mut().zip(&e).zip(&*best);
                match present {
                    Some(g) => {
                        for (((t, &e), &b), &g) in wins.zip(&g[y * w..][..w]) {
                            *t = 0u32.wrapping_sub(((e > b) & (g > PRESENT)) as u32);
                        }
                    }
                    None => wins.for_each(|((t, &e), &b)| *t = 0u32.wrapping_sub((e > b) as u32)),
                }
                for (j, t) in take.chunks(BLOCK).enumerate() {
                    if t.iter().all(|&t| t == 0) {
                        continue;
                    }
                    let x = j * BLOCK..j * BLOCK + t.len();
                    blend(&mut best[x.clone()], &e[x.clone()], t);
                    let (row, at) = (
                        r * w + x.start..r * w + x.end,
                        y * w + x.start..y * w + x.end,
                    );
                    for (o, band) in outs.iter_mut().zip(&bands) {
                        blend(&mut o[row.clone()], &band[at.clone()], t);
                    }
                    if let Some(c) = choice.as_mut() {
                        for (c, &t) in c[row].iter_mut().zip(t) {
                            *c = (label & t as u8) | (*c & !t as u8);
                        }
                    }
                }
            }
        });
}

/// Pixels per block that `select_level` skips when the frame wins none of them: a cache line
/// of f32.
const BLOCK: usize = 16;

/// `dst = src` where the mask `take` is all ones. Bitwise, because a plain `if` on two loaded
/// values compiles to a pointer select that does not vectorise.
#[inline(always)]
fn blend(dst: &mut [f32], src: &[f32], take: &[u32]) {
    for ((d, s), &m) in dst.iter_mut().zip(src).zip(take) {
        *d = f32::from_bits((s.to_bits() & m) | (d.to_bits() & !m));
    }
}

/// Splits equally long buffers into chunks and groups the chunks by position, so one parallel
/// job can write the same pixels of several planes.
fn chunk_groups<'a, T>(
    bufs: impl IntoIterator<Item = &'a mut [T]>,
    size: usize,
) -> Vec<Vec<&'a mut [T]>> {
    let mut chunks: Vec<_> = bufs.into_iter().map(|b| b.chunks_mut(size)).collect();
    let jobs = chunks.first().map_or(0, ExactSizeIterator::len);
    (0..jobs)
        .map(|_| chunks.iter_mut().map(|c| c.next().unwrap()).collect())
        .collect()
}

/// `Image::from_planes`, parallel over rows.
fn interleave<T: Sample>(planes: &[Plane]) -> Image<T> {
    let (w, h, n) = (planes[0].width(), planes[0].height(), planes.len());
    let mut data = vec![T::default(); w * h * n];
    data.par_chunks_mut(w * n).enumerate().for_each(|(y, row)| {
        for (x, px) in row.chunks_exact_mut(n).enumerate() {
            for (s, p) in px.iter_mut().zip(planes) {
                *s = T::from_f32(p.data()[y * w + x] * T::MAX);
            }
        }
    });
    Image::from_vec(w, h, n, data)
}

/// Rows of |luma| of one band level's colour bands (luma bands are the same linear mix of the
/// colour bands as luma is of the colours); a single band is its own luma.
struct AbsLuma<'a>(Vec<&'a [f32]>);

impl Rows for AbsLuma<'_> {
    fn row(&mut self, y: usize, out: &mut [f32]) {
        let w = out.len();
        let band = |c: usize| &self.0[c][y * w..][..w];
        if self.0.len() == 1 {
            for (o, v) in out.iter_mut().zip(band(0)) {
                *o = v.abs();
            }
        } else {
            let rgb = band(0).iter().zip(band(1)).zip(band(2));
            for (o, ((r, g), b)) in out.iter_mut().zip(rgb) {
                *o = luma_of(*r, *g, *b).abs();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::NoProgress;

    #[test]
    fn labels_copy_their_frame_away_from_seams() {
        let a = Image::<u8>::from_fn(40, 30, 3, |x, y, c| ((x * 5 + y * 3 + c * 40) % 256) as u8);
        let b = Image::<u8>::from_fn(40, 30, 3, |_, _, _| 200);
        let frames = [a.clone(), b];
        let (out, choice) = compose(
            &frames,
            Select::Labels(&[0; 1200], 8, None, None),
            usize::MAX,
            &NoProgress,
        );
        let err = a
            .data()
            .iter()
            .zip(out.data())
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap();
        assert!(err <= 1, "max error {err}");
        assert!(choice.iter().all(|&c| c == 0));
        let labels: Vec<u8> = (0..1200).map(|i| (i % 40 >= 20) as u8).collect();
        let (out, choice) = compose(
            &frames,
            Select::Labels(&labels, 8, None, None),
            usize::MAX,
            &NoProgress,
        );
        for y in 0..30 {
            assert_eq!(choice[y * 40 + 2], 0);
            assert_eq!(choice[y * 40 + 37], 1);
        }
        assert_eq!(out.at(39, 15, 1), 200);
        assert!(out.at(2, 15, 0).abs_diff(a.at(2, 15, 0)) <= 3);
    }

    #[test]
    fn a_frame_focused_farther_never_gives_a_nearer_label_its_finest_band() {
        // Frame 0, focused near, shows a flat near object left of x = 20; frame 1, focused far,
        // shows fine texture everywhere: on the left, the background through that object's
        // defocused edge.
        let near = Image::<u8>::from_fn(40, 30, 1, |x, _, _| if x < 20 { 120 } else { 90 });
        let far = Image::<u8>::from_fn(40, 30, 1, |x, y, _| 60 + 80 * ((x + y) % 2) as u8);
        let frames = [near, far];
        let labels: Vec<u8> = (0..1200).map(|i| (i % 40 >= 20) as u8).collect();
        // The checkerboard's amplitude on the near object's side, next to the edge.
        let texture_where = |order: Option<Order>, told, reached| {
            let keep = order.map(|order| KeepOut { order, told });
            let select = Select::Labels(&labels, 8, keep, reached);
            let (out, _) = compose(&frames, select, usize::MAX, &NoProgress);
            (10..20)
                .flat_map(|y| (16..19).map(move |x| (x, y)))
                .map(|(x, y)| out.at(x, y, 0).abs_diff(out.at(x + 1, y, 0)))
                .max()
                .unwrap()
        };
        let texture = |order| texture_where(order, None, None);
        assert!(texture(Some(Order::NearestFirst)) <= 4);
        // Without the order, or with frame 1 the nearer, its texture is chosen there.
        assert!(texture(None) >= 20);
        assert!(texture(Some(Order::FarthestFirst)) >= 20);
        assert!(texture(Some(Order::Unknown)) >= 20);
        // Nor where the near label says nothing of depth.
        let untold: Vec<bool> = (0..1200).map(|i| i % 40 >= 20).collect();
        assert!(texture_where(Some(Order::NearestFirst), Some(&untold), None) >= 20);
        // Nor, without the order, where frame 1 does not reach.
        let mut coverage = vec![Coverage::full(40, 30); 2];
        coverage[1].spans.fill((20, 40));
        let reached = Reached {
            coverage: &coverage,
            row: 0,
        };
        assert!(texture_where(None, None, Some(reached)) <= 4);
    }

    #[test]
    fn max_contrast_picks_the_textured_frame() {
        let tex = Image::<u8>::from_fn(
            64,
            64,
            1,
            |x, y, _| {
                if (x / 2 + y / 2) % 2 == 0 {
                    40
                } else {
                    220
                }
            },
        );
        let flat = Image::<u8>::from_fn(64, 64, 1, |_, _, _| 130);
        let (out, choice) = compose(
            &[flat, tex.clone()],
            Select::MaxContrast,
            usize::MAX,
            &NoProgress,
        );
        let inner = |p: usize| (8..56).contains(&(p % 64)) && (8..56).contains(&(p / 64));
        let picked = (0..64 * 64).filter(|&p| inner(p) && choice[p] == 1).count();
        assert!(picked > 48 * 48 * 9 / 10, "picked {picked}");
        let diff = (0..64 * 64)
            .filter(|&p| inner(p))
            .map(|p| (out.data()[p] as i32 - tex.data()[p] as i32).abs())
            .max()
            .unwrap();
        assert!(diff < 40, "max diff {diff}");
    }

    /// A stack tall enough for several bands, with labels in stripes and blobs.
    fn tall_stack() -> (Vec<Image<u8>>, Vec<u8>) {
        let (w, h) = (96, 700);
        let frames: Vec<Image<u8>> = (0..3)
            .map(|k| {
                Image::from_fn(w, h, 3, |x, y, c| {
                    ((x * (3 + k) + y * (5 + 2 * k) + c * 70 + (x * y) % (7 + k)) % 256) as u8
                })
            })
            .collect();
        let labels = (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                ((x / 20 + y / 37 + (x * x + y) / 500) % 3) as u8
            })
            .collect();
        (frames, labels)
    }

    #[test]
    fn bands_join_exactly_as_one_image() {
        let (frames, labels) = tall_stack();
        for select in [Select::Labels(&labels, 5, None, None), Select::MaxContrast] {
            let whole = compose(&frames, select, usize::MAX, &NoProgress);
            let levels = match select {
                Select::Labels(..) => 5,
                Select::MaxContrast => levels_for(96, 700),
            };
            let b = bands(700, levels, 40);
            assert!(b.len() > 1 || levels > 5, "{} bands", b.len());
            assert_eq!(compose(&frames, select, 40, &NoProgress), whole);
        }
        let b = bands(700, 5, 40);
        assert_eq!(b.len(), 700usize.div_ceil(32));
        assert_eq!(
            b[0],
            Band {
                ext: 0..160,
                keep: 0..32
            }
        );
        assert!(b.windows(2).all(|p| p[0].keep.end == p[1].keep.start));
        assert_eq!(b.last().unwrap().keep.end, 700);
    }
}
