//! Sub-pixel refinement of a frame's affine by dense, robust Lucas–Kanade against the reference.
//!
//! Keypoints alone leave ~0.5–1 px of error on defocused frames (few, blurred blobs); the dense
//! fit uses every textured pixel. It is inverse compositional (the reference is the template, so
//! its gradients are computed once and shared by all frames) with a gain and an offset (frames
//! differ in exposure), coarse to fine. On the finest level the two images are equalised in
//! defocus ([`super::equalise`], the pairing judged on the level above) and compared only so,
//! chiefly where the frame is the sharper one ([`BLURRIER`]), on every other pixel
//! ([`STRIDE`]); a Huber weight limits the pull of whatever still disagrees (occlusion edges,
//! parallax of near objects).

use super::equalise::{self, Stack};
use super::levels::{from_level, to_level, Levels};
use crate::stack::image::Plane;
use crate::stack::transform::Affine;
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

/// Parameters: 6 affine (about the level's centre, in pixels at the half-size), gain, offset.
const N: usize = 8;
/// Weight of the finest level's pixels where the frame is blurrier than the reference (the
/// equalisation blurs the reference there). A frame is fused only where it is sharp, so its
/// affine is fitted chiefly there; under parallax it then follows the depth the frame is focused
/// on rather than an average of every depth. Lower weights follow parallax better but pin the
/// affine less well where nothing moves; 0.2 balances the two, and parallax is the normal case
/// of a hand-held phone.
const BLURRIER: f32 = 0.2;
/// Huber threshold in robust standard deviations of the residual.
const HUBER: f32 = 1.5;
/// The finest level's Gauss–Newton steps sample every `STRIDE`-th pixel of every `STRIDE`-th
/// row: its gradients keep that level's precision at a quarter of the cost.
const STRIDE: usize = 2;

/// A template image with its gradients (central differences, zero on the border).
pub(super) struct View {
    pub width: usize,
    pub height: usize,
    pub t: Vec<f32>,
    pub gx: Vec<f32>,
    pub gy: Vec<f32>,
}

impl View {
    fn new(p: &Plane) -> View {
        View::from_layers(std::slice::from_ref(p), |_| 0)
    }

    /// Per pixel, the value and gradients of the layer `pick` selects: computed here rather
    /// than held for every layer, which cost 12 bytes a pixel of the level per layer.
    pub fn select(layers: &[Plane], pick: &[(u8, u8)]) -> View {
        View::from_layers(layers, |i| pick[i].0 as usize)
    }

    /// Per pixel `i`, the value and central differences of `layers[layer(i)]` there.
    fn from_layers(layers: &[Plane], layer: impl Fn(usize) -> usize + Sync) -> View {
        let (w, h) = (layers[0].width(), layers[0].height());
        let mut v = View {
            width: w,
            height: h,
            t: vec![0.0; w * h],
            gx: vec![0.0; w * h],
            gy: vec![0.0; w * h],
        };
        (
            v.t.par_chunks_mut(w),
            v.gx.par_chunks_mut(w),
            v.gy.par_chunks_mut(w),
        )
            .into_par_iter()
            .enumerate()
            .for_each(|(y, (t, gx, gy))| {
                for x in 0..w {
                    let i = y * w + x;
                    let p = layers[layer(i)].data();
                    t[x] = p[i];
                    if x > 0 && x + 1 < w && y > 0 && y + 1 < h {
                        gx[x] = (p[i + 1] - p[i - 1]) / 2.0;
                        gy[x] = (p[i + w] - p[i - w]) / 2.0;
                    }
                }
            });
        v
    }
}

/// The reference's levels, shared by every frame's refinement; the finest also blurred by each
/// of the equalisation sigmas.
pub struct Template {
    /// Levels from the finest (`first`) up.
    pub(super) levels: Vec<View>,
    pub(super) first: usize,
    pub(super) stack: Stack,
    /// The level above the finest, blurred by each equalisation sigma: where the defocus
    /// pairing is judged (`None` when the pyramid has no level above).
    pub(super) coarse: Option<Stack>,
}

