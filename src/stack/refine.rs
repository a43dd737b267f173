//! Full quality only where the output keeps it. A stack may come as a cheap development of
//! every frame at full size, which the fuse registers, labels, takes the spill out of and
//! blends at the coarse levels, and a full one the fuse asks for per frame just before the
//! compose, only over the regions whose finest blending levels that frame gives, with the
//! margins the blending and the warp reach. The stack says how it develops ([`Develop`]); the
//! engine stays pixel work, whatever the frames are.

use super::align::{patch_row, warp_refine_into, Exposure, Patch, Rect};
use super::fuse::{warp_of, Alignment};
use super::image::{Image, Sample};
use super::register::Placement;
use super::transform::Warp;
use super::{Progress, Stage};
use rayon::prelude::*;

/// A stack developed two ways: cheaply in whole, in full over the regions asked for.
pub trait Develop<T>: Sync {
    /// Frames in the stack.
    fn frames(&self) -> usize;
    /// Frame `i`, cheaply developed at its full size. The same image every time it is asked.
    fn cheap(&self, i: usize) -> Result<Image<T>, String>;
    /// Frames at full quality over the rectangles asked of each (`(i, rects)`, in the frame's
    /// own geometry), and cheaply as [`Develop::cheap`] gives those pixels: what refining
    /// takes, with no second cheap development of a whole frame. Frames are asked together so
    /// that the stack can share their work out over the cores; the pieces come in the order
    /// asked. An error names the frame.
    fn full(&self, asked: &[(usize, &[Rect])]) -> Result<Vec<Vec<Piece<T>>>, (usize, String)>;
    /// Bytes the stack holds until the compose (its undeveloped frames).
    fn held_bytes(&self) -> usize;
    /// Bytes developing one frame takes while it runs, cheaply or in full.
    fn working_bytes(&self) -> usize;
}

/// A rectangle of a frame developed both ways.
pub struct Piece<T> {
    pub full: Image<T>,
    pub cheap: Image<T>,
}

/// Output pixels around a frame's labels where its finest blending level may be taken from it
/// (the label mask's blur, σ 1.5, above its threshold): beyond this the blend's coarser levels
/// are all a frame gives, and the cheap development, at full size, carries those. Textured
/// pixels only: where the labelling found none every frame ties, flat to within noise, and the
/// cheap development is as good. Margins of 6 to 16 px fuse the simulator's raw stacks within
/// 0.01 dB of each other.
pub const MARGIN: usize = 6;

/// The grid on which the regions are marked in a frame's geometry, and the rows a region's
/// rectangles are cut into: few tall rectangles read less halo than many small ones, tall
/// ones develop more pixels no label needs.
const CELL: usize = 8;
const BAND: usize = 32;
/// Needed columns this close together are developed as one rectangle.
const GAP: usize = 16;

/// What the full development covered.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Developed {
    /// Pixels developed at full quality, over all frames.
    pub pixels: usize,
    /// The rectangles they were asked for in.
    pub rects: usize,
    /// Pixels a frame has: `pixels` over it is how many frames' worth were developed.
    pub frame_pixels: usize,
}

impl Developed {
    /// Frames' worth of full development.
    pub fn frames(&self) -> f64 {
        self.pixels as f64 / self.frame_pixels.max(1) as f64
    }
}

impl std::fmt::Display for Developed {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "{} px in full ({:.2} frames' worth, {} rectangles)",
            self.pixels,
            self.frames(),
            self.rects
        )
    }
}

