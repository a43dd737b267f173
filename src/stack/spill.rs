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
//!   both and the one that explains the stack better is used, since un-mixing in the wrong one
//!   leaves dark or bright rims.
//!
//! Only pairs at least two planes apart count: neighbouring planes blur each other too little to
//! fit, and a slanted surface spans them without any step. Where the near object covers more
//! than [`HIDDEN`] of the background the division amplifies noise, so the un-mixing fades out
//! there, and the pixel next to a nearer region keeps the frame as it is (the near object's
//! own edge is composed from its own frame). The fit and the spill are computed at a reduced
//! resolution (the spill is a blur, smooth by nature) and sampled bilinearly at full size.

use super::align::Coverage;
use super::blur::{downsample_area, gaussian_blur};
use super::flat_regions::{self, Settled};
use super::focal_axis;
use super::image::{luma_of, Image, Plane, Sample, Tap};
use super::morphology::{distance, window_max, window_min};
use super::order::Order;
use super::srgb;
use super::{Progress, Stage};
use rayon::prelude::*;
use std::rc::Rc;

/// Pixels of the reduced working resolution, at most: enough to fit blurs of 1 px and more.
/// A small near object whose deep blur in the farthest frames cannot be fitted at this size
/// gets it from the focal axis instead ([`focal_axis`]), which is what working on the 0.17 MP
/// replay bundles whole (200k) once gained, at four times the work.
const WORK_PIXELS: usize = 150_000;
/// Blur σ (full-resolution pixels) the fit tries, to ½ px.
const SIGMA_MIN: f32 = 1.0;
const SIGMA_MAX: f32 = 16.0;
/// Reduced pixels a near region's interior needs for its blur to be fitted.
const MIN_INTERIOR: usize = 200;
/// The background is taken as too deeply hidden where the near object's spill covers more than
/// this share of it: the un-mixing fades out over [`FADE`] below it.
const HIDDEN: f32 = 0.7;
const FADE: f32 = 0.2;
/// Spill coverage below this changes nothing.
const TRACE: f32 = 0.01;
/// Full-resolution pixels next to a nearer region that keep the frame as it is: the pixel at
/// the object's edge, whose colour is the object's own. 2 px also kept the second pixel out
/// spilt, a faint rim of the object's colour around it (1 px: the 1600×1200 tripod's band
/// +0.15 dB, the replay bundles' +0.10–0.11, no stack's PSNR lower).
const GUARD: usize = 1;
/// How far from a step the labels may have misplaced it, in full-resolution pixels.
const RING: usize = 8;
/// A label moves to the near object's frame only where the pixel is clearly the object's: its
/// squared colour distance to the object's mean under this share of that to the background's
/// (half the distance). Nearer than the background's alone moved labels on textured far
/// surfaces whose colours happen to lie near the object's (the committed 4-plane stack's depth
/// accuracy fell from 91.6 to 89.9 %; with this 90.9 %, PSNR unchanged).
const RELABEL: f32 = 0.25;
/// σ of the local mean colours [`refine`] compares, full-resolution pixels.
const MEAN_SIGMA: f32 = 6.0;

/// The values the lens's defocus mixed: linear light (a camera) or display values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Light {
    Linear,
    Display,
}

impl Light {
    /// Takes a stored (sRGB-encoded) value into this light. Linear light by table
    /// ([`srgb::tabulated`]): a `powf` for every channel of the reduced frames and, twice, of
    /// every pixel un-mixed was a tenth of the stage on the linear-light stacks. The table is
    /// fetched once here, for a whole pass, rather than once a value.
    fn mixing(self) -> impl Fn(f32) -> f32 + Copy + Sync {
        let curve = (self == Light::Linear).then(|| &srgb::tabulated().decode);
        move |v| match curve {
            Some(c) => c.at(v.clamp(0.0, 1.0)),
            None => v,
        }
    }

    /// Takes a value in this light back to its stored form (see [`Self::mixing`]).
    fn storing(self) -> impl Fn(f32) -> f32 + Copy + Sync {
        let curve = (self == Light::Linear).then(|| &srgb::tabulated().encode);
        move |v| match curve {
            Some(c) => c.at(v.clamp(0.0, 1.0)),
            None => v.clamp(0.0, 1.0),
        }
    }
}

/// A near label's defocus in a farther frame, as fitted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pair {
    pub near: u8,
    pub far: u8,
    /// σ of the Gaussian, in full-resolution pixels.
    pub sigma: f32,
    /// Predicted from the other pairs ([`with_predicted`]), not fitted.
    pub predicted: bool,
}

/// What the un-mixing did.
#[derive(Clone, Debug, PartialEq)]
pub struct Unmixed {
    /// `None` when no pair could be fitted (no depth steps, or regions too small).
    pub light: Option<Light>,
    pub pairs: Vec<Pair>,
    /// Per frame, the pixels changed.
    pub changed: Vec<usize>,
    /// Pixels whose label moved to a near object's frame (see [`refine`]).
    pub relabelled: usize,
    /// Near objects' pixels copied into the frames focused behind them ([`fill_near_objects`]).
    pub filled: usize,
    /// Flat regions given the frame that shows their outline crisp, first ([`flat_regions`]).
    pub settled: Settled,
    /// Pixels in a frame.
    pub frame_pixels: usize,
    /// The occlusion edges did not tell which frames are nearer, so nothing was done.
    pub untold: bool,
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
        if self.settled.regions > 0 {
            let (n, px) = (self.settled.regions, self.settled.pixels);
            let s = if n == 1 { "" } else { "s" };
            write!(
                f,
                "{n} flat region{s} ({px} pixels) given the nearer frame that shows the outline \
                 crisp; "
            )?;
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
             {:.1} % of the frames' pixels un-mixed, {} pixels moved to the near object's frame, \
             {} filled into the frames behind it",
            self.pairs.len(),
            self.pairs.iter().filter(|p| p.predicted).count(),
            match light {
                Light::Linear => "linear",
                Light::Display => "display",
            },
            100.0 * changed as f64 / all as f64,
            self.relabelled,
            self.filled
        )
    }
}

