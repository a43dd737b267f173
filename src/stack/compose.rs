//! Composes the output from the frames' Laplacian pyramids.
//!
//! Both fusion methods are one compositor with different rules for which frame a band
//! coefficient comes from:
//! - `Select::MaxContrast` (the classic baseline): every band from the frame with the most local
//!   band energy, the low-pass residual averaged.
//! - `Select::Labels` (graph cut): each band from the highest-contrast frame among the labels
//!   present within that band's reach, the residual weighted by the blurred label masks. Inside a
//!   label region this is a plain copy of the labelled frame (no noise picked from other frames);
//!   across a seam the transition is multiband, so no seam shows, and at an occlusion edge the
//!   crisp edge's coefficients win over the other frame's defocus spill.

use super::blur::gaussian_blur;
use super::image::{Image, Plane, Sample};
use super::pyramid::{collapse, gaussian_pyramid, laplacian_pyramid, levels_for};
use super::Progress;
use rayon::prelude::*;

/// A label counts as present at a level where its blurred mask exceeds this: anywhere within
/// the level's kernel reach, so every seam is crossed by a contrast choice.
const PRESENT: f32 = 1e-3;
/// Reach of the finest band beyond a label region, in pixels (σ of the mask blur).
const FINE_REACH: f32 = 1.5;

pub enum Select<'a> {
    MaxContrast,
    /// Per-pixel frame index, and the most pyramid levels to use.
    Labels(&'a [u8], usize),
}

/// Where one frame may be chosen at each band level, and the weight of its residual.
struct Eligibility {
    present: Option<Vec<Plane>>,
    residual_weight: Plane,
}

fn eligibility(
    select: &Select,
    i: usize,
    n: usize,
    w: usize,
    h: usize,
    levels: usize,
) -> Eligibility {
    match select {
        Select::MaxContrast => {
            let mut g = gaussian_pyramid(&Plane::new(w, h, 1), levels);
            let top = g.pop().expect("at least one level");
            let weight = Plane::from_fn(top.width, top.height, 1, |_, _, _| 1.0 / n as f32);
            Eligibility {
                present: None,
                residual_weight: weight,
            }
        }
        Select::Labels(labels, _) => {
            let data = labels
                .par_iter()
                .map(|&l| (l as usize == i) as u8 as f32)
                .collect();
            let mask = Plane::from_vec(w, h, 1, data);
            let mut g = gaussian_pyramid(&mask, levels);
            let residual_weight = g.pop().expect("at least one level");
            if let Some(g0) = g.first_mut() {
                *g0 = gaussian_blur(g0, FINE_REACH);
            }
            Eligibility {
                present: Some(g),
                residual_weight,
            }
        }
    }
}

/// The fused image and, per pixel, the frame its finest band came from.
pub fn compose<T: Sample>(
    frames: &[Image<T>],
    select: Select,
    progress: &dyn Progress,
) -> (Image<T>, Vec<u8>) {
    let (w, h) = (frames[0].width, frames[0].height);
    let levels = match select {
        Select::MaxContrast => levels_for(w, h),
        Select::Labels(_, max) => levels_for(w, h).min(max.max(1)),
    };
    let top = levels - 1;
    let n = frames.len();
    let used: Vec<usize> = match select {
        Select::MaxContrast => (0..n).collect(),
        Select::Labels(labels, _) => {
            let mut seen = vec![false; n];
            labels.iter().for_each(|&l| seen[l as usize] = true);
            (0..n).filter(|&i| seen[i]).collect()
        }
    };
    progress.stage("compose", used.len());
    let mut out: Vec<Vec<Plane>> = Vec::new();
    let mut best: Vec<Plane> = Vec::new();
    let mut choice = vec![0u8; w * h];
    for &i in &used {
        let bands: Vec<Vec<Plane>> = frames[i]
            .to_planes()
            .iter()
            .map(|p| laplacian_pyramid(p, levels))
            .collect();
        let energy = band_energy(&bands, top);
        let elig = eligibility(&select, i, n, w, h, levels);
        if out.is_empty() {
            out = bands
                .iter()
                .map(|b| b.iter().map(|p| Plane::new(p.width, p.height, 1)).collect())
                .collect();
            best = energy
                .iter()
                .map(|e| Plane::from_fn(e.width, e.height, 1, |_, _, _| -1.0))
                .collect();
        }
        for l in 0..top {
            let present = elig.present.as_ref().map(|g| &g[l].data);
            let take: Vec<bool> = best[l]
                .data
                .par_iter_mut()
                .zip(&energy[l].data)
                .enumerate()
                .map(|(p, (b, &e))| {
                    let t = e > *b && present.is_none_or(|g| g[p] > PRESENT);
                    if t {
                        *b = e;
                    }
                    t
                })
                .collect();
            if l == 0 {
                choice
                    .iter_mut()
                    .zip(&take)
                    .filter(|(_, &t)| t)
                    .for_each(|(c, _)| *c = i as u8);
            }
            for (o, b) in out.iter_mut().zip(&bands) {
                o[l].data
                    .par_iter_mut()
                    .zip(&b[l].data)
                    .zip(&take)
                    .for_each(|((o, &v), &t)| {
                        if t {
                            *o = v;
                        }
                    });
            }
        }
        for (o, b) in out.iter_mut().zip(&bands) {
            o[top]
                .data
                .par_iter_mut()
                .zip(&b[top].data)
                .zip(&elig.residual_weight.data)
                .for_each(|((o, v), m)| *o += v * m);
        }
        progress.advance(1);
    }
    let planes: Vec<Plane> = out.iter().map(|pyr| collapse(pyr)).collect();
    (Image::from_planes(&planes), choice)
}

