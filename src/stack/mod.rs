//! The stack engine: pure pixel work on in-memory frames, no I/O.
pub mod align;
pub mod blur;
pub mod compose;
pub mod expansion;
pub mod focus;
pub mod fuse;
pub mod graphcut;
pub mod image;
pub mod maxflow;
pub mod memory;
pub mod metrics;
pub mod pyramid;
pub mod register;
pub mod transform;
pub mod warp;

/// Progress of long work, reported per stage; implementations must be cheap and thread-safe.
pub trait Progress: Sync {
    /// A new stage of `total` steps begins.
    fn stage(&self, name: &'static str, total: usize);
    fn advance(&self, steps: usize);
    /// Whether the caller wants the work stopped; checked between stages.
    fn cancelled(&self) -> bool {
        false
    }
}

/// Reports nothing.
pub struct NoProgress;

impl Progress for NoProgress {
    fn stage(&self, _: &'static str, _: usize) {}
    fn advance(&self, _: usize) {}
}