/// Bytes [`unmix`] holds besides the frames, for the memory plan: throughout, the reduced
/// frames and a few full-size maps of one byte a pixel; while the near objects' extent is
/// refined, every depth's local mean colours of its object and of what lies behind it
/// ([`refine`]); later, the reduced frames' luma in both lights, the region masks and their
/// interiors (a byte a pixel), then one far frame's spill with one σ's sums and their blurs, and
/// the blurs kept for later far frames (no more planes than the luma took, see [`Blurs`]).
/// (The refinement's means had been left out: a 25-frame 1.2 MP fuse peaked at 236 MiB against
/// a plan of 209.)
pub fn working_bytes(frames: usize, width: usize, height: usize, channels: usize) -> usize {
    let f = reduction(width, height);
    let reduced = width.div_ceil(f) * height.div_ceil(f);
    let plane = 4 * reduced;
    let held = plane * frames * channels + 8 * width * height;
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

/// Un-mixes every frame in place, given the label map, where the labelling found texture and
/// the stack's focus order. Where the near side
/// of a step is mislabelled (a farther frame taken where the near object is, which shows the
/// background through the object's edge), the labels are moved to the near object's frame:
/// first flat regions' ([`flat_regions`]), then each pixel's near a step. Reports its own stage,
/// [`Stage::Spill`], a step for the flat regions and one per frame reduced, fitted (in each
/// light) and un-mixed: its work grows with the frames and their depth steps, and a watchdog
/// waiting on progress must see it move.
///
/// With an `Unknown` order it does nothing: the model is one of occlusion, and a stack whose
/// occlusion edges tell no order shows none to take out. Un-mixing it on an assumed order fitted
/// whatever its label boundaries happened to be (amber_macro, a real stack with 52–57 % of its
/// edges' contrast for nearest first: σ that follow no focal axis and swing from 1.5–6.5 to
/// 6.5–10.5 px with small changes of the labels) and left dark blotches where the fit did not
/// hold; the flats stacks, patches without any occlusion, were un-mixed on 3–8 % of their pixels.
pub fn unmix<T: Sample>(
    frames: &mut [Image<T>],
    labels: &mut [u8],
    textured: &[bool],
    coverage: &[Coverage],
    order: Order,
    progress: &dyn Progress,
) -> Unmixed {
    let n = frames.len();
    let mut out = Unmixed {
        light: None,
        pairs: Vec::new(),
        changed: vec![0; n],
        relabelled: 0,
        filled: 0,
        settled: Settled::default(),
        frame_pixels: frames.first().map_or(0, |f| f.pixels()),
        untold: order == Order::Unknown,
    };
    if n < 3 || frames[0].pixels() == 0 || out.untold {
        return out;
    }
    let (w, h) = (frames[0].width, frames[0].height);
    debug_assert_eq!(labels.len(), w * h);
    // Settle, reduce, refine, fit in two lights, un-mix: see `fit` and the loop below for the
    // steps.
    progress.stage(Stage::Spill, 4 * n + 2);
    out.settled = flat_regions::settle(frames, coverage, labels, textured, &|f| {
        order.depth_of(f, n)
    });
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
    let refined = refine(frames, coverage, &frame_of, &mut depth, &reduced, factor);
    out.relabelled = refined.relabelled;
    progress.advance(1);
    for (l, &d) in labels.iter_mut().zip(&depth) {
        *l = frame_of(d as usize) as u8;
    }
    let masks = region_masks(&refined.objects, w, h, n, factor);
    // The fit needs only luma, in both lights; the colour is decoded to linear light only when
    // that is the light chosen, so one light's reduced frames are held, never both.
    let (display, linear): (Vec<Plane>, Vec<Plane>) = reduced
        .par_iter()
        .map(|planes| (luma(planes, Light::Display), luma(planes, Light::Linear)))
        .unzip();
    let (light, pairs) = fit(
        [(Light::Linear, linear), (Light::Display, display)],
        &masks,
        factor,
        PROBES,
        progress,
    );
    let Some(light) = light else {
        return out;
    };
    let mut mixed = reduced;
    if light == Light::Linear {
        let mix = light.mixing();
        mixed.par_iter_mut().for_each(|planes| {
            for v in planes.iter_mut().flat_map(|p| p.data.iter_mut()) {
                *v = mix(*v);
            }
        });
    }
    out.light = Some(light);
    let nearest = window_min(&refined.objects, w, h, GUARD);
    let mut blurs = Blurs::new(&pairs, n, mixed[0].len());
    for l in 0..n {
        let groups = blurs.of(l, &mixed, &masks, factor);
        if !groups.is_empty() {
            let spill = Spill::sum(&groups, factor);
            let is_guarded = |p: usize| nearest[p] as usize + 2 <= l;
            out.changed[frame_of(l)] = spill.apply(&mut frames[frame_of(l)], &is_guarded, light);
        }
        progress.advance(1);
    }
    out.filled = fill_near_objects(frames, &depth, &refined.objects, coverage, &frame_of);
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

/// Full-resolution pixels from a depth step within which [`fill_near_objects`] fills.
const FILL_REACH: usize = 6;

/// Copies each near object's own pixels next to a depth step into the frames focused two or
/// more planes behind it, where the labels and the colour refinement ([`refine`]) agree that
/// the object is there and within [`FILL_REACH`] of the step; returns how many pixels.
///
/// The un-mixing cleans a far frame only outside the near object. Inside its edge the far frame
/// still shows the object defocused with the background through it, and the compose's coarser
/// bands, shared by the pixels on both sides of the step, took that texture over the object's
/// own where it had more contrast: the main job's blue polygon showed the background's stripes
/// over its first 5 px (1.5–5.5 px inside: 22.3–24.4 dB, its own frame 29.0–30.1). Filled, a
/// far frame shows at the step what the output wants on both sides of it, so whichever frame a
/// band comes from, the edge is the object's (those pixels 25.2–27.6 dB). Only near the step:
/// deeper in, a far frame's bands can be the better ones, where a slanted object lies between
/// the planes its label and the far frame are focused on (filling every such pixel however far
/// from the step lost 0.06 dB on the 1600×1200 tripod; within 3 or 6 px of it the tripod gained
/// 0.04 or 0.02). Pixels the colour calls background are left, so a label that overreaches the
/// object does not carry the near frame's blurred background into the far frames.
fn fill_near_objects<T: Sample>(
    frames: &mut [Image<T>],
    depth: &[u8],
    objects: &[u8],
    coverage: &[Coverage],
    frame_of: &(dyn Fn(usize) -> usize + Sync),
) -> usize {
    let (w, h, ch) = (frames[0].width, frames[0].height, frames[0].channels);
    // Only where every frame reaches: near the border a label can be the reference's because
    // the frame the labelling chose does not cover the pixel, which says nothing of depth
    // (filled there, the main job's right border took the reference's blurred checkerboard).
    let everywhere = Coverage::intersection(coverage);
    // Per pixel, its object's depth rank + 1 where it is filled, else 0.
    let mut fill = window_max(depth, w, h, FILL_REACH);
    fill.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, f) in row.iter_mut().enumerate() {
            let (i, k) = (y * w + x, depth[y * w + x]);
            let step = *f as usize >= k as usize + 2;
            let agreed = objects[i] == k && everywhere.covers(x, y);
            *f = if step && agreed { k + 1 } else { 0 };
        }
    });
    for l in 2..frames.len() {
        // The far frame is taken out of the stack while the nearer ones are read.
        let target = frame_of(l);
        let mut far = std::mem::replace(&mut frames[target], Image::new(0, 0, ch));
        let nearer = &*frames;
        far.data
            .par_chunks_mut(w * ch)
            .zip(fill.par_chunks(w))
            .enumerate()
            .for_each(|(y, (row, fill))| {
                for (x, &f) in fill.iter().enumerate() {
                    // f = k + 1 for an object at depth k: filled where k + 2 <= l.
                    if f > 0 && (f as usize) < l {
                        let i = (y * w + x) * ch;
                        let near = &nearer[frame_of(f as usize - 1)].data[i..][..ch];
                        row[x * ch..][..ch].copy_from_slice(near);
                    }
                }
            });
        frames[target] = far;
    }
    fill.iter().filter(|&&f| f > 0).count()
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

/// Per reduced pixel, the nearest and the farthest depth rank in its `factor`×`factor` block of
/// `depth`: which depths cover a block wholly, for every depth at once. (Summing each depth's
/// region masks farther than it, per depth, grew with the square of the frames: flats 25 with
/// 16 patches took 352 ms in the spill stage so, 318 ms this way.)
fn block_extremes(depth: &[u8], w: usize, h: usize, factor: usize) -> (Vec<u8>, Vec<u8>) {
    let rw = w.div_ceil(factor);
    let (lo, hi): (Vec<Vec<u8>>, Vec<Vec<u8>>) = (0..h.div_ceil(factor))
        .into_par_iter()
        .map(|ry| {
            let (mut lo, mut hi) = (vec![u8::MAX; rw], vec![0u8; rw]);
            for y in ry * factor..((ry + 1) * factor).min(h) {
                for (x, &d) in depth[y * w..][..w].iter().enumerate() {
                    let c = x / factor;
                    (lo[c], hi[c]) = (lo[c].min(d), hi[c].max(d));
                }
            }
            (lo, hi)
        })
        .unzip();
    (lo.concat(), hi.concat())
}

/// The near objects' true extent next to each depth step.
struct Refined {
    /// Per pixel, the depth rank of the object seen there.
    objects: Vec<u8>,
    /// Pixels whose label moved to the near object's frame.
    relabelled: usize,
}

