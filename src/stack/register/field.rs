//! The smooth offset field on top of a frame's global affine: the "smoothly varying affine" of
//! Zhang et al. §2.1, for what one affine cannot model, chiefly the parallax of near objects in
//! a hand-held sweep (a pixel or two against the background).
//!
//! Local shifts are measured like the dense refinement ([`super::refine`]): inverse-compositional
//! Lucas–Kanade against the reference on the finest refinement level, both brought to equal
//! defocus first ([`super::equalise`]; without it defocus biases a local fit by as much as the
//! parallax being measured), Huber-weighted. Each pixel's normal equations for a local shift,
//! gain and offset are pooled onto a grid of nodes, smoothed across nodes by a Gaussian (the
//! paper's low-pass Ψ term: pooling normal equations rather than shifts weighs each region by
//! its texture, and lets edges of every orientation constrain both components), and solved
//! with a ridge that shrinks the shift toward zero where the pooled evidence is weak. A few
//! rounds re-warp through the field. The field is kept only if it lowers the robust residual
//! clearly; otherwise the affine stands alone.

use super::equalise::{self, Stack};
use super::levels::{to_level, Levels};
use super::refine::{solve, warp_stack, Coords, Refined, Template, View};
use crate::stack::transform::{Affine, OffsetField};
use rayon::prelude::*;

/// Level pixels between grid nodes: 16–64 full-resolution pixels at the default `refine_pixels`.
const NODE: usize = 8;
/// Gaussian smoothing of the pooled normal equations, in nodes.
const SIGMA: f64 = 2.5;
/// Ridge on the shift, relative to the mean pooled gradient energy of a node: a node with that
/// much of the average texture has its shift halved. Weaker ridge and smoothing (1 and 2 nodes)
/// fit parallax better but defocus bias too: on parallax-free stacks they add up to 0.05 px RMS.
const RIDGE: f64 = 2.0;

/// Measure-and-warp rounds: the second and third correct the linearisation of the first.
const ROUNDS: usize = 3;
/// Relative drop of the robust residual the field must bring to be kept.
const MIN_GAIN: f64 = 0.02;
/// Huber threshold in robust standard deviations, as in the refinement.
const HUBER: f32 = 1.5;

/// Per-node accumulators: upper triangle of the 4×4 normal matrix of (dx, dy, gain, offset),
/// then the right-hand side.
type Acc = [f64; 14];
const UPPER: [(usize, usize); 10] = [
    (0, 0),
    (0, 1),
    (0, 2),
    (0, 3),
    (1, 1),
    (1, 2),
    (1, 3),
    (2, 2),
    (2, 3),
    (3, 3),
];

/// The offset field of a refined frame (reference → frame, full-resolution pixels), or None if
/// it does not lower the residual against the reference.
pub fn estimate(tpl: &Template, frame: &Levels, r: &Refined) -> Option<OffsetField> {
    let k = tpl.first;
    let (tw, th) = (tpl.levels[0].width, tpl.levels[0].height);
    let a = to_level(&r.affine, k);
    let stack = Stack::new(frame.get(k));
    let (cols, rows) = ((tw - 1).div_ceil(NODE) + 1, (th - 1).div_ceil(NODE) + 1);
    let mut field = OffsetField {
        step: NODE as f64,
        cols,
        rows,
        offsets: vec![(0.0, 0.0); cols * rows],
    };
    let obs = |f: Option<&OffsetField>| Observation::new(tpl, &stack, &a, f, r.gain, r.offset);
    let mut o = obs(None);
    let scale = o.scale()?;
    let before = o.cost(scale);
    let [[l00, l01, _], [l10, l11, _]] = a.0;
    for _ in 0..ROUNDS {
        let d = o.shifts(scale, cols, rows);
        // Inverse composition: W(x − d) ≈ W(x) − L·d for the affine's linear part L.
        for (f, (dx, dy)) in field.offsets.iter_mut().zip(d) {
            f.0 -= (l00 * dx + l01 * dy) as f32;
            f.1 -= (l10 * dx + l11 * dy) as f32;
        }
        o = obs(Some(&field));
    }
    if o.cost(scale) > (1.0 - MIN_GAIN) * before {
        return None;
    }
    let s = (1u64 << k) as f32;
    field.step *= s as f64;
    field
        .offsets
        .iter_mut()
        .for_each(|o| *o = (o.0 * s, o.1 * s));
    Some(field)
}

