//! Graph-cut labelling of a focus stack: which frame each output pixel is copied from.
//!
//! Minimises Σ U(p) + λ Σ B(p,q) (the paper's eq. 4): U is the DoG focus cost normalised across the
//! stack, B the seam cost |I_lp(p) − I_lq(p)| + |I_lp(q) − I_lq(q)| plus a small constant for any
//! label change. Solved by α-expansion on a coarse level, then re-solved at full resolution only
//! in a band around the coarse label boundaries and where the coarse label misses fine detail.
//!
//! Each pixel is offered only a few labels: its sharpest frames, the fallback frame where it ties
//! with them, and the labels it and its neighbours hold. On smooth or noisy content many frames
//! tie and the sharpest frame changes from pixel to pixel, so offering every frame everywhere made
//! the cost grow with frames × pixels; the labels found this way have the same energy within a
//! fraction of a percent.

use super::align::Coverage;
use super::blur::{downsample_area, downsample_samples};
use super::expansion::{energy, expand, neighbours, Costs, Grid, Move};
use super::focus::{focus_reach, frame_focus_amplitude, max_amplitude, FocusParams, AMP_SCALE};
use super::image::{Image, Sample};
use super::maxflow::GridMaxflow;
use super::{Progress, Stage};
use rayon::prelude::*;
use std::ops::Range;

#[derive(Clone, Debug)]
pub struct GraphCutParams {
    pub focus: FocusParams,
    /// Weight of the seam cost against the focus cost (λ in eq. 4).
    pub lambda: f32,
    /// Cost of any label change, in the seam cost's units: keeps flat areas from fragmenting.
    pub kappa: f32,
    /// DoG amplitude (luma units) that counts as texture rather than noise.
    pub noise_floor: f32,
    /// Frames whose focus amplitude is within this share of the noise floor of the sharpest
    /// frame's tie with it: their focus cost is nothing. Where every frame shows only noise (a
    /// plain background) the sharpest frame and the next differ by 7–10 amplitude units
    /// (median over amber_macro's and flats 8's backgrounds), against a noise floor of 131: as
    /// focus cost that is 80–130 seam units against about 20 for a seam there, so the noise
    /// picked the frame pixel by pixel. That labelled plain regions like salt and pepper, made
    /// the output noisier there than any frame (picking, at each pixel, the frame whose noise
    /// has the most detail: flats 8's green fine noise 32 % above a frame's), and kept the
    /// expansion moving on them (86 % of flats 8's full-resolution pixels free, 5.4 pixel-moves
    /// a pixel). At the noise floor, with [`Self::tie_bias`], the label stage took flats 8
    /// 460 → 100 ms, amber_macro 690 → 300 ms, ring_macro 440 → 140 ms (medians of 3
    /// interleaved runs), and the simulated stacks' PSNR against their truth moved by at most
    /// 0.03 dB.
    pub tie: f32,
    /// Focus cost, in [`Self::kappa`]'s units, of every frame but the fallback where the
    /// fallback ties with the sharpest: plain regions go to one frame, the reference (the one
    /// frame not resampled), rather than to whichever frame a move happened to reach. Without
    /// it every frame is as good there, and exhaustive expansion spread near patches' labels
    /// over plain regions the candidate moves could not reach: on the labelling-energy test's
    /// flats, 16 frames, the default labels' energy was 7.5 % above exhaustive expansion's; with
    /// it 0.1 %.
    pub tie_bias: f32,
    /// Where it is more than the noise floor, frames also tie within this share of the median
    /// frame's focus amplitude (measured on the coarse level, as the noise's level is smooth):
    /// under heavy noise a plain region's amplitudes are the noise's, and differ from frame to
    /// frame by more than the noise floor. There exhaustive expansion still labelled plain
    /// regions by their noise, which the candidates cannot follow (noisy 10 × 1.2 MP, noise of
    /// σ 8 levels: the default labels' energy 1.019 of exhaustive expansion's; with this 0.994).
    pub tie_noise: f32,
    /// Pixel count the coarse level is reduced to.
    pub coarse_pixels: usize,
    /// How many of its sharpest frames a pixel is offered, besides the labels it and its four
    /// neighbours hold; `usize::MAX` offers every frame everywhere (exhaustive expansion, the
    /// reference the labelling's energy is measured against).
    pub candidates: usize,
    /// Expansion cycles over a window's moves, at most. A third cycle re-ran most moves of a
    /// window to move a few pixels: on flats and amber_macro it cost a quarter of the moves'
    /// work and lowered the energy by under 0.05 %.
    pub max_cycles: usize,
    /// After the first pass over a level's tiles, later passes re-solve only strips along the
    /// first pass's tile borders, a tile's `1/border_strips` wide on each side: a fixed border
    /// moves the labels only a few pixels into a tile. At a sixteenth (23 % of the pixels) the
    /// full-resolution moves took 14 % fewer pixel-moves than at an eighth (44 %) on amber_macro
    /// and cuisine_phone, and the energy rose by under 0.001 %.
    pub border_strips: usize,
    /// Pyramid levels of the seam blending.
    pub blend_levels: usize,
}

