//! The spill synthesis: each far frame's spill `G∗(α·C)` and coverage `G∗α` built from the near
//! objects and their fitted blurs, and the un-mixing of the frame by it.

use super::add;
use super::blur_fit::Pair;
use super::light::Light;
use crate::stack::blur::gaussian_blur;
use crate::stack::image::{Image, Plane, Sample, Tap};
use rayon::prelude::*;
use std::rc::Rc;

/// The background is taken as too deeply hidden where the near object's spill covers more than
/// this share of it: the un-mixing fades out over [`FADE`] below it.
pub(super) const HIDDEN: f32 = 0.7;
const FADE: f32 = 0.2;
/// Spill coverage below this changes nothing.
const TRACE: f32 = 0.01;

/// Near objects blurred alike in one far frame: the σ of their pairs (full-resolution pixels)
/// and their near depths. The blur is linear, so they are summed before they are blurred, once:
/// on a stack of many planes many pairs share a σ (the fit's ½ px steps, the focal axis's
/// predictions).
#[derive(Clone, PartialEq)]
pub(super) struct Group {
    pub(super) sigma: f32,
    pub(super) near: Vec<u8>,
}

/// A [`Group`]'s near objects blurred: `G∗α` and `G∗(α·C)` per channel, in the mixing light.
pub(super) struct Blurred {
    pub(super) cover: Plane,
    pub(super) colour: Vec<Plane>,
}

impl Blurred {
    pub(super) fn of(mixed: &[Vec<Plane>], masks: &[Plane], g: &Group, factor: usize) -> Blurred {
        let (rw, rh) = (masks[0].width(), masks[0].height());
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
                    let (v, m) = (mixed[k][c].data(), masks[k].data());
                    for ((o, &v), &m) in ac.data_mut().iter_mut().zip(v).zip(m) {
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
/// largest σ), so a group's blur is kept from its first far frame to its last. What is kept stays within the planes the fit's luma in both lights took before (the memory
/// plan's `fit` term, [`working_bytes`]): at most `limit` blurs; beyond, a blur is made again.
pub(super) struct Blurs {
    /// Per far frame, its groups by σ.
    groups: Vec<Vec<Group>>,
    pub(super) kept: Vec<(Group, Rc<Blurred>)>,
    pub(super) limit: usize,
}

impl Blurs {
    pub(super) fn new(pairs: &[Pair], n: usize, channels: usize) -> Blurs {
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
    pub(super) fn of(
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
pub(super) struct Spill {
    pub(super) colour: Vec<Plane>,
    pub(super) cover: Plane,
    factor: usize,
}

impl Spill {
    /// The sum of a far frame's blurred groups, in σ order.
    pub(super) fn sum(groups: &[Rc<Blurred>], factor: usize) -> Spill {
        let (rw, rh) = (groups[0].cover.width(), groups[0].cover.height());
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
    pub(super) fn apply<T: Sample>(
        &self,
        frame: &mut Image<T>,
        guarded: &(dyn Fn(usize) -> bool + Sync),
        light: Light,
    ) -> usize {
        let (w, ch) = (frame.width(), frame.channels());
        let (rw, rh) = (self.cover.width(), self.cover.height());
        // Reduced pixels whose 2×2 block (what a bilinear sample there reads) holds any spill:
        // most of a frame holds none and is passed over without sampling.
        let spilt =
            |x: usize, y: usize| self.cover.data()[y.min(rh - 1) * rw + x.min(rw - 1)] >= TRACE;
        let active: Vec<bool> = (0..rw * rh)
            .map(|i| {
                let (x, y) = (i % rw, i / rw);
                spilt(x, y) || spilt(x + 1, y) || spilt(x, y + 1) || spilt(x + 1, y + 1)
            })
            .collect();
        let cols = Tap::all_reduced(w, self.factor, rw);
        let (mix, store) = (light.mixing(), light.storing());
        frame
            .data_mut()
            .par_chunks_mut(w * ch)
            .enumerate()
            .map(|(y, row)| {
                let ty = Tap::reduced(y, self.factor, rh);
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
