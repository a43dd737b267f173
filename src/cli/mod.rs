//! Command-line front ends over the library.
pub mod io;
pub mod simulate;