impl Default for GraphCutParams {
    fn default() -> Self {
        Self {
            focus: FocusParams::default(),
            lambda: 0.3,
            kappa: 0.02,
            noise_floor: 0.002,
            tie: 1.0,
            tie_bias: 0.5,
            tie_noise: 0.6,
            coarse_pixels: 60_000,
            candidates: 2,
            max_cycles: 2,
            border_strips: 16,
            blend_levels: 5,
        }
    }
}

impl GraphCutParams {
    /// Exhaustive expansion, the reference the labelling's energy is measured against: every
    /// frame offered everywhere, and the three cycles and the strips an eighth of a tile wide
    /// the default ran before they were cut, so that cheaper defaults are measured against a
    /// reference that did not get cheaper too.
    pub fn exhaustive() -> Self {
        Self {
            candidates: usize::MAX,
            max_cycles: 3,
            border_strips: 8,
            ..Self::default()
        }
    }
}

/// Focus amplitudes of every frame on a run of rows of a level, and their maximum per pixel.
struct Amps {
    /// Level pixel index of the first one held.
    offset: usize,
    per_frame: Vec<Vec<u16>>,
    max: Vec<u16>,
}

impl Amps {
    fn new(offset: usize, per_frame: Vec<Vec<u16>>) -> Self {
        let max = max_amplitude(&per_frame);
        Self {
            offset,
            per_frame,
            max,
        }
    }

    /// Every frame's amplitudes on rows `rows` of the full-resolution level, each computed on
    /// those rows plus the focus measure's reach, so they equal the whole image's exactly.
    fn for_rows<T: Sample>(
        frames: &[Image<T>],
        coverage: &[Coverage],
        p: &FocusParams,
        rows: Range<usize>,
    ) -> Self {
        let per_frame = frames
            .iter()
            .zip(coverage)
            .map(|(f, cov)| amplitude_rows(f, cov, p, rows.clone()))
            .collect();
        Self::new(rows.start * frames[0].width, per_frame)
    }
}

/// One frame's focus amplitudes on rows `rows`, zero where it has no content of its own: the
/// graph cut steers away, and `keep_covered` settles the flat areas where every frame scores
/// zero.
fn amplitude_rows<T: Sample>(
    frame: &Image<T>,
    cov: &Coverage,
    p: &FocusParams,
    rows: Range<usize>,
) -> Vec<u16> {
    let (w, h) = (frame.width, frame.height);
    let reach = focus_reach(p);
    let ext = rows.start.saturating_sub(reach)..(rows.end + reach).min(h);
    let mut a = frame_focus_amplitude(frame, ext.clone(), p);
    a.drain(..(rows.start - ext.start) * w);
    a.truncate(rows.len() * w);
    a.par_chunks_mut(w)
        .zip(&cov.spans[rows])
        .for_each(|(row, &(lo, hi))| {
            row[..lo as usize].fill(0);
            row[(hi as usize).max(lo as usize)..].fill(0);
        });
    a
}

/// Where a solve gets its focus amplitudes: held whole, or recomputed for each band of rows
/// (a memory budget's choice: the whole stack's take 2 bytes a pixel per frame).
enum Focus<'a, T> {
    Whole(&'a Amps),
    Bands {
        frames: &'a [Image<T>],
        coverage: &'a [Coverage],
        params: &'a FocusParams,
        rows: usize,
    },
}

impl<T: Sample> Focus<'_, T> {
    /// Most rows held at once.
    fn rows(&self) -> usize {
        match self {
            Focus::Whole(_) => usize::MAX,
            Focus::Bands { rows, .. } => *rows,
        }
    }

    /// Runs `f` on the amplitudes of (at least) rows `rows`.
    fn with<R>(&self, rows: Range<usize>, f: impl FnOnce(&Amps) -> R) -> R {
        match self {
            Focus::Whole(a) => f(a),
            Focus::Bands {
                frames,
                coverage,
                params,
                ..
            } => f(&Amps::for_rows(frames, coverage, params, rows)),
        }
    }
}

/// One resolution level of the labelling problem.
struct Level<'a, T> {
    channels: usize,
    colors: Vec<&'a [T]>,
    amps: &'a Amps,
    /// Integer units per unit of focus cost: channels·MAX/λ, so seam costs stay exact integers.
    unary_scale: f32,
    eps: f32,
    /// What each pixel's frames tie within, in amplitude units, and the frame ties go to.
    ties: &'a Ties<'a>,
    /// What any frame but the fallback costs where the fallback ties
    /// ([`GraphCutParams::tie_bias`]).
    bias: i32,
    kappa: i32,
}

/// What a pixel's focus costs share: the cost per unit of amplitude below the sharpest frame's
/// (one division a pixel), the amplitude below it that costs nothing ([`Ties`]), and whether
/// the fallback ties there (then any other frame pays [`GraphCutParams::tie_bias`]).
#[derive(Clone, Copy)]
struct PixelTerms {
    per_amp: f32,
    tie: f32,
    fallback_ties: bool,
}

