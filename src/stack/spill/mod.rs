//! Takes the defocused spill of nearer objects out of the frames focused farther, before they are
//! composed: the halo.
//!
//! Where the label map has a depth step, the frame focused on the far side shows the near object
//! defocused, spread over the background around it: `F = G∗(α·C) + (1 − G∗α)·B`, with `α` the
//! near object's mask, `C` its colour (both seen sharp in its own frame), `G` the Gaussian of
//! its defocus in the far frame and `B` the background the output wants. No frame holds `B`
//! clean there (the near-focused frame shows it blurred), so choosing frames cannot remove the
//! halo; un-mixing can: `B = (F − G∗(α·C)) / (1 − G∗α)`.
//!
//! Everything the model needs is estimated from the stack itself:
//! - `α` and `C` from the label map and the labelled frame (a region labelled `k` is where
//!   frame `k` is sharp);
//! - `G`'s σ for each pair of labels from how well frame `k`, blurred, explains frame `l` over
//!   the interior of `k`'s region (the blur fit); a near object too small for its deepest
//!   blurs to be fitted takes theirs from the stack's focal axis, fitted to the other pairs
//!   ([`focal_axis`]);
//! - the light the defocus mixed in: a camera's lens mixes in linear light while its frames are
//!   stored sRGB-encoded, but a renderer may have mixed display values; the blur fit is run in
//!   both and the one that explains the stack clearly better is used, since un-mixing in the
//!   wrong one leaves dark or bright rims; where neither does (dark or plain near objects give
//!   the fit little to measure in either), nothing is un-mixed.
//!
//! Only pairs at least two planes apart count: neighbouring planes blur each other too little to
//! fit, and a slanted surface spans them without any step. Where the near object covers more
//! than [`HIDDEN`] of the background the division amplifies noise, so the un-mixing fades out
//! there, and the pixel next to a nearer region keeps the frame as it is (the near object's
//! own edge is composed from its own frame). The fit and the spill are computed at a reduced
//! resolution (the spill is a blur, smooth by nature) and sampled bilinearly at full size.

mod blur_fit;
mod edge_fill;
mod light;
mod synthesis;
#[cfg(test)]
mod tests;

use super::align::Coverage;
use super::blur::downsample_area;
use super::image::{Image, Plane, Sample};
use super::morphology::window_min;
use super::order::Order;
use super::repair::{depth_steps, flat_regions, Repaired};
use super::{Progress, Stage};
pub use blur_fit::Pair;
use edge_fill::fill_near_objects;
pub use light::Light;
use light::{fit, luma, Fitted, CLEAR, PROBES};
use rayon::prelude::*;
use synthesis::{Blurs, Spill};

/// Pixels of the reduced working resolution, at most: enough to fit blurs of 1 px and more.
/// A small near object whose deep blur in the farthest frames cannot be fitted at this size
/// gets it from the focal axis instead ([`super::focal_axis`]).
const WORK_PIXELS: usize = 150_000;
/// Full-resolution pixels next to a nearer region that keep the frame as it is: the pixel at
/// the object's edge, whose colour is the object's own (a wider guard leaves a faint rim of the
/// object's colour spilt around it).
const GUARD: usize = 1;

/// What the un-mixing did.
#[derive(Clone, Debug, PartialEq)]
pub struct Unmixed {
    /// `None` when no pair could be fitted (no depth steps, or regions too small) or the fits
    /// did not tell the light (`unclear_light`).
    pub light: Option<Light>,
    /// Where the labels say something of depth (see `evidenced`), for the compose's rule that
    /// keeps farther frames out of a nearer label's finest band; `None` where nothing was
    /// looked at (an untold order, too few frames). The caller takes it.
    pub told: Option<Vec<bool>>,
    pub pairs: Vec<Pair>,
    /// Per frame, the pixels changed.
    pub changed: Vec<usize>,
    /// Near objects' pixels copied into the frames focused behind them (`edge_fill`).
    pub filled: usize,
    /// What the label repairs did, run first; `None` when they were not asked for or the order
    /// was not told.
    pub repaired: Option<Repaired>,
    /// Pixels in a frame.
    pub frame_pixels: usize,
    /// The occlusion edges did not tell which frames are nearer, so nothing was done.
    pub untold: bool,
    /// The blur fits in linear and display light explained the stack alike (their mean log
    /// residuals this far apart), so nothing was un-mixed.
    pub unclear_light: Option<f64>,
}