/// Replaces the cheap development in `frames` (warped onto the reference as the fuse holds
/// them, and spill-removed) by the full one wherever frame `i` is labelled `i` and the
/// labelling found texture (`labels`, `textured`; `None`: everywhere), within [`MARGIN`].
/// Whatever the fuse did to a frame after warping it (the spill removal) is kept: a pixel the
/// fuse left as warped takes the full development warped as the frame was, rounded once; one
/// it changed, the difference between the full and the cheap development warped and added
/// ([`warp_refine_into`]).
pub(super) fn refine<T: Sample>(
    frames: &mut [Image<T>],
    labels: Option<(&[u8], &[bool])>,
    alignment: Option<&Alignment>,
    reference: usize,
    stack: &dyn Develop<T>,
    progress: &dyn Progress,
) -> Result<Developed, (usize, String)> {
    let (w, h) = (frames[0].width(), frames[0].height());
    progress.stage(Stage::Develop, frames.len());
    let mut scratch = Vec::new();
    let mut done = Developed {
        frame_pixels: w * h,
        ..Developed::default()
    };
    // Each frame's warp and regions. Frames share the output's geometry (the fuse checks it),
    // so regions are known before anything is developed, and a frame that gives no region (or
    // inherits its placement, taking no label) is not developed again.
    let jobs: Vec<Job> = (0..frames.len())
        .into_par_iter()
        .filter_map(|i| {
            let warp = match alignment {
                Some(a) if matches!(a.registration.how[i], Placement::Inherited { .. }) => {
                    return None
                }
                Some(a) if i != reference => {
                    Some((warp_of(&a.registration, i), &a.exposure[i][..]))
                }
                _ => None,
            };
            let rects = match labels {
                None => vec![Rect {
                    x: 0,
                    y: 0,
                    width: w,
                    height: h,
                }],
                Some((labels, textured)) => {
                    regions(labels, textured, i as u8, (w, h), |x, y| match &warp {
                        Some((warp, _)) => warp.apply(x, y),
                        None => (x, y),
                    })
                }
            };
            (!rects.is_empty()).then_some(Job {
                frame: i,
                warp,
                rects,
            })
        })
        .collect();
    progress.advance(frames.len() - jobs.len());
    // Frames developed together, their windows in one parallel run, while their regions add up
    // to at most a frame: a frame's regions are a few windows of unequal size, which two cores
    // alone would not share evenly, and the memory plan holds one frame's worth both ways.
    let mut batches: Vec<&[Job]> = Vec::new();
    let mut rest = &jobs[..];
    while !rest.is_empty() {
        let mut area = 0;
        let n = rest
            .iter()
            .take_while(|j| {
                area += j.pixels();
                area <= w * h
            })
            .count()
            .max(1);
        let (batch, after) = rest.split_at(n);
        batches.push(batch);
        rest = after;
    }
    for batch in batches {
        if progress.cancelled() {
            break;
        }
        let asked: Vec<(usize, &[Rect])> = batch.iter().map(|j| (j.frame, &j.rects[..])).collect();
        let developed = stack.full(&asked)?;
        for (job, pieces) in batch.iter().zip(developed) {
            let frame = &mut frames[job.frame];
            let patches: Vec<Patch<T>> = job
                .rects
                .iter()
                .zip(&pieces)
                .map(|(&r, p)| (r, &p.full, &p.cheap))
                .collect();
            done.pixels += job.pixels();
            done.rects += job.rects.len();
            match &job.warp {
                Some((warp, exposure)) => {
                    warp_refine_into(&patches, (w, h), warp, exposure, frame, &mut scratch);
                }
                None => {
                    let ch = frame.channels();
                    for patch in &patches {
                        let r = patch.0;
                        for y in 0..r.height {
                            let row =
                                &mut frame.data_mut()[((r.y + y) * w + r.x) * ch..][..r.width * ch];
                            for (v, d) in row.iter_mut().zip(patch_row(patch, y)) {
                                if d != 0.0 {
                                    *v = T::from_f32(v.to_f32() + d);
                                }
                            }
                        }
                    }
                }
            }
            progress.advance(1);
        }
    }
    Ok(done)
}

/// A frame to refine: its warp onto the reference (`None`: it is the reference) and regions.
struct Job<'a> {
    frame: usize,
    warp: Option<(Warp, &'a [Exposure])>,
    rects: Vec<Rect>,
}

impl Job<'_> {
    fn pixels(&self) -> usize {
        self.rects.iter().map(|r| r.width * r.height).sum()
    }
}

