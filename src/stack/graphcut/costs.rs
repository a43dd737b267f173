//! The labelling's cost model: each frame's focus cost at a pixel (its focus amplitude below
//! the sharpest frame's, beyond what ties) and the seam cost between two labels, read from a
//! level's frames and focus amplitudes.

use super::ties::Ties;
use super::GraphCutParams;
use crate::stack::align::Coverage;
use crate::stack::expansion::Costs;
use crate::stack::focus::{
    focus_reach, frame_focus_amplitude, max_amplitude, FocusParams, AMP_SCALE,
};
use crate::stack::image::{Image, Sample};
use rayon::prelude::*;
use std::ops::Range;

/// Focus amplitudes of every frame on a run of rows of a level, and their maximum per pixel.
pub(super) struct Amps {
    /// Level pixel index of the first one held.
    pub(super) offset: usize,
    pub(super) per_frame: Vec<Vec<u16>>,
    pub(super) max: Vec<u16>,
}

impl Amps {
    pub(super) fn new(offset: usize, per_frame: Vec<Vec<u16>>) -> Self {
        let max = max_amplitude(&per_frame);
        Self {
            offset,
            per_frame,
            max,
        }
    }

    /// Every frame's amplitudes on rows `rows` of the full-resolution level, each computed on
    /// those rows plus the focus measure's reach, so they equal the whole image's exactly.
    pub(super) fn for_rows<T: Sample>(
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
        Self::new(rows.start * frames[0].width(), per_frame)
    }
}

/// One frame's focus amplitudes on rows `rows`, zero where it has no content of its own: the
/// graph cut steers away, and `keep_covered` settles the flat areas where every frame scores
/// zero.
pub(super) fn amplitude_rows<T: Sample>(
    frame: &Image<T>,
    cov: &Coverage,
    p: &FocusParams,
    rows: Range<usize>,
) -> Vec<u16> {
    let (w, h) = (frame.width(), frame.height());
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
pub(super) enum Focus<'a, T> {
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
    pub(super) fn rows(&self) -> usize {
        match self {
            Focus::Whole(_) => usize::MAX,
            Focus::Bands { rows, .. } => *rows,
        }
    }

    /// Runs `f` on the amplitudes of (at least) rows `rows`.
    pub(super) fn with<R>(&self, rows: Range<usize>, f: impl FnOnce(&Amps) -> R) -> R {
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
pub(super) struct Level<'a, T> {
    pub(super) channels: usize,
    pub(super) colors: Vec<&'a [T]>,
    pub(super) amps: &'a Amps,
    /// Integer units per unit of focus cost: channels·MAX/λ, so seam costs stay exact integers.
    pub(super) unary_scale: f32,
    pub(super) eps: f32,
    /// What each pixel's frames tie within, in amplitude units, and the frame ties go to.
    pub(super) ties: &'a Ties<'a>,
    /// What any frame but the fallback costs where the fallback ties
    /// ([`GraphCutParams::tie_bias`]).
    pub(super) bias: i32,
    pub(super) kappa: i32,
}

/// What a pixel's focus costs share: the cost per unit of amplitude below the sharpest frame's
/// (one division a pixel), the amplitude below it that costs nothing ([`Ties`]), and whether
/// the fallback ties there (then any other frame pays [`GraphCutParams::tie_bias`]).
#[derive(Clone, Copy)]
pub(super) struct PixelTerms {
    pub(super) per_amp: f32,
    pub(super) tie: f32,
    pub(super) fallback_ties: bool,
}

impl<'a, T: Sample> Level<'a, T> {
    pub(super) fn new(
        images: &'a [Image<T>],
        amps: &'a Amps,
        lambda: f32,
        p: &GraphCutParams,
        ties: &'a Ties<'a>,
    ) -> Self {
        let channels = images[0].channels();
        let full = channels as f32 * T::MAX;
        Self {
            channels,
            colors: images.iter().map(|i| i.data()).collect(),
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
    pub(super) fn sharpest(&self, p: usize, k: usize, top: &mut Vec<u8>) {
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
    pub(super) fn start_labels(&self, pixels: usize) -> Vec<u8> {
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
    pub(super) fn colors(&self, p: usize, l: u8) -> &[T] {
        &self.colors[l as usize][p * self.channels..(p + 1) * self.channels]
    }

    /// Whether the fallback frame's focus amplitude at `p` ties with the sharpest frame's.
    #[inline]
    pub(super) fn ties(&self, p: usize) -> bool {
        self.fallback_within(p - self.amps.offset, self.ties.at(p) as f32)
    }

    /// Whether the fallback frame's focus amplitude at amplitude index `i` is within `tie` of
    /// the sharpest frame's.
    #[inline]
    pub(super) fn fallback_within(&self, i: usize, tie: f32) -> bool {
        let m = self.amps.max[i] as f32;
        m - self.amps.per_frame[self.ties.fallback as usize][i] as f32 <= tie
    }

    /// Focus cost of label `l` at `p`, in the integer units of the seam cost.
    #[inline]
    pub(super) fn unary(&self, p: usize, l: u8) -> i32 {
        self.unary_with(p, l, self.pixel_terms(p))
    }

    /// The terms every label's focus cost at `p` shares.
    #[inline]
    pub(super) fn pixel_terms(&self, p: usize) -> PixelTerms {
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
    pub(super) fn unary_with(&self, p: usize, l: u8, t: PixelTerms) -> i32 {
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
pub(super) fn seam(
    kappa: i32,
    p: usize,
    q: usize,
    lp: u8,
    lq: u8,
    diff: impl Fn(usize) -> i32,
) -> i32 {
    if lp == lq {
        return 0;
    }
    diff(p) + diff(q) + kappa
}

/// Σ |a − b| over a pixel's channels, each truncated to an integer.
#[inline]
pub(super) fn color_diff<T: Sample>(a: &[T], b: &[T]) -> i32 {
    a.iter().zip(b).map(|(&x, &y)| x.abs_diff_i32(y)).sum()
}
