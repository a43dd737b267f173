//! The Gaussian pyramid levels registration works on, each knowing its scale.

use crate::stack::image::Plane;
use crate::stack::pyramid::reduce;
use crate::stack::transform::Affine;

/// Levels `first..first + planes.len()` of a Burt–Adelson pyramid: pixel (x, y) of level k sits
/// at (2^k·x, 2^k·y) in full resolution (`reduce` keeps even pixels' centres).
pub struct Levels {
    pub first: usize,
    pub planes: Vec<Plane>,
}

impl Levels {
    /// Levels `first..=last` of `full`'s pyramid, stopping early if a level gets tiny.
    pub fn build(full: &Plane, first: usize, last: usize) -> Levels {
        let mut planes = Vec::with_capacity(last + 1 - first);
        if first == 0 {
            planes.push(full.clone());
        }
        // Level k is reduced from level k − 1 without copying the full-resolution plane, which
        // is most of the memory of a frame being registered.
        let mut cur: Option<Plane> = None;
        for k in 1..=last {
            let src = cur.as_ref().unwrap_or(full);
            if src.width.min(src.height) < 16 {
                break;
            }
            let next = reduce(src);
            if k >= first {
                planes.push(next.clone());
            }
            cur = Some(next);
        }
        Levels { first, planes }
    }

    /// The plane of absolute level `k`.
    pub fn get(&self, k: usize) -> &Plane {
        &self.planes[k - self.first]
    }

    pub fn last(&self) -> usize {
        self.first + self.planes.len() - 1
    }
}

/// The smallest level whose plane has at most `max_pixels` pixels.
pub fn level_within(width: usize, height: usize, max_pixels: usize) -> usize {
    let (mut w, mut h, mut k) = (width, height, 0);
    while w * h > max_pixels && w.min(h) >= 32 {
        w = w.div_ceil(2);
        h = h.div_ceil(2);
        k += 1;
    }
    k
}

/// `a` (full-resolution coordinates) expressed in level-`k` coordinates.
pub fn to_level(a: &Affine, k: usize) -> Affine {
    let s = (1u64 << k) as f64;
    let [[p, q, c], [r, t, f]] = a.0;
    Affine([[p, q, c / s], [r, t, f / s]])
}

/// `a` (level-`k` coordinates) expressed in full-resolution coordinates.
pub fn from_level(a: &Affine, k: usize) -> Affine {
    let s = (1u64 << k) as f64;
    let [[p, q, c], [r, t, f]] = a.0;
    Affine([[p, q, c * s], [r, t, f * s]])
}
