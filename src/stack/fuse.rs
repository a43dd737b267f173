//! The fusion entry point: a stack in, one all-in-focus image and its label map out.

use super::align::{estimate_exposure, warp_frame_into, Coverage, Exposure, Rect};
use super::compose::{compose, KeepOut, Reached, Select};
use super::graphcut::{label_stack, Labelled};
use super::image::{Image, Sample};
use super::memory::{self, Plan, Stack};
use super::order::{focus_order, OrderEvidence};
use super::params::{FuseParams, Method};
use super::refine::{refine, Develop, Developed};
use super::register::{register_with, Placement, RegisterError, Registration};
use super::spill::{unmix, Unmixed};
use super::transform::Warp;
use super::{Progress, Stage};
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// Why a stack cannot be fused; `frame` indices are 0-based positions in the input.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FuseError {
    #[error("no frames to fuse")]
    NoFrames,
    #[error("a focus stack needs at least 2 frames, got 1")]
    OneFrame,
    #[error("at most 255 frames can be fused, got {0}")]
    TooManyFrames(usize),
    #[error("frame {frame} is {got:?} (width, height, channels) but frame 0 is {expected:?}")]
    Mismatch {
        frame: usize,
        expected: (usize, usize, usize),
        got: (usize, usize, usize),
    },
    #[error("frames of {0}x{1} are too small to fuse (at least 8x8)")]
    TooSmall(usize, usize),
    #[error("reference frame {reference} does not exist in a stack of {frames}")]
    Reference { reference: usize, frames: usize },
    #[error(transparent)]
    Register(#[from] RegisterError),
    #[error("the frames have no area in common to crop to; fuse without cropping")]
    NothingToCrop,
    #[error("frame {frame}: {reason}")]
    Develop { frame: usize, reason: String },
    #[error("cancelled")]
    Cancelled,
}

fn go_on(progress: &dyn Progress) -> Result<(), FuseError> {
    if progress.cancelled() {
        Err(FuseError::Cancelled)
    } else {
        Ok(())
    }
}

/// How the frames were brought into the reference's geometry.
pub struct Alignment {
    pub registration: Registration,
    /// Per frame and channel, its exposure against the reference (already undone).
    pub exposure: Vec<Vec<Exposure>>,
    /// Per frame, the reference pixels it covers.
    pub coverage: Vec<Coverage>,
}

pub struct Fused<T> {
    pub image: Image<T>,
    /// Per pixel, the frame the output was taken from.
    pub labels: Vec<u8>,
    /// Which way the frames were focused, as their occlusion edges tell (`Order::Unknown` when
    /// too few edges tell: then the composition assumes nearest first, the documented input
    /// order, and the spill removal does nothing).
    pub order: OrderEvidence,
    /// `None` when the frames were taken as aligned.
    pub alignment: Option<Alignment>,
    /// The rectangle of the reference frame the output shows, when cropped.
    pub crop: Option<Rect>,
    /// What taking the nearer objects' spill out of farther frames did (`None`: not asked).
    pub spill: Option<Unmixed>,
    /// Wall time of each stage, in order.
    pub timings: Vec<(Stage, Duration)>,
    /// How the memory budget was spent.
    pub memory: Plan,
    /// What was developed at full quality, when the stack came cheaply developed
    /// ([`fuse_developing`]).
    pub developed: Option<Developed>,
}

/// Checks that a stack can be fused at all.
pub fn validate<T>(frames: &[Image<T>], reference: usize) -> Result<(), FuseError> {
    match frames.len() {
        0 => return Err(FuseError::NoFrames),
        1 => return Err(FuseError::OneFrame),
        n if n > 255 => return Err(FuseError::TooManyFrames(n)),
        _ => {}
    }
    let geom = |f: &Image<T>| (f.width(), f.height(), f.channels());
    let expected = geom(&frames[0]);
    if let Some((frame, f)) = frames.iter().enumerate().find(|(_, f)| geom(f) != expected) {
        return Err(FuseError::Mismatch {
            frame,
            expected,
            got: geom(f),
        });
    }
    if expected.0 < 8 || expected.1 < 8 {
        return Err(FuseError::TooSmall(expected.0, expected.1));
    }
    if reference >= frames.len() {
        return Err(FuseError::Reference {
            reference,
            frames: frames.len(),
        });
    }
    Ok(())
}

/// Fuses a stack: registers and warps it onto the reference (unless `params.align` is
/// `None`), labels and composes. Takes the frames by value to warp them in place.
pub fn fuse<T: Sample>(
    frames: Vec<Image<T>>,
    params: &FuseParams,
    progress: &dyn Progress,
) -> Result<Fused<T>, FuseError> {
    fuse_from(frames, None, params, progress)
}

