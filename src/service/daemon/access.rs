//! Who may start and cancel a job: a D-Bus caller (only that uid, and root, may cancel it) or a
//! trigger key (anyone may), and the unguessable job ids that name them.

use super::interface::FocusdError;
use super::state::{Running, Shared};
use super::worker::{state_of, Request};
use crate::backend::input::{EvdevKeys, TriggerConfig};
use crate::base::clip;
use crate::capture::trigger::{self, Gesture};
use crate::capture::Stage;
use crate::service::output_dir;
use crate::service::ServiceError;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver};

/// Who started a job, which says who may cancel it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Owner {
    /// A D-Bus caller: only that uid and root.
    Caller(u32),
    /// A hardware key (`[trigger]`): anyone the D-Bus policy lets call Cancel. The person
    /// holding the phone is no uid.
    Key,
}

/// Starts a capture for `owner` (the `Capture` method and a key press) and returns its job id.
pub(super) fn start(shared: &Shared, owner: Owner) -> Result<String, FocusdError> {
    let mut s = shared.lock();
    if let Some(r) = &s.running {
        return Err(FocusdError::Busy(format!(
            "job {} is running; wait for its Finished or Failed signal, or Cancel it",
            r.id
        )));
    }
    let Some(requests) = s.requests.clone() else {
        return Err(FocusdError::Busy("the service is shutting down".into()));
    };
    let (image, report) = output_dir::next_paths(&s.config.output)
        .map_err(|e| FocusdError::Output(clip::chain(&e)))?;
    let id = new_job_id().map_err(|e| FocusdError::Busy(format!("no job id: {e}")))?;
    let cancel = Arc::new(AtomicBool::new(false));
    let report = s.config.output.report.then_some(report);
    let request = Request {
        id: id.clone(),
        faults: std::mem::take(&mut s.faults),
        config: s.config.clone(),
        output: image.clone(),
        report: report.clone(),
        cancel: cancel.clone(),
    };
    shared.beat.beat();
    s.running = Some(Running {
        id: id.clone(),
        owner,
        cancel,
        cancelled_at: None,
        at: (Stage::WaitingStill, 0, 0),
        outputs: std::iter::once(image).chain(report).collect(),
    });
    s.stage = state_of(Stage::WaitingStill);
    drop(s);
    requests
        .send(request)
        .map_err(|_| FocusdError::Busy("the service is shutting down".into()))?;
    tracing::info!(job = %id, "capture requested");
    Ok(id)
}

/// Cancels job `job` for the D-Bus caller with uid `caller`.
pub(super) fn cancel(shared: &Shared, job: &str, caller: u32) -> Result<(), FocusdError> {
    let mut s = shared.lock();
    // Echoed in the error: a caller's megabyte of text is not.
    let shown: String = job.chars().take(64).collect();
    match &mut s.running {
        // A key's job (Owner::Key) is anyone's to cancel.
        Some(Running {
            id,
            owner: Owner::Caller(uid),
            ..
        }) if id == job && caller != *uid && caller != 0 => Err(FocusdError::AccessDenied(
            format!("job {shown} was started by uid {uid}; only that user or root may cancel it"),
        )),
        Some(r) if r.id == job => {
            r.cancel();
            tracing::info!(job, "cancel requested");
            Ok(())
        }
        Some(r) => Err(FocusdError::NoSuchJob(format!(
            "job {shown:?} is not running (job {} is)",
            r.id
        ))),
        None => Err(FocusdError::NoSuchJob(format!(
            "job {shown:?} is not running (no job is)"
        ))),
    }
}

/// What a trigger key does (`[trigger]`, `capture::trigger`): a press starts a capture as
/// `Capture` does, or is ignored while one runs; a long press cancels the running one.
pub(super) fn on_gesture(shared: &Shared, gesture: Gesture) {
    match gesture {
        Gesture::Press => match start(shared, Owner::Key) {
            Ok(job) => tracing::info!(%job, "trigger key: capture started"),
            Err(e) => tracing::info!("trigger key pressed: ignored ({e})"),
        },
        Gesture::LongPress => match &mut shared.lock().running {
            Some(r) => {
                r.cancel();
                tracing::info!(job = %r.id, "trigger key held: cancel requested");
            }
            None => tracing::info!("trigger key held: no capture is running, nothing to cancel"),
        },
    }
}