/// One line for the logs.
impl std::fmt::Display for Unmixed {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        if self.untold {
            return write!(
                f,
                "left in: the occlusion edges do not tell which frames are nearer (see `order`)"
            );
        }
        if let Some(apart) = self.unclear_light {
            return write!(
                f,
                "left in: the blur fits do not tell the light the defocus mixed in (linear and \
                 display {apart:.2} apart in mean log residual, needs {CLEAR})"
            );
        }
        let Some(light) = self.light else {
            return write!(f, "no depth step to take a halo out of");
        };
        let (lo, hi) = self.pairs.iter().fold((f32::MAX, 0f32), |(lo, hi), p| {
            (lo.min(p.sigma), hi.max(p.sigma))
        });
        let changed: usize = self.changed.iter().sum();
        let all = (self.frame_pixels * self.changed.len()).max(1);
        write!(
            f,
            "{} near/far pairs ({} predicted), defocus σ {lo:.1}–{hi:.1} px, mixed in {} light; \
             {:.1} % of the frames' pixels un-mixed, {} filled into the frames behind it",
            self.pairs.len(),
            self.pairs.iter().filter(|p| p.predicted).count(),
            match light {
                Light::Linear => "linear",
                Light::Display => "display",
            },
            100.0 * changed as f64 / all as f64,
            self.filled
        )
    }
}

/// Bytes [`unmix`] holds besides the frames, for the memory plan: throughout, the reduced
/// frames and a few full-size maps of one byte a pixel; while the near objects' extent is
/// found, every depth's local mean colours of its object and of what lies behind it
/// ([`depth_steps::sides`]); later, the reduced frames' luma in both lights, the region masks and their
/// interiors (a byte a pixel), then one far frame's spill with one σ's sums and their blurs, and
/// the blurs kept for later far frames (no more planes than the luma took, see [`Blurs`]).
pub fn working_bytes(frames: usize, width: usize, height: usize, channels: usize) -> usize {
    let f = reduction(width, height);
    let reduced = width.div_ceil(f) * height.div_ceil(f);
    let plane = 4 * reduced;
    let held = plane * frames * channels + 9 * width * height;
    let refine = plane * 2 * channels * frames;
    let fit = plane * (3 * frames + 3 * (channels + 1)) + reduced * frames;
    held + refine.max(fit)
}

/// The factor the working resolution is reduced by: the least that fits [`WORK_PIXELS`].
fn reduction(width: usize, height: usize) -> usize {
    (1..)
        .find(|&f| width.div_ceil(f) * height.div_ceil(f) <= WORK_PIXELS)
        .expect("a factor as large as the image fits")
}

