//! Files in and out: reading what focusd parses without hanging on it or growing without
//! bound, decoding and encoding images, and writing outputs so that nothing partial lands.
pub mod bounded_read;
pub mod dng;
mod error;
pub mod imageio;
pub mod orientation;
pub mod outputs;
mod temp;

pub use error::FileError;
pub use temp::abandon;
