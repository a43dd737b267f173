//! Local registration: a dense displacement field on top of each frame's global affine, for what
//! one affine cannot model, chiefly near objects moving against the background by parallax in a
//! hand-held sweep (several pixels on a phone macro shot).
//!
//! A frame only contributes where it is sharp, and the reference is blurred exactly where the
//! far frames are sharp, so a frame is not matched against the reference but against its
//! neighbour towards it, which shares most of its blur; the fields are chained outwards from the
//! reference. Each pair is matched by coarse-to-fine windowed Lucas–Kanade flow on high-passed
//! planes (which drops exposure offsets and the low frequencies defocus changes most), on a
//! reduced pyramid level, both frames first warped by their global affines. The window lets the
//! field follow a near object rather than a smooth average over the frame; a ridge relative to
//! the window's texture keeps the coarser level's estimate where there is no texture to measure.
//!
//! Neighbouring frames also differ by defocus, which a flow mistakes for motion (a fraction of a
//! pixel on textured ground, several pixels at a dark occluder under strong defocus); on a tripod
//! stack that costs more than parallax gains. So each pair's flow is kept only where it removes a
//! clear share of the residual ([`trust`]), and the chained field only where some pair of the
//! chain surely moved: where its flow also removes a clear share of the residual a change of
//! defocus leaves (the sharper frame blurred). Per-pair parallax a change of defocus could
//! explain still adds up along the chain where a nearer pair moved surely; displacements under
//! half a pixel are dropped ([`DEAD`]), and a field whose displacements stay below
//! [`MIN_MOTION_PX`] is dropped whole: on a stack without parallax the affine stands alone, and
//! the output is what it was without local registration.
//!
//! Texture finer than the working level can hold reaches it attenuated, and a change of its
//! defocus between neighbours, or its aliases, which move and change with a sub-pixel shift,
//! the flow reads as motion and the trust test passes. Where the next finer level is at hand,
//! a frame's field is held to a wider dead zone where such texture dominates it ([`FINE`]), and
//! dropped where the working level itself is aliased there ([`ALIASED`]).
//!
//! Memory: the planes are the registration's own detection level; a side of the stack keeps one
//! high-passed pyramid and one chained flow at a time; each field is 8 bytes per level pixel.

use super::equalise::box_sums;
use super::levels::to_level;
use super::refine::resample;
use crate::stack::blur::gaussian_blur;
use crate::stack::image::Plane;
use crate::stack::pyramid::{expand, reduce};
use crate::stack::transform::{rank, Affine, OffsetField};
use rayon::prelude::*;
use std::sync::{Arc, OnceLock};

/// High-pass: each pyramid level minus its Gaussian blur of this σ (level pixels): keeps the
/// texture that locates a shift, drops exposure offsets and the low frequencies defocus changes.
const HIGH_PASS: f32 = 2.0;
/// Half-width of the Lucas–Kanade window (level pixels), pooled by two box passes (a tent of
/// σ ≈ 10): wide enough to see texture across most of a near object, so the flow is not led by
/// noise; narrower windows (σ 3–6) wandered by half a pixel on parallax-free stacks.
const WINDOW: usize = 12;
/// Pyramid levels of the flow below the working level: each handles about a pixel of motion, so
/// two reach 4 working-level pixels (16 full-resolution pixels at level 2).
const LEVELS: usize = 2;
/// Lucas–Kanade iterations per level, at most.
const ITERATIONS: usize = 8;
/// A level's iterations stop early once fewer than `SETTLED.1` of its pixels still moved by
/// `SETTLED.0` level pixels or more in the last step. On stacks without local motion most pairs
/// settle in one or two steps of the eight; where parallax moves a near object its pixels keep
/// moving and the level runs on. As accurate as always running eight, and faster; four fixed
/// steps instead lose accuracy where a near object moves (tests/register.rs).
const SETTLED: (f32, f32) = (0.02, 0.01);
/// Ridge on the increment, relative to the mean gradient energy of the pair: a window with the
/// average texture moves a quarter as far as its data says per step, one with little hardly
/// at all.
const RIDGE: f32 = 3.0;
/// The flow must remove at least this share of the windowed residual to be trusted at all, and
/// twice it to be trusted fully (see [`trust`]).
const EXPLAINED: f32 = 0.25;
/// Blurs (working-level σ, px) either frame of a pair may take to explain their difference as a
/// change of defocus before a flow is trusted (see [`trust`]): a ladder from a fraction of a
/// pixel to the strongest defocus change between neighbouring frames.
const DEFOCUS: [f32; 4] = [0.7, 1.4, 2.8, 5.6];
/// Local displacements up to `DEAD.0` full-resolution pixels are dropped and those beyond
/// `DEAD.1` kept whole (a ramp between): blur differences between neighbours fake motion of
/// a fraction of a pixel, which costs a tripod stack more than it gains.
const DEAD: (f32, f32) = (0.5, 1.0);
/// A field whose [`PERCENTILE`] displacement (full-resolution pixels) is below this is
/// dropped: the affine stands alone, and the output is what it was without local registration.
const MIN_MOTION_PX: f64 = 0.3;
/// The share of a field's pixels [`MIN_MOTION_PX`] is measured at.
const PERCENTILE: f64 = 0.99;
/// Texture too fine for the working level dominates a frame where its energy in the finer
/// level's Laplacian band, pooled over the window, exceeds this multiple of its pooled
/// high-passed energy at the working level. Ordinary sharp texture, its energy spread over the
/// octaves, reaches a few; a checkerboard at the working level's Nyquist limit tens to
/// hundreds; a near object's fine grain, whose outline the flow follows truly, also several.
const FINE: f32 = 2.0;
/// Where fine texture dominates, the dead zone is this many times [`DEAD`]: a change of its
/// defocus fakes motion of about a pixel (seed 25 of the 6 px parallax stacks:
/// a far frame's field of 1 px over fine dots that do not move), while parallax that matters
/// moves a near object by more (seed 23: its finely grained near object by 3 px).
const WIDE: f32 = 2.0;
/// Where fine texture dominates, the frame keeps no field where the working level is aliased:
/// its high-passed plane minus its reduction's expanded carries more than this multiple of its
/// own energy (pooled), which only aliases made by the reduction add (a checkerboard near the
/// working level's Nyquist limit reads 2–2.6; fine grain and dots 0.5–1.0). There the flow's
/// coarser levels start from aliases.
const ALIASED: f32 = 1.2;

