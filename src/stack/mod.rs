//! The stack engine: pure pixel work on in-memory frames, no I/O.
pub mod blur;
pub mod image;
pub mod maxflow;
pub mod transform;
pub mod warp;