/// Within [`RING`] pixels of a step from depth `k` to `k + 2` or farther, decides each pixel
/// by the near frame's own colours: nearer the near object's local mean colour (over where it
/// is labelled, away from the ring) than the background's (over where depth `k + 2` or farther
/// is labelled), it is the near object; clearly nearer ([`RELABEL`]) and labelled farther, its
/// label moves to the near frame (when that frame covers it). Labels are taken as they are
/// elsewhere. In the near
/// frame the object is sharp and the background behind it blurred, so the two colours separate
/// where the label map, which follows contrast, does not.
fn refine<T: Sample>(
    frames: &[Image<T>],
    coverage: &[Coverage],
    frame_of: &(dyn Fn(usize) -> usize + Sync),
    depth: &mut [u8],
    reduced: &[Vec<Plane>],
    factor: usize,
) -> Refined {
    let (w, h, ch) = (frames[0].width, frames[0].height, frames[0].channels);
    let n = reduced.len();
    let (rw, rh) = (w.div_ceil(factor), h.div_ceil(factor));
    let (lo, hi) = block_extremes(depth, w, h, factor);
    let nearest = window_min(depth, w, h, RING);
    let farthest = window_max(depth, w, h, RING);
    // Reduced pixels whose whole block is of one depth, or of some depth farther than one.
    let wholly = |f: &dyn Fn(usize) -> bool| -> Plane {
        let data = (0..rw * rh).map(|i| f32::from(u8::from(f(i)))).collect();
        Plane::from_vec(rw, rh, 1, data)
    };
    let s = MEAN_SIGMA / factor as f32;
    // Per depth k: the local mean colour of its object and of what lies behind it, in frame k.
    let means: Vec<Option<[Vec<Plane>; 2]>> = (0..n)
        .into_par_iter()
        .map(|k| {
            if k + 2 >= n {
                return None;
            }
            let inside = wholly(&|i| lo[i] as usize == k && hi[i] as usize == k);
            let behind = wholly(&|i| lo[i] as usize >= k + 2);
            Some([inside, behind].map(|wgt| {
                let norm = gaussian_blur(&wgt, s);
                reduced[k]
                    .iter()
                    .map(|c| {
                        let data = c.data.iter().zip(&wgt.data).map(|(v, m)| v * m).collect();
                        let mut mean =
                            gaussian_blur(&Plane::from_vec(wgt.width, wgt.height, 1, data), s);
                        for (v, &z) in mean.data.iter_mut().zip(&norm.data) {
                            *v = if z > 1e-3 { *v / z } else { f32::NAN };
                        }
                        mean
                    })
                    .collect()
            }))
        })
        .collect();
    let cols = taps(w, factor, rw);
    let mut objects = depth.to_vec();
    let relabelled = depth
        .par_chunks_mut(w)
        .zip(objects.par_chunks_mut(w))
        .enumerate()
        .map(|(y, (drow, orow))| {
            let ty = tap(y, factor, rh);
            let mut moved = 0;
            for x in 0..w {
                let i = y * w + x;
                let k = nearest[i] as usize;
                if farthest[i] as usize >= k + 2 {
                    let Some([inside, behind]) = &means[k] else {
                        continue;
                    };
                    // Never a label, nor a colour, from a frame that does not reach here.
                    if !coverage[frame_of(k)].covers(x, y) {
                        continue;
                    }
                    let px = &frames[frame_of(k)].data[i * ch..][..ch];
                    let (mut din, mut dout) = (0.0, 0.0);
                    for (c, v) in px.iter().enumerate() {
                        let v = v.to_f32() / T::MAX;
                        din += (v - inside[c].sample_taps(cols[x], ty)).powi(2);
                        dout += (v - behind[c].sample_taps(cols[x], ty)).powi(2);
                    }
                    if !(din.is_finite() && dout.is_finite()) {
                        continue;
                    }
                    if din < dout {
                        orow[x] = k as u8;
                        if drow[x] as usize >= k + 2 && din < RELABEL * dout {
                            drow[x] = k as u8;
                            moved += 1;
                        }
                    } else if drow[x] as usize == k {
                        orow[x] = farthest[i];
                    }
                }
            }
            moved
        })
        .sum();
    Refined {
        objects,
        relabelled,
    }
}

/// The luma of reduced sRGB-encoded planes, in `light`.
fn luma(planes: &[Plane], light: Light) -> Plane {
    let mix = light.mixing();
    let data = match planes {
        [r, g, b] => (r.data.iter().zip(&g.data).zip(&b.data))
            .map(|((&r, &g), &b)| luma_of(mix(r), mix(g), mix(b)))
            .collect(),
        _ => planes[0].data.iter().map(|&v| mix(v)).collect(),
    };
    Plane::from_vec(planes[0].width, planes[0].height, 1, data)
}

/// Near depths fitted in both lights before the rest: the [`PROBES`] with the most interior.
/// Where their fits tell the lights apart by more than [`CLEAR`] (mean log residual), the other
/// depths are fitted in the better light alone; otherwise in both, and all of them decide. The
/// fit in two lights was a quarter of the spill stage (smooth 10 × 1.2 MP, 45 of 185 ms). On
/// the benchmark's and bench-quality's stacks the probes' means differ by 2.2–3.8 where the
/// defocus was mixed in display values, by 1.0–1.1 where in linear light (either way the light
/// all pairs choose), and by 0.31 on noisy 10 × 1.2 MP (all pairs: 0.33), where they do not
/// decide.
const PROBES: usize = 2;
const CLEAR: f64 = 0.75;

/// The blur fit: for every pair of a near label `k` and a farther frame `l`, the σ at which
/// frame `k` blurred best explains frame `l` over the interior of `k`'s region (deeper inside
/// than 3σ, so the background around the region does not enter), in both lights (or, once the
/// [`PROBES`] tell them apart, in the better one). Returns the light whose fits leave the
/// smaller residual (geometric mean of the residuals relative to frame `l`'s variance there)
/// and its pairs; `None` when nothing could be fitted. `lights` are the reduced frames' luma in
/// each light; on a tie the first is taken. `probes`: [`PROBES`], or `usize::MAX` to fit every
/// depth in both lights.
fn fit(
    lights: [(Light, Vec<Plane>); 2],
    masks: &[Plane],
    factor: usize,
    probes: usize,
    progress: &dyn Progress,
) -> (Option<Light>, Vec<Pair>) {
    let n = masks.len();
    // How deep inside its region each pixel lies: the distance from the pixels outside it.
    // Capped at 255 reduced pixels, far beyond the deepest margin a fit asks for (3σ at
    // `SIGMA_MAX`).
    let interiors: Vec<Vec<u8>> = masks
        .par_iter()
        .map(|m| {
            let outside: Vec<bool> = m.data.iter().map(|&a| a < 0.5).collect();
            distance(&outside, m.width, m.height, u8::MAX)
        })
        .collect();
    // Probes only among the depths two or more planes before the last: the others have no
    // farther frame to fit (they are still visited, for the progress count).
    let first = margin(SIGMA_MIN, factor);
    let fitted = n.saturating_sub(2);
    let mut depths: Vec<usize> = (0..n).collect();
    depths[..fitted].sort_by_cached_key(|&k| {
        std::cmp::Reverse(interiors[k].iter().filter(|&&d| d > first).count())
    });
    let (probed, rest) = depths.split_at(probes.min(fitted));
    let fit_depths = |lumas: &[Plane], depths: &[usize]| -> Vec<(Pair, f64)> {
        let mut fits: Vec<(Pair, f64)> = depths
            .par_iter()
            .flat_map_iter(|&k| {
                let far: Vec<usize> = (k + 2..n).collect();
                let fits = fit_near(k, &far, lumas, &interiors[k], factor);
                progress.advance(1);
                fits
            })
            .collect();
        fits.sort_by_key(|(p, _)| (p.near, p.far));
        fits
    };
    let score = |fits: &[(Pair, f64)]| {
        (!fits.is_empty())
            .then(|| fits.iter().map(|(_, r)| r.max(1e-12).ln()).sum::<f64>() / fits.len() as f64)
    };
    let [(light_a, lumas_a), (light_b, lumas_b)] = lights;
    let (mut a, mut b) = (fit_depths(&lumas_a, probed), fit_depths(&lumas_b, probed));
    let told = match (score(&a), score(&b)) {
        (Some(sa), Some(sb)) if (sa - sb).abs() > CLEAR => Some(sa <= sb),
        _ => None,
    };
    // Told apart, the rest are fitted in one light; their fits in the other still count as done.
    let (light, fits) = match told {
        Some(first_better) => {
            let (light, lumas, mut fits) = match first_better {
                true => (light_a, lumas_a, a),
                false => (light_b, lumas_b, b),
            };
            fits.extend(fit_depths(&lumas, rest));
            progress.advance(rest.len());
            (light, fits)
        }
        None => {
            a.extend(fit_depths(&lumas_a, rest));
            b.extend(fit_depths(&lumas_b, rest));
            match (score(&a), score(&b)) {
                (Some(sa), Some(sb)) if sb < sa => (light_b, b),
                (Some(_), _) => (light_a, a),
                (None, Some(_)) => (light_b, b),
                (None, None) => return (None, Vec::new()),
            }
        }
    };
    let pairs = fits.into_iter().map(|(p, _)| p).collect();
    (Some(light), with_predicted(monotone(pairs, n), n))
}

