//! The stack engine: pure pixel work on in-memory frames, no I/O.
pub mod align;
pub mod blur;
pub mod compose;
pub mod expansion;
pub mod focal_axis;
pub mod focus;
pub mod fuse;
pub mod ghosts;
pub mod graphcut;
pub mod image;
pub mod maxflow;
pub mod memory;
pub mod metrics;
pub mod morphology;
pub mod order;
pub mod params;
pub mod pyramid;
pub mod register;
pub mod repair;
pub mod spill;
pub mod srgb;
pub mod transform;

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
