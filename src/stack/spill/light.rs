//! The light the defocus mixed in: linear light (a camera's lens) or display values (some
//! renderers), told apart by which of the two the blur fit explains the stack better in.

use super::blur_fit::{fit_near, margin, monotone, with_predicted, Pair, SIGMA_MIN};
use crate::stack::image::{luma_of, Plane};
use crate::stack::morphology::distance;
use crate::stack::srgb;
use crate::stack::Progress;
use rayon::prelude::*;

/// The values the lens's defocus mixed: linear light (a camera) or display values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Light {
    Linear,
    Display,
}

impl Light {
    /// Takes a stored (sRGB-encoded) value into this light. Linear light by table
    /// ([`srgb::tabulated`]) rather than a `powf` for every channel of every pixel un-mixed; the
    /// table is fetched once here, for a whole pass, rather than once a value.
    pub(super) fn mixing(self) -> impl Fn(f32) -> f32 + Copy + Sync {
        let curve = (self == Light::Linear).then(|| &srgb::tabulated().decode);
        move |v| match curve {
            Some(c) => c.at(v.clamp(0.0, 1.0)),
            None => v,
        }
    }

    /// Takes a value in this light back to its stored form (see [`Self::mixing`]).
    pub(super) fn storing(self) -> impl Fn(f32) -> f32 + Copy + Sync {
        let curve = (self == Light::Linear).then(|| &srgb::tabulated().encode);
        move |v| match curve {
            Some(c) => c.at(v.clamp(0.0, 1.0)),
            None => v.clamp(0.0, 1.0),
        }
    }
}

/// The luma of reduced sRGB-encoded planes, in `light`.
pub(super) fn luma(planes: &[Plane], light: Light) -> Plane {
    let mix = light.mixing();
    let data = match planes {
        [r, g, b] => (r.data().iter().zip(g.data()).zip(b.data()))
            .map(|((&r, &g), &b)| luma_of(mix(r), mix(g), mix(b)))
            .collect(),
        _ => planes[0].data().iter().map(|&v| mix(v)).collect(),
    };
    Plane::from_vec(planes[0].width(), planes[0].height(), 1, data)
}

/// Near depths fitted in both lights before the rest: the [`PROBES`] with the most interior.
/// Where their fits tell the lights apart by more than [`CLEAR`] (mean log residual), the other
/// depths are fitted in the better light alone; otherwise in both, and all of them decide: the
/// fit in two lights is a large share of the spill stage, and where the probes tell the lights
/// apart clearly, all pairs choose the same light.
pub(super) const PROBES: usize = 2;
/// How far apart (mean log residual) the fits in the two lights must be for the better one to
/// be taken: about a factor of two in residual.
pub(super) const CLEAR: f64 = 0.75;

/// What the blur fit found.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Fitted {
    /// No pair could be fitted.
    Nothing,
    /// The fits in the two lights explain the stack alike: their mean log residuals are this
    /// far apart, no more than [`CLEAR`]. Where the near objects are dark or plain, the fit has
    /// little texture to measure a blur on in either light and settles on whatever σ it can,
    /// and un-mixing in the wrong light leaves dark or bright rims: nothing is un-mixed.
    Untold(f64),
    /// The light the fits explain clearly better, and its pairs.
    Told(Light, Vec<Pair>),
}

/// The blur fit: for every pair of a near label `k` and a farther frame `l`, the σ at which
/// frame `k` blurred best explains frame `l` over the interior of `k`'s region (deeper inside
/// than 3σ, so the background around the region does not enter), in both lights (or, once the
/// [`PROBES`] tell them apart, in the better one). Tells the light whose fits leave the smaller
/// residual (geometric mean of the residuals relative to frame `l`'s variance there) by more
/// than [`CLEAR`], and its pairs. `lights` are the reduced frames' luma in each light.
/// `probes`: [`PROBES`], or `usize::MAX` to fit every depth in both lights.
pub(super) fn fit(
    lights: [(Light, Vec<Plane>); 2],
    masks: &[Plane],
    factor: usize,
    probes: usize,
    progress: &dyn Progress,
) -> Fitted {
    let n = masks.len();
    // How deep inside its region each pixel lies: the distance from the pixels outside it.
    // Capped at 255 reduced pixels, far beyond the deepest margin a fit asks for (3σ at
    // `SIGMA_MAX`).
    let interiors: Vec<Vec<u8>> = masks
        .par_iter()
        .map(|m| {
            let outside: Vec<bool> = m.data().iter().map(|&a| a < 0.5).collect();
            distance(&outside, m.width(), m.height(), u8::MAX)
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
                (Some(sa), Some(sb)) if (sa - sb).abs() <= CLEAR => {
                    return Fitted::Untold((sa - sb).abs())
                }
                (Some(sa), Some(sb)) if sb < sa => (light_b, b),
                (Some(_), _) => (light_a, a),
                (None, Some(_)) => (light_b, b),
                (None, None) => return Fitted::Nothing,
            }
        }
    };
    let pairs = fits.into_iter().map(|(p, _)| p).collect();
    Fitted::Told(light, with_predicted(monotone(pairs, n), n))
}