/// Runs the trigger keys on their own thread (they block in poll), sending each gesture to
/// the main loop, until the loop is gone.
pub(super) fn watch_keys(
    config: &TriggerConfig,
) -> Result<UnboundedReceiver<Gesture>, ServiceError> {
    let (tx, rx) = unbounded_channel();
    if config.keys.is_empty() {
        tracing::info!("trigger keys: none configured ([trigger] keys = [])");
        return Ok(rx);
    }
    let config = config.clone();
    std::thread::Builder::new()
        .name("focusd-keys".into())
        .spawn(move || {
            let mut keys = EvdevKeys::open(&config);
            trigger::watch(&mut keys, config.long_press(), |g| tx.send(g).is_ok());
        })
        .map_err(|e| ServiceError::Start("trigger key thread", e))?;
    Ok(rx)
}

/// A job id no other caller can guess (128 random bits, in hex): a job is named to cancel it.
pub(super) fn new_job_id() -> std::io::Result<String> {
    let mut bytes = [0u8; 16];
    let mut got = 0;
    while got < bytes.len() {
        // SAFETY: the pointer and length describe the unfilled rest of `bytes`.
        let n = unsafe { libc::getrandom(bytes[got..].as_mut_ptr().cast(), bytes.len() - got, 0) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() != std::io::ErrorKind::Interrupted {
                return Err(e);
            }
        } else {
            got += n as usize;
        }
    }
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

#[cfg(test)]
mod tests {
    use super::super::state::State;
    use super::*;
    use crate::service::config::Config;
    use crate::service::job::Source;
    use crate::service::watchdog::Heartbeat;
    use std::path::Path;
    use std::sync::atomic::Ordering;
    use std::sync::Mutex;

    /// A service with no bus and no worker: what a key or a call starts lands in the inbox.
    fn service(out: &Path) -> (Shared, crossbeam_channel::Receiver<Request>) {
        let (requests, inbox) = crossbeam_channel::unbounded();
        let mut config = Config::default();
        config.output.dir = Some(out.to_path_buf());
        let state = State {
            config,
            requests: Some(requests),
            running: None,
            stage: "idle",
            last_result: String::new(),
            faults: Vec::new(),
        };
        let shared = Shared {
            state: Mutex::new(state),
            source: Source::Device,
            beat: Heartbeat::default(),
        };
        (shared, inbox)
    }

    fn running(shared: &Shared) -> Option<(String, Owner, bool)> {
        let s = shared.lock();
        let r = s.running.as_ref()?;
        Some((r.id.clone(), r.owner, r.cancel.load(Ordering::SeqCst)))
    }

    #[test]
    fn a_press_starts_a_capture_and_a_press_during_it_is_ignored() {
        let dir = tempfile::tempdir().unwrap();
        let (shared, inbox) = service(dir.path());
        on_gesture(&shared, Gesture::Press);
        let job = inbox.try_recv().expect("a request").id;
        assert_eq!(running(&shared), Some((job.clone(), Owner::Key, false)));
        on_gesture(&shared, Gesture::Press);
        assert!(inbox.try_recv().is_err(), "a second job was started");
        assert_eq!(running(&shared), Some((job.clone(), Owner::Key, false)));
        // A call is Busy the same way.
        assert!(matches!(
            start(&shared, Owner::Caller(1000)),
            Err(FocusdError::Busy(_))
        ));
    }

    #[test]
    fn a_long_press_cancels_the_running_job_whoever_started_it_and_is_nothing_when_idle() {
        let dir = tempfile::tempdir().unwrap();
        let (shared, inbox) = service(dir.path());
        on_gesture(&shared, Gesture::LongPress);
        assert_eq!(running(&shared), None);
        assert!(inbox.try_recv().is_err());
        let job = start(&shared, Owner::Caller(1000)).unwrap();
        on_gesture(&shared, Gesture::LongPress);
        assert_eq!(running(&shared), Some((job, Owner::Caller(1000), true)));
    }

    #[test]
    fn a_keys_job_is_anyones_to_cancel_a_callers_only_its_own_and_roots() {
        let dir = tempfile::tempdir().unwrap();
        let (shared, _inbox) = service(dir.path());
        let job = start(&shared, Owner::Caller(1000)).unwrap();
        let e = cancel(&shared, &job, 1001).unwrap_err();
        assert!(
            matches!(&e, FocusdError::AccessDenied(m) if m.contains("uid 1000")),
            "{e:?}"
        );
        assert!(!running(&shared).unwrap().2);
        cancel(&shared, &job, 0).unwrap();
        assert!(running(&shared).unwrap().2);

        let (shared, _inbox) = service(dir.path());
        on_gesture(&shared, Gesture::Press);
        let (job, ..) = running(&shared).unwrap();
        assert!(matches!(
            cancel(&shared, "another", 1001),
            Err(FocusdError::NoSuchJob(_))
        ));
        cancel(&shared, &job, 1001).unwrap();
        assert_eq!(running(&shared), Some((job, Owner::Key, true)));
    }
}
