//! The blur fit: the σ of each near object's defocus in each farther frame, measured where the
//! object's region is deep enough to fit it, and predicted from the stack's focal axis where not.

use crate::stack::blur::gaussian_blur;
use crate::stack::focal_axis;
use crate::stack::image::Plane;

/// Blur σ (full-resolution pixels) the fit tries, to ½ px.
pub(super) const SIGMA_MIN: f32 = 1.0;
const SIGMA_MAX: f32 = 16.0;
/// Reduced pixels a near region's interior needs for its blur to be fitted.
const MIN_INTERIOR: usize = 200;

/// A near label's defocus in a farther frame, as fitted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pair {
    pub near: u8,
    pub far: u8,
    /// σ of the Gaussian, in full-resolution pixels.
    pub sigma: f32,
    /// Predicted from the other pairs (`with_predicted`), not fitted.
    pub predicted: bool,
}

/// How far inside its region (reduced pixels) a fit at `sigma` (full-resolution pixels) reads:
/// 3σ, so the background around the region does not enter.
pub(super) fn margin(sigma: f32, factor: usize) -> u8 {
    (3.0 * sigma / factor as f32).ceil() as u8
}

/// The fitted pairs with each σ raised to what its neighbours bound it by: through a lens, a
/// nearer object is blurred at least as much in the same farther frame, and an object at least
/// as much in a frame focused farther, so σ(k, l) ≥ σ(k + 1, l) and σ(k, l) ≥ σ(k, l − 1). A
/// fit that breaks this fell short, not its neighbour: a thin near object leaves its deeper
/// blurs too little interior, and the fit settles on the largest σ that still has some.
pub(super) fn monotone(mut pairs: Vec<Pair>, n: usize) -> Vec<Pair> {
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
pub(super) fn with_predicted(fitted: Vec<Pair>, n: usize) -> Vec<Pair> {
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
pub(super) fn fit_near(
    k: usize,
    far: &[usize],
    lumas: &[Plane],
    inside: &[u8],
    factor: usize,
) -> Vec<(Pair, f64)> {
    let (rw, rh) = (lumas[k].width(), lumas[k].height());
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
    let near = Plane::from_vec(cw, ch, 1, crop(lumas[k].data()));
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
                let v = lumas[l].data();
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
    // light then enters the fit's edge a little): without that second depth a small near
    // object's larger blurs would never be fitted, nor its spill un-mixed.
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
                    let v = lumas[l].data();
                    let err: f64 = inner
                        .runs
                        .iter()
                        .flat_map(|&(i, j, n)| blurred.data()[i..i + n].iter().zip(&v[j..j + n]))
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