impl Template {
    pub fn new(reference: &Levels, finest: usize, coarsest: usize) -> Template {
        let levels = (finest..=coarsest.min(reference.last()))
            .map(|k| View::new(reference.get(k)))
            .collect();
        let stack = Stack::new(reference.get(finest));
        let coarse = (reference.last() > finest).then(|| Stack::new(reference.get(finest + 1)));
        Template {
            levels,
            first: finest,
            stack,
            coarse,
        }
    }
}

/// The outcome of refining one frame.
#[derive(Clone, Copy, Debug)]
pub struct Refined {
    pub affine: Affine,
    /// Normalised cross-correlation of the aligned frame with the reference on the finest level.
    pub correlation: f64,
}

/// The state of the fit on one level: the warp in level pixels and the photometric correction
/// (frame ≈ gain · reference + offset).
struct Fit {
    w: Affine,
    gain: f32,
    offset: f32,
    correlation: f64,
}

/// What a worker's refinements keep from one frame to the next: the blur stacks of the finest
/// level and the one above, and the Gauss–Newton steps' buffers, each the same size for every
/// frame of a stack: made afresh for every frame they cost page faults and kernel time. The
/// planes compared with the template are not kept: held through the finest level's steps they
/// would raise the fuse's peak memory for little time saved.
#[derive(Default)]
pub struct Buffers {
    stack: Stack,
    up: Stack,
    scratch: Scratch,
}

/// Refines `init` (reference → frame, full-resolution pixels), coarse to fine, at most
/// `iterations` Gauss–Newton steps per level and round.
pub fn refine(
    tpl: &Template,
    frame: &Levels,
    init: Affine,
    iterations: usize,
    buffers: &mut Buffers,
) -> Refined {
    let mut fit = Fit {
        w: init,
        gain: 1.0,
        offset: 0.0,
        correlation: f64::NAN,
    };
    for (i, view) in tpl.levels.iter().enumerate().rev() {
        let k = tpl.first + i;
        fit.w = to_level(&fit.w, k);
        if i > 0 {
            let img = std::slice::from_ref(frame.get(k));
            iterate(
                view,
                img,
                None,
                &mut fit,
                iterations,
                1,
                &mut buffers.scratch,
            );
        } else {
            // Only equalised: the coarser levels' fit is close enough to judge defocus on, and a
            // plain pass here, or a second round, cost 35 % more time for 0.01 px less error
            // (1600×1200 layered stacks, linear light).
            let Buffers { stack, up, scratch } = buffers;
            stack.fill(frame.get(k));
            let cs = &mut scratch.cs;
            let pick = match &tpl.coarse {
                Some(coarse) => {
                    up.fill(frame.get(k + 1));
                    let t = &coarse.layers[0];
                    let w1 = to_level(&from_level(&fit.w, k), k + 1);
                    cs.remap(&w1, t.width(), t.height(), &up.layers[0], 1);
                    let warped = warp_stack(up, cs, fit.gain, fit.offset);
                    let p1 = equalise::choose(coarse, &warped);
                    equalise::finer(&p1, t.width(), t.height(), view.width, view.height)
                }
                None => {
                    cs.remap(&fit.w, view.width, view.height, &stack.layers[0], 1);
                    let warped = warp_stack(stack, cs, fit.gain, fit.offset);
                    equalise::choose(&tpl.stack, &warped)
                }
            };
            let eq = View::select(&tpl.stack.layers, &pick);
            iterate(
                &eq,
                &stack.layers,
                Some(&pick),
                &mut fit,
                iterations,
                STRIDE,
                scratch,
            );
        }
        fit.w = from_level(&fit.w, k);
    }
    Refined {
        affine: fit.w,
        correlation: fit.correlation,
    }
}

