//! The `org.focusd.Focusd1` interface: its methods, properties and signals, and the errors
//! callers get.

use super::access::{cancel, start, Owner};
use super::callers::Callers;
use super::state::Shared;
use crate::base::clip;
use crate::service::preview::Preview;
use std::sync::Arc;
use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::{interface, DBusError};

/// Errors callers get, as `org.focusd.Error.*`.
#[derive(Debug, DBusError)]
#[zbus(prefix = "org.focusd.Error")]
pub enum FocusdError {
    #[zbus(error)]
    ZBus(zbus::Error),
    /// A job is already running.
    Busy(String),
    /// `Cancel` named a job that is not running.
    NoSuchJob(String),
    /// The output directory cannot be used.
    Output(String),
    /// The call's arguments are not the method's.
    InvalidArgs(String),
    /// `Cancel` of a job another user started.
    AccessDenied(String),
    /// The preview cannot start (no camera, the camera busy, a bad bundle).
    Preview(String),
}

pub struct Focusd {
    pub(super) shared: Arc<Shared>,
    pub(super) callers: Callers,
    pub(super) preview: Arc<Preview>,
}

/// `proxy` also generates the client side, `Focusd1Proxy` and its signal streams, from these
/// declarations. Calls are handled one at a time (`spawn = false`: every method returns at
/// once), so a client that pipelines calls without reading the answers makes them wait in the
/// bus, under its limits, instead of growing the service with a task per call.
#[interface(
    name = "org.focusd.Focusd1",
    spawn = false,
    proxy(
        default_service = "org.focusd.Focusd",
        default_path = "/org/focusd/Focusd",
        async_name = "Focusd1Proxy"
    )
)]
impl Focusd {
    /// Starts a capture (sweep, register, fuse) and returns its job id at once; the result
    /// comes as `Finished` or `Failed`.
    async fn capture(&self, #[zbus(header)] header: Header<'_>) -> Result<String, FocusdError> {
        // zbus passes a method without arguments whatever body came with the call.
        let got = header.signature().to_string();
        if !got.is_empty() {
            return Err(FocusdError::InvalidArgs(format!(
                "Capture takes no arguments, got signature {got:?}"
            )));
        }
        let owner = self.callers.uid(&header).await?;
        start(&self.shared, Owner::Caller(owner))
    }

    /// Stops a running job; it ends with `Failed(job, "cancelled")`. Only the user that started
    /// it, and root, may; a job a hardware key started, anyone the D-Bus policy lets call.
    async fn cancel(
        &self,
        job: &str,
        #[zbus(header)] header: Header<'_>,
    ) -> Result<(), FocusdError> {
        let caller = self.callers.uid(&header).await?;
        cancel(&self.shared, job, caller)
    }

    /// Starts the live preview for the caller, or renews it, and returns the shared memory
    /// its frames are written to (docs/guide.md, "The live preview"). It runs until the caller
    /// calls `StopPreview` or leaves the bus, or `[service] preview_timeout_s` after the
    /// caller's last `StartPreview`; a capture pauses it. Returns at once: the camera opens
    /// meanwhile, and the memory's state says when it fails, and why.
    async fn start_preview(
        &self,
        #[zbus(header)] header: Header<'_>,
    ) -> Result<zbus::OwnedFd, FocusdError> {
        let got = header.signature().to_string();
        if !got.is_empty() {
            return Err(FocusdError::InvalidArgs(format!(
                "StartPreview takes no arguments, got signature {got:?}"
            )));
        }
        let client = header
            .sender()
            .ok_or_else(|| FocusdError::AccessDenied("the call names no sender".into()))?;
        let timeout = self.shared.lock().config.service.preview_timeout();
        let fd = self
            .preview
            .start(client.as_str(), timeout)
            .map_err(|e| FocusdError::Preview(clip::chain(&e)))?;
        Ok(fd.into())
    }

    /// Ends the caller's preview; the last client's ends it for all.
    async fn stop_preview(&self, #[zbus(header)] header: Header<'_>) -> Result<(), FocusdError> {
        let client = header
            .sender()
            .ok_or_else(|| FocusdError::AccessDenied("the call names no sender".into()))?;
        if self.preview.leave(client.as_str(), "stopped it") {
            Ok(())
        } else {
            Err(FocusdError::InvalidArgs(format!(
                "{client} has no preview to stop"
            )))
        }
    }

    /// `idle`, `waiting-still`, `sweeping`, `developing`, `registering` or `fusing`.
    #[zbus(property)]
    pub(super) fn state(&self) -> String {
        let s = self.shared.lock();
        if s.running.is_some() { s.stage } else { "idle" }.to_string()
    }

    /// The path of the last image written, or "".
    #[zbus(property)]
    fn last_result(&self) -> String {
        self.shared.lock().last_result.clone()
    }

    #[zbus(property)]
    fn version(&self) -> String {
        env!("CARGO_PKG_VERSION").to_string()
    }

    #[zbus(signal)]
    pub(super) async fn progress(
        emitter: &SignalEmitter<'_>,
        job: &str,
        stage: &str,
        done: u32,
        total: u32,
    ) -> zbus::Result<()>;

    #[zbus(signal)]
    pub(super) async fn finished(
        emitter: &SignalEmitter<'_>,
        job: &str,
        path: &str,
    ) -> zbus::Result<()>;

    #[zbus(signal)]
    pub(super) async fn failed(
        emitter: &SignalEmitter<'_>,
        job: &str,
        error: &str,
    ) -> zbus::Result<()>;
}