/// A displacement per pixel of a working-level grid, in working-level pixels: reference content
/// at (x, y) appears at (x + dx, y + dy) in the frame warped by its global affine.
#[derive(Clone)]
struct Flow {
    width: usize,
    height: usize,
    dx: Vec<f32>,
    dy: Vec<f32>,
}

impl Flow {
    fn zero(width: usize, height: usize) -> Flow {
        Flow {
            width,
            height,
            dx: vec![0.0; width * height],
            dy: vec![0.0; width * height],
        }
    }

    /// Bilinear sample at (x, y), clamped to the grid.
    fn at(&self, x: f32, y: f32) -> (f32, f32) {
        let (w, h) = (self.width, self.height);
        let x = x.clamp(0.0, (w - 1) as f32);
        let y = y.clamp(0.0, (h - 1) as f32);
        let (x0, y0) = (
            (x as usize).min(w.saturating_sub(2)),
            (y as usize).min(h.saturating_sub(2)),
        );
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let s = |v: &[f32]| {
            let top = v[y0 * w + x0] * (1.0 - fx) + v[y0 * w + x1] * fx;
            let bot = v[y1 * w + x0] * (1.0 - fx) + v[y1 * w + x1] * fx;
            top * (1.0 - fy) + bot * fy
        };
        (s(&self.dx), s(&self.dy))
    }

    /// `self` followed by `next`: where reference content lands in frame j (`self`), then where
    /// frame j's content lands in frame i (`next`).
    fn chain(&self, next: &Flow) -> Flow {
        let w = self.width;
        let (dx, dy): (Vec<f32>, Vec<f32>) = (0..w * self.height)
            .into_par_iter()
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let (ax, ay) = (self.dx[i], self.dy[i]);
                let (bx, by) = next.at(x + ax, y + ay);
                (ax + bx, ay + by)
            })
            .unzip();
        Flow { dx, dy, ..*self }
    }

    /// Twice the size and the displacement: the next finer level's start.
    fn expand_to(&self, w: usize, h: usize) -> Flow {
        let up = |v: &[f32]| {
            let p = Plane::from_vec(self.width, self.height, 1, v.to_vec());
            let mut e = expand(&p, w, h).into_data();
            e.iter_mut().for_each(|v| *v *= 2.0);
            e
        };
        Flow {
            width: w,
            height: h,
            dx: up(&self.dx),
            dy: up(&self.dy),
        }
    }
}

/// A frame's level plane warped onto the reference's grid by its affine (level coordinates),
/// NaN outside the frame; and, where the next finer level is at hand, what the
/// [`unrepresented`] energy is made from, made only for a frame that may keep a field.
pub struct Warped<'a> {
    plane: Plane,
    /// The frame at the next finer level and at this one, and the level affine.
    finer: Option<(&'a Plane, &'a Plane, Affine)>,
}

impl<'a> Warped<'a> {
    /// `plane` is the frame at pyramid level `k`, `finer` the frame at level `k − 1` where kept
    /// (`plane` its reduction), `ref_to_frame` its full-resolution affine.
    pub fn new(
        plane: &'a Plane,
        finer: Option<&'a Plane>,
        ref_to_frame: &Affine,
        k: usize,
    ) -> Warped<'a> {
        let a = to_level(ref_to_frame, k);
        Warped {
            plane: warp_level(plane, &a),
            finer: finer.map(|f| (f, plane, a)),
        }
    }

    /// The [`unrepresented`] energy per level pixel, warped as the plane is.
    fn unrepresented(&self) -> Option<Plane> {
        let (fine, coarse, a) = self.finer?;
        Some(warp_level(&unrepresented(fine, coarse), &a))
    }
}

