//! Upright difference-of-Gaussian blob keypoints.
//!
//! Blobs, not corners: a symmetric defocus blur leaves a blob's centre where it was and only
//! widens it, while the corners FAST/ORB rely on fade out (measured: kornia's ORB lost the
//! far-focus frames of the synthetic stacks entirely). No orientation is assigned: hand-held roll
//! is a degree or two, well within what the descriptor tolerates, and skipping it keeps
//! keypoints on a rotating blob from flipping between orientation peaks.

use crate::stack::blur::gaussian_blur;
use crate::stack::image::Plane;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Blur of the first Gaussian layer of each octave (Lowe's value).
const SIGMA0: f32 = 1.6;
/// Blur the input is assumed to carry already.
const INPUT_SIGMA: f32 = 0.5;
/// Scales per octave where extrema are searched.
const SCALES: usize = 3;
/// Keypoints closer than this to an octave's border have no full neighbourhood.
const BORDER: usize = 5;
/// Principal-curvature ratio above which an extremum sits on an edge and slides along it.
const EDGE_RATIO: f32 = 10.0;

/// A blob in detection-plane pixel coordinates (pixel centres, origin at the top-left pixel).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keypoint {
    pub x: f32,
    pub y: f32,
    /// Blob scale (Gaussian sigma) in detection-plane pixels.
    pub sigma: f32,
    /// |DoG| at the extremum: contrast, used to keep the strongest.
    pub response: f32,
    /// Octave and Gaussian layer the descriptor is sampled from.
    pub octave: usize,
    pub layer: usize,
}

/// The Gaussian layers per octave; octave `o` has pixels 2^o detection pixels apart.
pub struct ScaleSpace {
    pub octaves: Vec<Vec<Plane>>,
}

impl ScaleSpace {
    /// Sigma of Gaussian layer `s` in its octave's pixels.
    pub fn layer_sigma(s: usize) -> f32 {
        SIGMA0 * 2f32.powf(s as f32 / SCALES as f32)
    }

    pub fn build(p: &Plane, max_octaves: usize) -> ScaleSpace {
        let mut base = gaussian_blur(p, (SIGMA0 * SIGMA0 - INPUT_SIGMA * INPUT_SIGMA).sqrt());
        let mut octaves = Vec::new();
        while octaves.len() < max_octaves && base.width().min(base.height()) >= 4 * BORDER + 8 {
            let mut layers = vec![base];
            for s in 1..SCALES + 3 {
                let (a, b) = (Self::layer_sigma(s - 1), Self::layer_sigma(s));
                let next = gaussian_blur(&layers[s - 1], (b * b - a * a).sqrt());
                layers.push(next);
            }
            // Layer SCALES has twice the base blur: subsampled, it is the next octave's base.
            base = subsample(&layers[SCALES]);
            octaves.push(layers);
        }
        ScaleSpace { octaves }
    }
}

fn subsample(p: &Plane) -> Plane {
    let (w, h) = (p.width().div_ceil(2), p.height().div_ceil(2));
    Plane::from_fn(w, h, 1, |x, y, _| p.at(2 * x, 2 * y, 0))
}

/// Scale-space extrema of the DoG above `threshold`, off edges, refined to sub-pixel position,
/// the strongest `max_count` kept with at most a few per cell of a 16×16 grid so one busy
/// texture cannot take them all.
pub fn detect(ss: &ScaleSpace, threshold: f32, max_count: usize) -> Vec<Keypoint> {
    let mut all = Vec::new();
    for (o, layers) in ss.octaves.iter().enumerate() {
        let dog: Vec<Plane> = layers
            .windows(2)
            .map(|w| {
                let data = w[1].data().iter().zip(w[0].data()).map(|(b, a)| b - a);
                Plane::from_vec(w[0].width(), w[0].height(), 1, data.collect())
            })
            .collect();
        for s in 1..=SCALES {
            all.extend(extrema(&dog[s - 1..=s + 1], threshold, o, s));
        }
    }
    let Some(first) = ss.octaves.first() else {
        return all;
    };
    spread(all, first[0].width(), first[0].height(), max_count)
}

/// Extrema in the middle of three DoG layers of octave `o`.
fn extrema(d: &[Plane], threshold: f32, o: usize, s: usize) -> Vec<Keypoint> {
    let (w, h) = (d[1].width(), d[1].height());
    let scale = (1usize << o) as f32;
    (BORDER..h - BORDER)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut found = Vec::new();
            for x in BORDER..w - BORDER {
                let v = d[1].data()[y * w + x];
                if v.abs() <= threshold || !is_extremum(d, x, y, v) {
                    continue;
                }
                if let Some((dx, dy, ds, value)) = refine(d, x, y) {
                    if value.abs() > threshold {
                        found.push(Keypoint {
                            x: (x as f32 + dx) * scale,
                            y: (y as f32 + dy) * scale,
                            sigma: SIGMA0 * 2f32.powf((s as f32 + ds) / SCALES as f32) * scale,
                            response: value.abs(),
                            octave: o,
                            layer: s,
                        });
                    }
                }
            }
            found
        })
        .collect()
}

