//! What a fuse is asked to do: its method and parameters, shared by the fuse itself and the
//! memory plan that sizes it (so neither imports the other).

use super::graphcut::GraphCutParams;
use super::register::RegisterParams;

/// The default memory budget: a PinePhone has 2–3 GB shared with the phone's other work.
pub const DEFAULT_BUDGET: usize = 512 << 20;

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
    /// Register every frame to the reference first; `None` takes the frames as aligned.
    pub align: Option<RegisterParams>,
    /// The frame whose geometry and exposure the output takes.
    pub reference: usize,
    /// Crop the output to the largest rectangle every aligned frame covers.
    pub crop: bool,
    /// Bytes the fuse should stay within (see `memory::plan`).
    pub memory: usize,
    /// Take nearer objects' defocus spill out of farther frames before composing, and keep
    /// farther frames out of nearer labels' finest band, where they show the background through
    /// a defocused near object's edge (graph cut only; see `spill` and `compose`).
    pub spill: bool,
    /// Repair the labels of near objects' edges that took a frame focused farther: flat regions
    /// take the frame that shows their outline crisp, pixels next to a depth step the near
    /// object's frame where their colour says so (see `repair`). Run within the spill removal:
    /// without `spill` there is none.
    pub label_repair: bool,
}

impl Default for FuseParams {
    fn default() -> Self {
        Self {
            method: Method::GraphCut,
            graphcut: GraphCutParams::default(),
            align: Some(RegisterParams::default()),
            reference: 0,
            crop: false,
            memory: DEFAULT_BUDGET,
            spill: true,
            label_repair: true,
        }
    }
}

/// The reference frame when none is chosen: the middle one, `(n - 1) / 2`, whose pose and
/// magnification are nearest every other frame's in a sweep.
pub fn middle_frame(frames: usize) -> usize {
    frames.saturating_sub(1) / 2
}
