//! The scenes the demosaic is measured on (`src/develop`'s tests, `tests/develop.rs`,
//! `benches/tools/demosaic.rs`): one definition each, so that the figures the tool prints are
//! of the pictures the tests assert on.

use super::SimParams;
use crate::stack::image::Image;

impl SimParams {
    /// A noiseless 240×180 scene of two planes, for its all-in-focus truth: textured surfaces,
    /// sharp occluding edges and a ruler, different for each seed.
    pub fn demosaic_scene(seed: u64) -> SimParams {
        SimParams {
            width: 240,
            height: 180,
            planes: 2,
            seed,
            noise_sigma: 0.0,
            ..SimParams::default()
        }
    }

    /// A 256×192 stack of five aligned planes mixed in linear light, as a sensor records them:
    /// what the fused gap between developed mosaics and RGB frames is measured on.
    pub fn raw_stack(seed: u64) -> SimParams {
        SimParams {
            width: 256,
            height: 192,
            planes: 5,
            seed,
            linear_light: true,
            ..SimParams::default()
        }
    }
}

/// A 64×64 black-to-white edge in linear light (0.05 to 0.85, the same in every channel)
/// through the centre, leaning `slope` px across per row so that a slant passes every sub-pixel
/// phase, its ramp `width` px wide, as a sharp lens draws it (a one-pixel step is finer than any
/// Bayer sensor samples): where a demosaic's false colour and zipper show.
pub fn grey_edge(slope: f32, width: f32) -> Image<f32> {
    Image::from_fn(64, 64, 3, move |x, y, _| {
        let d = x as f32 - 32.0 - slope * (y as f32 - 32.0);
        (0.5 + d / width).clamp(0.0, 1.0) * 0.8 + 0.05
    })
}