/// How far inside its region (reduced pixels) a fit at `sigma` (full-resolution pixels) reads:
/// 3σ, so the background around the region does not enter.
fn margin(sigma: f32, factor: usize) -> u8 {
    (3.0 * sigma / factor as f32).ceil() as u8
}

/// The fitted pairs with each σ raised to what its neighbours bound it by: through a lens, a
/// nearer object is blurred at least as much in the same farther frame, and an object at least
/// as much in a frame focused farther, so σ(k, l) ≥ σ(k + 1, l) and σ(k, l) ≥ σ(k, l − 1). A
/// fit that breaks this fell short, not its neighbour: a thin near object leaves its deeper
/// blurs too little interior, and the fit settles on the largest σ that still has some (the
/// 1600×1200 tripod's ruler, 4 px in every frame behind it against a true 4–9 px; raised,
/// 4–9.5 px, its band +0.07 dB).
fn monotone(mut pairs: Vec<Pair>, n: usize) -> Vec<Pair> {
    let mut sigma = vec![None; n * n];
    // Bounds come from a larger `near` and a smaller `far`: visit those first.
    pairs.sort_by_key(|p| (p.far, std::cmp::Reverse(p.near)));
    for p in &mut pairs {
        let (k, l) = (p.near as usize, p.far as usize);
        for bound in [sigma[(k + 1) * n + l], sigma[k * n + l - 1]]
            .into_iter()
            .flatten()
        {
            p.sigma = p.sigma.max(bound);
        }
        sigma[k * n + l] = Some(p.sigma);
    }
    pairs.sort_by_key(|p| (p.near, p.far));
    pairs
}

/// `fitted` and, for every near depth with at least one fitted pair (a near object whose
/// blur was measured), its farther pairs that could not be fitted, with the σ the stack's
/// focal axis predicts ([`focal_axis`]): the deepest blurs of a small object leave too little
/// interior to fit, yet spill the most.
fn with_predicted(fitted: Vec<Pair>, n: usize) -> Vec<Pair> {
    let measured: Vec<focal_axis::Measured> = fitted
        .iter()
        .map(|p| (p.near as usize, p.far as usize, p.sigma))
        .collect();
    let Some(phi) = focal_axis::positions(n, &measured) else {
        return fitted;
    };
    let mut near: Vec<usize> = measured.iter().map(|&(k, _, _)| k).collect();
    near.sort_unstable();
    near.dedup();
    let predicted: Vec<Pair> = near
        .into_iter()
        .flat_map(|k| (k + 2..n).map(move |l| (k, l)))
        .filter(|&(k, l)| !measured.iter().any(|&(a, b, _)| (a, b) == (k, l)))
        .filter_map(|(k, l)| {
            let sigma = phi[l] - phi[k];
            (sigma >= SIGMA_MIN).then(|| Pair {
                near: k as u8,
                far: l as u8,
                sigma: (2.0 * sigma.min(SIGMA_MAX)).round() / 2.0,
                predicted: true,
            })
        })
        .collect();
    fitted.into_iter().chain(predicted).collect()
}

