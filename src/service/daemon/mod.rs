//! `focusd serve`: the D-Bus service that owns the capture. Bus name `org.focusd.Focusd`,
//! object `/org/focusd/Focusd`, interface `org.focusd.Focusd1`.
//!
//! The bus runs on tokio; jobs run on one worker thread fed by a crossbeam channel (the camera
//! and the IMU are used by one job at a time, and a fuse keeps the cores busy for seconds, which
//! must not stall the bus). The worker reports back through an unbounded tokio channel, which a
//! task turns into signals. The trigger keys (`[trigger]`) are read on a thread of their own
//! that only hands each press or long press to the main loop, which starts or cancels a job as
//! the `Capture` and `Cancel` methods do.
//!
//! The main loop watches the worker (`watchdog`): it sends systemd `WATCHDOG=1` only while the
//! worker is idle or its job beats. A job without progress for `[service] stall_timeout_s`, or
//! still running that long after a Cancel or SIGTERM, is blocked where no cancel check reaches
//! it; it is reported as Failed naming its stage, its temporary files are removed, and the
//! service exits non-zero (the blocked thread dies with the process, which also closes the
//! camera), so systemd restarts it clean.
//!
//! The rooms: `interface` (the D-Bus methods, properties and signals), `access` (who may start
//! and cancel a job, by call or by key), `callers` (each caller's uid, asked of the bus once),
//! `state` (what the service and its worker share), `worker` (the job thread and its
//! reporter), `relay` (worker events to signals) and `startup` (the config, the bus name and
//! the main loop).

mod access;
mod callers;
pub(super) mod interface;
mod relay;
mod startup;
mod state;
mod worker;

pub use interface::{Focusd, FocusdError};
pub use startup::serve;

use super::ServiceError;
use crate::backend::replay::faults::Fault;
use std::path::PathBuf;

pub const BUS_NAME: &str = "org.focusd.Focusd";
pub const OBJECT_PATH: &str = "/org/focusd/Focusd";

/// Which bus to serve on.
#[derive(Clone, Debug, PartialEq)]
pub enum Bus {
    Session,
    System,
    /// A bus address (`unix:path=...`), for private buses in tests.
    Address(String),
}

impl Bus {
    /// Errors of a reachable bus surface when the connection is built.
    pub fn builder(&self) -> Result<zbus::connection::Builder<'static>, ServiceError> {
        Ok(match self {
            Bus::Session => zbus::connection::Builder::session(),
            Bus::System => zbus::connection::Builder::system(),
            Bus::Address(a) => {
                let address =
                    a.parse::<zbus::Address>()
                        .map_err(|error| ServiceError::Address {
                            address: a.clone(),
                            error,
                        })?;
                zbus::connection::Builder::address(address)
            }
        })
    }
}

pub struct ServeOptions {
    pub config: Option<PathBuf>,
    pub replay: Option<PathBuf>,
    /// Replays take as long as the sweep they recorded.
    pub paced: bool,
    /// Failures injected into the first replayed job (the next one shows the recovery).
    pub faults: Vec<Fault>,
    pub bus: Bus,
}