/// What each pixel's frames tie within: the noise floor ([`GraphCutParams::tie`]), or a share
/// of the median frame's amplitude where that is more ([`GraphCutParams::tie_noise`]); and the
/// frame ties go to ([`GraphCutParams::tie_bias`]). The map is held at the coarse level,
/// `factor` times smaller than the level read, `width` pixels wide.
struct Ties<'m> {
    map: &'m [u16],
    coarse_width: usize,
    factor: usize,
    width: usize,
    fallback: u8,
}

impl<'m> Ties<'m> {
    /// Ties read from `map`, `factor` times smaller than a level `width` pixels wide.
    fn scaled(map: &'m [u16], factor: usize, width: usize, fallback: u8) -> Self {
        Self {
            map,
            coarse_width: width.div_ceil(factor),
            factor,
            width,
            fallback,
        }
    }

    /// Ties read from `map` at the level's own size.
    fn whole(map: &'m [u16], width: usize, fallback: u8) -> Self {
        Self::scaled(map, 1, width, fallback)
    }

    #[inline]
    fn at(&self, p: usize) -> u16 {
        let (x, y) = (p % self.width, p / self.width);
        self.map[y / self.factor * self.coarse_width + x / self.factor]
    }
}

/// The map [`Ties`] reads, from every frame's amplitudes at the coarse level. The lower median:
/// of a few frames the upper one is the second-sharpest, which would tie away real focus (the
/// 4-frame stack of `tests/fuse_quality.rs` fell below the pyramid baseline).
fn tie_map(amps: &[Vec<u16>], p: &GraphCutParams) -> Vec<u16> {
    let floor = p.tie * p.noise_floor * AMP_SCALE;
    let n = amps.len();
    let mut map = vec![0u16; amps[0].len()];
    map.par_chunks_mut(4096).enumerate().for_each(|(k, out)| {
        let mut v = [0u16; 256];
        for (j, o) in out.iter_mut().enumerate() {
            let i = k * 4096 + j;
            for (x, a) in v.iter_mut().zip(amps) {
                *x = a[i];
            }
            let (_, median, _) = v[..n].select_nth_unstable((n - 1) / 2);
            *o = (p.tie_noise * *median as f32).max(floor) as u16;
        }
    });
    map
}

impl<'a, T: Sample> Level<'a, T> {
    fn new(
        images: &'a [Image<T>],
        amps: &'a Amps,
        lambda: f32,
        p: &GraphCutParams,
        ties: &'a Ties<'a>,
    ) -> Self {
        let channels = images[0].channels;
        let full = channels as f32 * T::MAX;
        Self {
            channels,
            colors: images.iter().map(|i| i.data.as_slice()).collect(),
            amps,
            unary_scale: full / lambda,
            eps: p.noise_floor * AMP_SCALE,
            ties,
            bias: (p.tie_bias * p.kappa * full).round() as i32,
            kappa: (p.kappa * full).round() as i32,
        }
    }

    /// Writes into `top` the `k` frames with the largest focus amplitude at `p`, sharpest first
    /// (ties to the lower index); every frame when `k` is at least their number.
    fn sharpest(&self, p: usize, k: usize, top: &mut Vec<u8>) {
        let (a, i) = (&self.amps.per_frame, p - self.amps.offset);
        top.clear();
        if k >= a.len() {
            top.extend(0..a.len() as u8);
            return;
        }
        let amp = |l: u8| a[l as usize][i];
        for l in 0..a.len() as u8 {
            if top.len() == k && top.last().is_none_or(|&t| amp(t) >= amp(l)) {
                continue;
            }
            let at = top
                .iter()
                .position(|&t| amp(t) < amp(l))
                .unwrap_or(top.len());
            if top.len() == k {
                top.pop();
            }
            top.insert(at, l);
        }
    }

    /// Where labelling starts, at each of the level's first `pixels` pixels: the fallback where
    /// it ties with the sharpest frame ([`GraphCutParams::tie`]), so that plain regions start as
    /// the frame they end as; else the sharpest frame.
    fn start_labels(&self, pixels: usize) -> Vec<u8> {
        let mut top = Vec::with_capacity(1);
        (0..pixels)
            .map(|i| {
                if self.ties(i) {
                    return self.ties.fallback;
                }
                self.sharpest(i, 1, &mut top);
                top[0]
            })
            .collect()
    }

    /// Colours of frame `l` at `p`.
    #[inline]
    fn colors(&self, p: usize, l: u8) -> &[T] {
        &self.colors[l as usize][p * self.channels..(p + 1) * self.channels]
    }

    /// Whether the fallback frame's focus amplitude at `p` ties with the sharpest frame's.
    #[inline]
    fn ties(&self, p: usize) -> bool {
        self.fallback_within(p - self.amps.offset, self.ties.at(p) as f32)
    }

    /// Whether the fallback frame's focus amplitude at amplitude index `i` is within `tie` of
    /// the sharpest frame's.
    #[inline]
    fn fallback_within(&self, i: usize, tie: f32) -> bool {
        let m = self.amps.max[i] as f32;
        m - self.amps.per_frame[self.ties.fallback as usize][i] as f32 <= tie
    }