/// Fits near depth `k`'s blur in each of the frames `far`, on a crop around its region's
/// interior: σ in 1 px steps, then ½ px either side of each pair's best. A pair whose best σ is
/// the largest tried (the fit ran off the grid) or whose region is too small is left out.
fn fit_near(
    k: usize,
    far: &[usize],
    lumas: &[Plane],
    inside: &[u8],
    factor: usize,
) -> Vec<(Pair, f64)> {
    let (rw, rh) = (lumas[k].width, lumas[k].height);
    let f = factor as f32;
    let first = margin(SIGMA_MIN, factor);
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in inside.iter().enumerate().filter(|(_, &d)| d > first) {
        let (x, y) = (i % rw, i / rw);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if x0 == usize::MAX || far.is_empty() {
        return Vec::new();
    }
    // Room for the widest kernel, so the crop's edges do not change the interior's blur.
    let pad = (3.0 * SIGMA_MAX / f).ceil() as usize + 1;
    let (x0, y0) = (x0.saturating_sub(pad), y0.saturating_sub(pad));
    let (x1, y1) = ((x1 + pad).min(rw - 1), (y1 + pad).min(rh - 1));
    let (cw, ch) = (x1 - x0 + 1, y1 - y0 + 1);
    let crop = |p: &[f32]| -> Vec<f32> {
        (y0..=y1)
            .flat_map(|y| p[y * rw + x0..=y * rw + x1].iter().copied())
            .collect()
    };
    let near = Plane::from_vec(cw, ch, 1, crop(&lumas[k].data));
    let depth_in: Vec<u8> = (y0..=y1)
        .flat_map(|y| inside[y * rw + x0..=y * rw + x1].iter().copied())
        .collect();
    // The interior deeper than a margin, as runs along rows (start in the crop, start in the
    // far frames, which are read in place, and length), and each far frame's variance there.
    // A fit tries some twenty σ but only a few margins, so these are kept per margin.
    struct Interior {
        runs: Vec<(usize, usize, usize)>,
        count: usize,
        var: Vec<f64>,
    }
    let interior = |m: u8| -> Interior {
        let mut runs = Vec::new();
        for (y, row) in depth_in.chunks_exact(cw).enumerate() {
            let mut x = 0;
            while x < cw {
                if row[x] <= m {
                    x += 1;
                    continue;
                }
                let len = row[x..].iter().take_while(|&&d| d > m).count();
                runs.push((y * cw + x, (y0 + y) * rw + x0 + x, len));
                x += len;
            }
        }
        let count = runs.iter().map(|r| r.2).sum();
        let var = far
            .iter()
            .map(|&l| {
                let v = &lumas[l].data;
                let values = || runs.iter().flat_map(|&(_, j, n)| &v[j..j + n]);
                let mean = values().map(|&x| x as f64).sum::<f64>() / count as f64;
                values().map(|&x| (x as f64 - mean).powi(2)).sum()
            })
            .collect();
        Interior { runs, count, var }
    };
    let mut interiors: Vec<Option<Interior>> = (0..=u8::MAX).map(|_| None).collect();
    // Each far frame's residual at `sigma`, relative to its variance over the interior: deeper
    // than 3σ, or where a small object has too little of that, than 1.5σ (the background's
    // light then enters the fit's edge a little). Without that second depth the main job's
    // nearest objects, 60-100 px across, were fitted only up to σ 6 px and their spill into
    // the frames focused 2-3 planes behind (σ 4-6) was never un-mixed.
    let mut residuals = |sigma: f32| -> Option<Vec<f64>> {
        let m = [margin(sigma, factor), margin(0.5 * sigma, factor)]
            .into_iter()
            .find(|&m| {
                let inner = interiors[m as usize].get_or_insert_with(|| interior(m));
                inner.count >= MIN_INTERIOR
            })?;
        let inner = interiors[m as usize].as_ref()?;
        let blurred = gaussian_blur(&near, sigma / f);
        Some(
            far.iter()
                .zip(&inner.var)
                .map(|(&l, &var)| {
                    let v = &lumas[l].data;
                    let err: f64 = inner
                        .runs
                        .iter()
                        .flat_map(|&(i, j, n)| blurred.data[i..i + n].iter().zip(&v[j..j + n]))
                        .map(|(&b, &x)| (b as f64 - x as f64).powi(2))
                        .sum();
                    err / var.max(1e-9 * inner.count as f64)
                })
                .collect(),
        )
    };
    // Coarse steps until every pair's residual has risen twice past its least.
    let mut coarse: Vec<(f32, Vec<f64>)> = Vec::new();
    let mut least: Vec<(usize, f64)> = vec![(0, f64::MAX); far.len()];
    for (i, s) in (0..)
        .map(|i| SIGMA_MIN + i as f32)
        .take_while(|&s| s <= SIGMA_MAX)
        .enumerate()
    {
        let Some(r) = residuals(s) else { break };
        for (l, &v) in least.iter_mut().zip(&r) {
            if v < l.1 {
                *l = (i, v);
            }
        }
        coarse.push((s, r));
        if least.iter().all(|&(at, _)| i >= at + 2) {
            break;
        }
    }
    let Some(largest) = coarse.last().map(|(s, _)| *s) else {
        return Vec::new();
    };
    let mut best: Vec<(f32, f64)> = (0..far.len())
        .map(|j| {
            coarse
                .iter()
                .map(|(s, r)| (*s, r[j]))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .expect("at least one σ")
        })
        .collect();
    let ran_off: Vec<bool> = best.iter().map(|&(s, _)| s >= largest).collect();
    let mut finer: Vec<f32> = best
        .iter()
        .flat_map(|&(s, _)| [s - 0.5, s + 0.5])
        .filter(|&s| s >= SIGMA_MIN && s < largest)
        .collect();
    finer.sort_by(f32::total_cmp);
    finer.dedup();
    for s in finer {
        let Some(r) = residuals(s) else { continue };
        for (j, b) in best.iter_mut().enumerate() {
            if (s - b.0).abs() <= 0.5 && r[j] < b.1 {
                *b = (s, r[j]);
            }
        }
    }
    far.iter()
        .zip(best)
        .zip(ran_off)
        .filter(|(_, off)| !off)
        .map(|((&l, (sigma, rel)), _)| {
            let pair = Pair {
                near: k as u8,
                far: l as u8,
                sigma,
                predicted: false,
            };
            (pair, rel)
        })
        .collect()
}

/// Near objects blurred alike in one far frame: the σ of their pairs (full-resolution pixels)
/// and their near depths. The blur is linear, so they are summed before they are blurred, once:
/// on a stack of many planes many pairs share a σ (the fit's ½ px steps, the focal axis's
/// predictions).
#[derive(Clone, PartialEq)]
struct Group {
    sigma: f32,
    near: Vec<u8>,
}

/// A [`Group`]'s near objects blurred: `G∗α` and `G∗(α·C)` per channel, in the mixing light.
struct Blurred {
    cover: Plane,
    colour: Vec<Plane>,
}

impl Blurred {
    fn of(mixed: &[Vec<Plane>], masks: &[Plane], g: &Group, factor: usize) -> Blurred {
        let (rw, rh) = (masks[0].width, masks[0].height);
        let s = g.sigma / factor as f32;
        let near = g.near.iter().map(|&k| k as usize);
        let mut a = Plane::new(rw, rh, 1);
        for k in near.clone() {
            add(&mut a, &masks[k]);
        }
        let colour = (0..mixed[0].len())
            .into_par_iter()
            .map(|c| {
                let mut ac = Plane::new(rw, rh, 1);
                for k in near.clone() {
                    let (v, m) = (&mixed[k][c].data, &masks[k].data);
                    for ((o, &v), &m) in ac.data.iter_mut().zip(v).zip(m) {
                        *o += v * m;
                    }
                }
                gaussian_blur(&ac, s)
            })
            .collect();
        Blurred {
            cover: gaussian_blur(&a, s),
            colour,
        }
    }
}

/// Each far frame's groups, blurred once each: the same near objects are often blurred alike
/// in several far frames (where the fit's σ plateaus, and wherever the focal axis predicts the
/// largest σ), so a group's blur is kept from its first far frame to its last. Flats 25 with 16
/// patches: 92 groups, 29 blurs; smooth 10 × 1.2 MP: 27 and 20 (6 and 3 kept at once). What
/// is kept stays within the planes the fit's luma in both lights took before (the memory
/// plan's `fit` term, [`working_bytes`]): at most `limit` blurs; beyond, a blur is made again.
struct Blurs {
    /// Per far frame, its groups by σ.
    groups: Vec<Vec<Group>>,
    kept: Vec<(Group, Rc<Blurred>)>,
    limit: usize,
}

impl Blurs {
    fn new(pairs: &[Pair], n: usize, channels: usize) -> Blurs {
        let groups = (0..n)
            .map(|l| {
                let mut mine: Vec<&Pair> = pairs.iter().filter(|p| p.far as usize == l).collect();
                mine.sort_by(|a, b| a.sigma.total_cmp(&b.sigma));
                mine.chunk_by(|a, b| a.sigma == b.sigma)
                    .map(|g| Group {
                        sigma: g[0].sigma,
                        near: g.iter().map(|p| p.near).collect(),
                    })
                    .collect()
            })
            .collect();
        Blurs {
            groups,
            kept: Vec::new(),
            limit: 2 * n / (channels + 1),
        }
    }

    /// Far frame `l`'s groups blurred (in σ order), far frames taken in order; a blur is
    /// dropped after the last far frame that has its group.
    fn of(
        &mut self,
        l: usize,
        mixed: &[Vec<Plane>],
        masks: &[Plane],
        factor: usize,
    ) -> Vec<Rc<Blurred>> {
        let later = |g: &Group| self.groups[l + 1..].iter().any(|gs| gs.contains(g));
        let mut out = Vec::with_capacity(self.groups[l].len());
        let mut kept = Vec::new();
        for g in &self.groups[l] {
            let b = match self.kept.iter().position(|(k, _)| k == g) {
                Some(i) => self.kept.swap_remove(i).1,
                None => Rc::new(Blurred::of(mixed, masks, g, factor)),
            };
            if later(g) && self.kept.len() + kept.len() < self.limit {
                kept.push((g.clone(), b.clone()));
            }
            out.push(b);
        }
        self.kept.extend(kept);
        out
    }
}

/// One far frame's spill at the reduced resolution: the near objects' blurred colour `G∗(α·C)`
/// per channel and their blurred coverage `G∗α`, in the mixing light.
struct Spill {
    colour: Vec<Plane>,
    cover: Plane,
    factor: usize,
}

impl Spill {
    /// The sum of a far frame's blurred groups, in σ order.
    fn sum(groups: &[Rc<Blurred>], factor: usize) -> Spill {
        let (rw, rh) = (groups[0].cover.width, groups[0].cover.height);
        let mut colour = vec![Plane::new(rw, rh, 1); groups[0].colour.len()];
        let mut cover = Plane::new(rw, rh, 1);
        for g in groups {
            add(&mut cover, &g.cover);
            for (acc, b) in colour.iter_mut().zip(&g.colour) {
                add(acc, b);
            }
        }
        Spill {
            colour,
            cover,
            factor,
        }
    }

    /// Un-mixes `frame` where the spill covers some of it and `guarded` does not keep it;
    /// returns the pixels changed.
    fn apply<T: Sample>(
        &self,
        frame: &mut Image<T>,
        guarded: &(dyn Fn(usize) -> bool + Sync),
        light: Light,
    ) -> usize {
        let (w, ch) = (frame.width, frame.channels);
        let (rw, rh) = (self.cover.width, self.cover.height);
        // Reduced pixels whose 2×2 block (what a bilinear sample there reads) holds any spill:
        // most of a frame holds none and is passed over without sampling.
        let spilt =
            |x: usize, y: usize| self.cover.data[y.min(rh - 1) * rw + x.min(rw - 1)] >= TRACE;
        let active: Vec<bool> = (0..rw * rh)
            .map(|i| {
                let (x, y) = (i % rw, i / rw);
                spilt(x, y) || spilt(x + 1, y) || spilt(x, y + 1) || spilt(x + 1, y + 1)
            })
            .collect();
        let cols = taps(w, self.factor, rw);
        let (mix, store) = (light.mixing(), light.storing());
        frame
            .data
            .par_chunks_mut(w * ch)
            .enumerate()
            .map(|(y, row)| {
                let ty = tap(y, self.factor, rh);
                let active = &active[ty.cell() * rw..][..rw];
                let mut changed = 0;
                for ((x, px), &tx) in row.chunks_exact_mut(ch).enumerate().zip(&cols) {
                    if !active[tx.cell()] {
                        continue;
                    }
                    let a = self.cover.sample_taps(tx, ty);
                    if a < TRACE || guarded(y * w + x) {
                        continue;
                    }
                    let keep = ((HIDDEN - a) / FADE).clamp(0.0, 1.0);
                    if keep == 0.0 {
                        continue;
                    }
                    for (c, v) in px.iter_mut().enumerate() {
                        let f = mix(v.to_f32() / T::MAX);
                        let s = self.colour[c].sample_taps(tx, ty);
                        let b = ((f - s) / (1.0 - a)).clamp(0.0, 1.0);
                        *v = T::from_f32(store(keep * b + (1.0 - keep) * f) * T::MAX);
                    }
                    changed += 1;
                }
                changed
            })
            .sum()
    }
}

/// The bilinear taps of full-resolution pixel `i`'s centre on an axis reduced by `factor` to
/// `reduced` pixels.
fn tap(i: usize, factor: usize, reduced: usize) -> Tap {
    Tap::new((i as f32 + 0.5) * (1.0 / factor as f32) - 0.5, reduced)
}

/// [`tap`] of each of `full` pixels: a frame's columns read the same taps on every row and in
/// every plane.
fn taps(full: usize, factor: usize, reduced: usize) -> Vec<Tap> {
    (0..full).map(|x| tap(x, factor, reduced)).collect()
}

fn add(acc: &mut Plane, b: &Plane) {
    acc.data.iter_mut().zip(&b.data).for_each(|(a, v)| *a += v);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::NoProgress;
    use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
    use std::sync::Mutex;

    const SIZE: usize = 160;
    const CENTRE: f32 = 80.0;
    const RADIUS: f32 = 40.0;

    /// A pair as the fit gives it.
    fn fitted(near: u8, far: u8, sigma: f32) -> Pair {
        Pair {
            near,
            far,
            sigma,
            predicted: false,
        }
    }

    /// A textured disc (the near object) over a textured background, seen by three frames:
    /// focused on the disc (the background blurred by 3 px), between (disc 2, background
    /// 1.5), and on the background (the disc blurred by 4 px over it), mixed in `light` and
    /// stored in sRGB-encoded 8 bits. Returns the frames and the sharp background.
    fn scene(light: Light) -> (Vec<Image<u8>>, Vec<Plane>) {
        scene_of(light, RADIUS, 4.0)
    }

    /// [`scene`] with a disc of `radius`, blurred by `blur` in the frame focused behind it.
    fn scene_of(light: Light, radius: f32, blur: f32) -> (Vec<Image<u8>>, Vec<Plane>) {
        let plane = |f: &dyn Fn(f32, f32) -> f32| {
            Plane::from_fn(SIZE, SIZE, 1, |x, y, _| f(x as f32, y as f32))
        };
        let alpha = plane(&|x, y| {
            let r = ((x - CENTRE).powi(2) + (y - CENTRE).powi(2)).sqrt();
            (radius + 0.5 - r).clamp(0.0, 1.0)
        });
        let stripes = |x: f32, y: f32, p: f32| 0.5 + 0.35 * ((x + 0.5 * y) * p).sin();
        let near: Vec<Plane> = [0.9, 0.3, 0.2]
            .iter()
            .map(|&c| plane(&|x, y| light.mixing()(c * stripes(x, y, 0.7))))
            .collect();
        let far: Vec<Plane> = [0.3, 0.5, 0.8]
            .iter()
            .map(|&c| plane(&|x, y| light.mixing()(c * stripes(y, -x, 0.45))))
            .collect();
        let frame = |near_sigma: f32, far_sigma: f32| {
            let a = gaussian_blur(&alpha, near_sigma);
            let planes: Vec<Plane> = near
                .iter()
                .zip(&far)
                .map(|(c, b)| {
                    let ac = Plane {
                        data: c.data.iter().zip(&alpha.data).map(|(v, m)| v * m).collect(),
                        ..*c
                    };
                    let (ac, b) = (gaussian_blur(&ac, near_sigma), gaussian_blur(b, far_sigma));
                    let data = (0..SIZE * SIZE)
                        .map(|i| light.storing()(ac.data[i] + (1.0 - a.data[i]) * b.data[i]))
                        .collect();
                    Plane::from_vec(SIZE, SIZE, 1, data)
                })
                .collect();
            Image::<u8>::from_planes(&planes)
        };
        let frames = vec![frame(0.0, 3.0), frame(blur / 2.0, 1.5), frame(blur, 0.0)];
        let background = far
            .iter()
            .map(|b| Plane {
                data: b.data.iter().map(|&v| light.storing()(v)).collect(),
                ..*b
            })
            .collect();
        (frames, background)
    }

    fn full(frames: usize) -> Vec<Coverage> {
        vec![Coverage::full(SIZE, SIZE); frames]
    }

    /// [`unmix`] on the whole of every frame, everything textured, without progress.
    fn unmix_in(frames: &mut [Image<u8>], labels: &mut [u8], order: Order) -> Unmixed {
        let n = frames.len();
        unmix_covered(frames, labels, &full(n), order)
    }

    /// [`unmix_in`] with each frame covering what `coverage` says.
    fn unmix_covered(
        frames: &mut [Image<u8>],
        labels: &mut [u8],
        coverage: &[Coverage],
        order: Order,
    ) -> Unmixed {
        unmix(
            frames,
            labels,
            &[true; SIZE * SIZE],
            coverage,
            order,
            &NoProgress,
        )
    }

    /// Pixel `i`'s three samples in `f`.
    fn pixel(f: &Image<u8>, i: usize) -> &[u8] {
        &f.data[i * 3..][..3]
    }

    fn distance(i: usize) -> f32 {
        let (x, y) = ((i % SIZE) as f32, (i / SIZE) as f32);
        ((x - CENTRE).powi(2) + (y - CENTRE).powi(2)).sqrt() - RADIUS
    }

    /// The disc labelled 0 exactly, to its edge pixel, and the rest 2.
    fn exact_labels() -> Vec<u8> {
        (0..SIZE * SIZE)
            .map(|i| if distance(i) < 0.5 { 0 } else { 2 })
            .collect()
    }

    /// The disc labelled 0 and the rest 2, as a label map that follows contrast gets them
    /// roughly: 3 px too wide on the left, 3 px too narrow on the right.
    fn labels() -> Vec<u8> {
        (0..SIZE * SIZE)
            .map(|i| {
                let shift = if i % SIZE < SIZE / 2 { 3.0 } else { -3.0 };
                if distance(i) < shift {
                    0
                } else {
                    2
                }
            })
            .collect()
    }

    /// RMS error of `frame` against `truth` over pixels 2–12 px outside the disc: the halo.
    fn halo(frame: &Image<u8>, truth: &[Plane]) -> f32 {
        halo_within(frame, truth, 2.0..12.0)
    }

    /// [`halo`] over the pixels whose distance outside the disc is in `ring`.
    fn halo_within(frame: &Image<u8>, truth: &[Plane], ring: std::ops::Range<f32>) -> f32 {
        let ring: Vec<usize> = (0..SIZE * SIZE)
            .filter(|&i| ring.contains(&distance(i)))
            .collect();
        let sum: f32 = ring
            .iter()
            .flat_map(|&i| (0..3).map(move |c| (i, c)))
            .map(|(i, c)| (frame.data[i * 3 + c] as f32 / 255.0 - truth[c].data[i]).powi(2))
            .sum();
        (sum / (ring.len() * 3) as f32).sqrt()
    }

    #[test]
    fn the_halo_is_taken_out_in_the_light_the_defocus_mixed_in() {
        for light in [Light::Linear, Light::Display] {
            let (mut frames, background) = scene(light);
            let before = frames.clone();
            let mut l = labels();
            let out = unmix_in(&mut frames, &mut l, Order::NearestFirst);
            assert_eq!(out.light, Some(light));
            let pair = out.pairs.iter().find(|p| (p.near, p.far) == (0, 2));
            let sigma = pair.expect("the disc's blur in frame 2 is fitted").sigma;
            assert!((sigma - 4.0).abs() <= 0.5, "{light:?}: σ {sigma}");
            let (was, now) = (halo(&before[2], &background), halo(&frames[2], &background));
            assert!(now < 0.6 * was, "{light:?}: halo RMS {was} -> {now}");
            // Far from the disc, and in the frames nothing spills into, nothing changes.
            let far_away = (0..SIZE * SIZE).filter(|&i| distance(i) > 30.0);
            assert!(far_away
                .into_iter()
                .all(|i| frames[2].data[i * 3] == before[2].data[i * 3]));
            assert_eq!((&frames[0], &frames[1]), (&before[0], &before[1]));
            // Of the right side's 3 px the labels missed, the pixels clearly the disc's colour go
            // back to its frame (the stripes make the rest too close to call); outside the disc
            // no label moves.
            let right = |i: usize| i % SIZE > SIZE / 2 + 8;
            let missed =
                (0..SIZE * SIZE).filter(|&i| right(i) && (-2.5..-0.5).contains(&distance(i)));
            let (moved, all) = missed.fold((0, 0), |(m, a), i| (m + usize::from(l[i] == 0), a + 1));
            assert!(moved * 3 >= all, "{light:?}: {moved} of {all} moved");
            let outside = (0..SIZE * SIZE).filter(|&i| right(i) && distance(i) > 1.0);
            assert!(
                outside.into_iter().all(|i| l[i] == 2),
                "{light:?}: a label moved outside"
            );
        }
    }

    /// With the disc labelled exactly: the pixel at its edge keeps its frame's colour (the
    /// guard), the one beyond is un-mixed already, where a 2 px guard left a rim of the disc's
    /// colour.
    #[test]
    fn only_the_pixel_at_the_edge_is_guarded() {
        let (mut frames, background) = scene_of(Light::Linear, RADIUS, 4.0);
        let before = frames.clone();
        let mut labels = exact_labels();
        unmix_in(&mut frames, &mut labels, Order::NearestFirst);
        let (was, now) = (
            halo_within(&before[2], &background, 2.0..3.0),
            halo_within(&frames[2], &background, 2.0..3.0),
        );
        assert!(now < 0.6 * was, "second pixel out: RMS {was} -> {now}");
        let edge = (0..SIZE * SIZE).filter(|&i| (0.5..0.9).contains(&distance(i)));
        assert!(edge
            .into_iter()
            .all(|i| pixel(&frames[2], i) == pixel(&before[2], i)));
    }

    /// Inside the disc's edge the frame focused behind it shows the disc's own pixels once
    /// un-mixed, not the disc defocused with the background through it; deeper in, and in the
    /// frame one plane behind, nothing is filled.
    #[test]
    fn the_near_object_s_edge_is_filled_into_the_frame_behind_it() {
        let (mut frames, _) = scene(Light::Linear);
        let before = frames.clone();
        let mut labels = exact_labels();
        let out = unmix_in(&mut frames, &mut labels, Order::NearestFirst);
        let edge: Vec<usize> = (0..SIZE * SIZE)
            .filter(|&i| (-5.0..-1.0).contains(&distance(i)))
            .collect();
        let own = edge
            .iter()
            .filter(|&&i| pixel(&frames[2], i) == pixel(&frames[0], i))
            .count();
        let was = edge
            .iter()
            .filter(|&&i| pixel(&before[2], i) == pixel(&frames[0], i))
            .count();
        assert!(
            own * 10 >= edge.len() * 9,
            "{own} of {} (was {was})",
            edge.len()
        );
        assert!(out.filled >= own, "{} filled", out.filled);
        let deep = (0..SIZE * SIZE).filter(|&i| distance(i) < -8.0);
        assert!(deep
            .into_iter()
            .all(|i| pixel(&frames[2], i) == pixel(&before[2], i)));
        assert_eq!(frames[1], before[1]);
    }

    /// Where a frame does not reach, a label may be the reference's for want of the frame the
    /// labelling chose, not for depth: nothing is filled there.
    #[test]
    fn nothing_is_filled_where_a_frame_does_not_reach() {
        let (mut frames, _) = scene(Light::Linear);
        let before = frames.clone();
        let mut labels = exact_labels();
        // Frame 1 misses the columns left of the disc's centre.
        let mut coverage = full(3);
        coverage[1].spans.fill((CENTRE as u32, SIZE as u32));
        let out = unmix_covered(&mut frames, &mut labels, &coverage, Order::NearestFirst);
        assert!(out.filled > 0);
        let left_edge = (0..SIZE * SIZE)
            .filter(|&i| (i % SIZE) < CENTRE as usize && (-5.0..-1.0).contains(&distance(i)));
        assert!(left_edge
            .into_iter()
            .all(|i| pixel(&frames[2], i) == pixel(&before[2], i)));
    }

    /// The same haloed scene with an order its edges did not tell: left exactly as it is, labels
    /// too, and the log says why.
    #[test]
    fn an_untold_order_leaves_the_frames_as_they_are() {
        let (mut frames, _) = scene(Light::Linear);
        let (before, mut l) = (frames.clone(), labels());
        let out = unmix_in(&mut frames, &mut l, Order::Unknown);
        assert_eq!(frames, before);
        assert_eq!(l, labels());
        assert!(out.untold && out.pairs.is_empty(), "{out:?}");
        assert!(out.to_string().contains("do not tell"), "{out}");
    }

    /// Records the stages announced and the steps advanced.
    #[derive(Default)]
    struct Steps {
        stages: Mutex<Vec<(Stage, usize)>>,
        done: AtomicUsize,
    }

    impl Progress for Steps {
        fn stage(&self, stage: Stage, total: usize) {
            self.stages.lock().unwrap().push((stage, total));
        }
        fn advance(&self, steps: usize) {
            self.done.fetch_add(steps, Relaxed);
        }
    }

    /// The daemon's watchdog fails a job whose progress stands still: the spill removal
    /// announces its own stage and advances through every step it announced.
    #[test]
    fn the_spill_removal_reports_its_progress_to_the_end() {
        let (mut frames, _) = scene(Light::Linear);
        let steps = Steps::default();
        let out = unmix(
            &mut frames,
            &mut labels(),
            &[true; SIZE * SIZE],
            &full(3),
            Order::NearestFirst,
            &steps,
        );
        assert!(!out.pairs.is_empty());
        let stages = steps.stages.into_inner().unwrap();
        assert_eq!(stages, [(Stage::Spill, 14)]);
        assert_eq!(steps.done.into_inner(), 14);
    }

    /// The main job's nearest object is fitted into the frames two and three planes behind it
    /// but is too small for the two farthest: those pairs are added with the σ the other
    /// pairs' focal axis gives (2 px a plane here); a near depth with nothing fitted gets none.
    #[test]
    fn the_pairs_too_small_to_fit_are_predicted_from_the_others() {
        let fitted = |near: u8, far: u8| fitted(near, far, 2.0 * f32::from(far - near));
        let pairs = vec![
            fitted(0, 2),
            fitted(0, 3),
            fitted(1, 3),
            fitted(1, 4),
            fitted(1, 5),
            fitted(2, 4),
            fitted(2, 5),
        ];
        let all = with_predicted(pairs.clone(), 6);
        assert_eq!(
            all[..pairs.len()],
            pairs[..],
            "the fitted pairs are kept as they are"
        );
        let added: Vec<(u8, u8, f32)> = all[pairs.len()..]
            .iter()
            .map(|p| {
                assert!(p.predicted);
                (p.near, p.far, p.sigma)
            })
            .collect();
        // Depth 3 has no fitted pair, so (3, 5) is not added.
        assert_eq!(added, [(0, 4, 8.0), (0, 5, 10.0)]);
    }

    /// The tripod's ruler: fitted at 4 px in every frame behind it, while the object behind
    /// it (depth 1) is blurred more in the same frames. Each σ is raised to its bound; pairs
    /// already in order are kept.
    #[test]
    fn a_fit_short_of_its_neighbours_is_raised_to_them() {
        let pairs = vec![
            fitted(0, 2, 4.0),
            fitted(0, 3, 4.0),
            fitted(0, 4, 4.0),
            fitted(1, 3, 4.5),
            fitted(1, 4, 6.5),
            fitted(2, 4, 3.0),
        ];
        let raised: Vec<(u8, u8, f32)> = monotone(pairs, 5)
            .iter()
            .map(|p| (p.near, p.far, p.sigma))
            .collect();
        assert_eq!(
            raised,
            [
                (0, 2, 4.0),
                (0, 3, 4.5),
                (0, 4, 6.5),
                (1, 3, 4.5),
                (1, 4, 6.5),
                (2, 4, 3.0)
            ]
        );
    }

    /// A disc 24 px in radius blurred by 7 px behind: deeper than 3σ it has no interior to fit
    /// on, deeper than 1.5σ enough. Its spill is still fitted and un-mixed.
    #[test]
    fn a_small_object_s_deep_blur_is_still_fitted() {
        let (radius, blur) = (24.0, 7.0);
        let (mut frames, _) = scene_of(Light::Linear, radius, blur);
        let mut labels: Vec<u8> = (0..SIZE * SIZE)
            .map(|i| u8::from(distance(i) + RADIUS > radius) * 2)
            .collect();
        let out = unmix_in(&mut frames, &mut labels, Order::NearestFirst);
        let fitted: Vec<(u8, u8, f32)> =
            out.pairs.iter().map(|p| (p.near, p.far, p.sigma)).collect();
        assert!(
            matches!(fitted[..], [(0, 2, s)] if (s - blur).abs() <= 1.0),
            "{fitted:?}"
        );
        assert!(out.changed[2] > 0, "{out:?}");
    }

    /// Five textured discs side by side, one per depth 0–4, over a background (depth 5), seen
    /// by six frames each focused on one depth (disc k blurred by 1.5·|l − k| px in frame l),
    /// mixed in `light`: each frame's luma in both lights, and the depths' masks.
    fn discs(light: Light) -> ([(Light, Vec<Plane>); 2], Vec<Plane>) {
        let (w, h) = (400, 80);
        let mix = light.mixing();
        let plane =
            |f: &dyn Fn(f32, f32) -> f32| Plane::from_fn(w, h, 1, |x, y, _| f(x as f32, y as f32));
        let alpha: Vec<Plane> = (0..5)
            .map(|k| {
                plane(&|x, y| (30.5 - (x - 40.0 - 80.0 * k as f32).hypot(y - 40.0)).clamp(0.0, 1.0))
            })
            .collect();
        let texture = |x: f32, y: f32, k: f32| mix(0.5 + 0.35 * ((x + 0.5 * y) * 0.7 + k).sin());
        let frames: Vec<Plane> = (0..6)
            .map(|l| {
                let mut acc =
                    gaussian_blur(&plane(&|x, y| texture(y, -x, 9.0)), 1.5 * (5 - l) as f32);
                for (k, a) in alpha.iter().enumerate() {
                    let s = 1.5 * (l as f32 - k as f32).abs();
                    let ac = plane(&|x, y| {
                        a.data[y as usize * w + x as usize] * texture(x, y, k as f32)
                    });
                    let (a, ac) = (gaussian_blur(a, s), gaussian_blur(&ac, s));
                    for ((v, a), c) in acc.data.iter_mut().zip(&a.data).zip(&ac.data) {
                        *v = c + (1.0 - a) * *v;
                    }
                }
                acc.data.iter_mut().for_each(|v| *v = light.storing()(*v));
                acc
            })
            .collect();
        let lumas = |light: Light| {
            frames
                .iter()
                .map(|f| luma(std::slice::from_ref(f), light))
                .collect()
        };
        let behind = plane(&|x, y| {
            1.0 - alpha
                .iter()
                .map(|a| a.data[y as usize * w + x as usize])
                .sum::<f32>()
        });
        let masks = alpha.into_iter().chain([behind]).collect();
        (
            [
                (Light::Linear, lumas(Light::Linear)),
                (Light::Display, lumas(Light::Display)),
            ],
            masks,
        )
    }

    #[test]
    fn the_light_told_by_the_probes_gives_what_every_depth_fitted_in_both_gives() {
        for light in [Light::Linear, Light::Display] {
            let (lights, masks) = discs(light);
            let probed = fit(lights.clone(), &masks, 1, PROBES, &NoProgress);
            let every = fit(lights, &masks, 1, usize::MAX, &NoProgress);
            assert_eq!(probed.0, Some(light));
            assert!(
                probed.1.iter().filter(|p| !p.predicted).count() >= 4,
                "{probed:?}"
            );
            assert_eq!(probed, every);
        }
    }

    #[test]
    fn a_stack_given_farthest_first_is_un_mixed_the_same() {
        let (frames, _) = scene(Light::Linear);
        let (mut forward, mut fl) = (frames.clone(), labels());
        unmix_in(&mut forward, &mut fl, Order::NearestFirst);
        let mut reversed: Vec<Image<u8>> = frames.into_iter().rev().collect();
        let mut rl: Vec<u8> = labels().iter().map(|&l| 2 - l).collect();
        let out = unmix_in(&mut reversed, &mut rl, Order::FarthestFirst);
        assert_eq!(reversed[0], forward[2]);
        assert!(rl.iter().zip(&fl).all(|(&r, &f)| r == 2 - f));
        assert!(out.pairs.iter().all(|p| (p.near, p.far) == (2, 0)));
    }

    /// The spill of near objects sharing a σ, summed before one blur, is the sum of each
    /// one's own blurred spill (to float rounding).
    #[test]
    fn pairs_sharing_a_blur_are_blurred_once_to_the_same_spill() {
        let (w, h) = (48, 40);
        let plane = |seed: usize| {
            Plane::from_fn(w, h, 1, |x, y, _| {
                ((x * 7 + y * 13 + seed * 31) % 17) as f32 / 16.0
            })
        };
        let masks: Vec<Plane> = (0..5).map(|k| plane(k + 10)).collect();
        let mixed: Vec<Vec<Plane>> = (0..5)
            .map(|k| (0..3).map(|c| plane(3 * k + c)).collect())
            .collect();
        // Near depths 0 and 2 share σ 6 px in far frame 3 and again in far frame 4.
        let pairs = [
            fitted(0, 3, 6.0),
            fitted(1, 3, 4.0),
            fitted(2, 3, 6.0),
            fitted(0, 4, 6.0),
            fitted(1, 4, 5.0),
            fitted(2, 4, 6.0),
        ];
        let factor = 2;
        let mut blurs = Blurs::new(&pairs, 5, 3);
        let mut spills = Vec::new();
        for l in 0..5 {
            let groups = blurs.of(l, &mixed, &masks, factor);
            assert_eq!(groups.len(), [0, 0, 0, 2, 2][l]);
            if l == 3 {
                // Blurred once, kept for far frame 4, and the same blur given there.
                assert_eq!(blurs.kept.len(), 1);
                assert!(Rc::ptr_eq(&blurs.kept[0].1, &groups[1]));
            }
            if !groups.is_empty() {
                spills.push((l, Spill::sum(&groups, factor)));
            }
        }
        assert!(blurs.kept.is_empty());
        // Each far frame's spill is the sum of its pairs' spills, each pair blurred alone.
        let alone = |p: &Pair| {
            let g = Group {
                sigma: p.sigma,
                near: vec![p.near],
            };
            Spill::sum(&[Rc::new(Blurred::of(&mixed, &masks, &g, factor))], factor)
        };
        let close = |got: &Plane, want: Vec<f32>| {
            got.data
                .iter()
                .zip(want)
                .all(|(g, w)| (g - w).abs() <= 1e-5 * w.abs().max(1.0))
        };
        for (l, spill) in &spills {
            let parts: Vec<Spill> = pairs
                .iter()
                .filter(|p| p.far as usize == *l)
                .map(alone)
                .collect();
            let sum = |f: &dyn Fn(&Spill) -> &Plane| -> Vec<f32> {
                (0..w * h)
                    .map(|i| parts.iter().map(|s| f(s).data[i]).sum())
                    .collect()
            };
            assert!(close(&spill.cover, sum(&|s| &s.cover)), "far frame {l}");
            for c in 0..3 {
                assert!(
                    close(&spill.colour[c], sum(&|s| &s.colour[c])),
                    "far frame {l}, channel {c}"
                );
            }
            assert!(spill.cover.data.iter().any(|&a| a > 0.1));
        }
        // With room for none, nothing is kept: the shared group is blurred again.
        let mut tight = Blurs::new(&pairs, 5, 3);
        tight.limit = 0;
        for l in 0..5 {
            tight.of(l, &mixed, &masks, factor);
            assert!(tight.kept.is_empty());
        }
    }

    #[test]
    fn without_a_step_two_planes_deep_nothing_changes() {
        let (frames, _) = scene(Light::Linear);
        // Two frames, and three whose labels are all one plane.
        for (mut f, mut l) in [
            (
                frames[1..].to_vec(),
                labels().iter().map(|&l| l / 2).collect::<Vec<u8>>(),
            ),
            (frames.clone(), vec![1; SIZE * SIZE]),
        ] {
            let (before, labels_before) = (f.clone(), l.clone());
            let cover = full(f.len());
            let out = unmix(
                &mut f,
                &mut l,
                &[true; SIZE * SIZE],
                &cover,
                Order::NearestFirst,
                &NoProgress,
            );
            assert_eq!((out.light, out.changed.iter().sum::<usize>()), (None, 0));
            assert_eq!((f, l), (before, labels_before));
        }
    }
}
