//! Command-line front ends over the library.
pub mod fuse;
pub mod io;
pub mod progress;
pub mod simulate;
