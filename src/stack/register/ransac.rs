//! Robust global affine from point correspondences: seeded RANSAC on 3-point samples, then
//! least squares on the inliers, re-selecting inliers until they settle.
//!
//! Written here rather than taken from `arrsac`: the model is 6 numbers and a 3×3 solve, and a
//! fixed seed keeps registration reproducible run to run.

use crate::stack::transform::Affine;
use nalgebra::{Matrix3, Matrix3x2, RowVector2, Vector3};

/// A correspondence: (x, y) in the first image, (u, v) in the second.
pub type Pair = ((f64, f64), (f64, f64));

/// Hand-held frames differ by a near-similarity: a linear part this far from a rotation is a
/// coincidence of outliers, not a pose.
const MAX_SHEAR: f64 = 0.1;
const SCALE_RANGE: (f64, f64) = (0.8, 1.25);

/// A robust fit: the affine, its inlier indices and their RMS residual (pixels).
#[derive(Clone, Debug)]
pub struct Fit {
    pub affine: Affine,
    pub inliers: Vec<usize>,
    pub rms: f64,
}

/// Least-squares affine through the pairs `idx` (at least 3, not collinear).
pub fn fit_affine(pairs: &[Pair], idx: &[usize]) -> Option<Affine> {
    if idx.len() < 3 {
        return None;
    }
    // Centre the points so the normal equations stay well conditioned at megapixel coordinates.
    let n = idx.len() as f64;
    let (mx, my) = idx.iter().fold((0.0, 0.0), |s, &i| {
        (s.0 + pairs[i].0 .0 / n, s.1 + pairs[i].0 .1 / n)
    });
    // Normal equations, one right-hand side per output coordinate.
    let mut m = Matrix3::zeros();
    let mut rhs = Matrix3x2::zeros();
    for &i in idx {
        let ((x, y), (u, v)) = pairs[i];
        let r = Vector3::new(x - mx, y - my, 1.0);
        m += r * r.transpose();
        rhs += r * RowVector2::new(u, v);
    }
    // Partial pivoting; a pivot this small against the largest entry means collinear points.
    let lu = m.lu();
    let scale = m.amax();
    if lu.u().diagonal().iter().any(|p| p.abs() <= 1e-12 * scale) {
        return None;
    }
    let s = lu.solve(&rhs)?;
    let ([a, b, c], [d, e, f]) = (s.column(0).into(), s.column(1).into());
    Some(Affine([
        [a, b, c - a * mx - b * my],
        [d, e, f - d * mx - e * my],
    ]))
}

/// Whether the linear part is a plausible hand-held pose: near-conformal, modest scale.
fn plausible(a: &Affine) -> bool {
    let [[p, q, _], [r, s, _]] = a.0;
    let scale = (p * s - q * r).abs().sqrt();
    let shear = ((p - s).powi(2) + (q + r).powi(2)).sqrt() / scale.max(1e-9);
    (SCALE_RANGE.0..=SCALE_RANGE.1).contains(&scale) && shear <= MAX_SHEAR
}

fn residual(a: &Affine, p: &Pair) -> f64 {
    let (u, v) = a.apply(p.0 .0, p.0 .1);
    (u - p.1 .0).hypot(v - p.1 .1)
}

fn inliers_of(a: &Affine, pairs: &[Pair], threshold: f64) -> Vec<usize> {
    (0..pairs.len())
        .filter(|&i| residual(a, &pairs[i]) <= threshold)
        .collect()
}

/// SplitMix64: a tiny seeded generator, enough for sampling.
struct Rng(u64);

impl Rng {
    fn below(&mut self, n: usize) -> usize {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) % n as u64) as usize
    }
}

/// RANSAC with at most `iterations` samples (fewer once a 99.9 % confident consensus is found),
/// inliers within `threshold` pixels. None with fewer than 3 pairs or no plausible model.
pub fn ransac_affine(pairs: &[Pair], threshold: f64, iterations: usize, seed: u64) -> Option<Fit> {
    let n = pairs.len();
    if n < 3 {
        return None;
    }
    let mut rng = Rng(seed);
    let mut best: Vec<usize> = Vec::new();
    let mut needed = iterations;
    let mut it = 0;
    while it < needed.min(iterations) {
        it += 1;
        let s = [rng.below(n), rng.below(n), rng.below(n)];
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        let Some(a) = fit_affine(pairs, &s).filter(plausible) else {
            continue;
        };
        let inl = inliers_of(&a, pairs, threshold);
        if inl.len() > best.len() {
            best = inl;
            let w = best.len() as f64 / n as f64;
            needed = ((1.0 - 0.999f64).ln() / (1.0 - w.powi(3)).max(1e-12).ln()).ceil() as usize;
        }
    }
    let mut affine = fit_affine(pairs, &best)?;
    // Least squares on the consensus, then re-select: the refit usually gains a few inliers.
    for _ in 0..5 {
        let inl = inliers_of(&affine, pairs, threshold);
        let same = inl == best;
        best = inl;
        affine = fit_affine(pairs, &best)?;
        if same {
            break;
        }
    }
    if !plausible(&affine) {
        return None;
    }
    let rms = (best
        .iter()
        .map(|&i| residual(&affine, &pairs[i]).powi(2))
        .sum::<f64>()
        / best.len() as f64)
        .sqrt();
    Some(Fit {
        affine,
        inliers: best,
        rms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_affine_despite_outliers() {
        let truth = Affine::similarity(1.01, 0.02, (320.0, 240.0), (7.0, -4.0));
        let mut rng = Rng(7);
        let pairs: Vec<Pair> = (0..200)
            .map(|i| {
                let p = (rng.below(640) as f64, rng.below(480) as f64);
                let q = if i % 3 == 0 {
                    (rng.below(640) as f64, rng.below(480) as f64)
                } else {
                    truth.apply(p.0, p.1)
                };
                (p, q)
            })
            .collect();
        let fit = ransac_affine(&pairs, 2.0, 1000, 1).unwrap();
        assert!(fit.affine.corner_error(&truth, 640, 480) < 1e-6);
        assert!(fit.inliers.len() >= 133 && fit.rms < 1e-6);
        assert!(ransac_affine(&pairs[..2], 2.0, 1000, 1).is_none());
    }
}