/// `p` (a level plane) resampled onto the reference's grid through the level affine `a`.
fn warp_level(p: &Plane, a: &Affine) -> Plane {
    let (w, h) = (p.width(), p.height());
    Plane::from_vec(w, h, 1, resample(w, h, p, |x, y| a.apply(x, y)))
}

/// Per pixel of `coarse` (the reduction of `fine`), the mean squared Laplacian band of `fine`
/// (`fine` minus `coarse` expanded) over the 2×2 pixels it covers: texture too fine for
/// `coarse`, which holds it only attenuated and aliased.
fn unrepresented(fine: &Plane, coarse: &Plane) -> Plane {
    let (fw, fh) = (fine.width(), fine.height());
    let w = coarse.width();
    let up = expand(coarse, fw, fh);
    let (f, u) = (fine.data(), up.data());
    let data = (0..w * coarse.height())
        .into_par_iter()
        .map(|i| {
            let (x, y) = (2 * (i % w), 2 * (i / w));
            let (mut sum, mut n) = (0.0, 0.0);
            for (x, y) in [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)] {
                if x < fw && y < fh {
                    let e = f[y * fw + x] - u[y * fw + x];
                    (sum, n) = (sum + e * e, n + 1.0);
                }
            }
            sum / n
        })
        .collect();
    Plane::from_vec(w, coarse.height(), 1, data)
}

/// Where `p` is defined (1, else 0), and `p` with NaN (outside the frame) as 0: filtered
/// alike, their ratio is the filter of the defined pixels alone.
fn masked(p: &Plane) -> (Plane, Plane) {
    let valid = p.data().iter().map(|v| if v.is_nan() { 0.0 } else { 1.0 });
    let valid = Plane::from_vec(p.width(), p.height(), 1, valid.collect());
    (valid, filled(p))
}

/// `p` with NaN (outside the frame) as 0.
fn filled(p: &Plane) -> Plane {
    let data = p.data().iter().map(|&v| if v.is_nan() { 0.0 } else { v });
    Plane::from_vec(p.width(), p.height(), 1, data.collect())
}

/// `p` minus its blur; NaN (outside the frame) stays NaN and does not leak into the blur.
fn high_pass(p: &Plane) -> Plane {
    let (valid, filled) = masked(p);
    let (bv, bf) = (
        gaussian_blur(&valid, HIGH_PASS),
        gaussian_blur(&filled, HIGH_PASS),
    );
    let data = p
        .data()
        .iter()
        .zip(bv.data().iter().zip(bf.data()))
        .map(|(v, (n, s))| if *n > 1e-3 { v - s / n } else { f32::NAN })
        .collect();
    Plane::from_vec(p.width(), p.height(), 1, data)
}

/// A plane's high-passed pyramid, the working level first, up to [`LEVELS`] reduced ones: what
/// [`flow`] matches; and its working level blurred by each rung of [`DEFOCUS`] and its pooled
/// energy, what [`trust`] compares against, each made the first time a pair needs it. Made once
/// per frame: a frame is the far side of one pair of the chain and the near side of the next,
/// and the reference's levels serve both sides' chains (each side makes its own ladder, as its
/// pairs need it).
struct Pyramid {
    levels: Arc<Vec<Plane>>,
    ladder: [OnceLock<Plane>; DEFOCUS.len()],
    energy: OnceLock<Vec<f32>>,
}

impl Pyramid {
    fn new(p: &Plane) -> Pyramid {
        let mut levels = vec![p.clone()];
        for _ in 0..LEVELS {
            let last = levels.last().expect("level");
            if last.width().min(last.height()) < 32 {
                break;
            }
            let reduced = reduce_nan(last);
            levels.push(reduced);
        }
        Pyramid::with_levels(Arc::new(levels.iter().map(high_pass).collect()))
    }

    fn with_levels(levels: Arc<Vec<Plane>>) -> Pyramid {
        Pyramid {
            levels,
            ladder: Default::default(),
            energy: OnceLock::new(),
        }
    }

    /// The working level blurred by rung `k` of [`DEFOCUS`].
    fn rung(&self, k: usize) -> &Plane {
        self.ladder[k].get_or_init(|| blur_nan(&self.levels[0], DEFOCUS[k]))
    }

    /// The working level's high-passed energy pooled over the window: where a frame is the
    /// sharper of a pair, its energy is the larger.
    fn energy(&self) -> &[f32] {
        self.energy.get_or_init(|| {
            let p = &self.levels[0];
            let data: Vec<f32> = p
                .data()
                .iter()
                .map(|v| if v.is_nan() { 0.0 } else { v * v })
                .collect();
            pool(&data, p.width(), p.height())
        })
    }

