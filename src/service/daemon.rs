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

use super::config::Config;
use super::feedback::{Desk, Moment, Moments};
use super::job::{self, Rig, Source};
use super::output;
use super::pictures;
use super::watchdog::{self, Heartbeat, Stall};
use crate::backend::input::{EvdevKeys, TriggerConfig};
use crate::backend::replay::faults::Fault;
use crate::capture::sweep::Monitor;
use crate::capture::trigger::{self, Gesture};
use crate::capture::Stage;
use crate::stack::Progress;
use anyhow::{Context, Result};
use futures_util::StreamExt;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::signal::unix::{signal, SignalKind};
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};
use zbus::message::Header;
use zbus::object_server::{InterfaceRef, SignalEmitter};
use zbus::{interface, DBusError};

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
    pub fn builder(&self) -> Result<zbus::connection::Builder<'static>> {
        Ok(match self {
            Bus::Session => zbus::connection::Builder::session(),
            Bus::System => zbus::connection::Builder::system(),
            Bus::Address(a) => {
                let address = a
                    .parse::<zbus::Address>()
                    .with_context(|| format!("--address {a:?} is not a D-Bus address"))?;
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
}

struct Running {
    id: String,
    owner: Owner,
    cancel: Arc<AtomicBool>,
    /// When Cancel or SIGTERM asked the job to stop.
    cancelled_at: Option<Instant>,
    /// The stage the job reached, with its steps done and total (for a stall's message).
    at: (Stage, usize, usize),
    /// The files the job writes; a stall removes their temporary files.
    outputs: Vec<PathBuf>,
}

impl Running {
    fn cancel(&mut self) {
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
            (stage, ..) => stage.name().to_string(),
        }
    }

    /// Why the service gives up on the job.
    fn stall_message(&self, stall: Stall) -> String {
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

struct State {
    config: Config,
    /// The worker's inbox; taken at shutdown, which ends the worker after its job.
    requests: Option<crossbeam_channel::Sender<Request>>,
    running: Option<Running>,
    stage: &'static str,
    last_result: String,
    /// Injected into the next job, once.
    faults: Vec<Fault>,
}

/// What the service and its worker share.
struct Shared {
    state: Mutex<State>,
    source: Source,
    /// The running job's.
    beat: Heartbeat,
}

impl Shared {
    /// A worker that panicked mid-job leaves nothing half-written here (each field is set in
    /// one step), so a poisoned lock is still good.
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// What the worker reports; the event task turns it into signals.
enum Event {
    Stage,
    Progress {
        job: String,
        stage: Stage,
        done: u32,
        total: u32,
    },
    Finished {
        job: String,
        path: String,
    },
    Failed {
        job: String,
        error: String,
    },
}

struct Request {
    id: String,
    faults: Vec<Fault>,
    config: Config,
    output: PathBuf,
    report: Option<PathBuf>,
    cancel: Arc<AtomicBool>,
}

pub struct Focusd {
    shared: Arc<Shared>,
}

#[interface(name = "org.focusd.Focusd1")]
impl Focusd {
    /// Starts a capture (sweep, register, fuse) and returns its job id at once; the result
    /// comes as `Finished` or `Failed`.
    async fn capture(
        &self,
        #[zbus(header)] header: Header<'_>,
        #[zbus(connection)] conn: &zbus::Connection,
    ) -> Result<String, FocusdError> {
        // zbus passes a method without arguments whatever body came with the call.
        let got = header.signature().to_string();
        if !got.is_empty() {
            return Err(FocusdError::InvalidArgs(format!(
                "Capture takes no arguments, got signature {got:?}"
            )));
        }
        let owner = caller_uid(&header, conn).await?;
        start(&self.shared, Owner::Caller(owner))
    }

    /// Stops a running job; it ends with `Failed(job, "cancelled")`. Only the user that started
    /// it, and root, may; a job a hardware key started, anyone the D-Bus policy lets call.
    async fn cancel(
        &self,
        job: &str,
        #[zbus(header)] header: Header<'_>,
        #[zbus(connection)] conn: &zbus::Connection,
    ) -> Result<(), FocusdError> {
        let caller = caller_uid(&header, conn).await?;
        cancel(&self.shared, job, caller)
    }

    /// `idle`, `waiting-still`, `sweeping`, `registering` or `fusing`.
    #[zbus(property)]
    fn state(&self) -> String {
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
    async fn progress(
        emitter: &SignalEmitter<'_>,
        job: &str,
        stage: &str,
        done: u32,
        total: u32,
    ) -> zbus::Result<()>;

    #[zbus(signal)]
    async fn finished(emitter: &SignalEmitter<'_>, job: &str, path: &str) -> zbus::Result<()>;

    #[zbus(signal)]
    async fn failed(emitter: &SignalEmitter<'_>, job: &str, error: &str) -> zbus::Result<()>;
}

/// Who started a job, which says who may cancel it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Owner {
    /// A D-Bus caller: only that uid and root.
    Caller(u32),
    /// A hardware key (`[trigger]`): anyone the D-Bus policy lets call Cancel. The person
    /// holding the phone is no uid.
    Key,
}

/// Starts a capture for `owner` (the `Capture` method and a key press) and returns its job id.
fn start(shared: &Shared, owner: Owner) -> Result<String, FocusdError> {
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
    let (image, report) =
        output::next_paths(&s.config.output).map_err(|e| FocusdError::Output(format!("{e:#}")))?;
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
fn cancel(shared: &Shared, job: &str, caller: u32) -> Result<(), FocusdError> {
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
fn on_gesture(shared: &Shared, gesture: Gesture) {
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
fn watch_keys(config: &TriggerConfig) -> Result<UnboundedReceiver<Gesture>> {
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
        .context("starting the trigger key thread")?;
    Ok(rx)
}

/// The uid of a method call's sender, from the bus.
async fn caller_uid(header: &Header<'_>, conn: &zbus::Connection) -> Result<u32, FocusdError> {
    let sender = header
        .sender()
        .ok_or_else(|| FocusdError::AccessDenied("the call names no sender".into()))?;
    let dbus = zbus::fdo::DBusProxy::new(conn).await?;
    let uid = dbus
        .get_connection_unix_user(sender.clone().into())
        .await
        .map_err(|e| FocusdError::AccessDenied(format!("cannot tell who {sender} is: {e}")))?;
    Ok(uid)
}

/// A job id no other caller can guess (128 random bits, in hex): a job is named to cancel it.
fn new_job_id() -> std::io::Result<String> {
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

/// Relays a job's progress to the event task, and its cancel flag to the sweep and the engine.
struct Reporter {
    job: String,
    shared: Arc<Shared>,
    events: UnboundedSender<Event>,
    cancel: Arc<AtomicBool>,
    /// The engine's current stage, its steps and the steps done.
    stage: Mutex<(Stage, usize)>,
    done: AtomicUsize,
}

/// The `State` property while a job is in `stage`.
fn state_of(stage: Stage) -> &'static str {
    match stage {
        Stage::WaitingStill | Stage::Sweeping => stage.name(),
        Stage::Fuse(s) if s.registers() => "registering",
        Stage::Fuse(_) => "fusing",
    }
}

impl Reporter {
    /// The job is at step `done` of `total` of `stage`: the state follows it, and memory the
    /// last stage freed goes back.
    fn set_stage(&self, stage: Stage, done: usize, total: usize) {
        self.shared.beat.beat();
        let state = state_of(stage);
        let mut s = self.shared.lock();
        let mut began = false;
        if let Some(r) = s.running.as_mut().filter(|r| r.id == self.job) {
            began = r.at.0 != stage;
            r.at = (stage, done, total);
        }
        let state_changed = s.stage != state;
        s.stage = state;
        drop(s);
        if state_changed {
            let _ = self.events.send(Event::Stage);
        }
        if began {
            // A stage has begun: what the last one freed goes back to the system (as the CLI's
            // bar does), once per stage and not on every per-plane report.
            crate::malloc::release_freed_memory();
        }
    }

    fn send(&self, stage: Stage, done: usize, total: usize) {
        let _ = self.events.send(Event::Progress {
            job: self.job.clone(),
            stage,
            done: done as u32,
            total: total as u32,
        });
    }
}

impl Monitor for Reporter {
    fn progress(&self, stage: Stage, done: usize, total: usize) {
        self.set_stage(stage, done, total);
        self.send(stage, done, total);
    }

    fn cancelled(&self) -> bool {
        self.shared.beat.beat();
        self.cancel.load(Ordering::SeqCst)
    }
}

impl Progress for Reporter {
    fn stage(&self, stage: crate::stack::Stage, total: usize) {
        let stage = Stage::from(stage);
        self.set_stage(stage, 0, total);
        *self.stage.lock().unwrap_or_else(|e| e.into_inner()) = (stage, total);
        self.done.store(0, Ordering::SeqCst);
        self.send(stage, 0, total);
    }

    /// Sends at most one signal per percent of a stage.
    fn advance(&self, steps: usize) {
        self.shared.beat.beat();
        let (name, total) = *self.stage.lock().unwrap_or_else(|e| e.into_inner());
        let before = self.done.fetch_add(steps, Ordering::SeqCst);
        let after = before + steps;
        let percent = |d: usize| d * 100 / total.max(1);
        if percent(after) != percent(before) || after == total {
            self.send(name, after.min(total), total);
        }
    }

    fn cancelled(&self) -> bool {
        self.shared.beat.beat();
        self.cancel.load(Ordering::SeqCst)
    }
}

/// Runs jobs one after another until the request channel closes.
fn worker(
    shared: Arc<Shared>,
    requests: crossbeam_channel::Receiver<Request>,
    events: UnboundedSender<Event>,
) {
    for r in requests {
        let reporter = Reporter {
            job: r.id.clone(),
            shared: shared.clone(),
            events: events.clone(),
            cancel: r.cancel.clone(),
            stage: Mutex::new((Stage::WaitingStill, 0)),
            done: AtomicUsize::new(0),
        };
        let _ = events.send(Event::Stage);
        let source = match &shared.source {
            Source::Replay { dir, paced, .. } => Source::Replay {
                dir: dir.clone(),
                paced: *paced,
                faults: r.faults.clone(),
            },
            Source::Device => Source::Device,
        };
        // A bug that panics fails the job, not the service: the worker would be gone and the
        // service busy for good. Unwinding drops the rig, which releases the camera.
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
            Rig::open(&r.config, &source).and_then(|mut rig| {
                for line in &rig.description {
                    tracing::info!(job = %r.id, "{line}");
                }
                job::run(
                    &mut rig,
                    &r.config.fuse,
                    &r.output,
                    r.report.as_deref(),
                    &reporter,
                    &reporter,
                )
            })
        }))
        .unwrap_or_else(|panic| {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(anyhow::anyhow!(
                "internal error: {what} (please report this)"
            ))
        });
        // Idle before the signal, so a client may start the next job as soon as it hears.
        let event = {
            let mut s = shared.lock();
            if s.running.as_ref().is_none_or(|x| x.id != r.id) {
                // The watchdog gave up on the job and reported it.
                continue;
            }
            s.running = None;
            s.stage = "idle";
            match result {
                Ok(_) => {
                    s.last_result = r.output.display().to_string();
                    tracing::info!(job = %r.id, path = %s.last_result, "finished");
                    Event::Finished {
                        job: r.id,
                        path: s.last_result.clone(),
                    }
                }
                Err(e) => {
                    let error = if job::is_cancel(&e) {
                        "cancelled".to_string()
                    } else {
                        crate::clip::clip(&format!("{e:#}"))
                    };
                    tracing::warn!(job = %r.id, %error, "failed");
                    Event::Failed { job: r.id, error }
                }
            }
        };
        let _ = events.send(Event::Stage);
        let _ = events.send(event);
    }
}

/// Turns worker events into signals and property changes.
/// Also tells the person holding the phone (`feedback`): hold still, done, failed.
async fn relay(iface: InterfaceRef<Focusd>, mut events: UnboundedReceiver<Event>, desk: Desk) {
    let mut moments = Moments::default();
    while let Some(e) = events.recv().await {
        let emitter = iface.signal_emitter();
        let sent = match e {
            Event::Stage => {
                let i = iface.get().await;
                let state = i.state();
                notify_status(&state);
                i.state_changed(emitter).await
            }
            Event::Progress {
                job,
                stage,
                done,
                total,
            } => {
                if let Some(m) = moments.progress(&job, stage, done, total) {
                    desk.feedback(m);
                }
                Focusd::progress(emitter, &job, stage.name(), done, total).await
            }
            Event::Finished { job, path } => {
                desk.notify(Ok(&path));
                let r = Focusd::finished(emitter, &job, &path).await;
                let _ = iface.get().await.last_result_changed(emitter).await;
                r
            }
            Event::Failed { job, error } => {
                // A cancel is the user's own doing: nothing to tell them.
                if error != "cancelled" {
                    desk.feedback(Moment::Failed);
                    desk.notify(Err(&error));
                }
                Focusd::failed(emitter, &job, &error).await
            }
        };
        if let Err(e) = sent {
            tracing::warn!("cannot emit a signal: {e}");
        }
    }
}

fn notify_status(state: &str) {
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(state)]);
}

/// The config (built-in defaults without a file), with its output directory chosen and ready.
fn load(path: &Option<PathBuf>, bus: &Bus) -> Result<Config> {
    let mut config = match path {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    if config.output.dir.is_none() && *bus != Bus::System {
        // A user's service: where the gallery looks.
        match std::env::var_os("HOME").filter(|h| !h.is_empty()) {
            Some(home) => {
                let config_home = std::env::var_os("XDG_CONFIG_HOME").filter(|c| !c.is_empty());
                let pictures =
                    pictures::pictures_dir(Path::new(&home), config_home.as_deref().map(Path::new));
                config.output.dir = Some(pictures.join("focusd"));
            }
            None => tracing::warn!(
                "HOME is not set: writing to {} in the working directory",
                config.output.dir().display()
            ),
        }
    }
    output::prepare(&config.output)?;
    Ok(config)
}

/// Serves until SIGTERM or SIGINT, which cancel a running job and wait for it to end.
pub fn serve(opts: ServeOptions) -> Result<()> {
    let config = load(&opts.config, &opts.bus)?;
    let source = match &opts.replay {
        Some(dir) => Source::Replay {
            dir: dir.clone(),
            paced: opts.paced,
            faults: Vec::new(),
        },
        None => Source::Device,
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let result = runtime.block_on(run(opts, config, source));
    // A job blocked in a read keeps its thread: nothing waits for it.
    runtime.shutdown_background();
    result
}

async fn run(opts: ServeOptions, config: Config, source: Source) -> Result<()> {
    let (requests, inbox) = crossbeam_channel::unbounded();
    let (events, outbox) = unbounded_channel::<Event>();
    let shared = Arc::new(Shared {
        state: Mutex::new(State {
            config,
            requests: Some(requests),
            running: None,
            stage: "idle",
            last_result: String::new(),
            faults: opts.faults.clone(),
        }),
        source,
        beat: Heartbeat::default(),
    });
    let service = Focusd {
        shared: shared.clone(),
    };
    let conn = opts
        .bus
        .builder()?
        .serve_at(OBJECT_PATH, service)
        .build()
        .await
        .with_context(|| format!("cannot connect to the {:?} bus", opts.bus))?;
    let mut lost = own_name(&conn, &opts.bus).await?;
    let iface = conn
        .object_server()
        .interface::<_, Focusd>(OBJECT_PATH)
        .await?;
    let worker = {
        let shared = shared.clone();
        std::thread::Builder::new()
            .name("focusd-job".into())
            .spawn(move || worker(shared, inbox, events))
            .context("starting the job thread")?
    };
    let mut gestures = watch_keys(&shared.lock().config.trigger)?;
    let desk = Desk::new((opts.bus != Bus::System).then(|| conn.clone()));
    let relay = tokio::spawn(relay(iface.clone(), outbox, desk));
    let _ = sd_notify::notify(&[
        sd_notify::NotifyState::Ready,
        sd_notify::NotifyState::Status("idle"),
    ]);
    // systemd's period; pinged at half of it.
    let watchdog = sd_notify::watchdog_enabled();
    let mut pinged: Option<Instant> = None;
    tracing::info!("serving {BUS_NAME} at {OBJECT_PATH}");
    let (mut term, mut int, mut hup) = (
        signal(SignalKind::terminate())?,
        signal(SignalKind::interrupt())?,
        signal(SignalKind::hangup())?,
    );
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut stopping = false;
    // Why the service ends with an error once its job has stopped: the bus is gone.
    let mut fatal: Option<anyhow::Error> = None;
    loop {
        tokio::select! {
            _ = term.recv() => stopping = stop(&shared),
            _ = int.recv() => stopping = stop(&shared),
            Some(_) = lost.next(), if fatal.is_none() => {
                let e = anyhow::anyhow!("lost the bus name {BUS_NAME}; exiting for systemd to restart the service");
                tracing::error!("{e}");
                fatal = Some(e);
                stopping = stop(&shared);
            }
            _ = conn.closed(), if fatal.is_none() => {
                let e = anyhow::anyhow!("the connection to the {:?} bus closed; exiting for systemd to restart the service", opts.bus);
                tracing::error!("{e}");
                fatal = Some(e);
                stopping = stop(&shared);
            }
            _ = hup.recv() => reload(&opts.config, &opts.bus, &shared),
            Some(g) = gestures.recv() => on_gesture(&shared, g),
            _ = tick.tick() => {
                if let Some((job, error)) = give_up_if_stalled(&shared) {
                    let _ = Focusd::failed(iface.signal_emitter(), &job, &error).await;
                    return Err(anyhow::anyhow!("job {job}: {error}"));
                }
                if let Some(period) = watchdog {
                    if pinged.is_none_or(|t| t.elapsed() >= period / 2) {
                        let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
                        pinged = Some(Instant::now());
                    }
                }
                if stopping && worker.is_finished() {
                    break;
                }
            }
        }
    }
    worker
        .join()
        .map_err(|_| anyhow::anyhow!("the job thread panicked"))?;
    // The worker's last events (a cancelled job's Failed) go out before the service ends.
    relay.await?;
    fatal.map_or(Ok(()), Err)
}

/// Takes `BUS_NAME` without replacing its owner and without letting another take it over, and
/// returns the stream that says when it is lost all the same (the bus restarted, say).
async fn own_name(conn: &zbus::Connection, bus: &Bus) -> Result<zbus::fdo::NameLostStream> {
    use zbus::fdo::{RequestNameFlags, RequestNameReply};
    let dbus = zbus::fdo::DBusProxy::new(conn).await?;
    let lost = dbus.receive_name_lost_with_args(&[(0, BUS_NAME)]).await?;
    let taken = || {
        anyhow::anyhow!(
            "{BUS_NAME} is already owned on the {bus:?} bus: another focusd serve is running \
             (stop it first; focusd does not take the name over)"
        )
    };
    match conn
        .request_name_with_flags(BUS_NAME, RequestNameFlags::DO_NOT_QUEUE)
        .await
    {
        Ok(RequestNameReply::PrimaryOwner) => Ok(lost),
        Ok(_) | Err(zbus::Error::NameTaken) => Err(taken()),
        Err(e) => Err(e).with_context(|| {
            format!(
                "cannot own {BUS_NAME} on the {bus:?} bus (does the D-Bus policy let this user own \
                 it? see systemd/org.focusd.Focusd.conf)"
            )
        }),
    }
}

/// SIGTERM or SIGINT: cancels the running job and closes the worker's inbox, which ends the
/// worker once the job has cleaned up. Returns that the service is stopping.
fn stop(shared: &Shared) -> bool {
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
fn give_up_if_stalled(shared: &Shared) -> Option<(String, String)> {
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
        if let Ok(tmp) = crate::outputs::temp_path(path) {
            let _ = std::fs::remove_file(tmp);
        }
    }
    Some((r.id, error))
}

/// SIGHUP: the new config replaces the old only if it is good.
fn reload(path: &Option<PathBuf>, bus: &Bus, shared: &Shared) {
    let Some(p) = path else {
        tracing::info!("SIGHUP: no config file to reload (running on the built-in defaults)");
        return;
    };
    match load(path, bus) {
        Ok(c) => {
            let mut s = shared.lock();
            if c.trigger != s.config.trigger {
                tracing::warn!("SIGHUP: [trigger] changes take effect when the service restarts");
            }
            s.config = c;
            drop(s);
            tracing::info!("SIGHUP: reloaded {}", p.display());
        }
        Err(e) => tracing::error!(
            "SIGHUP: {}; keeping the old config",
            crate::clip::clip(&format!("{e:#}"))
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