/// Gauss–Newton steps until one moves no corner by more than a hundredth of a pixel.
fn iterate(
    view: &View,
    frame: &[Plane],
    pick: Option<&[(u8, u8)]>,
    fit: &mut Fit,
    iterations: usize,
    stride: usize,
    scratch: &mut Scratch,
) {
    let mut scale = None;
    for _ in 0..iterations {
        let Some((dw, dgain, doff)) =
            gauss_newton(view, frame, pick, fit, &mut scale, stride, scratch)
        else {
            break;
        };
        let Some(inv) = dw.inverse() else { break };
        fit.w = fit.w.compose(&inv);
        fit.gain += dgain;
        fit.offset += doff;
        if dw.corner_error(&Affine::IDENTITY, view.width, view.height) < 0.01 {
            break;
        }
    }
}

/// Where each template pixel of a lattice lands in a frame: the top-left source pixel and the
/// bilinear weights, computed once per warp and shared by every layer sampled through it. Held
/// for the lattice's points only: the finest level's steps sample every other pixel of every
/// other row, and maps of the whole template there were three quarters unused.
#[derive(Default)]
pub(super) struct Coords {
    /// Per lattice point, `u32::MAX` where it falls outside the frame (or on the template's
    /// border).
    idx: Vec<u32>,
    fx: Vec<f32>,
    fy: Vec<f32>,
    /// Frame row length.
    stride: usize,
    /// Lattice points across and down: the template's size at a step of 1.
    width: usize,
    height: usize,
}

impl Coords {
    /// Where `w` sends the template pixels on a lattice of `stride` (every `stride`-th pixel of
    /// every `stride`-th row), in `self`'s buffers: a refinement maps the template anew at
    /// every Gauss–Newton step, and fresh buffers each step were about 30 % of the page faults
    /// of registering a layered 8 × 1.9 MP stack.
    fn remap(&mut self, w: &Affine, tw: usize, th: usize, frame: &Plane, stride: usize) {
        self.map_every(stride, tw, th, frame, |x, y| w.apply(x, y));
    }

    fn map_every(
        &mut self,
        stride: usize,
        tw: usize,
        th: usize,
        frame: &Plane,
        map: impl Fn(f64, f64) -> (f64, f64) + Sync,
    ) {
        let (lw, lh) = (tw.div_ceil(stride), th.div_ceil(stride));
        let n = lw * lh;
        for v in [&mut self.fx, &mut self.fy] {
            v.clear();
            v.resize(n, 0.0);
        }
        self.idx.clear();
        self.idx.resize(n, u32::MAX);
        (self.stride, self.width, self.height) = (frame.width(), lw, lh);
        // Each row written in place: rows made apart and joined were copied twice over.
        self.idx
            .par_chunks_mut(lw.max(1))
            .zip(self.fx.par_chunks_mut(lw.max(1)))
            .zip(self.fy.par_chunks_mut(lw.max(1)))
            .enumerate()
            .map(|(ly, row)| (ly * stride, row))
            .filter(|&(y, _)| y != 0 && y + 1 != th)
            .for_each(|(y, ((idx, fx), fy))| {
                // The template's border maps nothing.
                for lx in (1..lw).take_while(|&lx| lx * stride + 1 < tw) {
                    if let Some((k, u, v)) = locate(map((lx * stride) as f64, y as f64), frame) {
                        (idx[lx], fx[lx], fy[lx]) = (k as u32, u, v);
                    }
                }
            });
    }

    /// Bilinear sample of `p` for lattice point `i`, None outside.
    #[inline]
    pub fn sample(&self, p: &Plane, i: usize) -> Option<f32> {
        let k = self.idx[i];
        if k == u32::MAX {
            return None;
        }
        Some(bilinear(
            p.data(),
            self.stride,
            k as usize,
            self.fx[i],
            self.fy[i],
        ))
    }
}