    /// The working level's high-passed plane minus the next level's expanded, squared and
    /// pooled: at most about the working level's [`Pyramid::energy`] where the reduction holds
    /// only what the working level does, more where it adds aliases. Zero without a next level.
    fn aliases(&self) -> Vec<f32> {
        let p = &self.levels[0];
        let (w, h) = (p.width(), p.height());
        let Some(next) = self.levels.get(1) else {
            return vec![0.0; w * h];
        };
        let up = expand(&filled(next), w, h);
        let data: Vec<f32> = p
            .data()
            .iter()
            .zip(up.data())
            .map(|(v, u)| if v.is_nan() { 0.0 } else { (v - u) * (v - u) })
            .collect();
        pool(&data, w, h)
    }
}

/// The chain of local fields of one side of the reference: call [`Chain::next`] with each frame
/// in order outwards from the reference; only the last frame's pyramid and flow are kept, and
/// the pyramids of the pairs whose defocus ladder is still to run.
pub struct Chain {
    prev: Arc<Pyramid>,
    flow: Flow,
    /// Per pixel, the most any pair of the chain so far was surely moved there (see [`trust`]),
    /// of the pairs whose ladder has run.
    sure: Vec<f32>,
    /// The pairs whose ladder has not run yet: no field has needed it so far.
    pending: Vec<Trust>,
    /// Per pixel, at least the most any pair of the chain so far was surely moved there: `sure`
    /// raised by the pending pairs' [`Trust::bound`].
    bound: Vec<f32>,
    /// Pyramid level the planes are at.
    level: usize,
}

impl Chain {
    /// The chains of the two sides of the reference, both starting at its level plane (not
    /// warped), whose pyramid they share.
    pub fn both(reference: &Plane, level: usize) -> [Chain; 2] {
        let start = Pyramid::new(&Warped::new(reference, None, &Affine::IDENTITY, 0).plane);
        let (w, h) = (reference.width(), reference.height());
        [0, 1].map(|_| Chain {
            prev: Arc::new(Pyramid::with_levels(Arc::clone(&start.levels))),
            flow: Flow::zero(w, h),
            sure: vec![0.0; w * h],
            pending: Vec::new(),
            bound: vec![0.0; w * h],
            level,
        })
    }

