//! focusd: hand-held focus stacking. The command line (`src/cli/`) is the binary's own and
//! not part of this library.
pub mod backend;
pub mod bounded_read;
pub mod capture;
pub mod clip;
pub mod develop;
pub mod imageio;
pub mod malloc;
pub mod outputs;
pub mod service;
pub mod setting;
pub mod sim;
pub mod stack;