/// Whether `v` at (x, y) of the middle layer is the largest or the smallest of its 3×3×3
/// neighbourhood (ties count). Most pixels above the threshold are neither, and show it within
/// a row or two, so each row of three stops the search once it is settled; the middle layer,
/// which rules out most, is read first.
fn is_extremum(d: &[Plane], x: usize, y: usize, v: f32) -> bool {
    let w = d[1].width();
    let (mut max, mut min) = (true, true);
    for layer in [&d[1], &d[0], &d[2]] {
        for yy in y - 1..=y + 1 {
            for &n in &layer.data()[yy * w + x - 1..=yy * w + x + 1] {
                max &= v >= n;
                min &= v <= n;
            }
            if !(max || min) {
                return false;
            }
        }
    }
    true
}

/// Quadratic fit of the DoG around (x, y, middle layer): the sub-pixel offset and value, or None
/// on an edge or when the true extremum lies beyond the neighbouring sample.
fn refine(d: &[Plane], x: usize, y: usize) -> Option<(f32, f32, f32, f32)> {
    let w = d[1].width();
    let at = |s: usize, dx: isize, dy: isize| {
        d[s].data()[((y as isize + dy) as usize) * w + (x as isize + dx) as usize]
    };
    let v = at(1, 0, 0);
    let g = [
        (at(1, 1, 0) - at(1, -1, 0)) / 2.0,
        (at(1, 0, 1) - at(1, 0, -1)) / 2.0,
        (at(2, 0, 0) - at(0, 0, 0)) / 2.0,
    ];
    let dxx = at(1, 1, 0) + at(1, -1, 0) - 2.0 * v;
    let dyy = at(1, 0, 1) + at(1, 0, -1) - 2.0 * v;
    let dss = at(2, 0, 0) + at(0, 0, 0) - 2.0 * v;
    let dxy = (at(1, 1, 1) - at(1, -1, 1) - at(1, 1, -1) + at(1, -1, -1)) / 4.0;
    let dxs = (at(2, 1, 0) - at(2, -1, 0) - at(0, 1, 0) + at(0, -1, 0)) / 4.0;
    let dys = (at(2, 0, 1) - at(2, 0, -1) - at(0, 0, 1) + at(0, 0, -1)) / 4.0;
    let (tr, det) = (dxx + dyy, dxx * dyy - dxy * dxy);
    if det <= 0.0 || tr * tr * EDGE_RATIO >= (EDGE_RATIO + 1.0).powi(2) * det {
        return None;
    }
    let h = Matrix3::new(dxx, dxy, dxs, dxy, dyy, dys, dxs, dys, dss);
    // (Near) singular: no extremum to place.
    if h.determinant().abs() < 1e-12 {
        return None;
    }
    let off = h.lu().solve(&-Vector3::from(g))?;
    if off.iter().any(|o| o.abs() > 0.6) {
        return None;
    }
    let value = v + 0.5 * (g[0] * off[0] + g[1] * off[1] + g[2] * off[2]);
    Some((off[0], off[1], off[2], value))
}

/// The strongest keypoints, at most `max_count`, each grid cell capped at twice its fair share.
fn spread(mut kps: Vec<Keypoint>, w: usize, h: usize, max_count: usize) -> Vec<Keypoint> {
    const GRID: usize = 16;
    kps.sort_by(|a, b| b.response.total_cmp(&a.response));
    let cap = (2 * max_count).div_ceil(GRID * GRID);
    let mut used = vec![0usize; GRID * GRID];
    let mut kept = Vec::with_capacity(max_count.min(kps.len()));
    for k in kps {
        let cx = ((k.x.max(0.0) as usize) * GRID / w).min(GRID - 1);
        let cy = ((k.y.max(0.0) as usize) * GRID / h).min(GRID - 1);
        let c = &mut used[cy * GRID + cx];
        if *c < cap {
            *c += 1;
            kept.push(k);
            if kept.len() == max_count {
                break;
            }
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_blob_at_its_centre_and_scale() {
        let (cx, cy, r) = (40.3f32, 31.7f32, 4.0f32);
        let p = Plane::from_fn(80, 64, 1, |x, y, _| {
            let d2 = (x as f32 - cx).powi(2) + (y as f32 - cy).powi(2);
            0.2 + 0.6 * (-d2 / (2.0 * r * r)).exp()
        });
        let ss = ScaleSpace::build(&p, 3);
        let kps = detect(&ss, 0.002, 10);
        let k = kps[0];
        assert!((k.x - cx).abs() < 0.3 && (k.y - cy).abs() < 0.3, "{k:?}");
        assert!((k.sigma / r - 1.0).abs() < 0.3, "{k:?}");
    }
}