    /// The offset field of the next frame outwards (`ref_to_frame` its global affine, full
    /// resolution), or None where it stays within [`MIN_MOTION_PX`] of the affine.
    pub fn next(&mut self, frame: Warped, ref_to_frame: &Affine) -> Option<OffsetField> {
        let next = Arc::new(Pyramid::new(&frame.plane));
        let (d, trust) = flow(&self.prev, &next);
        self.flow = self.flow.chain(&d);
        trust.bound(&mut self.bound);
        self.pending.push(trust);
        self.prev = next;
        let s = (1u64 << self.level) as f32;
        // Too few pixels move beyond the dead zone even as sure as they can be: the field is
        // dropped whatever the ladders say, and they wait for a frame whose field needs them
        // (on a stack without parallax, most never run).
        if !self.may_move(s) {
            return None;
        }
        for trust in self.pending.drain(..) {
            let sure = trust.sure();
            self.sure
                .iter_mut()
                .zip(&sure)
                .for_each(|(s, n)| *s = s.max(*n));
        }
        self.bound.clone_from(&self.sure);
        // No pair of the chain surely moved anywhere yet: every offset is zero (on a stack
        // without parallax, every frame's).
        if self.sure.iter().all(|&s| s == 0.0) {
            return None;
        }
        // Per pixel, how much wider than `DEAD` this frame's dead zone is: 1, [`WIDE`] where
        // its texture is too fine for the working level, 0 (no field) where the working level
        // is also aliased there (the chain's flow and sureness go on unchanged for the frames
        // beyond).
        let widen = frame.unrepresented().map(|u| {
            let energy = self.prev.energy();
            let fine: Vec<bool> = pool(filled(&u).data(), u.width(), u.height())
                .iter()
                .zip(energy)
                .map(|(u, e)| *u > FINE * e)
                .collect();
            let aliases = fine.contains(&true).then(|| self.prev.aliases());
            fine.iter()
                .enumerate()
                .map(|(i, &fine)| match &aliases {
                    Some(a) if fine && a[i] > ALIASED * energy[i] => 0.0,
                    Some(_) if fine => WIDE,
                    _ => 1.0,
                })
                .collect::<Vec<f32>>()
        });
        // Frame point = A(x + g) = A(x) + L·g for the affine's linear part L.
        let [[l00, l01, _], [l10, l11, _]] = ref_to_frame.0;
        let (l00, l01, l10, l11) = (l00 as f32, l01 as f32, l10 as f32, l11 as f32);
        let offsets = self
            .flow
            .dx
            .iter()
            .zip(&self.flow.dy)
            .zip(&self.sure)
            .enumerate()
            .map(|(i, ((&x, &y), &sure))| {
                let m = widen.as_ref().map_or(1.0, |v| v[i]);
                let (x, y) = (s * sure * x, s * sure * y);
                let k = if m > 0.0 {
                    ((x.hypot(y) - m * DEAD.0) / (m * (DEAD.1 - DEAD.0))).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let (x, y) = (k * x, k * y);
                (l00 * x + l01 * y, l10 * x + l11 * y)
            })
            .collect();
        let field = OffsetField {
            step: s as f64,
            cols: self.flow.width,
            rows: self.flow.height,
            offsets,
        };
        (field.reach(PERCENTILE) >= MIN_MOTION_PX).then_some(field)
    }

    /// Whether the field could reach [`MIN_MOTION_PX`], sureness at its `bound`: not when at
    /// most the share beyond [`PERCENTILE`] of its pixels are moved beyond the narrowest dead
    /// zone, [`DEAD`]`.0` (`s` full-resolution pixels a level pixel). Offsets within it are
    /// dropped, and they only shrink as sureness falls: the field is then dropped whatever the
    /// ladders say. Computed as the field is, so a NaN or infinite displacement counts as
    /// beyond.
    fn may_move(&self, s: f32) -> bool {
        let (f, n) = (&self.flow, self.bound.len());
        let beyond = (0..n)
            .filter(|&i| {
                let (b, x, y) = (self.bound[i], f.dx[i], f.dy[i]);
                // Sureness 0 leaves a finite displacement at 0.
                if b == 0.0 && x.is_finite() && y.is_finite() {
                    return false;
                }
                let d = (s * b * x).hypot(s * b * y);
                d > DEAD.0 || d.is_nan()
            })
            .count();
        // The percentile is 0 where no more pixels are beyond than sort above it, nor than
        // sort below it (NaNs may sort below 0).
        let k = rank(n, PERCENTILE);
        beyond > (n - 1 - k).min(k)
    }
}

/// Coarse-to-fine windowed Lucas–Kanade flow taking `a`'s content to where it shows in `b`
/// (pyramids of one size), kept only where [`trust`] keeps it, and the trust test's rest.
fn flow(a: &Arc<Pyramid>, b: &Arc<Pyramid>) -> (Flow, Trust) {
    let (pa, pb) = (&a.levels, &b.levels);
    let top = pa.len() - 1;
    let mut f = Flow::zero(pa[top].width(), pa[top].height());
    for k in (0..=top).rev() {
        if k < top {
            f = f.expand_to(pa[k].width(), pa[k].height());
        }
        let t = Tensor::new(&pa[k]);
        let n = pa[k].width() * pa[k].height();
        let mut scratch = [vec![0.0; n], vec![0.0; n]];
        for _ in 0..ITERATIONS {
            if lucas_kanade_step(&pa[k], &pb[k], &t, &mut f, &mut scratch) < SETTLED.1 {
                break;
            }
        }
    }
    let trust = trust(a, b, &mut f);
    (f, trust)
}

/// Keeps the flow only where it explains the pair clearly better than no local motion (the
/// windowed squared residual through the flow against that through the affine alone), and
/// returns what tells where the pair surely moved ([`Trust::sure`]): where the flow also
/// explains it clearly better than a change of defocus, the least residual through the affine
/// alone with the locally sharper frame (more high-passed energy in the window) blurred by any
/// of [`DEFOCUS`]. A change of defocus between neighbours moves an edge's profile, which a flow
/// reads as motion; against the frames as they are that flow wins, against the sharper frame
/// blurred as the other is it does not. Blurring the blurrier frame is no model of defocus and
/// would also explain parallax away. Each frame comes with its ladder, as [`Pyramid`] holds it.
fn trust(pa: &Arc<Pyramid>, pb: &Arc<Pyramid>, f: &mut Flow) -> Trust {
    let (a, b) = (&pa.levels[0], &pb.levels[0]);
    let (plain, moved) = rayon::join(|| residual(a, b, None), || residual(a, b, Some(&*f)));
    let kept: Vec<f32> = plain
        .par_iter()
        .zip(&moved)
        .map(|(e0, e1)| weight(*e0, *e1))
        .collect();
    // Where the flow is not kept, the pair's sureness is 0 whatever the rungs, the least
    // residual being at most the plain one (NaN weights do not count as 0).
    let at: Vec<usize> = (0..kept.len()).filter(|&i| kept[i] != 0.0).collect();
    f.dx.par_iter_mut()
        .zip(f.dy.par_iter_mut())
        .zip(&kept)
        .for_each(|((dx, dy), k)| {
            *dx *= k;
            *dy *= k;
        });
    Trust {
        pa: Arc::clone(pa),
        pb: Arc::clone(pb),
        least: at.iter().map(|&i| plain[i]).collect(),
        moved: at.iter().map(|&i| moved[i]).collect(),
        at,
    }
}

/// The share of the residual `e0` the flow removes (leaving `e1`), mapped to a weight 0..1; it
/// falls as `e0` does.
fn weight(e0: f32, e1: f32) -> f32 {
    let removed = if e0 > 0.0 { 1.0 - e1 / e0 } else { 0.0 };
    ((removed - EXPLAINED) / EXPLAINED).clamp(0.0, 1.0)
}

/// `b` (through the flow `f`, if given) minus `a`, squared and pooled over the window; NaN
/// (outside a frame) counts 0.
fn residual(a: &Plane, b: &Plane, f: Option<&Flow>) -> Vec<f32> {
    let (w, h) = (a.width(), a.height());
    let squared = |v: f32, a: f32| {
        let e = v - a;
        if e.is_nan() {
            0.0
        } else {
            e * e
        }
    };
    let data: Vec<f32> = if let Some(f) = f {
        let b = Bilinear::new(b);
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                squared(b.at(x + f.dx[i], y + f.dy[i]), a.data()[i])
            })
            .collect()
    } else {
        b.data()
            .par_iter()
            .zip(a.data())
            .map(|(&v, &a)| squared(v, a))
            .collect()
    };
    pool(&data, w, h)
}