    /// Focus cost of label `l` at `p`, in the integer units of the seam cost.
    #[inline]
    fn unary(&self, p: usize, l: u8) -> i32 {
        self.unary_with(p, l, self.pixel_terms(p))
    }

    /// The terms every label's focus cost at `p` shares.
    #[inline]
    fn pixel_terms(&self, p: usize) -> PixelTerms {
        let i = p - self.amps.offset;
        let m = self.amps.max[i] as f32;
        let tie = self.ties.at(p) as f32;
        PixelTerms {
            per_amp: self.unary_scale / (m + self.eps),
            tie,
            fallback_ties: self.fallback_within(i, tie),
        }
    }

    /// [`Self::unary`] given [`Self::pixel_terms`] at `p`: the amplitude below the sharpest
    /// frame's, beyond the tie.
    #[inline]
    fn unary_with(&self, p: usize, l: u8, t: PixelTerms) -> i32 {
        let i = p - self.amps.offset;
        let m = self.amps.max[i] as f32;
        let a = self.amps.per_frame[l as usize][i] as f32;
        let other = if t.fallback_ties && l != self.ties.fallback {
            self.bias
        } else {
            0
        };
        ((m - a - t.tie).max(0.0) * t.per_amp) as i32 + other
    }
}

/// The whole level's costs, read from the frames: what the labelling's energy is measured with.
impl<T: Sample> Costs for Level<'_, T> {
    fn unary(&self, p: usize, l: u8) -> i32 {
        Level::unary(self, p, l)
    }

    fn pairwise(&self, p: usize, q: usize, lp: u8, lq: u8) -> i32 {
        seam(self.kappa, p, q, lp, lq, |i| {
            color_diff(self.colors(i, lp), self.colors(i, lq))
        })
    }
}

/// The seam cost B(p,q) of labels `lp`, `lq` (eq. 4), given `diff`, the two frames' colour
/// difference at a pixel ([`color_diff`]): both pixels' difference, plus κ for any change.
#[inline]
fn seam(kappa: i32, p: usize, q: usize, lp: u8, lq: u8, diff: impl Fn(usize) -> i32) -> i32 {
    if lp == lq {
        return 0;
    }
    diff(p) + diff(q) + kappa
}

/// Σ |a − b| over a pixel's channels, each truncated to an integer.
#[inline]
fn color_diff<T: Sample>(a: &[T], b: &[T]) -> i32 {
    a.iter().zip(b).map(|(&x, &y)| x.abs_diff_i32(y)).sum()
}

/// Energy of `labels` for an aligned stack, by the same terms the labelling minimises, at full
/// resolution: to compare labellings (the default candidates against exhaustive expansion).
pub fn labelling_energy<T: Sample>(
    frames: &[Image<T>],
    coverage: &[Coverage],
    labels: &[u8],
    fallback: u8,
    p: &GraphCutParams,
) -> i64 {
    let (w, h) = (frames[0].width, frames[0].height);
    let amps = Amps::for_rows(frames, coverage, &p.focus, 0..h);
    let f = coarse_factor(w * h, p.coarse_pixels);
    let coarse: Vec<Vec<u16>> = amps
        .per_frame
        .iter()
        .map(|a| downsample_samples(a, w, h, f))
        .collect();
    let map = tie_map(&coarse, p);
    let ties = Ties::scaled(&map, f, w, fallback);
    energy(w, h, labels, &Level::new(frames, &amps, p.lambda, p, &ties))
}

/// One tile's problem gathered into contiguous memory: the costs of the few labels worth trying,
/// for the tile and a ring of fixed pixels around it. Reading ten full-size frames at scattered
/// addresses for every edge of every move is what made the solve slow.
///
/// Only the pixels a move reads are gathered, the free ones and their neighbours; the others'
/// entries are left zero. Where few pixels of a tile are free (the later passes' strips, the
/// full resolution's band) gathering them all cost as much as the moves.
struct TileCosts<T> {
    /// Label → slot in the tables below.
    slot: [u8; 256],
    slots: usize,
    channels: usize,
    /// `[pixel][slot][channel]` colours.
    colors: Vec<T>,
    /// `[pixel][slot]` focus costs.
    unary: Vec<i32>,
    kappa: i32,
}

impl<T: Sample> TileCosts<T> {
    /// Gathers the rectangle `(x0, y0, w, h)` of `level` for `labels`, at the pixels `read`
    /// marks (row-major in the rectangle).
    fn gather(
        level: &Level<T>,
        width: usize,
        rect: (usize, usize, usize, usize),
        labels: &[u8],
        read: &[bool],
    ) -> Self {
        let (x0, y0, w, h) = rect;
        let mut slot = [u8::MAX; 256];
        for (k, &l) in labels.iter().enumerate() {
            slot[l as usize] = k as u8;
        }
        let (ns, ch) = (labels.len(), level.channels);
        let mut colors = Vec::with_capacity(w * h * ns * ch);
        let mut unary = Vec::with_capacity(w * h * ns);
        for (y, read) in (y0..y0 + h).zip(read.chunks_exact(w)) {
            for (x, &read) in (x0..x0 + w).zip(read) {
                if !read {
                    colors.resize(colors.len() + ns * ch, T::default());
                    unary.resize(unary.len() + ns, 0);
                    continue;
                }
                let p = y * width + x;
                let terms = level.pixel_terms(p);
                for &l in labels {
                    // Sample by sample: a memcpy call for each label's three samples cost more
                    // than the copy.
                    for &c in level.colors(p, l) {
                        colors.push(c);
                    }
                    unary.push(level.unary_with(p, l, terms));
                }
            }
        }
        Self {
            slot,
            slots: ns,
            channels: ch,
            colors,
            unary,
            kappa: level.kappa,
        }
    }
}

