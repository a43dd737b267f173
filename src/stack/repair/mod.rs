//! The label repairs: where the labelling put a frame focused farther on a near object's edge.
//!
//! Next to a near object, the frames focused behind it show the background's texture through
//! its defocused rim, which the focus measure takes for the sharpest detail there; the labels
//! then give the object's edge a far frame, the compose gives it a blurred, haloed edge, and
//! the spill removal finds no near region there to take the halo out of. Two repairs mend it,
//! each with its own evidence:
//! - a plain near object (no frame has texture on it, so its label says nothing of depth) takes
//!   the frame that shows its outline crisp ([`flat_regions`]);
//! - next to a depth step, a pixel whose colour in the near frame is clearly the near object's
//!   takes the near frame ([`depth_steps`]).
//!
//! Both need the stack's focus order, so they run within the spill removal, which knows it;
//! `FuseParams::label_repair` turns them off alone, and turning the spill removal off turns
//! them off too.

pub mod depth_steps;
pub mod flat_regions;

pub use flat_regions::Settled;

/// What the label repairs did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Repaired {
    /// Flat regions given the frame that shows their outline crisp.
    pub settled: Settled,
    /// Pixels next to a depth step whose label moved to the near object's frame.
    pub relabelled: usize,
}

/// One line for the logs.
impl std::fmt::Display for Repaired {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        let (n, px) = (self.settled.regions, self.settled.pixels);
        let s = if n == 1 { "" } else { "s" };
        write!(
            f,
            "{n} flat region{s} ({px} pixels) given the nearer frame that shows the outline \
             crisp, {} pixels at depth steps moved to the near object's frame",
            self.relabelled
        )
    }
}
