//! The service side: the configuration file and the capture job that the CLI and the daemon
//! both run.
pub mod config;
pub mod job;