impl<T: Sample> Costs for TileCosts<T> {
    #[inline]
    fn unary(&self, p: usize, l: u8) -> i32 {
        self.unary[p * self.slots + self.slot[l as usize] as usize]
    }

    /// Each label's slot is looked up once for both pixels: the lookups were a fifth of the
    /// seam cost's instructions.
    #[inline]
    fn pairwise(&self, p: usize, q: usize, lp: u8, lq: u8) -> i32 {
        let ch = self.channels;
        let (a, b) = (
            self.slot[lp as usize] as usize * ch,
            self.slot[lq as usize] as usize * ch,
        );
        let row = self.slots * ch;
        seam(self.kappa, p, q, lp, lq, |i| {
            let px = &self.colors[i * row..(i + 1) * row];
            color_diff(&px[a..a + ch], &px[b..b + ch])
        })
    }
}

/// Coarse factor so the coarse level has at most `target` pixels.
fn coarse_factor(pixels: usize, target: usize) -> usize {
    ((pixels as f64 / target.max(1) as f64).sqrt().ceil() as usize).max(1)
}

/// A stack's labels, and where its focus measure found texture.
pub struct Labelled {
    /// Per pixel, the frame to copy it from.
    pub labels: Vec<u8>,
    /// Per pixel, whether some frame's focus amplitude there is above noise (four times
    /// [`GraphCutParams::noise_floor`]); elsewhere every frame ties and the label says nothing of
    /// depth ([`super::flat_regions`]).
    pub textured: Vec<bool>,
}

/// Labels each pixel of an aligned stack with the index of the frame to copy it from. A frame is
/// never chosen where its `coverage` misses; `fallback` must cover every pixel (the reference).
/// With `band_rows` below the height, the full-resolution focus amplitudes are never held
/// whole but recomputed for bands of that many rows: the same labels, in less memory.
pub fn label_stack<T: Sample>(
    frames: &[Image<T>],
    coverage: &[Coverage],
    fallback: u8,
    p: &GraphCutParams,
    band_rows: usize,
    progress: &dyn Progress,
) -> Labelled {
    let (w, h) = (frames[0].width, frames[0].height);
    let f = coarse_factor(w * h, p.coarse_pixels);
    let whole = band_rows >= h || f == 1;
    progress.stage(Stage::Focus, frames.len());
    let (mut kept, mut camps) = (Vec::new(), Vec::new());
    for (frame, cov) in frames.iter().zip(coverage) {
        let a = amplitude_rows(frame, cov, &p.focus, 0..h);
        if f > 1 {
            camps.push(downsample_samples(&a, w, h, f));
        }
        if whole {
            kept.push(a);
        }
        progress.advance(1);
    }
    let held = whole.then(|| Amps::new(0, kept));
    let focus = match &held {
        Some(a) => Focus::Whole(a),
        None => Focus::Bands {
            frames,
            coverage,
            params: &p.focus,
            rows: band_rows,
        },
    };
    let texture = (4.0 * p.noise_floor * AMP_SCALE) as u16;
    if f == 1 {
        let map = focus.with(0..h, |a| tie_map(&a.per_frame, p));
        let ties = Ties::whole(&map, w, fallback);
        let (mut labels, textured) = focus.with(0..h, |a| {
            let labels = Level::new(frames, a, p.lambda, p, &ties).start_labels(w * h);
            (labels, a.max.iter().map(|&m| m > texture).collect())
        });
        let solve = Solve {
            frames,
            focus: &focus,
            lambda: p.lambda,
            params: p,
            ties: &ties,
        };
        solve.tiled(w, h, &mut labels, None, 256, 2, progress);
        keep_covered(&mut labels, w, coverage, fallback);
        return Labelled { labels, textured };
    }

    // Coarse level: seam weight λ/f keeps the energy's balance (areas shrink by f², seams by f).
    let small: Vec<Image<T>> = frames.par_iter().map(|i| downsample_area(i, f)).collect();
    let (cw, ch) = (small[0].width, small[0].height);
    let camps = Amps::new(0, camps);
    let map = tie_map(&camps.per_frame, p);
    let coarse_ties = Ties::whole(&map, cw, fallback);
    let coarse = Level::new(&small, &camps, p.lambda / f as f32, p, &coarse_ties);
    let mut clabels = coarse.start_labels(cw * ch);
    let solve = Solve {
        frames: &small,
        focus: &Focus::<T>::Whole(&camps),
        lambda: p.lambda / f as f32,
        params: p,
        ties: &coarse_ties,
    };
    solve.tiled(cw, ch, &mut clabels, None, 64, 2, progress);

    // Full resolution: upsample, then free a band around coarse boundaries and the pixels where
    // the coarse label is clearly not the sharp frame (detail finer than a coarse pixel).
    let boundary = coarse_boundaries(cw, ch, &clabels);
    let mut labels = vec![0u8; w * h];
    let mut free = vec![false; w * h];
    let mut textured = vec![false; w * h];
    let step = focus.rows().min(h);
    for y0 in (0..h).step_by(step) {
        let rows = y0..(y0 + step).min(h);
        focus.with(rows.clone(), |a| {
            labels[rows.start * w..rows.end * w]
                .par_chunks_mut(w)
                .zip(free[rows.start * w..rows.end * w].par_chunks_mut(w))
                .zip(textured[rows.start * w..rows.end * w].par_chunks_mut(w))
                .zip(rows.clone())
                .for_each(|(((lrow, frow), trow), y)| {
                    for x in 0..w {
                        let c = (y / f) * cw + x / f;
                        let l = clabels[c];
                        lrow[x] = l;
                        let i = y * w + x - a.offset;
                        trow[x] = a.max[i] > texture;
                        let missed = trow[x] && 2 * a.per_frame[l as usize][i] < a.max[i];
                        frow[x] = boundary[c] || missed;
                    }
                });
        });
    }
    let ties = Ties::scaled(&map, f, w, fallback);
    let solve = Solve {
        frames,
        focus: &focus,
        lambda: p.lambda,
        params: p,
        ties: &ties,
    };
    solve.tiled(w, h, &mut labels, Some(&free), 64, 2, progress);
    keep_covered(&mut labels, w, coverage, fallback);
    Labelled { labels, textured }
}

