//! The kernel's video device interface, with no C bindings generated at build time: V4L2 video
//! nodes (formats, controls, memory-mapped single- and multi-planar streaming), V4L2
//! sub-devices (pad formats and crops, controls) and media controllers (topology, links).
//!
//! [`abi`] holds the structures and ioctl numbers, checked against the kernel headers;
//! [`device`], [`stream`], [`subdev`] and [`media`] are the safe calls over them. The camera
//! backend ([`crate::backend::v4l2`]) decides what to call.

pub mod abi;
pub mod device;
pub mod media;
pub mod stream;
pub mod subdev;

pub use device::{BufType, Capabilities, ControlDesc, Device, FrameFormat, PlaneLayout};
pub use stream::{Dequeued, Stream};
