//! The client side of `org.focusd.Focusd1`, for `focusd trigger` and for tests that drive the
//! service: zbus generates `Focusd1Proxy` and its signal streams from the server's own
//! declaration (`daemon::Focusd`), so the two cannot drift apart. A method's error is the
//! server's `FocusdError`, decoded from its D-Bus name.

pub use super::daemon::interface::{
    FailedArgs, FailedStream, FinishedArgs, FinishedStream, Focusd1Proxy, ProgressArgs,
    ProgressStream,
};
pub use super::daemon::FocusdError;