/// Relabels with `fallback` every pixel whose label's frame does not cover it.
fn keep_covered(labels: &mut [u8], w: usize, coverage: &[Coverage], fallback: u8) {
    labels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, l) in row.iter_mut().enumerate() {
            if !coverage[*l as usize].covers(x, y) {
                *l = fallback;
            }
        }
    });
}

/// Coarse pixels with an 8-neighbour of another label.
fn coarse_boundaries(w: usize, h: usize, labels: &[u8]) -> Vec<bool> {
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let l = labels[i];
            (y.saturating_sub(1)..(y + 2).min(h))
                .any(|yy| (x.saturating_sub(1)..(x + 2).min(w)).any(|xx| labels[yy * w + xx] != l))
        })
        .collect()
}

/// One level's problem: its frames' colours, where its focus amplitudes come from, λ.
struct Solve<'a, T> {
    frames: &'a [Image<T>],
    focus: &'a Focus<'a, T>,
    lambda: f32,
    params: &'a GraphCutParams,
    ties: &'a Ties<'a>,
}

impl<T: Sample> Solve<'_, T> {
    /// Runs α-expansion over tiles in parallel, `passes` times with the tile grid shifted by
    /// half a tile between passes so no tile border stays fixed. With banded focus amplitudes,
    /// the windows of a pass are solved a band of rows at a time; every window of a pass still
    /// sees the labels as they were before the pass, so the bands change nothing.
    #[allow(clippy::too_many_arguments)]
    fn tiled(
        &self,
        w: usize,
        h: usize,
        labels: &mut [u8],
        free: Option<&[bool]>,
        tile: usize,
        passes: usize,
        progress: &dyn Progress,
    ) {
        let windows_for = |offset: usize| -> Vec<Window> {
            let starts = |n: usize| -> Vec<usize> {
                let mut s = vec![0];
                let mut v = if offset > 0 && offset < n {
                    offset
                } else {
                    tile
                };
                while v < n {
                    s.push(v);
                    v += tile;
                }
                s
            };
            let (xs, ys) = (starts(w), starts(h));
            let mut out = Vec::new();
            for (j, &y0) in ys.iter().enumerate() {
                let y1 = ys.get(j + 1).copied().unwrap_or(h);
                for (i, &x0) in xs.iter().enumerate() {
                    let x1 = xs.get(i + 1).copied().unwrap_or(w);
                    out.push(Window {
                        x0,
                        y0,
                        w: x1 - x0,
                        h: y1 - y0,
                    });
                }
            }
            out
        };
        let plans: Vec<Vec<Window>> = (0..passes)
            .map(|k| windows_for(if k % 2 == 1 { tile / 2 } else { 0 }))
            .collect();
        progress.stage(Stage::Labels, plans.iter().map(Vec::len).sum());
        // After the first pass each tile is optimal for its fixed borders, so later passes
        // only re-solve the strips along the first pass's tile borders (`border_strips`).
        let reach = tile / self.params.border_strips;
        let near_border = |v: usize| v % tile < reach || v % tile >= tile - reach;
        let strips: Vec<bool> = (0..w * h)
            .into_par_iter()
            .map(|p| free.is_none_or(|f| f[p]) && (near_border(p % w) || near_border(p / w)))
            .collect();
        for (k, windows) in plans.into_iter().enumerate() {
            let mut results: Vec<(Window, Vec<u8>)> = Vec::new();
            let grid = Grid {
                width: w,
                height: h,
                labels,
                free: if k == 0 { free } else { Some(&strips) },
            };
            // Windows come row of tiles by row of tiles: a band is as many rows of them as fit.
            let mut rest = &windows[..];
            while let Some(first) = rest.first() {
                let limit = first.y0.saturating_add(self.focus.rows());
                let n = rest
                    .iter()
                    .position(|v| v.y0 + v.h > limit.max(first.y0 + v.h))
                    .unwrap_or(rest.len());
                let (band, next) = rest.split_at(n.max(1));
                rest = next;
                let y1 = band.iter().map(|v| v.y0 + v.h).max().unwrap_or(h);
                let rows = first.y0.saturating_sub(1)..(y1 + 1).min(h);
                self.focus.with(rows, |amps| {
                    let level = Level::new(self.frames, amps, self.lambda, self.params, self.ties);
                    results.par_extend(
                        band.par_iter()
                            .map_init(GridMaxflow::new, |solver, &win| {
                                let r = solve_window(&grid, win, &level, self.params, solver);
                                progress.advance(1);
                                r.map(|out| (win, out))
                            })
                            .flatten(),
                    );
                });
            }
            for (win, out) in results {
                for y in 0..win.h {
                    let s = (win.y0 + y) * w + win.x0;
                    labels[s..s + win.w].copy_from_slice(&out[y * win.w..(y + 1) * win.w]);
                }
            }
        }
    }
}

