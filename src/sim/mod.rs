//! Synthetic focus stacks with exact ground truth.
//!
//! A procedural macro scene (a textured background surface, several textured objects at different
//! depths that occlude each other, and a slanted ruler whose depth varies continuously) is
//! rendered through a thin-lens defocus model once per focus plane, optionally moved by a
//! hand-held pose, and degraded with per-frame gain and sensor noise. Alongside the frames come
//! the all-in-focus truth, the per-pixel focus-plane index and the true frame transforms.
//!
//! Pure pixel work: no file I/O (the `simulate` command writes the files).
//!
//! * [`scene`] builds the scene (shapes from [`shape`], surfaces from [`texture`]);
//! * [`optics`] maps depth to defocus sigma; [`pose`] draws hand-held poses;
//! * [`mod@render`] composites the layers, warps, and adds gain and noise.
//!
//! [`kinds`] builds the scenes other than the layered table-top (smooth depth without occlusions,
//! dark or light occluders, photographs); [`flats`] renders another kind of stack: smooth regions
//! where many frames tie, hard for the labelling.

pub mod bundle;
pub mod demosaic_scenes;
pub mod flats;
pub mod kinds;
pub mod optics;
pub mod pose;
pub mod render;
pub mod rng;
pub mod scene;
pub mod shape;
pub mod texture;
pub mod warp;

use crate::stack::image::Image;
use crate::stack::transform::Affine;
use serde::{Deserialize, Serialize};

/// Everything that determines a simulated stack; `render` is a pure function of it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimParams {
    pub width: usize,
    pub height: usize,
    /// Number of focus planes = number of frames.
    pub planes: usize,
    pub seed: u64,
    /// false: every frame has the identity pose (an "aligned" stack, as from a tripod).
    pub handheld: bool,
    /// Max translation as a fraction of the width (hand-held only), e.g. 0.03.
    pub max_shift: f64,
    /// Max roll about the image centre in degrees (hand-held only), e.g. 1.5.
    pub max_rotation_deg: f64,
    /// Total magnification change across the sweep (hand-held only), e.g. 0.02: frame i has
    /// absolute scale 1 + breathing·(i/(n−1) − 0.5), applied relative to the reference frame's.
    pub breathing: f64,
    /// Per-frame gain uniformly in 1 ± gain_jitter (the reference frame keeps gain 1).
    pub gain_jitter: f64,
    /// Per-frame, per-channel white-balance gain uniformly in 1 ± wb_jitter, on top of the gain
    /// (the reference frame keeps 1, 1, 1).
    pub wb_jitter: f64,
    /// Gaussian read noise sigma in 8-bit units; shot noise adds variance noise_sigma²·v/255 at
    /// signal level v, so at full scale the total noise is √2·noise_sigma.
    pub noise_sigma: f64,
    /// Extra shift (px) of the nearest layers relative to the far background, along the frame's
    /// translation, at full max_shift (hand-held only; 0..=8).
    pub parallax_px: f64,
    /// Defocus Gaussian sigma (px) of a layer one focus plane away from the frame's focus.
    pub blur_per_plane: f64,
    /// Cap on the defocus sigma (px): far-out-of-focus layers saturate here.
    pub max_blur: f64,
    /// Focus distance of plane 0 (the nearest) in diopters (1/m), e.g. 20 = 5 cm.
    pub near_diopters: f64,
    /// Focus distance of the last plane (the farthest) in diopters.
    pub far_diopters: f64,
    /// Mix layers, blur, resample and apply gain in linear light and encode sRGB only at the end,
    /// as a camera does; false mixes the display values (the committed stacks' model). A spill
    /// model fitted to display-value mixing would only invert the simulator's own formula.
    #[serde(default)]
    pub linear_light: bool,
    /// What the scene shows.
    #[serde(default)]
    pub scene: SceneKind,
    /// Total magnification change across the sweep of a stack that is not hand-held (a tripod
    /// stack whose lens breathes), e.g. 0.006; hand-held stacks use `breathing`.
    #[serde(default)]
    pub tripod_breathing: f64,
}

