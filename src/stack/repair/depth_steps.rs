//! Which side of each depth step a pixel lies on, by the near frame's own colours, and the
//! relabel that moves the pixels clearly the near object's to its frame.
//!
//! The label map follows contrast, and next to a near object's edge the frames focused farther
//! show the background's texture through its defocused rim: the labels can put the step a few
//! pixels inside the object. In the near frame the object is sharp and the background behind
//! it blurred, so the two colours separate where the labels do not.

use crate::stack::align::Coverage;
use crate::stack::blur::gaussian_blur;
use crate::stack::image::{Image, Plane, Sample, Tap};
use crate::stack::morphology::{window_max, window_min};
use rayon::prelude::*;

/// How far from a step the labels may have misplaced it, in full-resolution pixels.
const RING: usize = 8;
/// A pixel is clearly the near object's, and its label may move, where its squared colour
/// distance to the object's mean is under this share of that to the background's (half the
/// distance): nearer than the background's alone also takes textured far surfaces whose
/// colours happen to lie near the object's.
const CLEARLY: f32 = 0.25;
/// σ of the local mean colours [`sides`] compares, full-resolution pixels.
const MEAN_SIGMA: f32 = 6.0;

/// Per reduced pixel, the nearest and the farthest depth rank in its `factor`×`factor` block of
/// `depth`: which depths cover a block wholly, for every depth at once (rather than summing
/// each depth's region masks farther than it, which grows with the square of the frames).
fn block_extremes(depth: &[u8], w: usize, h: usize, factor: usize) -> (Vec<u8>, Vec<u8>) {
    let rw = w.div_ceil(factor);
    let (lo, hi): (Vec<Vec<u8>>, Vec<Vec<u8>>) = (0..h.div_ceil(factor))
        .into_par_iter()
        .map(|ry| {
            let (mut lo, mut hi) = (vec![u8::MAX; rw], vec![0u8; rw]);
            for y in ry * factor..((ry + 1) * factor).min(h) {
                for (x, &d) in depth[y * w..][..w].iter().enumerate() {
                    let c = x / factor;
                    (lo[c], hi[c]) = (lo[c].min(d), hi[c].max(d));
                }
            }
            (lo, hi)
        })
        .unzip();
    (lo.concat(), hi.concat())
}

/// Each pixel's side of the depth steps near it.
pub struct Sides {
    /// Per pixel, the depth rank of the object seen there: the labels' depth, but next to a
    /// step the near object's where the colours say it is there, and the background's where
    /// they say it is not.
    pub objects: Vec<u8>,
    /// Per pixel, whether it is clearly the near object's ([`CLEARLY`]).
    clear: Vec<bool>,
}

/// Within [`RING`] pixels of a step from depth `k` to `k + 2` or farther, decides each pixel
/// by the near frame's own colours: nearer the near object's local mean colour (over where it
/// is labelled, away from the ring) than the background's (over where depth `k + 2` or farther
/// is labelled), it is the near object, else the background. Only where the near frame covers
/// the pixel; elsewhere, and away from the steps, the labels' depth is taken as it is. `depth`
/// is the label map as depth ranks, 0 nearest; `reduced`, each depth's frame reduced by
/// `factor`.
pub fn sides<T: Sample>(
    frames: &[Image<T>],
    coverage: &[Coverage],
    frame_of: &(dyn Fn(usize) -> usize + Sync),
    depth: &[u8],
    reduced: &[Vec<Plane>],
    factor: usize,
) -> Sides {
    let (w, h, ch) = (frames[0].width(), frames[0].height(), frames[0].channels());
    let n = reduced.len();
    let (rw, rh) = (w.div_ceil(factor), h.div_ceil(factor));
    let (lo, hi) = block_extremes(depth, w, h, factor);
    let nearest = window_min(depth, w, h, RING);
    let farthest = window_max(depth, w, h, RING);
    // Reduced pixels whose whole block is of one depth, or of some depth farther than one.
    let wholly = |f: &dyn Fn(usize) -> bool| -> Plane {
        let data = (0..rw * rh).map(|i| f32::from(u8::from(f(i)))).collect();
        Plane::from_vec(rw, rh, 1, data)
    };
    let s = MEAN_SIGMA / factor as f32;
    // Per depth k: the local mean colour of its object and of what lies behind it, in frame k.
    let means: Vec<Option<[Vec<Plane>; 2]>> = (0..n)
        .into_par_iter()
        .map(|k| {
            if k + 2 >= n {
                return None;
            }
            let inside = wholly(&|i| lo[i] as usize == k && hi[i] as usize == k);
            let behind = wholly(&|i| lo[i] as usize >= k + 2);
            Some([inside, behind].map(|wgt| {
                let norm = gaussian_blur(&wgt, s);
                reduced[k]
                    .iter()
                    .map(|c| {
                        let data = c
                            .data()
                            .iter()
                            .zip(wgt.data())
                            .map(|(v, m)| v * m)
                            .collect();
                        let mut mean =
                            gaussian_blur(&Plane::from_vec(wgt.width(), wgt.height(), 1, data), s);
                        for (v, &z) in mean.data_mut().iter_mut().zip(norm.data()) {
                            *v = if z > 1e-3 { *v / z } else { f32::NAN };
                        }
                        mean
                    })
                    .collect()
            }))
        })
        .collect();
    let cols = Tap::all_reduced(w, factor, rw);
    let mut objects = depth.to_vec();
    let mut clear = vec![false; w * h];
    objects
        .par_chunks_mut(w)
        .zip(clear.par_chunks_mut(w))
        .zip(depth.par_chunks(w))
        .enumerate()
        .for_each(|(y, ((orow, crow), drow))| {
            let ty = Tap::reduced(y, factor, rh);
            for x in 0..w {
                let i = y * w + x;
                let k = nearest[i] as usize;
                if farthest[i] as usize >= k + 2 {
                    let Some([inside, behind]) = &means[k] else {
                        continue;
                    };
                    // Never a side, nor a colour, from a frame that does not reach here.
                    if !coverage[frame_of(k)].covers(x, y) {
                        continue;
                    }
                    let px = &frames[frame_of(k)].data()[i * ch..][..ch];
                    let (mut din, mut dout) = (0.0, 0.0);
                    for (c, v) in px.iter().enumerate() {
                        let v = v.to_f32() / T::MAX;
                        din += (v - inside[c].sample_taps(cols[x], ty)).powi(2);
                        dout += (v - behind[c].sample_taps(cols[x], ty)).powi(2);
                    }
                    if !(din.is_finite() && dout.is_finite()) {
                        continue;
                    }
                    if din < dout {
                        orow[x] = k as u8;
                        crow[x] = din < CLEARLY * dout;
                    } else if drow[x] as usize == k {
                        orow[x] = farthest[i];
                    }
                }
            }
        });
    Sides { objects, clear }
}

/// Moves to the near object's depth every pixel that [`sides`] found clearly the object's but
/// that is labelled two or more planes behind it; returns how many moved.
pub fn relabel(depth: &mut [u8], sides: &Sides) -> usize {
    depth
        .par_iter_mut()
        .zip(&sides.objects)
        .zip(&sides.clear)
        .map(|((d, &k), &clear)| {
            let moved = clear && *d as usize >= k as usize + 2;
            if moved {
                *d = k;
            }
            usize::from(moved)
        })
        .sum()
}
