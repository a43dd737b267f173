//! What the integration tests share, one module per kind of fixture.
#![allow(dead_code)] // each test crate uses a part

pub mod daemon;
pub mod iio;
pub mod libraw;
pub mod parallax;
pub mod stacks;
pub mod system;
