//! The V4L2 camera and its lens (video node and lens sub-device).
//!
//! Everything that needs no device is in pure modules, tested with synthetic buffers and fake
//! sysfs trees: [`format`] (choosing and converting pixel formats), [`exposure`] (the exposure
//! window from buffer timestamps and sensor controls), [`lens`] (finding nodes and the lens
//! control), [`config`], [`sensor`] (Bayer codes, orders and modes). [`pipeline`] negotiates a
//! device profile through [`media_ops`], a trait the kernel or the phones' driver fixtures
//! answer. [`camera`] is the thin layer over [`crate::backend::videodev`].

pub mod camera;
pub mod config;
pub mod detect;
pub mod exposure;
pub mod format;
pub mod lens;
pub mod media_ops;
pub mod pipeline;
pub mod preview;
pub mod profile;
pub mod sensor;

pub use camera::{open, V4l2Camera};
pub use config::V4l2Config;
#[cfg(test)]
mod fixtures;
