//! A ghost check that needs no ground truth: is every textured part of a fused image some input
//! frame's pixels, moved a little?
//!
//! A ghost (an object twice, its text doubled) or a seam through a misregistered object is a
//! tile that matches no single input frame anywhere near its place. The check therefore works
//! only from the output and the raw inputs:
//!
//! 1. everything is resampled to [`WIDTH`] px wide, so the fixed sizes below mean the same at any
//!    resolution;
//! 2. each input frame is aligned to the output by a global affine the check finds itself (block
//!    matching by normalised cross-correlation, then a robust affine fit), not with the fuse's
//!    transforms, so a registration error cannot hide itself;
//! 3. the output is cut into [`TILE`] px tiles; the textured half of them (luma standard deviation
//!    at or above the median, and above [`MIN_STD`]) are checked: a tile's score is the best
//!    normalised cross-correlation against any aligned frame at any integer shift within
//!    ±[`SEARCH`] px (local parallax is allowed), and a tile below [`THRESHOLD`] is a ghost.
//!
//! Both images are smoothed by [`SMOOTH`] px first, so half-pixel offsets and sensor noise do not
//! lower a true match much. What the check can see (tests/ghosts.rs): content moved well beyond
//! the window, and two copies far enough apart that their mix no longer looks like one frame's
//! defocus; a misregistration inside the window is "moved a little" and passes. Even a perfect
//! all-in-focus image scores a few per cent on small stacks, since at occlusion edges no frame
//! holds a sharp near edge over a sharp background. The parameters are fixed, so that the
//! figures this check gives are comparable across versions of the fuse.

use super::align::{warp_frame, Exposure};
use super::blur::gaussian_blur;
use super::image::{Image, Plane, Sample};
use super::register::ransac::{ransac_affine, Pair};
use super::transform::{Affine, Warp};
use rayon::prelude::*;

/// Working width, px: the sizes below are at this width.
pub const WIDTH: usize = 1000;
/// Tile side, px.
pub const TILE: usize = 32;
/// Search radius around a tile's aligned place, px. It has to absorb only what is no ghost: the
/// check's own alignment error (under a pixel at the corners for a frame whose sharp content is
/// the background; tests/ghosts.rs) and half-pixel offsets, so ±2 px. A wider window hides
/// parallax itself: it was ±5 px, and 6 px of parallax at 1600 px is 3.75 px here, so a near
/// object put 3–4 px away from where every frame shows it against its background (misregistered
/// by the parallax) still passed as "moved a little". At ±2 px, a tile whose content sits more
/// than ~3 px (at 1600 px) from where every frame shows it is a ghost. (A frame focused on near
/// layers that move against the background is aligned partly to them, off by up to their
/// parallax: the tiles of those layers then still find it, the background's find other frames.)
pub const SEARCH: usize = 2;
/// Below this best correlation a tile is a ghost.
pub const THRESHOLD: f32 = 0.8;
/// Luma standard deviation (0..=1) a tile needs to count as textured at all.
pub const MIN_STD: f32 = 0.01;
/// Gaussian sigma, px, both images are smoothed with before the tiles are compared.
pub const SMOOTH: f32 = 1.0;

/// Block size and search radius of the global alignment at a quarter of [`WIDTH`] (coarse), and
/// block size and radius at [`WIDTH`] around the coarse shift (fine).
const COARSE_BLOCK: usize = 24;
const COARSE_RADIUS: isize = 20;
const FINE_BLOCK: usize = 48;
const FINE_RADIUS: isize = 4;
/// RANSAC inlier distance (px at [`WIDTH`]) of the alignment's affine fit.
const FIT_THRESHOLD: f64 = 1.5;

/// The outcome of [`check`].
#[derive(Clone, Debug)]
pub struct GhostReport {
    /// Tiles across and down (at [`WIDTH`]).
    pub cols: usize,
    pub rows: usize,
    /// Per tile, row-major: its best correlation if it is textured, else None.
    pub scores: Vec<Option<f32>>,
    /// Per input frame: the affine the check found from output to frame at [`WIDTH`] (None when
    /// the frame could not be aligned; it then takes no part).
    pub alignments: Vec<Option<Affine>>,
}

