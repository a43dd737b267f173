//! focusd: hand-held focus stacking.
pub mod cli;
pub mod sim;
pub mod stack;