/// Where a point (u, v) lies in `frame`: the index of the top-left of its four source pixels and
/// its offsets from it; None outside the frame.
#[inline(always)]
fn locate((u, v): (f64, f64), frame: &Plane) -> Option<(usize, f32, f32)> {
    let (iw, ih) = (frame.width() as f32 - 1.0, frame.height() as f32 - 1.0);
    let (u, v) = (u as f32, v as f32);
    (u >= 0.0 && v >= 0.0 && u < iw && v < ih).then(|| {
        // Truncation floors a non-negative coordinate, without `floor`'s library call
        // (baseline x86-64 has no rounding instruction).
        let (x0, y0) = (u as usize, v as usize);
        (y0 * frame.width() + x0, u - x0 as f32, v - y0 as f32)
    })
}

/// Bilinear sample of `d` (rows of `stride`) at offsets (fx, fy) from its sample `k`.
#[inline(always)]
fn bilinear(d: &[f32], stride: usize, k: usize, fx: f32, fy: f32) -> f32 {
    let top = d[k] + fx * (d[k + 1] - d[k]);
    let bot = d[k + stride] + fx * (d[k + stride + 1] - d[k + stride]);
    top + fy * (bot - top)
}

/// `frame` sampled where `map` sends each pixel (x, y) of a `tw`×`th` template, NaN outside the
/// frame and on the template's border: what [`Coords`] maps and samples, in one pass that holds
/// no map (a plane warped once needs none).
pub fn resample(
    tw: usize,
    th: usize,
    frame: &Plane,
    map: impl Fn(f64, f64) -> (f64, f64) + Sync,
) -> Vec<f32> {
    (0..tw * th)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % tw, i / tw);
            let inner = x != 0 && y != 0 && x + 1 < tw && y + 1 < th;
            let at = inner
                .then(|| locate(map(x as f64, y as f64), frame))
                .flatten();
            at.map_or(f32::NAN, |(k, fx, fy)| {
                bilinear(frame.data(), frame.width(), k, fx, fy)
            })
        })
        .collect()
}

/// Each layer of the frame's stack resampled onto the template through `cs` and corrected for
/// gain and offset; NaN outside the frame.
fn warp_stack(stack: &Stack, cs: &Coords, gain: f32, offset: f32) -> Vec<Plane> {
    let (w, h) = (cs.width, cs.height);
    stack
        .layers
        .par_iter()
        .map(|l| {
            let data = (0..w * h)
                .map(|i| cs.sample(l, i).map_or(f32::NAN, |v| (v - offset) / gain))
                .collect();
            Plane::from_vec(w, h, 1, data)
        })
        .collect()
}

/// The buffers a level's Gauss–Newton steps reuse (see [`Coords::remap`]).
#[derive(Default)]
struct Scratch {
    cs: Coords,
    resid: Vec<f32>,
    valid: Vec<f32>,
}