/// A pair's trust test before its defocus ladder: the pixels where the flow is kept, and there
/// the least residual without it so far and the residual through it. The ladder, which only
/// lowers the least residual and so the weight, runs when a field needs it.
struct Trust {
    pa: Arc<Pyramid>,
    pb: Arc<Pyramid>,
    at: Vec<usize>,
    least: Vec<f32>,
    moved: Vec<f32>,
}

impl Trust {
    /// Raises `bound` to at least where the pair could surely have moved: the weight before the
    /// ladder (1 where NaN).
    fn bound(&self, bound: &mut [f32]) {
        for ((&i, &l), &m) in self.at.iter().zip(&self.least).zip(&self.moved) {
            let w = weight(l, m);
            bound[i] = bound[i].max(if w.is_nan() { 1.0 } else { w });
        }
    }

    /// Per pixel, where the pair surely moved (0..1, 0 where the flow is not kept).
    fn sure(mut self) -> Vec<f32> {
        let (pa, pb) = (&self.pa, &self.pb);
        let (a, b) = (&pa.levels[0], &pb.levels[0]);
        let (at, least, moved) = (&self.at, &mut self.least, &self.moved);
        // The least residual, lowered rung by rung, then turned into the weight. A pixel whose
        // weight is already 0 stays 0: a rung's residuals are made only for the frame some
        // pixel still takes them from, and no rung once none does. Each frame's rungs are
        // blurred only when first taken.
        for k in 0..DEFOCUS.len() {
            let live = |j: usize| weight(least[j], moved[j]) != 0.0;
            if !(0..at.len()).any(live) {
                break;
            }
            let (ea, eb) = rayon::join(|| pa.energy(), || pb.energy());
            let from_a = |j: usize| ea[at[j]] >= eb[at[j]];
            let takes = |a: bool| (0..at.len()).any(|j| from_a(j) == a && live(j));
            let (ra, rb) = rayon::join(
                || takes(true).then(|| residual(pa.rung(k), b, None)),
                || takes(false).then(|| residual(a, pb.rung(k), None)),
            );
            for (j, l) in least.iter_mut().enumerate() {
                if let Some(r) = if from_a(j) { &ra } else { &rb } {
                    *l = l.min(r[at[j]]);
                }
            }
        }
        let mut sure = vec![0.0; a.width() * a.height()];
        for ((&i, &l), &m) in at.iter().zip(least.iter()).zip(moved) {
            sure[i] = weight(l, m);
        }
        sure
    }
}

/// Gaussian blur with NaN (outside the frame) kept out of it and kept NaN.
fn blur_nan(p: &Plane, sigma: f32) -> Plane {
    let (valid, filled) = masked(p);
    let (bv, bf) = rayon::join(
        || gaussian_blur(&valid, sigma),
        || gaussian_blur(&filled, sigma),
    );
    let data = p
        .data()
        .iter()
        .zip(bv.data().iter().zip(bf.data()))
        .map(|(v, (n, s))| {
            if v.is_nan() || *n <= 1e-3 {
                f32::NAN
            } else {
                s / n
            }
        })
        .collect();
    Plane::from_vec(p.width(), p.height(), 1, data)
}

/// `reduce` with NaN (outside the frame) kept out: outside pixels count as 0 and any output
/// pixel they touch much becomes NaN.
fn reduce_nan(p: &Plane) -> Plane {
    let (valid, filled) = masked(p);
    let (rv, rf) = (reduce(&valid), reduce(&filled));
    let data = rv
        .data()
        .iter()
        .zip(rf.data())
        .map(|(n, s)| if *n > 0.9 { s / n } else { f32::NAN })
        .collect();
    Plane::from_vec(rv.width(), rv.height(), 1, data)
}

/// The pooled structure tensor of a level's reference plane and its ridge: the normal
/// equations' matrix, which with the reference's gradient alone is the same at every
/// Lucas–Kanade step of the level, so it is pooled once per level rather than every step.
struct Tensor {
    /// Per pixel: the gradient (zero where undefined).
    grad: Vec<[f32; 2]>,
    /// Pooled gx² + ridge, gx·gy, gy² + ridge.
    xx: Vec<f32>,
    xy: Vec<f32>,
    yy: Vec<f32>,
}