impl GhostReport {
    /// Textured tiles checked.
    pub fn textured(&self) -> usize {
        self.scores.iter().flatten().count()
    }

    /// Textured tiles below [`THRESHOLD`].
    pub fn ghosts(&self) -> usize {
        self.scores
            .iter()
            .flatten()
            .filter(|&&s| s < THRESHOLD)
            .count()
    }

    /// Share of the textured tiles that are ghosts, 0..=1 (0 without textured tiles).
    pub fn share(&self) -> f64 {
        self.ghosts() as f64 / self.textured().max(1) as f64
    }
}

/// Checks `output` against the raw `frames` (any sizes; each is aligned by itself).
pub fn check<T: Sample, U: Sample>(output: &Image<T>, frames: &[Image<U>]) -> GhostReport {
    let out = to_width(&output.luma(), WIDTH);
    let smooth_out = gaussian_blur(&out, SMOOTH);
    let (w, h) = (out.width(), out.height());
    let mut alignments = Vec::with_capacity(frames.len());
    let mut aligned = Vec::with_capacity(frames.len());
    for f in frames {
        let luma = to_width(&f.luma(), WIDTH);
        let a = align(&out, &luma);
        if let Some(a) = a {
            let (warped, _) = warp_frame(&luma, &out, &Warp::affine(a), &[Exposure::SAME]);
            aligned.push(gaussian_blur(&warped, SMOOTH));
        }
        alignments.push(a);
    }
    let m = SEARCH;
    let cols = w.saturating_sub(2 * m) / TILE;
    let rows = h.saturating_sub(2 * m) / TILE;
    let stds: Vec<f32> = (0..cols * rows)
        .map(|t| {
            let (x0, y0) = (m + (t % cols) * TILE, m + (t / cols) * TILE);
            stats(&smooth_out, x0, y0, TILE).1
        })
        .collect();
    let mut sorted = stds.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    let scores = (0..cols * rows)
        .into_par_iter()
        .map(|t| {
            if stds[t] < median.max(MIN_STD) {
                return None;
            }
            let (x0, y0) = (m + (t % cols) * TILE, m + (t / cols) * TILE);
            let s = aligned
                .iter()
                .map(|f| {
                    let at = (x0 as isize, y0 as isize);
                    best_ncc(&smooth_out, (x0, y0), f, at, TILE, SEARCH as isize).0
                })
                .fold(-1.0f32, f32::max);
            Some(s)
        })
        .collect();
    GhostReport {
        cols,
        rows,
        scores,
        alignments,
    }
}

/// `p` resampled to `width` px wide (area-like: smoothed before it is shrunk).
fn to_width(p: &Plane, width: usize) -> Plane {
    let s = width as f32 / p.width() as f32;
    let height = ((p.height() as f32 * s).round() as usize).max(1);
    let src = if s < 1.0 {
        gaussian_blur(p, 0.5 / s)
    } else {
        p.clone()
    };
    Plane::from_fn(width, height, 1, |x, y, _| {
        src.sample_bilinear((x as f32 + 0.5) / s - 0.5, (y as f32 + 0.5) / s - 0.5)
    })
}

/// Mean and standard deviation of the `n`×`n` block at (x0, y0).
fn stats(p: &Plane, x0: usize, y0: usize, n: usize) -> (f32, f32) {
    let (mut s, mut s2) = (0.0f64, 0.0f64);
    for y in y0..y0 + n {
        for &v in &p.data()[y * p.width() + x0..y * p.width() + x0 + n] {
            s += v as f64;
            s2 += (v as f64) * (v as f64);
        }
    }
    let k = (n * n) as f64;
    let mean = s / k;
    (mean as f32, (s2 / k - mean * mean).max(0.0).sqrt() as f32)
}