/// [`fuse`] on a stack's cheap development, with the full development asked for only where
/// the output keeps it, just before the compose ([`super::refine`]).
pub fn fuse_developing<T: Sample>(
    stack: &dyn Develop<T>,
    params: &FuseParams,
    progress: &dyn Progress,
) -> Result<Fused<T>, FuseError> {
    let t = Instant::now();
    progress.stage(Stage::Develop, stack.frames());
    let mut frames = Vec::with_capacity(stack.frames());
    for i in 0..stack.frames() {
        go_on(progress)?;
        let f = stack
            .cheap(i)
            .map_err(|reason| FuseError::Develop { frame: i, reason })?;
        frames.push(f);
        progress.advance(1);
    }
    let cheap = t.elapsed();
    let mut fused = fuse_from(frames, Some(stack), params, progress)?;
    // One `developing` time: the cheap development first, the full one before the compose.
    let full: Duration = fused
        .timings
        .iter()
        .filter(|(s, _)| *s == Stage::Develop)
        .map(|(_, d)| *d)
        .sum();
    fused.timings.retain(|(s, _)| *s != Stage::Develop);
    fused.timings.insert(0, (Stage::Develop, cheap + full));
    Ok(fused)
}

fn fuse_from<T: Sample>(
    mut frames: Vec<Image<T>>,
    lazy: Option<&dyn Develop<T>>,
    params: &FuseParams,
    progress: &dyn Progress,
) -> Result<Fused<T>, FuseError> {
    validate(&frames, params.reference)?;
    go_on(progress)?;
    let mut timings = Vec::new();
    let mut t = Instant::now();
    let mut lap = |stage: Stage, timings: &mut Vec<(Stage, Duration)>| {
        timings.push((stage, t.elapsed()));
        t = Instant::now();
    };
    let reference = params.reference;
    let plan = memory::plan(&stack_of(&frames, lazy), params);
    let alignment = match &params.align {
        Some(p) => {
            let registration =
                register_with(&frames, reference, p, plan.concurrent_frames, progress).map_err(
                    |e| match e {
                        RegisterError::Cancelled => FuseError::Cancelled,
                        e => FuseError::Register(e),
                    },
                )?;
            lap(Stage::Register, &mut timings);
            go_on(progress)?;
            let a = align(&mut frames, registration, reference, progress);
            lap(Stage::Warp, &mut timings);
            go_on(progress)?;
            Some(a)
        }
        None => None,
    };
    let full: Vec<Coverage>;
    let coverage = match &alignment {
        Some(a) => &a.coverage,
        None => {
            full = vec![Coverage::full(frames[0].width(), frames[0].height()); frames.len()];
            &full
        }
    };
    let mut spill = None;
    let mut developed = None;
    // The full development, over what the compose will take from each frame.
    let mut develop = |frames: &mut [Image<T>], labels: Option<(&[u8], &[bool])>| match lazy {
        Some(stack) => {
            let a = alignment.as_ref();
            developed = Some(
                refine(frames, labels, a, reference, stack, progress)
                    .map_err(|(frame, reason)| FuseError::Develop { frame, reason })?,
            );
            go_on(progress)
        }
        None => Ok(()),
    };
    let (mut image, mut labels, order) = match params.method {
        Method::GraphCut => {
            let Labelled {
                mut labels,
                textured,
            } = label_stack(
                &frames,
                coverage,
                reference as u8,
                &params.graphcut,
                plan.label_rows,
                progress,
            );
            let order = focus_order(&frames, &labels, coverage);
            lap(Stage::Labels, &mut timings);
            go_on(progress)?;
            if params.spill {
                spill = Some(unmix(
                    &mut frames,
                    &mut labels,
                    &textured,
                    reference as u8,
                    coverage,
                    order.order,
                    params.label_repair,
                    progress,
                ));
                lap(Stage::Spill, &mut timings);
                go_on(progress)?;
            }
            let told = spill.as_mut().and_then(|s| s.told.take());
            if lazy.is_some() {
                develop(&mut frames, Some((&labels, &textured)))?;
                lap(Stage::Develop, &mut timings);
            }
            let (image, _) = compose(
                &frames,
                Select::Labels(
                    &labels,
                    params.graphcut.blend_levels,
                    params.spill.then_some(KeepOut {
                        order: order.order,
                        told: told.as_deref(),
                    }),
                    Some(Reached { coverage, row: 0 }),
                ),
                plan.band_rows,
                progress,
            );
            lap(Stage::Compose, &mut timings);
            go_on(progress)?;
            (image, labels, order)
        }
        Method::Pyramid => {
            if lazy.is_some() {
                develop(&mut frames, None)?;
                lap(Stage::Develop, &mut timings);
            }
            let (image, labels) = compose(&frames, Select::MaxContrast, plan.band_rows, progress);
            let order = focus_order(&frames, &labels, coverage);
            lap(Stage::Pyramid, &mut timings);
            go_on(progress)?;
            (image, labels, order)
        }
    };
    let crop = match (&alignment, params.crop) {
        (Some(a), true) => {
            let rect = Coverage::intersection(&a.coverage)
                .largest_rect()
                .ok_or(FuseError::NothingToCrop)?;
            (image, labels) = crop_to(&image, &labels, rect);
            Some(rect)
        }
        _ => None,
    };
    Ok(Fused {
        image,
        labels,
        order,
        alignment,
        crop,
        spill,
        timings,
        memory: plan,
        developed,
    })
}