/// The kinds of scene the simulator draws.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SceneKind {
    /// Textured objects on several planes overlapping each other and a slanted ruler over a
    /// table-top: depth steps everywhere.
    #[default]
    Layers,
    /// One surface tilted in depth from the nearest plane to the farthest: no occlusion.
    Tilted,
    /// One curved surface (a dome or a cylinder) nearest in its middle: no occlusion.
    Curved,
    /// Dark objects on the near planes over a light ground tilted across the far half.
    DarkOnLight,
    /// Light objects on the near planes over a dark ground tilted across the far half.
    LightOnDark,
}

impl SceneKind {
    /// Every kind with its command-line name.
    pub const ALL: [(SceneKind, &'static str); 5] = [
        (SceneKind::Layers, "layers"),
        (SceneKind::Tilted, "tilted"),
        (SceneKind::Curved, "curved"),
        (SceneKind::DarkOnLight, "dark-on-light"),
        (SceneKind::LightOnDark, "light-on-dark"),
    ];
}

impl Default for SimParams {
    /// 640×480, 6 planes, aligned, noise 1.5, no gain jitter; hand-held fields hold sensible values
    /// for when `handheld` is switched on.
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            planes: 6,
            seed: 1,
            handheld: false,
            max_shift: 0.03,
            max_rotation_deg: 1.5,
            breathing: 0.02,
            gain_jitter: 0.0,
            wb_jitter: 0.0,
            noise_sigma: 1.5,
            parallax_px: 1.0,
            blur_per_plane: 2.0,
            max_blur: 9.0,
            near_diopters: 20.0,
            far_diopters: 5.0,
            linear_light: false,
            scene: SceneKind::Layers,
            tripod_breathing: 0.0,
        }
    }
}

/// Inclusive limits `validate` enforces.
pub const SIZE_RANGE: (usize, usize) = (16, 8192);
pub const PLANES_RANGE: (usize, usize) = (2, 64);
/// Frames are kept in memory: width·height·planes may not exceed this.
pub const MAX_STACK_PIXELS: usize = 400_000_000;
/// Upper limit of `parallax_px`: a macro subject a few cm away against a background several
/// times farther moves this much against it for a few mm of hand motion.
pub const MAX_PARALLAX_PX: f64 = 8.0;

impl SimParams {
    /// Checks every value; the error is one line naming the bad value and the allowed range.
    pub fn validate(&self) -> Result<(), String> {
        fn within(name: &str, v: f64, lo: f64, hi: f64) -> Result<(), String> {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(format!("{name} {v} is out of range {lo}..={hi}"))
            }
        }
        let (slo, shi) = SIZE_RANGE;
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if !(slo..=shi).contains(&v) {
                return Err(format!("{name} {v} is out of range {slo}..={shi}"));
            }
        }
        let (plo, phi) = PLANES_RANGE;
        if !(plo..=phi).contains(&self.planes) {
            return Err(format!(
                "planes {} is out of range {plo}..={phi}",
                self.planes
            ));
        }
        let total = self.width * self.height * self.planes;
        if total > MAX_STACK_PIXELS {
            return Err(format!(
                "stack {}x{}x{} has {total} pixels, more than the {MAX_STACK_PIXELS} limit",
                self.width, self.height, self.planes
            ));
        }
        within("max_shift", self.max_shift, 0.0, 0.2)?;
        within("max_rotation_deg", self.max_rotation_deg, 0.0, 10.0)?;
        within("breathing", self.breathing, 0.0, 0.2)?;
        within("tripod_breathing", self.tripod_breathing, 0.0, 0.2)?;
        within("gain_jitter", self.gain_jitter, 0.0, 0.5)?;
        within("wb_jitter", self.wb_jitter, 0.0, 0.5)?;
        within("noise_sigma", self.noise_sigma, 0.0, 50.0)?;
        within("parallax_px", self.parallax_px, 0.0, MAX_PARALLAX_PX)?;
        within("max_blur", self.max_blur, 0.5, 30.0)?;
        within("blur_per_plane", self.blur_per_plane, 0.3, self.max_blur)?;
        within("near_diopters", self.near_diopters, 0.1, 1000.0)?;
        if !(self.far_diopters.is_finite()
            && self.far_diopters >= 0.0
            && self.far_diopters < self.near_diopters)
        {
            return Err(format!(
                "far_diopters {} is out of range 0..{} (must be below near_diopters)",
                self.far_diopters, self.near_diopters
            ));
        }
        Ok(())
    }

    /// Index of the reference frame: (planes − 1) / 2.
    pub fn reference(&self) -> usize {
        (self.planes - 1) / 2
    }
}