/// The rectangles of a `w`×`h` frame whose pixels the textured output pixels labelled `label`
/// (of the `w`×`h` output), and those within [`MARGIN`] of them, are made from; `to_frame`
/// takes an output pixel to the frame's geometry.
fn regions(
    labels: &[u8],
    textured: &[bool],
    label: u8,
    (w, h): (usize, usize),
    to_frame: impl Fn(f64, f64) -> (f64, f64),
) -> Vec<Rect> {
    // Blocks of output pixels holding the label, each marking the cells its centre maps near:
    // the margin, half the block, and the warp's bicubic taps and rounding.
    const BLOCK: usize = 4;
    let reach = (MARGIN + BLOCK / 2 + 3) as f64;
    let (cw, chh) = (w.div_ceil(CELL), h.div_ceil(CELL));
    let mut cells = vec![false; cw * chh];
    for by in (0..h).step_by(BLOCK) {
        for bx in (0..w).step_by(BLOCK) {
            let (x1, y1) = ((bx + BLOCK).min(w), (by + BLOCK).min(h));
            let ours = |y: usize| {
                let row = y * w + bx..y * w + x1;
                (labels[row.clone()].iter().zip(&textured[row])).any(|(&l, &t)| l == label && t)
            };
            if !(by..y1).any(ours) {
                continue;
            }
            let (u, v) = to_frame((bx + x1) as f64 / 2.0, (by + y1) as f64 / 2.0);
            let cell = |a: f64, n: usize| (a.max(0.0) as usize / CELL).min(n - 1);
            if u + reach < 0.0 || v + reach < 0.0 || u - reach >= w as f64 || v - reach >= h as f64
            {
                continue;
            }
            for cy in cell(v - reach, chh)..=cell(v + reach, chh) {
                cells[cy * cw + cell(u - reach, cw)..=cy * cw + cell(u + reach, cw)].fill(true);
            }
        }
    }
    let mut rects = Vec::new();
    let band_cells = BAND / CELL;
    for b0 in (0..chh).step_by(band_cells) {
        let rows = b0..(b0 + band_cells).min(chh);
        let used: Vec<usize> = (0..cw)
            .filter(|&cx| rows.clone().any(|cy| cells[cy * cw + cx]))
            .collect();
        // Runs of needed columns, joined across gaps narrower than GAP.
        let mut runs: Vec<(usize, usize)> = Vec::new();
        for cx in used {
            match runs.last_mut() {
                Some((_, end)) if (cx - *end) * CELL <= GAP => *end = cx + 1,
                _ => runs.push((cx, cx + 1)),
            }
        }
        for (c0, c1) in runs {
            let marked = |cy: &usize| (c0..c1).any(|cx| cells[cy * cw + cx]);
            let top = rows.clone().find(marked).expect("a run has a marked cell");
            let bottom = rows
                .clone()
                .rev()
                .find(marked)
                .expect("a run has a marked cell");
            let (x, y) = (c0 * CELL, top * CELL);
            rects.push(Rect {
                x,
                y,
                width: (c1 * CELL).min(w) - x,
                height: ((bottom + 1) * CELL).min(h) - y,
            });
        }
    }
    rects
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{render, SimParams};
    use crate::stack::{fuse, fuse_developing, FuseParams, NoProgress};

    /// The `r` of an image.
    fn crop<T: Sample>(img: &Image<T>, r: Rect) -> Image<T> {
        let (w, ch) = (img.width(), img.channels());
        let data = (r.y..r.y + r.height)
            .flat_map(|y| &img.data()[(y * w + r.x) * ch..][..r.width * ch])
            .copied()
            .collect();
        Image::from_vec(r.width, r.height, ch, data)
    }

    /// Pictures already developed, the cheap development `cheap` of each: the full one is the
    /// picture itself.
    struct Pictures<'a> {
        full: &'a [Image<u8>],
        cheap: Vec<Image<u8>>,
    }

    impl Develop<u8> for Pictures<'_> {
        fn frames(&self) -> usize {
            self.full.len()
        }
        fn cheap(&self, i: usize) -> Result<Image<u8>, String> {
            Ok(self.cheap[i].clone())
        }
        fn full(&self, asked: &[(usize, &[Rect])]) -> Result<Vec<Vec<Piece<u8>>>, (usize, String)> {
            let piece = |i: usize, r| Piece {
                full: crop(&self.full[i], r),
                cheap: crop(&self.cheap[i], r),
            };
            Ok(asked
                .iter()
                .map(|&(i, rects)| rects.iter().map(|&r| piece(i, r)).collect())
                .collect())
        }
        fn held_bytes(&self) -> usize {
            0
        }
        fn working_bytes(&self) -> usize {
            0
        }
    }

    #[test]
    fn a_cheap_development_equal_to_the_full_one_fuses_exactly_as_the_pictures() {
        // Hand-held, so the regions go through the warps, with the spill removal on.
        let s = render(&SimParams {
            width: 256,
            height: 192,
            planes: 4,
            seed: 3,
            handheld: true,
            ..SimParams::default()
        });
        let params = FuseParams {
            reference: 1,
            ..FuseParams::default()
        };
        let want = fuse(s.frames.clone(), &params, &NoProgress).expect("fuses");
        let stack = Pictures {
            full: &s.frames,
            cheap: s.frames.clone(),
        };
        let got = fuse_developing(&stack, &params, &NoProgress).expect("fuses");
        assert_eq!(got.labels, want.labels);
        assert!(
            got.image == want.image,
            "the full development changed nothing"
        );
        let d = got.developed.expect("counted");
        assert!(d.pixels > 0 && d.frames() < 4.0, "{d}");
        assert_eq!(got.timings[0].0, Stage::Develop);
    }

    #[test]
    fn the_full_development_replaces_the_cheap_one_where_it_is_kept() {
        // Cheap frames with their finest detail gone (each pixel the mean of its 2×2 cell):
        // the lazy fuse takes the detail back where the labels keep it, so it is far nearer
        // the pictures' fuse than the cheap frames' own fuse is.
        let s = render(&SimParams {
            width: 256,
            height: 192,
            planes: 4,
            seed: 8,
            ..SimParams::default()
        });
        let cells = |f: &Image<u8>| {
            Image::from_fn(f.width(), f.height(), 3, |x, y, c| {
                let (x0, y0) = (x & !1, y & !1);
                let sum: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .iter()
                    .map(|(dx, dy)| u32::from(f.at(x0 + dx, y0 + dy, c)))
                    .sum();
                ((sum + 2) / 4) as u8
            })
        };
        let params = FuseParams {
            align: None,
            spill: false,
            label_repair: false,
            ..FuseParams::default()
        };
        let cheap: Vec<Image<u8>> = s.frames.iter().map(cells).collect();
        let want = fuse(s.frames.clone(), &params, &NoProgress).expect("fuses");
        let blurred = fuse(cheap.clone(), &params, &NoProgress).expect("fuses");
        let stack = Pictures {
            full: &s.frames,
            cheap,
        };
        let got = fuse_developing(&stack, &params, &NoProgress).expect("fuses");
        let (lazy, cheap) = (
            crate::stack::psnr(&got.image, &want.image, 8),
            crate::stack::psnr(&blurred.image, &want.image, 8),
        );
        eprintln!("lazily {lazy:.2} dB, cheap frames alone {cheap:.2} dB against the pictures");
        assert!(
            lazy > cheap + 20.0,
            "lazily {lazy:.2} dB, cheap {cheap:.2} dB"
        );
    }

    #[test]
    fn regions_cover_the_label_and_its_margin_and_little_else() {
        // A 40×30 patch of label 2 in a 512×384 output, the frame shifted by (100, 50).
        let (w, h) = (512, 384);
        let mut labels = vec![0u8; w * h];
        for y in 200..230 {
            labels[y * w + 300..y * w + 340].fill(2);
        }
        let textured = vec![true; w * h];
        let rects = regions(&labels, &textured, 2, (w, h), |x, y| (x + 100.0, y + 50.0));
        let inside = |x: usize, y: usize| {
            rects
                .iter()
                .any(|r| (r.x..r.x + r.width).contains(&x) && (r.y..r.y + r.height).contains(&y))
        };
        // Every frame pixel the patch and its margin map to is covered.
        for y in 250 - MARGIN..280 + MARGIN {
            for x in 400 - MARGIN..440 + MARGIN {
                assert!(inside(x, y), "({x}, {y}) left out of {rects:?}");
            }
        }
        let area: usize = rects.iter().map(|r| r.width * r.height).sum();
        let least = (40 + 2 * MARGIN) * (30 + 2 * MARGIN);
        assert!(area < 2 * least, "{area} pixels for {least}: {rects:?}");
        assert!(regions(&labels, &textured, 1, (w, h), |x, y| (x, y)).is_empty());
        // Mapped off the frame, or flat: nothing.
        assert!(regions(&labels, &textured, 2, (w, h), |x, y| (x + 900.0, y)).is_empty());
        let flat = vec![false; w * h];
        assert!(regions(&labels, &flat, 2, (w, h), |x, y| (x, y)).is_empty());
    }
}