/// A rectangle of the label grid.
#[derive(Clone, Copy, Debug)]
struct Window {
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
}

/// Solves one window as its own grid, with a ring of fixed pixels around it; returns the
/// window's new labels, or `None` when nothing in it may change.
fn solve_window<T: Sample>(
    grid: &Grid,
    win: Window,
    level: &Level<T>,
    params: &GraphCutParams,
    solver: &mut GridMaxflow,
) -> Option<Vec<u8>> {
    let (gw, gh) = (grid.width, grid.height);
    let (rx0, ry0) = (win.x0.saturating_sub(1), win.y0.saturating_sub(1));
    let (rx1, ry1) = ((win.x0 + win.w + 1).min(gw), (win.y0 + win.h + 1).min(gh));
    let (rw, rh) = (rx1 - rx0, ry1 - ry0);
    let mut labels = Vec::with_capacity(rw * rh);
    let mut free = Vec::with_capacity(rw * rh);
    for y in ry0..ry1 {
        labels.extend_from_slice(&grid.labels[y * gw + rx0..y * gw + rx1]);
        for x in rx0..rx1 {
            let inside =
                (win.x0..win.x0 + win.w).contains(&x) && (win.y0..win.y0 + win.h).contains(&y);
            free.push(inside && grid.free.is_none_or(|f| f[y * gw + x]));
        }
    }
    let local = Grid {
        width: rw,
        height: rh,
        labels: &labels,
        free: Some(&free),
    };
    let moves = moves(&local, (rx0, ry0, gw), level, params.candidates)?;
    let offered: Vec<u8> = moves.iter().map(|m| m.label).collect();
    let read: Vec<bool> = (0..rw * rh)
        .map(|p| free[p] || neighbours(rw, rh, p).any(|q| free[q]))
        .collect();
    let costs = TileCosts::gather(level, gw, (rx0, ry0, rw, rh), &offered, &read);
    let out = expand(&local, moves, &costs, params.max_cycles, solver);
    let (ox, oy) = (win.x0 - rx0, win.y0 - ry0);
    Some(
        (0..win.h)
            .flat_map(|y| {
                out[(oy + y) * rw + ox..(oy + y) * rw + ox + win.w]
                    .iter()
                    .copied()
            })
            .collect(),
    )
}

