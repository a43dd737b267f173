//! focusd: hand-held focus stacking. The command line (`src/cli/`) is the binary's own and
//! not part of this library.
//!
//! The rooms: [`stack`] fuses a focus stack (the engine); [`capture`] sweeps the lens and
//! waits for a still hand; [`backend`] drives the camera, the IMU, the keys and replays;
//! [`develop`] turns raw frames into RGB; [`files`] reads images and writes outputs;
//! [`service`] is the configuration, the capture job and the D-Bus daemon; [`sim`] simulates
//! stacks with their ground truth; [`base`] holds what every room leans on.
pub mod backend;
pub mod base;
pub mod capture;
pub mod develop;
pub mod files;
pub mod service;
pub mod sim;
pub mod stack;
