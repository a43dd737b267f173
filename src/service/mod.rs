//! The service side: the configuration file, the capture job that the CLI and the daemon both
//! run, the output directory, the D-Bus daemon and its watchdog.
pub mod config;
pub mod daemon;
mod error;
pub mod feedback;
pub mod fuse_settings;
pub mod job;
pub mod output_dir;
pub mod pictures;
pub mod preview;
pub mod proxy;
pub mod watchdog;

pub use error::ServiceError;