impl Tensor {
    fn new(a: &Plane) -> Tensor {
        let (w, h) = (a.width(), a.height());
        let mut grad = vec![[0.0f32; 2]; w * h];
        grad.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            if y == 0 || y + 1 == h {
                return;
            }
            for (x, g) in row.iter_mut().enumerate().take(w - 1).skip(1) {
                let i = y * w + x;
                let gx = 0.5 * (a.data()[i + 1] - a.data()[i - 1]);
                let gy = 0.5 * (a.data()[i + w] - a.data()[i - w]);
                if !(gx.is_nan() || gy.is_nan()) {
                    *g = [gx, gy];
                }
            }
        });
        let prod = |f: fn([f32; 2]) -> f32| {
            let data: Vec<f32> = grad.iter().map(|&g| f(g)).collect();
            pool(&data, w, h)
        };
        // The three in parallel: a side's chain of frames is otherwise one thread's work.
        let (mut xx, (xy, mut yy)) = rayon::join(
            || prod(|[x, _]| x * x),
            || rayon::join(|| prod(|[x, y]| x * y), || prod(|[_, y]| y * y)),
        );
        let energy = xx.iter().chain(&yy).sum::<f32>() / (2 * w * h) as f32;
        let ridge = RIDGE * energy + 1e-12;
        xx.iter_mut().chain(&mut yy).for_each(|v| *v += ridge);
        Tensor { grad, xx, xy, yy }
    }
}

/// One Gauss–Newton step of the windowed flow: `b` sampled through `f`, its residual against
/// `a` weighted by `a`'s gradient and pooled over a window, each pixel's increment solved with
/// `a`'s pooled tensor `t`. Returns the share of pixels that moved by `SETTLED.0` or more.
/// `scratch` holds the level's two products between steps (any content, the level's size).
fn lucas_kanade_step(
    a: &Plane,
    b: &Plane,
    t: &Tensor,
    f: &mut Flow,
    scratch: &mut [Vec<f32>; 2],
) -> f32 {
    let (w, h) = (a.width(), a.height());
    // Per pixel: gx·e, gy·e; zero where the residual is undefined (outside the frame). Written
    // straight into the two planes pooled, with no interleaved copy between.
    let [xe, ye] = scratch;
    let (b, cols) = (
        Bilinear::new(b),
        (0..w).map(|x| x as f32).collect::<Vec<_>>(),
    );
    xe.par_chunks_mut(w)
        .zip(ye.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (xr, yr))| {
            let (row, yf) = (y * w..(y + 1) * w, y as f32);
            let at = cols.iter().zip(&f.dx[row.clone()]).zip(&f.dy[row.clone()]);
            let of = a.data()[row.clone()].iter().zip(&t.grad[row]);
            for (((xo, yo), ((&x, &dx), &dy)), (&av, &[gx, gy])) in
                xr.iter_mut().zip(yr).zip(at).zip(of)
            {
                let e = b.at(x + dx, yf + dy) - av;
                (*xo, *yo) = if e.is_nan() {
                    (0.0, 0.0)
                } else {
                    (gx * e, gy * e)
                };
            }
        });
    let (xe, ye) = rayon::join(|| pool(xe, w, h), || pool(ye, w, h));
    f.dx.par_iter_mut()
        .zip(f.dy.par_iter_mut())
        .enumerate()
        .map(|(i, (dx, dy))| {
            let (a, b, c) = (t.xx[i], t.xy[i], t.yy[i]);
            let det = a * c - b * b;
            if det <= 0.0 {
                return 0;
            }
            let (rx, ry) = (-xe[i], -ye[i]);
            let (ux, uy) = ((c * rx - b * ry) / det, (a * ry - b * rx) / det);
            *dx += ux;
            *dy += uy;
            usize::from(ux.abs().max(uy.abs()) >= SETTLED.0)
        })
        .sum::<usize>() as f32
        / (w * h) as f32
}

/// Bilinear samples of a plane, NaN outside or where a tap is NaN; its bounds converted to
/// floats once, not at every sample.
struct Bilinear<'a> {
    data: &'a [f32],
    w: usize,
    h: usize,
    /// The last column and row, as floats.
    x_max: f32,
    y_max: f32,
}

impl<'a> Bilinear<'a> {
    fn new(p: &'a Plane) -> Self {
        let (w, h) = (p.width(), p.height());
        Bilinear {
            data: &p.data()[..w * h],
            w,
            h,
            x_max: (w - 1) as f32,
            y_max: (h - 1) as f32,
        }
    }