/// The frame warped onto the template (level coordinates) and compared with the reference at
/// equal defocus.
struct Observation {
    view: View,
    /// Frame minus equalised reference, in reference units; NaN outside the frame.
    resid: Vec<f32>,
}

impl Observation {
    fn new(
        tpl: &Template,
        stack: &Stack,
        a: &Affine,
        field: Option<&OffsetField>,
        gain: f32,
        offset: f32,
    ) -> Observation {
        let (tw, th) = (tpl.levels[0].width, tpl.levels[0].height);
        let cs = Coords::mapped(tw, th, &stack.layers[0], |x, y| {
            let (u, v) = a.apply(x, y);
            let (dx, dy) = field.map_or((0.0, 0.0), |f| f.at(x, y));
            (u + dx, v + dy)
        });
        let warped = warp_stack(stack, &cs, gain, offset);
        let pick = equalise::choose(&tpl.stack, &warped);
        let view = View::select(&tpl.stack_views, &pick);
        let resid = (0..tw * th)
            .map(|i| warped[pick[i].1 as usize].data[i] - view.t[i])
            .collect();
        Observation { view, resid }
    }

    /// Robust standard deviation of the residual; None with too little overlap.
    fn scale(&self) -> Option<f32> {
        let mut v: Vec<f32> = self
            .resid
            .iter()
            .filter(|e| !e.is_nan())
            .map(|e| e.abs())
            .collect();
        if v.len() < 64 || v.len() * 4 < self.resid.len() {
            return None;
        }
        let mid = v.len() / 2;
        Some(1.4826 * *v.select_nth_unstable_by(mid, f32::total_cmp).1 + 1e-6)
    }

    /// Mean Huber cost of the residual in units of `scale`.
    fn cost(&self, scale: f32) -> f64 {
        let (sum, n) =
            self.resid
                .iter()
                .filter(|e| !e.is_nan())
                .fold((0.0f64, 0usize), |(s, n), e| {
                    let r = e.abs() / scale;
                    let c = if r <= HUBER {
                        0.5 * r * r
                    } else {
                        HUBER * (r - 0.5 * HUBER)
                    };
                    (s + c as f64, n + 1)
                });
        sum / n.max(1) as f64
    }

    /// The shift increment (template level pixels) at every node: pooled, smoothed and
    /// ridge-regularised normal equations.
    fn shifts(&self, scale: f32, cols: usize, rows: usize) -> Vec<(f64, f64)> {
        let pooled = smooth(&self.pool(scale, cols, rows), cols, rows);
        let energy = pooled.iter().map(|a| a[0] + a[4]).sum::<f64>() / (2 * pooled.len()) as f64;
        let ridge = RIDGE * energy + 1e-12;
        pooled
            .iter()
            .map(|a| {
                let mut h = [[0.0; 4]; 4];
                for (v, &(i, j)) in a.iter().zip(&UPPER) {
                    h[i][j] = *v;
                }
                // The shift is shrunk toward zero; gain and offset only kept solvable.
                h[0][0] += ridge;
                h[1][1] += ridge;
                h[2][2] += 1e-6 * h[2][2] + 1e-12;
                h[3][3] += 1e-6 * h[3][3] + 1e-12;
                let b = [a[10], a[11], a[12], a[13]];
                solve(h, b).map_or((0.0, 0.0), |d| (d[0], d[1]))
            })
            .collect()
    }

    /// Each pixel's Huber-weighted normal equations, split bilinearly between its four nodes.
    fn pool(&self, scale: f32, cols: usize, rows: usize) -> Vec<Acc> {
        let v = &self.view;
        let (tw, th) = (v.width, v.height);
        let nf = NODE as f64;
        let per_row: Vec<Vec<Acc>> = (0..rows)
            .into_par_iter()
            .map(|j| {
                let mut acc = vec![[0.0; 14]; cols];
                let y0 = (j * NODE).saturating_sub(NODE - 1);
                let y1 = ((j + 1) * NODE).min(th);
                for y in y0..y1 {
                    let wy = 1.0 - (y as f64 - (j * NODE) as f64).abs() / nf;
                    for x in 0..tw {
                        let i = y * tw + x;
                        let e = self.resid[i];
                        if e.is_nan() {
                            continue;
                        }
                        let r = e.abs() / scale;
                        let wt = if r <= HUBER { 1.0 } else { HUBER / r } as f64;
                        let jac = [v.gx[i] as f64, v.gy[i] as f64, v.t[i] as f64, 1.0];
                        let (c, fx) = (x / NODE, (x % NODE) as f64 / nf);
                        for (node, wx) in [(c, 1.0 - fx), (c + 1, fx)] {
                            if wx <= 0.0 || node >= cols {
                                continue;
                            }
                            let w = wt * wx * wy;
                            let a = &mut acc[node];
                            for (s, &(p, q)) in a.iter_mut().zip(&UPPER) {
                                *s += w * jac[p] * jac[q];
                            }
                            for p in 0..4 {
                                a[10 + p] += w * jac[p] * e as f64;
                            }
                        }
                    }
                }
                acc
            })
            .collect();
        per_row.concat()
    }
}

