//! What the service and its worker share: the running job, the config, the worker's inbox; and
//! what stopping and a stalled job do to it.

use super::access::Owner;
use super::worker::Request;
use crate::backend::replay::faults::Fault;
use crate::capture::Stage;
use crate::service::config::Config;
use crate::service::job::Source;
use crate::service::watchdog::{self, Heartbeat, Stall};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

pub(super) struct Running {
    pub(super) id: String,
    pub(super) owner: Owner,
    pub(super) cancel: Arc<AtomicBool>,
    /// When Cancel or SIGTERM asked the job to stop.
    pub(super) cancelled_at: Option<Instant>,
    /// The stage the job reached, with its steps done and total (for a stall's message).
    pub(super) at: (Stage, usize, usize),
    /// The files the job writes; a stall removes their temporary files.
    pub(super) outputs: Vec<PathBuf>,
}

impl Running {
    pub(super) fn cancel(&mut self) {
        self.cancel.store(true, Ordering::SeqCst);
        self.cancelled_at.get_or_insert_with(Instant::now);
    }

    /// Where the job is, in words.
    fn whereabouts(&self) -> String {
        match self.at {
            (Stage::Sweeping, done, total) => format!(
                "sweeping, at plane {done} (planes 0 to {})",
                total.saturating_sub(1)
            ),
            (Stage::Developing, done, total) => {
                format!(
                    "developing, at raw frame {done} (frames 0 to {})",
                    total.saturating_sub(1)
                )
            }
            (stage, ..) => stage.name().to_string(),
        }
    }

    /// Why the service gives up on the job.
    pub(super) fn stall_message(&self, stall: Stall) -> String {
        let (at, secs) = (self.whereabouts(), stall.silence.as_secs());
        let what = if stall.cancelled {
            format!("cancelled, but the job is blocked in stage {at} (no progress for {secs} s)")
        } else {
            format!(
                "stalled: no progress for {secs} s in stage {at}; the job is blocked (a device \
                 or file read that does not return?)"
            )
        };
        format!("{what} and cannot be stopped, so focusd exits for systemd to restart it")
    }
}

pub(super) struct State {
    pub(super) config: Config,
    /// The worker's inbox; taken at shutdown, which ends the worker after its job.
    pub(super) requests: Option<crossbeam_channel::Sender<Request>>,
    pub(super) running: Option<Running>,
    pub(super) stage: &'static str,
    pub(super) last_result: String,
    /// Injected into the next job, once.
    pub(super) faults: Vec<Fault>,
}

/// What the service and its worker share.
pub(super) struct Shared {
    pub(super) state: Mutex<State>,
    pub(super) source: Source,
    /// The running job's.
    pub(super) beat: Heartbeat,
}

impl Shared {
    /// A worker that panicked mid-job leaves nothing half-written here (each field is set in
    /// one step), so a poisoned lock is still good.
    pub(super) fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// SIGTERM or SIGINT: cancels the running job and closes the worker's inbox, which ends the
/// worker once the job has cleaned up. Returns that the service is stopping.
pub(super) fn stop(shared: &Shared) -> bool {
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
    tracing::info!("stopping");
    let mut s = shared.lock();
    if let Some(r) = &mut s.running {
        r.cancel();
    }
    s.requests = None;
    true
}

/// A running job that is stuck (see `watchdog`): takes it from the worker, closes the inbox,
/// removes its temporary files, and returns its id and the error it fails with.
pub(super) fn give_up_if_stalled(shared: &Shared) -> Option<(String, String)> {
    let mut s = shared.lock();
    let timeout = s.config.service.stall_timeout();
    let r = s.running.as_ref()?;
    let stall = watchdog::stall(
        shared.beat.silence(),
        r.cancelled_at.map(|t| t.elapsed()),
        timeout,
    )?;
    let r = s.running.take()?;
    s.requests = None;
    s.stage = "idle";
    drop(s);
    let error = r.stall_message(stall);
    tracing::error!(job = %r.id, %error, "failed");
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&format!(
        "job {} failed: {error}",
        r.id
    ))]);
    for path in &r.outputs {
        crate::files::outputs::discard_temp(path);
    }
    Some((r.id, error))
}