/// Per-frame ground truth that is not an image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameInfo {
    /// Where the frame is focused, diopters (1/m); frame 0 is the nearest.
    pub focus_diopters: f64,
    /// Multiplicative exposure gain applied to the frame.
    pub gain: f64,
    /// Per-channel white-balance gain applied on top of `gain`.
    pub white_balance: [f64; 3],
    /// Pose parameters of `ref_to_frame` (translation px, roll degrees, scale).
    pub translation: [f64; 2],
    pub rotation_deg: f64,
    pub scale: f64,
    /// Extra shift (px, x and y) of a layer at plane 0 against the far background in this frame;
    /// nearer-than-background layers at plane q move (1 − q/(planes − 1)) of it.
    pub parallax: [f64; 2],
}

/// A rendered stack with its ground truth.
#[derive(Clone, Debug)]
pub struct SimStack {
    /// RGB frames, frame i focused at plane i (0 = nearest), each in its own pose; not yet
    /// JPEG-coded.
    pub frames: Vec<Image<u8>>,
    /// The all-in-focus image in the reference frame's geometry (RGB), noise-free, gain 1.
    pub truth: Image<u8>,
    /// One channel: index of the plane focused at each reference pixel's true depth (0 = nearest).
    pub depth: Image<u8>,
    /// One channel: 255 on a depth step (an occlusion edge: a 4-neighbour shows another layer at
    /// least half a plane nearer or farther), else 0. The smooth depth change along the slanted
    /// ruler is no step.
    pub steps: Image<u8>,
    /// The largest defocus sigma (px) any layer has in any frame: how far a step's spill reaches.
    pub max_sigma: f64,
    /// (planes − 1) / 2.
    pub reference: usize,
    /// The true affine taking reference pixel coords to frame i pixel coords (identity for the
    /// reference). With parallax it is exact for the far background (the dominant plane); nearer
    /// layers move up to `parallax_px` more.
    pub ref_to_frame: Vec<Affine>,
    /// Focus distance, gain and pose of every frame.
    pub info: Vec<FrameInfo>,
}

/// Renders the stack for `p`; deterministic for a given `SimParams` (including the seed).
///
/// Panics if `p.validate()` fails (check it first for user input).
pub fn render(p: &SimParams) -> SimStack {
    if let Err(e) = p.validate() {
        panic!("invalid simulation parameters: {e}");
    }
    let scene = scene::Scene::generate(p);
    render::render_scene(p, &scene).stack
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_value_and_range() {
        assert!(SimParams::default().validate().is_ok());
        let e = SimParams {
            planes: 1,
            ..SimParams::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(e, "planes 1 is out of range 2..=64");
        let e = SimParams {
            width: 9000,
            ..SimParams::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(e, "width 9000 is out of range 16..=8192");
        let e = SimParams {
            noise_sigma: f64::NAN,
            ..SimParams::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.starts_with("noise_sigma NaN"), "{e}");
        let e = SimParams {
            far_diopters: 30.0,
            ..SimParams::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.contains("far_diopters 30"), "{e}");
    }
}
