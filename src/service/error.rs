//! Why a capture job or the service fails. The messages are the ones a user reads after
//! `focusd: error:` or in a `Failed` signal; a variant with a `#[source]` is a context whose
//! cause follows it in the chain (`base::clip::chain`).

use super::config::ConfigError;
use super::daemon::Bus;
use crate::backend::replay::BundleError;
use crate::capture::CaptureError;
use crate::files::FileError;
use crate::stack::fuse::FuseError;
use std::io;

#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Bundle(#[from] BundleError),
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error(transparent)]
    Fuse(#[from] FuseError),
    #[error(transparent)]
    File(#[from] FileError),
    #[error("encoding the report")]
    Report(#[source] serde_json::Error),
    #[error("[output] dir {dir}: cannot create it (set [output] dir to a writable directory)")]
    OutputDir {
        dir: String,
        #[source]
        error: io::Error,
    },
    /// A panic in a job: a bug, which fails the job rather than the service.
    #[error("internal error: {0} (please report this)")]
    Panicked(String),
    /// A thread or the async runtime could not start; says which.
    #[error("starting the {0}")]
    Start(&'static str, #[source] io::Error),
    #[error("--address {address:?} is not a D-Bus address")]
    Address {
        address: String,
        #[source]
        error: zbus::Error,
    },
    #[error("cannot connect to the {bus:?} bus")]
    Connect {
        bus: Bus,
        #[source]
        error: zbus::Error,
    },
    #[error(
        "{name} is already owned on the {bus:?} bus: another focusd serve is running \
         (stop it first; focusd does not take the name over)"
    )]
    NameTaken { name: &'static str, bus: Bus },
    #[error(
        "cannot own {name} on the {bus:?} bus (does the D-Bus policy let this user own \
         it? see systemd/org.focusd.Focusd.conf)"
    )]
    CannotOwn {
        name: &'static str,
        bus: Bus,
        #[source]
        error: zbus::Error,
    },
    #[error("lost the bus name {0}; exiting for systemd to restart the service")]
    NameLost(&'static str),
    #[error("the connection to the {0:?} bus closed; exiting for systemd to restart the service")]
    BusClosed(Bus),
    /// A job the watchdog gave up on, with the reason it failed with.
    #[error("job {job}: {error}")]
    Stalled { job: String, error: String },
    #[error("the job thread panicked")]
    WorkerPanicked,
    #[error(transparent)]
    Bus(#[from] zbus::Error),
    #[error(transparent)]
    Io(#[from] io::Error),
    #[error(transparent)]
    Task(#[from] tokio::task::JoinError),
}

impl ServiceError {
    /// Whether the job was cancelled rather than failed.
    pub fn is_cancel(&self) -> bool {
        matches!(
            self,
            ServiceError::Capture(CaptureError::Cancelled)
                | ServiceError::Fuse(FuseError::Cancelled)
        )
    }
}
