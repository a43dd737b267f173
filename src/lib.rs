//! focusd: hand-held focus stacking.
pub mod backend;
pub mod capture;
pub mod cli;
pub mod imageio;
pub mod service;
pub mod sim;
pub mod stack;
