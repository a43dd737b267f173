//! Where each frame of a stack is focused, as one position per frame on an axis measured in
//! pixels of defocus blur.
//!
//! Through a thin lens, the blur a point focused in frame `k` shows in frame `l` grows with the
//! distance between the two focus settings in dioptres, so every pair's σ is, to first order,
//! `|φ_l − φ_k|` for one position `φ` per frame. Fitting the positions to the pairs whose blur
//! could be measured gives the blur of the pairs that could not: a near object too small for
//! its deepest blur to be measured inside it (the main job's nearest objects in the frames
//! focused farthest) still spills into those frames, and by about as much as the chain of its
//! nearer pairs says.

use nalgebra::{DMatrix, DVector};

/// A measured blur: frames `near` and `far` (depth ranks, `near < far`) and its σ.
pub type Measured = (usize, usize, f32);

/// Weight of the prior that keeps frames no pair measures evenly spaced between their
/// neighbours, against a measured pair's weight of 1: enough to pin them, too little to move a
/// measured pair's positions.
const PRIOR: f64 = 0.01;

/// Positions `φ` of `n` frames, the first at 0, fitted by least squares to `measured` (each
/// pair's `φ_far − φ_near` against its σ) with a weak prior of even spacing (the median of the
/// pairs' σ per frame between them). `None` when nothing was measured.
pub fn positions(n: usize, measured: &[Measured]) -> Option<Vec<f32>> {
    if measured.is_empty() || n < 2 {
        return None;
    }
    let mut per_frame: Vec<f32> = measured
        .iter()
        .map(|&(k, l, s)| s / (l - k) as f32)
        .collect();
    per_frame.sort_by(f32::total_cmp);
    let step = f64::from(per_frame[per_frame.len() / 2]);
    // Normal equations of the unknowns φ_1..φ_{n-1}; φ_0 = 0 is dropped from them.
    let m = n - 1;
    let mut a = DMatrix::<f64>::zeros(m, m);
    let mut b = DVector::<f64>::zeros(m);
    let mut equation = |k: usize, l: usize, target: f64, weight: f64| {
        for (i, si) in [(k, -1.0), (l, 1.0)] {
            if i == 0 {
                continue;
            }
            b[i - 1] += weight * si * target;
            for (j, sj) in [(k, -1.0), (l, 1.0)] {
                if j != 0 {
                    a[(i - 1, j - 1)] += weight * si * sj;
                }
            }
        }
    };
    for &(k, l, s) in measured {
        equation(k, l, f64::from(s), 1.0);
    }
    for k in 0..m {
        equation(k, k + 1, step, PRIOR);
    }
    // The prior's chain makes the normal equations positive definite; one unknown per frame, so
    // the matrix is sized at run time.
    let phi = a.cholesky()?.solve(&b);
    Some(
        std::iter::once(0.0)
            .chain(phi.iter().map(|&v| v as f32))
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every pair's σ from positions `phi`, leaving out `missing`.
    fn pairs(phi: &[f32], missing: &[(usize, usize)]) -> Vec<Measured> {
        let n = phi.len();
        (0..n)
            .flat_map(|k| (k + 2..n).map(move |l| (k, l)))
            .filter(|p| !missing.contains(p))
            .map(|(k, l)| (k, l, phi[l] - phi[k]))
            .collect()
    }

    #[test]
    fn the_pairs_left_out_are_predicted_from_the_others() {
        // Unevenly spaced settings, as a sweep even in lens steps but not in dioptres gives.
        let phi = [0.0, 1.5, 3.5, 6.0, 7.0, 9.5];
        let missing = [(0, 4), (0, 5), (1, 5)];
        let fitted = positions(phi.len(), &pairs(&phi, &missing)).expect("pairs were measured");
        for (k, l) in missing {
            let predicted = fitted[l] - fitted[k];
            let truth = phi[l] - phi[k];
            assert!(
                (predicted - truth).abs() < 0.05,
                "pair ({k}, {l}): predicted σ {predicted:.3}, truth {truth}"
            );
        }
    }

    #[test]
    fn a_frame_no_pair_measures_sits_evenly_between_its_neighbours() {
        // Frame 3 is in no measured pair; the others are evenly 2 px apart.
        let phi = [0.0, 2.0, 4.0, 6.0, 8.0, 10.0];
        let measured: Vec<Measured> = pairs(&phi, &[])
            .into_iter()
            .filter(|&(k, l, _)| k != 3 && l != 3)
            .collect();
        let fitted = positions(phi.len(), &measured).expect("pairs were measured");
        assert!((fitted[3] - 6.0).abs() < 0.05, "frame 3 at {}", fitted[3]);
    }

    #[test]
    fn noisy_pairs_are_averaged() {
        let phi = [0.0, 2.0, 4.0, 6.0, 8.0];
        let mut measured = pairs(&phi, &[(0, 4)]);
        // One pair measured ½ px long, one ½ px short: (0, 4) stays near its truth of 8.
        measured[0].2 += 0.5;
        measured[1].2 -= 0.5;
        let fitted = positions(phi.len(), &measured).expect("pairs were measured");
        assert!((fitted[4] - 8.0).abs() < 0.3, "frame 4 at {}", fitted[4]);
    }

    #[test]
    fn nothing_measured_gives_no_positions() {
        assert_eq!(positions(5, &[]), None);
        assert_eq!(positions(1, &[(0, 0, 1.0)]), None);
    }
}