/// Un-mixes every frame in place, given the label map, where the labelling found texture, the
/// frame it gives where every frame ties (`fallback`) and the stack's focus order. With
/// `repair`, the label repairs run first ([`super::repair`]): the labels of a near object's
/// mislabelled edge move to its frame. Reports its own stage,
/// [`Stage::Spill`], a step for each repair and one per frame reduced, fitted (in each light)
/// and un-mixed: its work grows with the frames and their depth steps, and a watchdog waiting
/// on progress must see it move.
///
/// With an `Unknown` order it does nothing: the model is one of occlusion, and a stack whose
/// occlusion edges tell no order shows none to take out. Un-mixed on an assumed order, the fit
/// follows whatever the label boundaries happen to be (σ that follow no focal axis and swing
/// with small changes of the labels) and leaves dark blotches where it does not hold.
#[allow(clippy::too_many_arguments)]
pub fn unmix<T: Sample>(
    frames: &mut [Image<T>],
    labels: &mut [u8],
    textured: &[bool],
    fallback: u8,
    coverage: &[Coverage],
    order: Order,
    repair: bool,
    progress: &dyn Progress,
) -> Unmixed {
    let n = frames.len();
    let mut out = Unmixed {
        light: None,
        told: None,
        pairs: Vec::new(),
        changed: vec![0; n],
        filled: 0,
        repaired: None,
        frame_pixels: frames.first().map_or(0, |f| f.pixels()),
        untold: order == Order::Unknown,
        unclear_light: None,
    };
    if n < 3 || frames[0].pixels() == 0 || out.untold {
        return out;
    }
    let (w, h) = (frames[0].width(), frames[0].height());
    debug_assert_eq!(labels.len(), w * h);
    // Settle flat regions, reduce, find the steps' sides and relabel, fit in two lights, un-mix:
    // see `fit` and the loop below for the steps.
    progress.stage(Stage::Spill, 4 * n + 2);
    // Where the labels say something of depth: the labelling's texture, the flat regions the
    // repair settles, and the flat pixels not given the tie's frame nearer than their rim.
    let mut told = textured.to_vec();
    let settled = repair.then(|| {
        flat_regions::settle(frames, coverage, labels, &mut told, &|f| {
            order.depth_of(f, n)
        })
    });
    let told = flat_regions::tied_nearer(&told, labels, fallback, w, h, &|f| order.depth_of(f, n));
    progress.advance(1);
    // Everything below works on depth ranks, 0 nearest, and maps back to frame indices.
    let frame_of = |d: usize| order.frame_at(d, n);
    let factor = reduction(w, h);
    let reduced: Vec<Vec<Plane>> = (0..n)
        .into_par_iter()
        .map(|d| {
            let planes = downsample_area(&frames[frame_of(d)], factor).to_planes();
            progress.advance(1);
            planes
        })
        .collect();
    let mut depth: Vec<u8> = labels.iter().map(|&l| frame_of(l as usize) as u8).collect();
    let everywhere = Coverage::intersection(coverage);
    let evidence = |p: usize| told[p] && everywhere.covers(p % w, p / w);
    let mut said: Vec<bool> = (0..w * h).into_par_iter().map(evidence).collect();
    let steps = evidenced(depth.clone(), &evidence, w, n);
    let sides = depth_steps::sides(frames, coverage, &frame_of, &steps, &reduced, factor);
    if let Some(settled) = settled {
        let relabelled = depth_steps::relabel(&mut depth, &sides);
        // A pixel relabelled by the colour at a step tells its depth by that colour.
        for ((l, &d), said) in labels.iter_mut().zip(&depth).zip(&mut said) {
            let to = frame_of(d as usize) as u8;
            *said |= to != *l;
            *l = to;
        }
        out.repaired = Some(Repaired {
            settled,
            relabelled,
        });
    }
    out.told = Some(said);
    progress.advance(1);
    let objects = evidenced(sides.objects, &evidence, w, n);
    let masks = region_masks(&objects, w, h, n, factor);
    // The fit needs only luma, in both lights; the colour is decoded to linear light only when
    // that is the light chosen, so one light's reduced frames are held, never both.
    let (display, linear): (Vec<Plane>, Vec<Plane>) = reduced
        .par_iter()
        .map(|planes| (luma(planes, Light::Display), luma(planes, Light::Linear)))
        .unzip();
    let (light, pairs) = match fit(
        [(Light::Linear, linear), (Light::Display, display)],
        &masks,
        factor,
        PROBES,
        progress,
    ) {
        Fitted::Told(light, pairs) => (light, pairs),
        Fitted::Untold(apart) => {
            out.unclear_light = Some(apart);
            return out;
        }
        Fitted::Nothing => return out,
    };
    let mut mixed = reduced;
    if light == Light::Linear {
        let mix = light.mixing();
        mixed.par_iter_mut().for_each(|planes| {
            for v in planes.iter_mut().flat_map(|p| p.data_mut().iter_mut()) {
                *v = mix(*v);
            }
        });
    }
    out.light = Some(light);
    let nearest = window_min(&objects, w, h, GUARD);
    let mut blurs = Blurs::new(&pairs, n, mixed[0].len());
    for l in 0..n {
        let groups = blurs.of(l, &mixed, &masks, factor);
        if !groups.is_empty() {
            let spill = Spill::sum(&groups, factor);
            // Next to a nearer region, or labelled nearer where the label says nothing of
            // depth (see `evidenced`: nothing is known to take out there).
            let is_guarded = |p: usize| {
                nearest[p] as usize + 2 <= l || (depth[p] as usize + 2 <= l && !evidence(p))
            };
            out.changed[frame_of(l)] = spill.apply(&mut frames[frame_of(l)], &is_guarded, light);
        }
        progress.advance(1);
    }
    out.filled = fill_near_objects(frames, &depth, &objects, &frame_of);
    out.pairs = pairs
        .into_iter()
        .map(|p| Pair {
            near: frame_of(p.near as usize) as u8,
            far: frame_of(p.far as usize) as u8,
            ..p
        })
        .collect();
    out
}

