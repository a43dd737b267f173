//! Upright SIFT-style descriptors: 4×4 cells × 8 gradient orientations around each keypoint, the
//! window scaled with the keypoint's blob scale so focus breathing does not change it.

use super::keypoints::{Keypoint, ScaleSpace};
use crate::stack::image::{Plane, Tap};
use rayon::prelude::*;

/// Cells per side and orientation bins per cell: 128 values, Lowe's layout.
const CELLS: usize = 4;
const BINS: usize = 8;
pub const LEN: usize = CELLS * CELLS * BINS;
/// Cell width in units of the keypoint's sigma.
const CELL_SIGMAS: f32 = 3.0;
/// Lowe's clamp: no single gradient dominates after normalisation.
const CLAMP: f32 = 0.2;

/// Descriptors of `kps`, `LEN` values each, unit length.
pub fn describe(ss: &ScaleSpace, kps: &[Keypoint]) -> Vec<[f32; LEN]> {
    kps.par_iter()
        .map(|k| {
            let layer = &ss.octaves[k.octave][k.layer];
            let scale = (1usize << k.octave) as f32;
            one(layer, k.x / scale, k.y / scale, k.sigma / scale)
        })
        .collect()
}

/// Samples per cell side: the window is read on a fixed 16×16 grid scaled with the keypoint,
/// so the cost does not grow with its scale.
const SAMPLES: usize = 4;
const GRID: usize = CELLS * SAMPLES;

/// One descriptor at (x, y) in the layer's own pixels; `sigma` in the same units.
fn one(p: &Plane, x: f32, y: f32, sigma: f32) -> [f32; LEN] {
    let step = CELL_SIGMAS * sigma / SAMPLES as f32;
    // Intensities on the grid plus a one-sample ring, so gradients are grid differences.
    let half = (GRID + 1) as f32 / 2.0;
    // The grid is upright: a column's taps are the same on every row, and a row's in every
    // column, so each is found once rather than per sample.
    let taps = |c: f32, n: usize| -> [Tap; GRID + 2] {
        std::array::from_fn(|i| Tap::new(c + (i as f32 - half) * step, n))
    };
    let (cols, rows) = (taps(x, p.width()), taps(y, p.height()));
    let mut g = [[0.0f32; GRID + 2]; GRID + 2];
    for (row, &ty) in g.iter_mut().zip(&rows) {
        for (v, &tx) in row.iter_mut().zip(&cols) {
            *v = p.sample_taps(tx, ty);
        }
    }
    // Gaussian weight over the window, sigma half the window width (Lowe's); separable.
    let centre = GRID as f32 / 2.0 - 0.5;
    let weight: [f32; GRID] =
        std::array::from_fn(|i| (-2.0 * (i as f32 - centre).powi(2) / (GRID * GRID) as f32).exp());
    let mut d = [0.0f32; LEN];
    for j in 0..GRID {
        for i in 0..GRID {
            let gx = g[j + 1][i + 2] - g[j + 1][i];
            let gy = g[j + 2][i + 1] - g[j][i + 1];
            let mag = (gx * gx + gy * gy).sqrt() * weight[i] * weight[j];
            let turn = atan2_turns(gy, gx);
            let cx = (i as f32 + 0.5) / SAMPLES as f32 - 0.5;
            let cy = (j as f32 + 0.5) / SAMPLES as f32 - 0.5;
            spread(&mut d, cx, cy, turn * BINS as f32, mag);
        }
    }
    normalise(&mut d);
    for v in d.iter_mut() {
        *v = v.min(CLAMP);
    }
    normalise(&mut d);
    d
}

/// The angle of (x, y) in turns, 0..1, to within ~0.001 turn: plenty for 8 bins, and much
/// cheaper than `atan2`.
fn atan2_turns(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let m = ax.max(ay);
    if m == 0.0 {
        return 0.0;
    }
    let r = ax.min(ay) / m;
    // atan(r) on 0..1 by a minimax polynomial, in turns.
    let r2 = r * r;
    let mut a = r * (0.159_037_6 + r2 * (-0.052_023_6 + r2 * 0.018_182_5));
    if ay > ax {
        a = 0.25 - a;
    }
    if x < 0.0 {
        a = 0.5 - a;
    }
    if y < 0.0 {
        a = 1.0 - a;
    }
    a.rem_euclid(1.0)
}

/// Trilinear vote into the two nearest cells along x and y and the two nearest orientation bins.
fn spread(d: &mut [f32; LEN], cx: f32, cy: f32, co: f32, mag: f32) {
    let (x0, y0, o0) = (cx.floor(), cy.floor(), co.floor());
    let (fx, fy, fo) = (cx - x0, cy - y0, co - o0);
    for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
        let yy = y0 as isize + dy;
        if !(0..CELLS as isize).contains(&yy) {
            continue;
        }
        for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
            let xx = x0 as isize + dx;
            if !(0..CELLS as isize).contains(&xx) {
                continue;
            }
            let base = (yy as usize * CELLS + xx as usize) * BINS;
            for (dob, wo) in [(0, 1.0 - fo), (1, fo)] {
                let b = (o0 as usize + dob) % BINS;
                d[base + b] += mag * wy * wx * wo;
            }
        }
    }
}

fn normalise(d: &mut [f32; LEN]) {
    let n = d.iter().map(|v| v * v).sum::<f32>().sqrt();
    if n > 0.0 {
        d.iter_mut().for_each(|v| *v /= n);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn descriptor_is_unit_and_shift_stable() {
        let p = Plane::from_fn(64, 64, 1, |x, y, _| {
            ((x as f32 * 0.37).sin() * (y as f32 * 0.23).cos() + 1.0) / 2.0
        });
        let a = one(&p, 32.0, 30.0, 2.0);
        let b = one(&p, 32.2, 30.1, 2.0);
        let c = one(&p, 20.0, 40.0, 2.0);
        for k in 0..64 {
            let t = k as f32 / 64.0 * std::f32::consts::TAU;
            let (y, x) = (t.sin(), t.cos());
            let exact = y.atan2(x).rem_euclid(std::f32::consts::TAU) / std::f32::consts::TAU;
            let diff = (atan2_turns(y, x) - exact).abs();
            assert!(diff.min(1.0 - diff) < 2e-3, "{k}");
        }
        let n: f32 = a.iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-4);
        let dist = |u: &[f32; LEN], v: &[f32; LEN]| {
            u.iter().zip(v).map(|(p, q)| (p - q).powi(2)).sum::<f32>()
        };
        assert!(dist(&a, &b) < 0.2 * dist(&a, &c));
    }
}