    #[inline(always)]
    fn at(&self, x: f32, y: f32) -> f32 {
        if !(x >= 0.0 && y >= 0.0 && x <= self.x_max && y <= self.y_max) {
            return f32::NAN;
        }
        // Truncation floors a non-negative coordinate. A checked conversion costs a dozen
        // instructions for ranges a plane never has; this is one.
        // SAFETY: 0 ≤ x ≤ width − 1 and 0 ≤ y ≤ height − 1 (checked above; NaN fails the
        // check), and a plane's sides are below 2^61 (its buffer holds at most isize::MAX
        // bytes), so both truncate to values an i64 holds.
        let (xi, yi) = unsafe { (x.to_int_unchecked::<i64>(), y.to_int_unchecked::<i64>()) };
        let (x0, y0) = (xi as usize, yi as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (fx, fy) = (x - xi as f32, y - yi as f32);
        let (r0, r1) = (
            &self.data[y0 * self.w..][..self.w],
            &self.data[y1 * self.w..][..self.w],
        );
        let top = r0[x0] * (1.0 - fx) + r0[x1] * fx;
        let bot = r1[x0] * (1.0 - fx) + r1[x1] * fx;
        top * (1.0 - fy) + bot * fy
    }
}

/// Sum over the window of `w`×`h` samples: two box passes, a tent close to a Gaussian, at a
/// cost that does not grow with its size.
fn pool(data: &[f32], w: usize, h: usize) -> Vec<f32> {
    box_sums(&box_sums(data, w, h, WINDOW), w, h, WINDOW)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tex(x: f64, y: f64) -> f32 {
        (0.5 + 0.2 * (x * 0.37).sin() * (y * 0.29).cos() + 0.1 * (x * 0.11 + y * 0.13).sin()) as f32
    }

    #[test]
    fn flow_recovers_a_shift_and_stays_still_without_one() {
        let a = Plane::from_fn(160, 120, 1, |x, y, _| tex(x as f64, y as f64));
        let b = Plane::from_fn(160, 120, 1, |x, y, _| tex(x as f64 - 1.3, y as f64 + 0.6));
        let (a, b) = (Arc::new(Pyramid::new(&a)), Arc::new(Pyramid::new(&b)));
        let (f, _) = flow(&a, &b);
        for i in [60 * 160 + 80, 30 * 160 + 40, 90 * 160 + 120] {
            assert!(
                (f.dx[i] - 1.3).abs() < 0.05 && (f.dy[i] + 0.6).abs() < 0.05,
                "{} {}",
                f.dx[i],
                f.dy[i]
            );
        }
        let (still, _) = flow(&a, &a);
        assert!(still.dx.iter().chain(&still.dy).all(|d| d.abs() < 1e-3));
    }

    /// A frame moved only by its affine, with a checkerboard of period 4.4 px (2.2 at the
    /// working level, near its Nyquist limit) sharp in it and slightly defocused in the
    /// reference: the flow reads the checkerboard's aliases as motion of about 3 px, and with
    /// the finer level at hand the frame keeps no field.
    #[test]
    fn texture_too_fine_for_the_working_level_keeps_no_field() {
        let checker = |x: f64, y: f64| {
            let p = std::f64::consts::TAU / 4.4;
            let c = ((x * p).sin() * (y * p).sin()).signum();
            (0.5 + 0.2 * c + 0.1 * (x * 0.05 + y * 0.03).sin()) as f32
        };
        let (w, h, (sx, sy)) = (320, 240, (1.3, -0.7));
        let sharp = Plane::from_fn(w, h, 1, |x, y, _| checker(x as f64 - sx, y as f64 - sy));
        let still = Plane::from_fn(w, h, 1, |x, y, _| checker(x as f64, y as f64));
        let reference = reduce(&gaussian_blur(&still, 1.0));
        let shift = Affine([[1.0, 0.0, sx], [0.0, 1.0, sy]]);
        let field = |finer: Option<&Plane>| {
            let [mut chain, _] = Chain::both(&reference, 1);
            let coarse = reduce(&sharp);
            let frame = Warped::new(&coarse, finer, &shift, 1);
            chain.next(frame, &shift).map(|f| f.reach(0.99))
        };
        let fooled = field(None);
        assert!(
            fooled.is_some_and(|r| r > 1.0),
            "without the finer level the flow should read the aliases as motion: {fooled:?}"
        );
        assert_eq!(field(Some(&sharp)), None);
    }

    /// A step reports the share of pixels still moving: all of a shifted pair's first step,
    /// none of an identical pair's, which is what lets a level stop early.
    #[test]
    fn a_step_reports_how_much_still_moves() {
        let a = Plane::from_fn(160, 120, 1, |x, y, _| tex(x as f64, y as f64));
        let b = Plane::from_fn(160, 120, 1, |x, y, _| tex(x as f64 - 0.8, y as f64));
        let (ha, hb) = (high_pass(&a), high_pass(&b));
        let t = Tensor::new(&ha);
        let scratch = || [vec![f32::NAN; 160 * 120], vec![f32::NAN; 160 * 120]];
        let mut f = Flow::zero(160, 120);
        assert!(lucas_kanade_step(&ha, &hb, &t, &mut f, &mut scratch()) > 0.9);
        let mut f = Flow::zero(160, 120);
        assert_eq!(lucas_kanade_step(&ha, &ha, &t, &mut f, &mut scratch()), 0.0);
    }
}