/// `objects` (depth ranks) with the pixels `evidence` leaves out taken as the farthest depth,
/// no near object, since a label there says nothing of depth:
/// - where not every frame reaches, the labelling could choose only among the frames that reach
///   the pixel (at the border, often the reference alone), and a strip of the reference's label
///   along a border of far labels would be taken for a near object;
/// - where no frame has texture, the label repair did not settle the region and its label is
///   the tie's frame, [`MIN_STEP`](super::order::MIN_STEP) planes nearer than the one around
///   it ([`flat_regions::tied_nearer`]): that plain patch of the background would be taken for
///   a near object, and its "spill" taken out of the background around it, where there is no
///   depth step.
fn evidenced(
    mut objects: Vec<u8>,
    evidence: &(dyn Fn(usize) -> bool + Sync),
    w: usize,
    n: usize,
) -> Vec<u8> {
    let farthest = (n - 1) as u8;
    objects.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, d) in row.iter_mut().enumerate() {
            if !evidence(y * w + x) {
                *d = farthest;
            }
        }
    });
    objects
}

/// Per depth rank, the share of each reduced pixel it covers in `depth`: one pass counting
/// every rank at once.
fn region_masks(depth: &[u8], w: usize, h: usize, n: usize, factor: usize) -> Vec<Plane> {
    let (rw, rh) = (w.div_ceil(factor), h.div_ceil(factor));
    let rows: Vec<Vec<f32>> = (0..rh)
        .into_par_iter()
        .map(|ry| {
            let mut count = vec![0.0f32; n * rw];
            let ys = ry * factor..((ry + 1) * factor).min(h);
            for y in ys.clone() {
                for (x, &d) in depth[y * w..][..w].iter().enumerate() {
                    count[d as usize * rw + x / factor] += 1.0;
                }
            }
            for (i, c) in count.iter_mut().enumerate() {
                let rx = i % rw;
                let bw = ((rx + 1) * factor).min(w) - rx * factor;
                *c /= (bw * ys.len()) as f32;
            }
            count
        })
        .collect();
    (0..n)
        .map(|d| {
            let data = rows
                .iter()
                .flat_map(|r| r[d * rw..(d + 1) * rw].iter().copied())
                .collect();
            Plane::from_vec(rw, rh, 1, data)
        })
        .collect()
}

fn add(acc: &mut Plane, b: &Plane) {
    acc.data_mut()
        .iter_mut()
        .zip(b.data())
        .for_each(|(a, v)| *a += v);
}
