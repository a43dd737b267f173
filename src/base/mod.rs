//! What every room leans on: user settings checked against their ranges, messages clipped
//! before they reach a terminal, the journal or the bus, and the allocator tuned for a
//! working set of a few very large buffers.
pub mod clip;
pub mod malloc;
pub mod setting;