fn stack_of<T>(frames: &[Image<T>], lazy: Option<&dyn Develop<T>>) -> Stack {
    Stack {
        frames: frames.len(),
        width: frames[0].width(),
        height: frames[0].height(),
        channels: frames[0].channels(),
        sample_bytes: size_of::<T>(),
        held: lazy.map_or(0, |s| s.held_bytes()),
        developing: lazy.map_or(0, |s| s.working_bytes()),
    }
}

/// Estimates every frame's exposure and warps it onto the reference, in place. A frame
/// registered by inheriting a neighbour's pose is left out.
fn align<T: Sample>(
    frames: &mut [Image<T>],
    registration: Registration,
    reference: usize,
    progress: &dyn Progress,
) -> Alignment {
    let r = &frames[reference];
    // Frame by frame in parallel: each samples 100k points through its warp.
    let exposure: Vec<Vec<Exposure>> = frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| match registration.how[i] {
            Placement::Direct | Placement::Chained { .. } => {
                estimate_exposure(f, r, &warp_of(&registration, i))
            }
            _ => vec![Exposure::SAME; r.channels()],
        })
        .collect();
    let coverage = warp_onto_reference(frames, &registration, &exposure, reference, progress);
    Alignment {
        registration,
        exposure,
        coverage,
    }
}

/// Warps every frame onto the reference in place, by its registration with its `exposure`
/// undone; returns the reference pixels each covers. The fuse's own step, public so that tools
/// can see the frames as the labelling saw them. A frame registered by inheriting a neighbour's
/// pose stands in as the reference and covers nothing: too little texture to match means too
/// little to contribute, and its pose is only a guess.
pub fn warp_onto_reference<T: Sample>(
    frames: &mut [Image<T>],
    registration: &Registration,
    exposure: &[Vec<Exposure>],
    reference: usize,
    progress: &dyn Progress,
) -> Vec<Coverage> {
    let n = frames.len();
    progress.stage(Stage::Warp, n - 1);
    let (w, h) = (frames[0].width(), frames[0].height());
    let mut coverage = vec![Coverage::full(w, h); n];
    let (before, rest) = frames.split_at_mut(reference);
    let (r, after) = rest
        .split_first_mut()
        .expect("reference checked by validate");
    let (mut spare, mut scratch) = (r.clone(), Vec::new());
    for (i, f) in before.iter_mut().enumerate().chain(
        after
            .iter_mut()
            .enumerate()
            .map(|(k, f)| (reference + 1 + k, f)),
    ) {
        if let Placement::Inherited { .. } = registration.how[i] {
            f.clone_from(r);
            coverage[i].spans.fill((0, 0));
        } else {
            let warp = warp_of(registration, i);
            coverage[i] = warp_frame_into(f, r, &warp, &exposure[i], &mut spare, &mut scratch);
            std::mem::swap(f, &mut spare);
        }
        progress.advance(1);
    }
    coverage
}

/// Frame `i`'s warp: its affine and local field.
pub(super) fn warp_of(registration: &Registration, i: usize) -> Warp {
    Warp {
        affine: registration.ref_to_frame[i],
        field: registration.field[i].clone(),
    }
}

/// The `rect` of an image and of its label map.
fn crop_to<T: Sample>(image: &Image<T>, labels: &[u8], rect: Rect) -> (Image<T>, Vec<u8>) {
    let (w, ch) = (image.width(), image.channels());
    let rows = rect.y..rect.y + rect.height;
    let data = rows
        .clone()
        .flat_map(|y| &image.data()[(y * w + rect.x) * ch..][..rect.width * ch])
        .copied()
        .collect();
    let labels = rows
        .flat_map(|y| &labels[y * w + rect.x..][..rect.width])
        .copied()
        .collect();
    (Image::from_vec(rect.width, rect.height, ch, data), labels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::NoProgress;

    #[test]
    fn bad_stacks_are_refused_with_the_reason() {
        let f = |w, h, c| Image::<u8>::new(w, h, c);
        let fuse =
            |frames: &[Image<u8>]| fuse(frames.to_vec(), &FuseParams::default(), &NoProgress).err();
        assert_eq!(fuse(&[]), Some(FuseError::NoFrames));
        assert_eq!(fuse(&[f(16, 16, 3)]), Some(FuseError::OneFrame));
        assert_eq!(
            fuse(&[f(16, 16, 3), f(16, 16, 3), f(16, 12, 3)]),
            Some(FuseError::Mismatch {
                frame: 2,
                expected: (16, 16, 3),
                got: (16, 12, 3)
            })
        );
        assert_eq!(
            fuse(&[f(4, 16, 1), f(4, 16, 1)]),
            Some(FuseError::TooSmall(4, 16))
        );
        assert_eq!(
            fuse(&vec![f(8, 8, 1); 256]),
            Some(FuseError::TooManyFrames(256))
        );
    }
}