/// The expansion moves of a window's grid (`local`, at `(x0, y0)` of a level `width` wide): each
/// free pixel is offered its `k` sharpest frames, the fallback where that ties with them
/// ([`GraphCutParams::tie_bias`]), and the labels it and its 4 neighbours hold. Without the
/// fallback, exhaustive expansion took it over pixels the candidates never offered it (layered
/// 8 × 1.9 MP: energy 2.4 % above exhaustive expansion's; with it 0.1 %). In label order; `None`
/// when no pixel is free.
fn moves<T: Sample>(
    local: &Grid,
    (x0, y0, width): (usize, usize, usize),
    level: &Level<T>,
    k: usize,
) -> Option<Vec<Move>> {
    let (w, h) = (local.width, local.height);
    let mut pixels: Vec<Vec<u32>> = vec![Vec::new(); 256];
    let mut top = Vec::new();
    let mut any_free = false;
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            if !local.free.is_none_or(|f| f[p]) {
                continue;
            }
            any_free = true;
            let at = (y0 + y) * width + x0 + x;
            level.sharpest(at, k, &mut top);
            if level.ties(at) {
                top.push(level.ties.fallback);
            }
            // The labels offered, as a set of 256 bits: sorting and deduplicating a list of
            // them was a tenth of this function's time.
            let mut offer = [0u64; 4];
            let own = neighbours(w, h, p).chain([p]).map(|q| local.labels[q]);
            for l in top.iter().copied().chain(own) {
                offer[l as usize / 64] |= 1 << (l % 64);
            }
            for (word, mut bits) in offer.into_iter().enumerate() {
                while bits != 0 {
                    pixels[word * 64 + bits.trailing_zeros() as usize].push(p as u32);
                    bits &= bits - 1;
                }
            }
        }
    }
    any_free.then(|| {
        (0..=255u8)
            .zip(pixels)
            .filter(|(_, px)| !px.is_empty())
            .map(|(label, pixels)| Move { label, pixels })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sharpest_frames_come_best_first_ties_to_the_lower_index() {
        let amps = [3u16, 7, 7, 1, 9];
        let frames: Vec<Image<u8>> = amps.iter().map(|_| Image::new(1, 1, 1)).collect();
        let amps = Amps::new(0, amps.iter().map(|&a| vec![a]).collect());
        let p = GraphCutParams::default();
        let map = tie_map(&amps.per_frame, &p);
        let ties = Ties::whole(&map, 1, 0);
        let level = Level::new(&frames, &amps, 0.3, &p, &ties);
        let mut top = Vec::new();
        for (k, want) in [
            (1, vec![4]),
            (2, vec![4, 1]),
            (3, vec![4, 1, 2]),
            (4, vec![4, 1, 2, 0]),
            (usize::MAX, vec![0, 1, 2, 3, 4]),
        ] {
            level.sharpest(0, k, &mut top);
            assert_eq!(top, want, "k = {k}");
        }
    }

    /// A frame within the noise floor below the sharpest costs nothing, and labelling starts
    /// from the fallback frame there; just outside it, the fallback costs and the sharpest
    /// starts. (Three frames see nothing, so the median frame's amplitude widens no tie.)
    #[test]
    fn frames_within_the_noise_tie_cost_nothing_and_start_from_the_fallback() {
        let p = GraphCutParams::default();
        let tie = (p.tie * p.noise_floor * AMP_SCALE) as u16;
        let frames: Vec<Image<u8>> = (0..5).map(|_| Image::new(2, 1, 1)).collect();
        let mut amps = vec![vec![1000, 1000], vec![1000 - tie + 1, 1000 - tie - 2]];
        amps.extend([vec![0, 0], vec![0, 0], vec![0, 0]]);
        let amps = Amps::new(0, amps);
        let map = tie_map(&amps.per_frame, &p);
        let ties = Ties::whole(&map, 2, 1);
        let level = Level::new(&frames, &amps, p.lambda, &p, &ties);
        assert_eq!(level.unary(0, 1), 0);
        assert!(level.unary(1, 1) > 0);
        assert_eq!(level.start_labels(2), [1, 0]);
    }

    /// Where every frame's amplitude is high, as under heavy noise, frames tie within a share of
    /// the median frame's: 300 below the sharpest costs nothing at a median of 800, and costs
    /// without that share.
    #[test]
    fn heavy_noise_widens_the_tie() {
        let frames: Vec<Image<u8>> = (0..3).map(|_| Image::new(1, 1, 1)).collect();
        let amps = Amps::new(0, vec![vec![1000], vec![700], vec![800]]);
        let cost = |p: GraphCutParams| {
            let map = tie_map(&amps.per_frame, &p);
            Level::new(&frames, &amps, p.lambda, &p, &Ties::whole(&map, 1, 1)).unary(0, 1)
        };
        assert_eq!(cost(GraphCutParams::default()), 0);
        let floor_only = GraphCutParams {
            tie_noise: 0.0,
            ..GraphCutParams::default()
        };
        assert!(cost(floor_only) > 0);
    }

    /// Three frames of one plain grey surface, each with its own noise: no frame is sharper, so
    /// the labels stay on the fallback frame instead of following each pixel's noisiest frame.
    #[test]
    fn a_plain_noisy_surface_keeps_the_fallback_frame() {
        let (w, h) = (96, 96);
        let mut seed = 7u64;
        let frames: Vec<Image<u8>> = (0..3)
            .map(|_| {
                let mut f = Image::new(w, h, 3);
                for v in f.data.iter_mut() {
                    seed = seed
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    *v = 120 + (seed >> 61) as u8;
                }
                f
            })
            .collect();
        let coverage = vec![Coverage::full(w, h); 3];
        let share = |p: &GraphCutParams| {
            let l = label_stack(&frames, &coverage, 1, p, h, &crate::stack::NoProgress).labels;
            l.iter().filter(|&&l| l == 1).count() as f64 / l.len() as f64
        };
        let with_tie = share(&GraphCutParams::default());
        let without = share(&GraphCutParams {
            tie: 0.0,
            tie_noise: 0.0,
            ..GraphCutParams::default()
        });
        assert!(
            with_tie > 0.95,
            "fallback share {with_tie} (without the tie {without})"
        );
        assert!(
            without < 0.9,
            "without the tie the noise decides: {without}"
        );
    }
}