/// Separable Gaussian ([`SIGMA`] nodes) over the node grid, truncated at its edges.
fn smooth(a: &[Acc], cols: usize, rows: usize) -> Vec<Acc> {
    let r = (3.0 * SIGMA).ceil() as isize;
    let k: Vec<f64> = (-r..=r)
        .map(|d| (-((d * d) as f64) / (2.0 * SIGMA * SIGMA)).exp())
        .collect();
    let pass = |src: &[Acc], along_x: bool| -> Vec<Acc> {
        let mut out = vec![[0.0; 14]; cols * rows];
        for y in 0..rows {
            for x in 0..cols {
                let o = &mut out[y * cols + x];
                for (d, w) in (-r..=r).zip(&k) {
                    let (sx, sy) = if along_x {
                        (x as isize + d, y as isize)
                    } else {
                        (x as isize, y as isize + d)
                    };
                    if sx < 0 || sy < 0 || sx >= cols as isize || sy >= rows as isize {
                        continue;
                    }
                    let s = &src[sy as usize * cols + sx as usize];
                    o.iter_mut().zip(s).for_each(|(o, s)| *o += w * s);
                }
            }
        }
        out
    };
    pass(&pass(a, true), false)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::image::Plane;
    use crate::stack::register::refine::refine;
    use crate::stack::transform::Warp;

    fn tex(x: f64, y: f64) -> f32 {
        (0.5 + 0.2 * (x * 0.37).sin() * (y * 0.29).cos() + 0.1 * (x * 0.11 + y * 0.13).sin()) as f32
    }

    /// A smooth bump: reference point p shows up at p + bump(p) in the frame.
    fn bump(x: f64, y: f64) -> (f64, f64) {
        let g = (-((x - 80.0).powi(2) + (y - 60.0).powi(2)) / (2.0 * 30.0f64.powi(2))).exp();
        (1.2 * g, -0.6 * g)
    }

    /// RMS over the frame of the warp's distance from the true positions.
    fn rms(w: &Warp) -> f64 {
        let mut s = 0.0;
        for y in 0..120 {
            for x in 0..160 {
                let (x, y) = (x as f64, y as f64);
                let (u, v) = w.apply(x, y);
                let (dx, dy) = bump(x, y);
                s += (u - x - dx).powi(2) + (v - y - dy).powi(2);
            }
        }
        (s / (160.0 * 120.0)).sqrt()
    }

    #[test]
    fn follows_a_local_displacement_and_not_a_global_one() {
        let reference = Plane::from_fn(160, 120, 1, |x, y, _| tex(x as f64, y as f64));
        // Frame pixel q shows the scene point at q − bump (the bump is smooth, so q − bump(q)
        // inverts p + bump(p) to well under 0.1 px).
        let frame = Plane::from_fn(160, 120, 1, |x, y, _| {
            let (dx, dy) = bump(x as f64, y as f64);
            tex(x as f64 - dx, y as f64 - dy)
        });
        let tpl = Template::new(&Levels::build(&reference, 0, 1), 0, 1);
        let levels = Levels::build(&frame, 0, 1);
        let r = refine(&tpl, &levels, Affine::IDENTITY, 20);
        let field = estimate(&tpl, &levels, &r).expect("a field");
        let affine = Warp::affine(r.affine);
        let warp = Warp {
            affine: r.affine,
            field: Some(field),
        };
        assert!(
            rms(&warp) < 0.7 * rms(&affine),
            "{} vs {}",
            rms(&warp),
            rms(&affine)
        );
        // A frame that only an affine moves gets no field.
        let shifted = Plane::from_fn(160, 120, 1, |x, y, _| tex(x as f64 - 0.7, y as f64 + 0.4));
        let levels = Levels::build(&shifted, 0, 1);
        let r = refine(&tpl, &levels, Affine::IDENTITY, 20);
        assert!(estimate(&tpl, &levels, &r).is_none());
    }
}
