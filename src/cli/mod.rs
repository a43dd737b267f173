//! Command-line front ends over the library.
pub mod capture;
pub mod fuse;
pub mod io;
pub mod progress;
pub mod simulate;
