//! The Gaussian pyramid levels registration works on, each knowing its scale.

use crate::stack::image::{Image, Plane, Sample};
use crate::stack::pyramid::{reduce, RowSource};
use crate::stack::transform::Affine;

/// The smallest side a level is reduced from: registration, which never works at full size,
/// needs frames of at least this many pixels each way.
pub const MIN_SIDE: usize = 16;

/// Levels `first..first + planes.len()` of a Burt–Adelson pyramid: pixel (x, y) of level k sits
/// at (2^k·x, 2^k·y) in full resolution (`reduce` keeps even pixels' centres).
pub struct Levels {
    pub first: usize,
    pub planes: Vec<Plane>,
}

/// A frame's luma as rows made as the first reduction reads them: a frame being registered
/// then holds no full-resolution luma plane (12 MB at 3 MP) unless level 0 itself is wanted.
pub struct Luma<'a, T>(pub &'a Image<T>);

impl<T: Sample> RowSource for Luma<'_, T> {
    fn size(&self) -> (usize, usize) {
        (self.0.width(), self.0.height())
    }

    fn row<'b>(&'b self, y: usize, buf: &'b mut [f32]) -> &'b [f32] {
        self.0.luma_row(y, buf);
        buf
    }
}

impl Levels {
    /// Levels `first..=last` of `full`'s pyramid, stopping early if a level gets tiny.
    pub fn build(full: &impl RowSource, first: usize, last: usize) -> Levels {
        let (w, h) = full.size();
        let mut planes = Vec::with_capacity(last + 1 - first);
        if first == 0 {
            let (mut buf, mut data) = (vec![0.0f32; w], Vec::with_capacity(w * h));
            for y in 0..h {
                data.extend_from_slice(full.row(y, &mut buf));
            }
            planes.push(Plane::from_vec(w, h, 1, data));
        }
        // Level k is reduced from level k − 1; level 1 straight from the source's rows.
        let mut cur: Option<Plane> = None;
        for k in 1..=last {
            let size = cur.as_ref().map_or((w, h), |p| (p.width(), p.height()));
            if size.0.min(size.1) < MIN_SIDE {
                break;
            }
            let next = match &cur {
                Some(p) => reduce(p),
                None => reduce(full),
            };
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_of_a_frames_streamed_luma_are_those_of_its_luma_plane() {
        let mut frame = Image::<u8>::new(70, 45, 3);
        for (i, v) in frame.data_mut().iter_mut().enumerate() {
            *v = ((i * 37 + i / 211) % 256) as u8;
        }
        let plane = frame.luma();
        for first in [0, 1, 2] {
            let (a, b) = (
                Levels::build(&Luma(&frame), first, 3),
                Levels::build(&plane, first, 3),
            );
            assert_eq!((a.first, a.last()), (b.first, b.last()));
            assert!(a.planes.iter().zip(&b.planes).all(|(a, b)| a == b));
        }
    }
}