/// One robust Gauss–Newton step: the increment warp, gain and offset changes; None when too
/// little of the frame overlaps or the system is singular. Updates the fit's correlation.
/// `pick`: per template pixel, the defocus pairing ([`equalise::choose`]): the frame's plane
/// to sample, and the pixel's weight, [`BLURRIER`] where the template is the one blurred
/// (None: the first plane, all weighing alike).
fn gauss_newton(
    view: &View,
    frame: &[Plane],
    pick: Option<&[(u8, u8)]>,
    fit: &mut Fit,
    scale: &mut Option<f32>,
    stride: usize,
    scratch: &mut Scratch,
) -> Option<(Affine, f32, f32)> {
    let (tw, th) = (view.width, view.height);
    let (gain, offset) = (fit.gain, fit.offset);
    // Residuals of the current warp, NaN outside the frame and on the template's border.
    let Scratch { cs, resid, valid } = scratch;
    cs.remap(&fit.w, tw, th, &frame[0], stride);
    // Per lattice point, `lw` across: lattice point (lx, ly) is template pixel
    // (lx, ly) · `stride`.
    let lw = cs.width;
    resid.resize(cs.width * cs.height, 0.0);
    resid.par_chunks_mut(lw).enumerate().for_each(|(ly, row)| {
        for (lx, r) in row.iter_mut().enumerate() {
            let (j, i) = (ly * lw + lx, (ly * tw + lx) * stride);
            let img = &frame[pick.map_or(0, |p| p[i].1 as usize)];
            *r = cs
                .sample(img, j)
                .map_or(f32::NAN, |v| v - gain * view.t[i] - offset);
        }
    });
    valid.clear();
    valid.extend(resid.iter().filter(|r| !r.is_nan()).map(|r| r.abs()));
    if valid.len() < 64 || valid.len() * 4 * stride * stride < tw * th {
        return None;
    }
    // Robust scale: fixed after the first step so the weights, and with them the minimised
    // cost, do not shift between steps.
    let s = *scale.get_or_insert_with(|| {
        let mid = valid.len() / 2;
        1.4826 * *valid.select_nth_unstable_by(mid, f32::total_cmp).1 + 1e-6
    });
    let (cx, cy) = ((tw as f32 - 1.0) / 2.0, (th as f32 - 1.0) / 2.0);
    let half = tw.max(th) as f32 / 2.0;
    let (h, b, c) = (0..cs.height)
        .into_par_iter()
        .map(|ly| {
            // Sums over the row kept in `LANES` lanes, each lane a point of a block of that
            // many: the normal equations' 44 products a point become vector multiply-adds.
            // Summed a point at a time they were most of a step's time.
            let mut h = [[[0.0f32; LANES]; N]; N];
            let mut b = [[0.0f32; LANES]; N];
            let mut c = [[0.0f32; LANES]; 6];
            let ny = ((ly * stride) as f32 - cy) / half;
            for lx0 in (0..lw).step_by(LANES) {
                // Per lane: the Jacobian row, its weight and the residual; zero where the
                // point lies outside the frame or past the row's end.
                let mut j = [[0.0f32; LANES]; N];
                let (mut wt, mut e, mut f, mut inside) =
                    ([0.0f32; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
                for k in (0..LANES).take_while(|&k| lx0 + k < lw) {
                    let lx = lx0 + k;
                    let (x, i) = (lx * stride, (ly * tw + lx) * stride);
                    let r = resid[ly * lw + lx];
                    if r.is_nan() {
                        continue;
                    }
                    let t = view.t[i];
                    let huber = r.abs() / s;
                    let w = if huber <= HUBER { 1.0 } else { HUBER / huber };
                    wt[k] = match pick.map(|p| p[i].0) {
                        Some(template) if template > 0 => w * BLURRIER,
                        _ => w,
                    };
                    let (gx, gy) = (view.gx[i] * gain, view.gy[i] * gain);
                    let nx = (x as f32 - cx) / half;
                    for (a, v) in [nx * gx, ny * gx, gx, nx * gy, ny * gy, gy, t, 1.0]
                        .into_iter()
                        .enumerate()
                    {
                        j[a][k] = v;
                    }
                    (e[k], f[k], inside[k]) = (r, r + gain * t + offset, 1.0);
                }
                for a in 0..N {
                    let ja: [f32; LANES] = std::array::from_fn(|k| wt[k] * j[a][k]);
                    lanes_add(&mut b[a], &ja, &e);
                    for bb in a..N {
                        lanes_add(&mut h[a][bb], &ja, &j[bb]);
                    }
                }
                let t = &j[6];
                for (acc, (p, q)) in c.iter_mut().zip([
                    (&inside, &inside),
                    (&inside, t),
                    (&inside, &f),
                    (t, t),
                    (&f, &f),
                    (t, &f),
                ]) {
                    lanes_add(acc, p, q);
                }
            }
            let sum = |l: &[f32; LANES]| l.iter().map(|&v| f64::from(v)).sum::<f64>();
            (
                h.map(|r| r.map(|l| sum(&l))),
                b.map(|l| sum(&l)),
                c.map(|l| sum(&l)),
            )
        })
        .reduce(
            || ([[0.0; N]; N], [0.0; N], [0.0; 6]),
            |mut x, y| {
                for a in 0..N {
                    x.1[a] += y.1[a];
                    for bb in 0..N {
                        x.0[a][bb] += y.0[a][bb];
                    }
                }
                x.2.iter_mut().zip(y.2).for_each(|(p, q)| *p += q);
                x
            },
        );
    fit.correlation = ncc(&c);
    let d = solve(SMatrix::from(h), b.into())?;
    // The increment about the centre, in level pixels.
    let (cx, cy, hf) = (cx as f64, cy as f64, half as f64);
    let (a0, a1, a3, a4) = (d[0] / hf, d[1] / hf, d[3] / hf, d[4] / hf);
    let dw = Affine([
        [1.0 + a0, a1, d[2] - a0 * cx - a1 * cy],
        [a3, 1.0 + a4, d[5] - a3 * cx - a4 * cy],
    ]);
    Some((dw, d[6] as f32, d[7] as f32))
}

/// Points of a Gauss–Newton step summed together, one vector lane each (eight: two SSE
/// registers on baseline x86-64, two NEON ones on arm64).
const LANES: usize = 8;

/// `acc[k] += p[k] · q[k]` for every lane.
#[inline(always)]
fn lanes_add(acc: &mut [f32; LANES], p: &[f32; LANES], q: &[f32; LANES]) {
    for ((a, p), q) in acc.iter_mut().zip(p).zip(q) {
        *a += p * q;
    }
}

/// Normalised cross-correlation from the sums [n, Σt, Σf, Σt², Σf², Σtf].
fn ncc(c: &[f64; 6]) -> f64 {
    let [n, st, sf, stt, sff, stf] = *c;
    let var = (stt - st * st / n) * (sff - sf * sf / n);
    if var > 0.0 {
        (stf - st * sf / n) / var.sqrt()
    } else {
        0.0
    }
}

/// Cholesky solve of the normal equations, their lower triangle given (the upper triangle of
/// `h`'s rows, read as columns); None unless positive definite by a margin: a pivot below
/// 1e-12 of its diagonal entry is rank deficiency that rounding kept from reaching zero.
fn solve(h: SMatrix<f64, N, N>, b: SVector<f64, N>) -> Option<SVector<f64, N>> {
    let chol = h.cholesky()?;
    let pivots = chol.l_dirty().diagonal();
    if pivots
        .iter()
        .zip(h.diagonal().iter())
        .any(|(l, d)| l * l <= 1e-12 * d.abs().max(1e-30))
    {
        return None;
    }
    Some(chol.solve(&b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_small_affine_with_gain() {
        let tex = |x: f64, y: f64| {
            (0.5 + 0.2 * (x * 0.21).sin() * (y * 0.17).cos() + 0.1 * (x * 0.05 + y * 0.08).sin())
                as f32
        };
        let truth = Affine::similarity(1.01, 0.01, (48.0, 40.0), (1.3, -0.7));
        let reference = Plane::from_fn(96, 80, 1, |x, y, _| tex(x as f64, y as f64));
        let inv = truth.inverse().unwrap();
        let frame = Plane::from_fn(96, 80, 1, |x, y, _| {
            let (u, v) = inv.apply(x as f64, y as f64);
            1.05 * tex(u, v) + 0.01
        });
        let tpl = Template::new(&Levels::build(&reference, 0, 1), 0, 1);
        let frame = Levels::build(&frame, 0, 1);
        let r = refine(&tpl, &frame, Affine::IDENTITY, 20, &mut Buffers::default());
        assert!(r.affine.corner_error(&truth, 96, 80) < 0.02, "{r:?}");
        assert!(r.correlation > 0.99);
    }
}
