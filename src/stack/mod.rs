//! The stack engine: pure pixel work on in-memory frames, no I/O.
//!
//! The library's API is what this module re-exports: [`fuse`] with its parameters
//! ([`FuseParams`]) and result ([`Fused`]), the frames ([`Image`]), progress reporting
//! ([`Progress`], [`Stage`]), the memory plan and the metrics a caller compares outputs by. The
//! modules themselves are the crate's own.
pub(crate) mod align;
pub(crate) mod blur;
pub(crate) mod compose;
pub(crate) mod expansion;
pub(crate) mod focal_axis;
pub(crate) mod focus;
pub(crate) mod fuse;
pub(crate) mod ghosts;
pub(crate) mod graphcut;
pub(crate) mod image;
pub(crate) mod maxflow;
pub(crate) mod memory;
pub(crate) mod metrics;
pub(crate) mod morphology;
pub(crate) mod order;
pub(crate) mod params;
pub(crate) mod pyramid;
pub(crate) mod refine;
pub(crate) mod register;
pub(crate) mod repair;
pub(crate) mod spill;
pub(crate) mod srgb;
pub(crate) mod transform;

pub use align::{Coverage, Exposure, Rect};
pub use focus::FocusParams;
pub use fuse::{fuse, fuse_developing, validate, Alignment, FuseError, Fused};
pub use graphcut::GraphCutParams;
pub use image::{Image, Sample};
pub use memory::{mib, plan as memory_plan, Plan as MemoryPlan, Stack as StackShape};
pub use metrics::{psnr, tenengrad};
pub use order::{Order, OrderEvidence};
pub use params::{middle_frame, FuseParams, Method, DEFAULT_BUDGET};
pub use refine::{Develop, Developed, Piece};
pub use register::{Placement, RegisterError, RegisterParams, Registration};
pub use repair::{Repaired, Settled};
pub use spill::{Light, Pair, Unmixed};
pub use transform::{Affine, FieldExtent, FrameTransform, OffsetField, Transforms};

/// Not API: the engine's inner steps, re-exported for the crate's tests, benches and
/// measurement tools. Anything here may change or go without notice.
#[doc(hidden)]
pub mod internal {
    pub use super::align::{warp_frame, warp_frame_into};
    pub use super::blur::{gaussian_blur, gaussian_blur_channels};
    pub use super::focus::{focus_amplitude, AMP_SCALE};
    pub use super::fuse::warp_onto_reference;
    /// The ghost check of an output against its frames.
    pub mod ghosts {
        pub use crate::stack::ghosts::{check, GhostReport, SEARCH, WIDTH};
    }
    pub use super::graphcut::{label_stack, labelling_energy};
    pub use super::image::Plane;
    pub use super::maxflow::GridMaxflow;
    pub use super::metrics::{best_frame_oracle, depth_oracle, psnr_where, step_band};
    pub use super::pyramid::{collapse, laplacian_pyramid, levels_for};
    pub use super::register::{register, register_with};
    pub use super::transform::Warp;
}

/// The engine's stages, in the order a fuse runs them. Their names are a contract: the
/// daemon's `Progress` signals and the CLI's progress text and timings show them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Stage {
    Register,
    Warp,
    /// The focus measure, the first part of the labelling.
    Focus,
    Labels,
    /// Taking nearer objects' defocused spill out of the frames focused farther.
    Spill,
    Compose,
    /// The pyramid method's whole fusion, timed as one stage (its progress is `Compose`'s).
    Pyramid,
    /// Developing raw frames: cheaply in whole before the fuse, in full where the output
    /// keeps them before the compose.
    Develop,
}

impl Stage {
    pub const fn name(self) -> &'static str {
        match self {
            Stage::Register => "register",
            Stage::Warp => "warp",
            Stage::Focus => "focus",
            Stage::Labels => "labels",
            Stage::Spill => "spill",
            Stage::Compose => "compose",
            Stage::Pyramid => "pyramid",
            Stage::Develop => "developing",
        }
    }

    /// Whether the stage brings the frames into the reference's geometry rather than fusing
    /// them: the daemon's `registering` state and the report's `register` time.
    pub const fn registers(self) -> bool {
        matches!(self, Stage::Register | Stage::Warp)
    }
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.pad(self.name())
    }
}

/// Progress of long work, reported per stage; implementations must be cheap and thread-safe.
pub trait Progress: Sync {
    /// A new stage of `total` steps begins.
    fn stage(&self, stage: Stage, total: usize);
    fn advance(&self, steps: usize);
    /// Whether the caller wants the work stopped; checked between stages.
    fn cancelled(&self) -> bool {
        false
    }
}

/// Reports nothing.
pub struct NoProgress;

impl Progress for NoProgress {
    fn stage(&self, _: Stage, _: usize) {}
    fn advance(&self, _: usize) {}
}
