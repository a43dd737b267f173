//! What every room leans on: calendar times, user settings checked against their ranges, messages clipped
//! before they reach a terminal, the journal or the bus, and the allocator tuned for a
//! working set of a few very large buffers.
pub mod civil;
pub mod clip;
pub mod malloc;
pub mod setting;
