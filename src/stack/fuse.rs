//! The fusion entry point: aligned frames in, one all-in-focus image and its label map out.

use super::compose::{compose, Select};
use super::graphcut::{label_stack, GraphCutParams};
use super::image::{Image, Sample};
use super::Progress;
use std::time::{Duration, Instant};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Graph-cut labelling plus multiband seam blending (the paper's method).
    GraphCut,
    /// Laplacian-pyramid max-contrast fusion (the baseline).
    Pyramid,
}

#[derive(Clone, Debug)]
pub struct FuseParams {
    pub method: Method,
    pub graphcut: GraphCutParams,
}

impl Default for FuseParams {
    fn default() -> Self {
        Self {
            method: Method::GraphCut,
            graphcut: GraphCutParams::default(),
        }
    }
}

/// Why a stack cannot be fused; `frame` indices are 0-based positions in the input.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
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
}

pub struct Fused<T> {
    pub image: Image<T>,
    /// Per pixel, the frame the output was taken from.
    pub labels: Vec<u8>,
    /// Wall time of each stage, in order.
    pub timings: Vec<(&'static str, Duration)>,
}

/// Checks that a stack can be fused at all.
pub fn validate<T>(frames: &[Image<T>]) -> Result<(), FuseError> {
    match frames.len() {
        0 => return Err(FuseError::NoFrames),
        1 => return Err(FuseError::OneFrame),
        n if n > 255 => return Err(FuseError::TooManyFrames(n)),
        _ => {}
    }
    let geom = |f: &Image<T>| (f.width, f.height, f.channels);
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
    Ok(())
}

/// Fuses an aligned stack.
pub fn fuse<T: Sample>(
    frames: &[Image<T>],
    params: &FuseParams,
    progress: &dyn Progress,
) -> Result<Fused<T>, FuseError> {
    validate(frames)?;
    let mut timings = Vec::new();
    let mut t = Instant::now();
    let mut lap = |name: &'static str, timings: &mut Vec<(&'static str, Duration)>| {
        timings.push((name, t.elapsed()));
        t = Instant::now();
    };
    let (image, labels) = match params.method {
        Method::GraphCut => {
            let labels = label_stack(frames, &params.graphcut, progress);
            lap("labels", &mut timings);
            let (image, _) = compose(
                frames,
                Select::Labels(&labels, params.graphcut.blend_levels),
                progress,
            );
            lap("compose", &mut timings);
            (image, labels)
        }
        Method::Pyramid => {
            let r = compose(frames, Select::MaxContrast, progress);
            lap("pyramid", &mut timings);
            r
        }
    };
    Ok(Fused {
        image,
        labels,
        timings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::NoProgress;

    #[test]
    fn bad_stacks_are_refused_with_the_reason() {
        let f = |w, h, c| Image::<u8>::new(w, h, c);
        let fuse = |frames: &[Image<u8>]| fuse(frames, &FuseParams::default(), &NoProgress).err();
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
