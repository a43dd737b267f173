//! The edge fill: near objects' own pixels next to a depth step copied into the frames focused
//! behind them.

use crate::stack::image::{Image, Sample};
use crate::stack::morphology::window_max;
#[cfg(doc)]
use crate::stack::repair::depth_steps;
use rayon::prelude::*;

/// Full-resolution pixels from a depth step within which [`fill_near_objects`] fills.
const FILL_REACH: usize = 6;

/// Copies each near object's own pixels next to a depth step into the frames focused two or
/// more planes behind it, where the labels and the colours at the step ([`depth_steps::sides`]) agree that
/// the object is there and within [`FILL_REACH`] of the step; returns how many pixels.
/// `objects` are the depth ranks the colours agree with, the farthest where not every frame
/// reaches.
///
/// The un-mixing cleans a far frame only outside the near object. Inside its edge the far frame
/// still shows the object defocused with the background through it, and the compose's coarser
/// bands, shared by the pixels on both sides of the step, took that texture over the object's
/// own where it had more contrast: the background's texture showed over the object's first
/// pixels. Filled, a far frame shows at the step what the output wants on both sides of it, so
/// whichever frame a band comes from, the edge is the object's. Only near the step: deeper in, a
/// far frame's bands can be the better ones, where a slanted object lies between the planes its
/// label and the far frame are focused on. Pixels the colour calls background are left, so a label that overreaches the
/// object does not carry the near frame's blurred background into the far frames.
pub(super) fn fill_near_objects<T: Sample>(
    frames: &mut [Image<T>],
    depth: &[u8],
    objects: &[u8],
    frame_of: &(dyn Fn(usize) -> usize + Sync),
) -> usize {
    let (w, h, ch) = (frames[0].width(), frames[0].height(), frames[0].channels());
    // Nothing is filled where not every frame reaches: `objects` holds the farthest rank there,
    // which no plane lies behind (near the border a label can be the reference's because the
    // frame the labelling chose does not cover the pixel, which says nothing of depth; filled
    // there, a border would take the reference's blurred background).
    // Per pixel, its object's depth rank + 1 where it is filled, else 0.
    let mut fill = window_max(depth, w, h, FILL_REACH);
    fill.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, f) in row.iter_mut().enumerate() {
            let (i, k) = (y * w + x, depth[y * w + x]);
            let step = *f as usize >= k as usize + 2;
            let agreed = objects[i] == k;
            *f = if step && agreed { k + 1 } else { 0 };
        }
    });
    for l in 2..frames.len() {
        // The far frame is taken out of the stack while the nearer ones are read.
        let target = frame_of(l);
        let mut far = std::mem::replace(&mut frames[target], Image::new(0, 0, ch));
        let nearer = &*frames;
        far.data_mut()
            .par_chunks_mut(w * ch)
            .zip(fill.par_chunks(w))
            .enumerate()
            .for_each(|(y, (row, fill))| {
                for (x, &f) in fill.iter().enumerate() {
                    // f = k + 1 for an object at depth k: filled where k + 2 <= l.
                    if f > 0 && (f as usize) < l {
                        let i = (y * w + x) * ch;
                        let near = &nearer[frame_of(f as usize - 1)].data()[i..][..ch];
                        row[x * ch..][..ch].copy_from_slice(near);
                    }
                }
            });
        frames[target] = far;
    }
    fill.iter().filter(|&&f| f > 0).count()
}