/// Best normalised cross-correlation of `a`'s `n`×`n` block at `at` against `b`'s block at
/// `near` moved by (dx, dy), |dx|, |dy| ≤ `r` (shifts that leave `b` are skipped); with the best
/// shift. -1 when `a`'s block is flat or no shift fits.
fn best_ncc(
    a: &Plane,
    at: (usize, usize),
    b: &Plane,
    near: (isize, isize),
    n: usize,
    r: isize,
) -> (f32, (isize, isize)) {
    let (x0, y0) = at;
    let (ma, sa) = stats(a, x0, y0, n);
    let mut best = (-1.0f32, (0, 0));
    if sa <= 0.0 {
        return best;
    }
    for dy in -r..=r {
        for dx in -r..=r {
            let (bx, by) = (near.0 + dx, near.1 + dy);
            if bx < 0 || by < 0 || bx as usize + n > b.width() || by as usize + n > b.height() {
                continue;
            }
            let (bx, by) = (bx as usize, by as usize);
            let (mb, sb) = stats(b, bx, by, n);
            if sb <= 0.0 {
                continue;
            }
            let mut cov = 0.0f64;
            for y in 0..n {
                let ra = &a.data()[(y0 + y) * a.width() + x0..][..n];
                let rb = &b.data()[(by + y) * b.width() + bx..][..n];
                for (&u, &v) in ra.iter().zip(rb) {
                    cov += ((u - ma) * (v - mb)) as f64;
                }
            }
            let ncc = (cov / (n * n) as f64 / (sa as f64 * sb as f64)) as f32;
            if ncc > best.0 {
                best = (ncc, (dx, dy));
            }
        }
    }
    best
}

/// The affine from `out`'s pixels to `frame`'s (both at the working width): textured blocks
/// matched at a quarter of the resolution over a wide window, refined at full resolution, then a
/// robust affine through the block centres. None with too few matches.
fn align(out: &Plane, frame: &Plane) -> Option<Affine> {
    let quarter = |p: &Plane| to_width(p, p.width() / 4);
    let (oq, fq) = (quarter(out), quarter(frame));
    let b = COARSE_BLOCK;
    let r = COARSE_RADIUS as usize;
    let mut starts = Vec::new();
    let mut y = r;
    while y + b + r <= oq.height() {
        let mut x = r;
        while x + b + r <= oq.width() {
            starts.push((x, y));
            x += b / 2;
        }
        y += b / 2;
    }
    let pairs: Vec<Pair> = starts
        .par_iter()
        .filter_map(|&(x, y)| {
            if stats(&oq, x, y, b).1 < MIN_STD {
                return None;
            }
            let at = (x as isize, y as isize);
            let (c, (dx, dy)) = best_ncc(&oq, (x, y), &fq, at, b, COARSE_RADIUS);
            if c < 0.5 {
                return None;
            }
            // Refine the block's centre region at full resolution around the coarse shift.
            let fb = FINE_BLOCK;
            let (cx, cy) = (4 * x + 2 * b - fb / 2, 4 * y + 2 * b - fb / 2);
            let (gx, gy) = (cx as isize + 4 * dx, cy as isize + 4 * dy);
            let (c2, (ex, ey)) = best_ncc(out, (cx, cy), frame, (gx, gy), fb, FINE_RADIUS);
            if c2 < 0.5 {
                return None;
            }
            let centre = (
                cx as f64 + fb as f64 / 2.0 - 0.5,
                cy as f64 + fb as f64 / 2.0 - 0.5,
            );
            let moved = (
                (gx + ex) as f64 + fb as f64 / 2.0 - 0.5,
                (gy + ey) as f64 + fb as f64 / 2.0 - 0.5,
            );
            Some((centre, moved))
        })
        .collect();
    ransac_affine(&pairs, FIT_THRESHOLD, 500, 1)
        .filter(|f| f.inliers.len() >= 6)
        .map(|f| f.affine)
}