/// Local energy of the luma band at each level but the residual (luma bands are the same linear
/// mix of the colour bands as luma is of the colours).
fn band_energy(bands: &[Vec<Plane>], top: usize) -> Vec<Plane> {
    (0..top)
        .map(|l| {
            let data: Vec<f32> = if bands.len() == 1 {
                bands[0][l].data.par_iter().map(|v| v.abs()).collect()
            } else {
                (&bands[0][l].data, &bands[1][l].data, &bands[2][l].data)
                    .into_par_iter()
                    .map(|(r, g, b)| (0.299 * r + 0.587 * g + 0.114 * b).abs())
                    .collect()
            };
            let (bw, bh) = (bands[0][l].width, bands[0][l].height);
            gaussian_blur(&Plane::from_vec(bw, bh, 1, data), 1.0)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::NoProgress;

    #[test]
    fn labels_copy_their_frame_away_from_seams() {
        let a = Image::<u8>::from_fn(40, 30, 3, |x, y, c| ((x * 5 + y * 3 + c * 40) % 256) as u8);
        let b = Image::<u8>::from_fn(40, 30, 3, |_, _, _| 200);
        let frames = [a.clone(), b];
        let (out, choice) = compose(&frames, Select::Labels(&[0; 1200], 8), &NoProgress);
        let err = a
            .data
            .iter()
            .zip(&out.data)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap();
        assert!(err <= 1, "max error {err}");
        assert!(choice.iter().all(|&c| c == 0));
        let labels: Vec<u8> = (0..1200).map(|i| (i % 40 >= 20) as u8).collect();
        let (out, choice) = compose(&frames, Select::Labels(&labels, 8), &NoProgress);
        for y in 0..30 {
            assert_eq!(choice[y * 40 + 2], 0);
            assert_eq!(choice[y * 40 + 37], 1);
        }
        assert_eq!(out.at(39, 15, 1), 200);
        assert!(out.at(2, 15, 0).abs_diff(a.at(2, 15, 0)) <= 3);
    }

    #[test]
    fn max_contrast_picks_the_textured_frame() {
        let tex = Image::<u8>::from_fn(
            64,
            64,
            1,
            |x, y, _| {
                if (x / 2 + y / 2) % 2 == 0 {
                    40
                } else {
                    220
                }
            },
        );
        let flat = Image::<u8>::from_fn(64, 64, 1, |_, _, _| 130);
        let (out, choice) = compose(&[flat, tex.clone()], Select::MaxContrast, &NoProgress);
        let inner = |p: usize| (8..56).contains(&(p % 64)) && (8..56).contains(&(p / 64));
        let picked = (0..64 * 64).filter(|&p| inner(p) && choice[p] == 1).count();
        assert!(picked > 48 * 48 * 9 / 10, "picked {picked}");
        let diff = (0..64 * 64)
            .filter(|&p| inner(p))
            .map(|p| (out.data[p] as i32 - tex.data[p] as i32).abs())
            .max()
            .unwrap();
        assert!(diff < 40, "max diff {diff}");
    }
}
