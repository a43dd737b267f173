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

mod costs;
mod ties;
mod tiles;

use super::align::Coverage;
use super::blur::{downsample_area, downsample_samples};
use super::expansion::energy;
use super::focus::{FocusParams, AMP_SCALE};
use super::image::{Image, Sample};
use super::{Progress, Stage};
use costs::{amplitude_rows, Amps, Focus, Level};
use rayon::prelude::*;
use ties::{tie_map, Ties};
use tiles::Solve;

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
    /// plain background) the frames differ by far less than the noise floor, yet as focus cost
    /// that outweighs a seam, so without the tie the noise would pick the frame pixel by pixel:
    /// plain regions labelled like salt and pepper, noisier than any frame, and the expansion
    /// kept busy on them.
    pub tie: f32,
    /// Focus cost, in [`Self::kappa`]'s units, of every frame but the fallback where the
    /// fallback ties with the sharpest: plain regions go to one frame, the reference (the one
    /// frame not resampled), rather than to whichever frame a move happened to reach. Without
    /// it every frame is as good there, and exhaustive expansion spreads near patches' labels
    /// over plain regions the candidate moves cannot reach.
    pub tie_bias: f32,
    /// Where it is more than the noise floor, frames also tie within this share of the median
    /// frame's focus amplitude (measured on the coarse level, as the noise's level is smooth):
    /// under heavy noise a plain region's amplitudes are the noise's, and differ from frame to
    /// frame by more than the noise floor; without this, exhaustive expansion would still
    /// label plain regions by their noise, which the candidates cannot follow.
    pub tie_noise: f32,
    /// Pixel count the coarse level is reduced to.
    pub coarse_pixels: usize,
    /// How many of its sharpest frames a pixel is offered, besides the labels it and its four
    /// neighbours hold; `usize::MAX` offers every frame everywhere (exhaustive expansion, the
    /// reference the labelling's energy is measured against).
    pub candidates: usize,
    /// Expansion cycles over a window's moves, at most: a third cycle re-runs most moves of a
    /// window to move a few pixels.
    pub max_cycles: usize,
    /// After the first pass over a level's tiles, later passes re-solve only strips along the
    /// first pass's tile borders, a tile's `1/border_strips` wide on each side: a fixed border
    /// moves the labels only a few pixels into a tile.
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
    let (w, h) = (frames[0].width(), frames[0].height());
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
    let (cw, ch) = (small[0].width(), small[0].height());
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

/// Energy of `labels` for an aligned stack, by the same terms the labelling minimises, at full
/// resolution: to compare labellings (the default candidates against exhaustive expansion).
pub fn labelling_energy<T: Sample>(
    frames: &[Image<T>],
    coverage: &[Coverage],
    labels: &[u8],
    fallback: u8,
    p: &GraphCutParams,
) -> i64 {
    let (w, h) = (frames[0].width(), frames[0].height());
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
                for v in f.data_mut().iter_mut() {
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
