//! Start-up and the main loop: the config with its XDG output directory, the bus name, the
//! worker, relay and key threads, and what signals and the watchdog do until the service ends.

use super::access::{on_gesture, watch_keys};
use super::callers::Callers;
use super::interface::Focusd;
use super::relay::relay;
use super::state::{give_up_if_stalled, stop, Shared, State};
use super::worker::{worker, Event};
use super::{Bus, ServeOptions, BUS_NAME, OBJECT_PATH};
use crate::base::clip;
use crate::service::config::Config;
use crate::service::feedback::Desk;
use crate::service::job::Source;
use crate::service::preview::{self, Preview};
use crate::service::watchdog::Heartbeat;
use crate::service::ServiceError;
use crate::service::{output_dir, pictures};
use futures_util::StreamExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::signal::unix::{signal, SignalKind};
use tokio::sync::mpsc::unbounded_channel;

type Result<T> = std::result::Result<T, ServiceError>;

/// The config (built-in defaults without a file), with its output directory chosen, ready and
/// absolute.
pub(super) fn load(path: &Option<PathBuf>, bus: &Bus) -> Result<Config> {
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
    output_dir::settle(&mut config.output)?;
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
        .map_err(|e| ServiceError::Start("async runtime", e))?;
    let result = runtime.block_on(run(opts, config, source));
    // A job blocked in a read keeps its thread: nothing waits for it.
    runtime.shutdown_background();
    result
}

pub(super) async fn run(opts: ServeOptions, config: Config, source: Source) -> Result<()> {
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
    let connect = |builder: zbus::connection::Builder<'static>| async {
        builder
            .build()
            .await
            .map_err(|error| ServiceError::Connect {
                bus: opts.bus.clone(),
                error,
            })
    };
    let preview = Arc::new(Preview::new({
        let shared = shared.clone();
        move || {
            let config = shared.lock().config.clone();
            preview::open_source(&config, &shared.source)
        }
    }));
    let service = Focusd {
        shared: shared.clone(),
        callers: Callers::new(connect(opts.bus.builder()?).await?),
        preview: preview.clone(),
    };
    let conn = opts
        .bus
        .builder()?
        .serve_at(OBJECT_PATH, service)
        .build()
        .await
        .map_err(|error| ServiceError::Connect {
            bus: opts.bus.clone(),
            error,
        })?;
    let mut lost = own_name(&conn, &opts.bus).await?;
    let iface = conn
        .object_server()
        .interface::<_, Focusd>(OBJECT_PATH)
        .await?;
    tokio::spawn(preview::watch(preview.clone(), conn.clone()));
    let worker = {
        let shared = shared.clone();
        let preview = preview.clone();
        std::thread::Builder::new()
            .name("focusd-job".into())
            .spawn(move || worker(shared, inbox, events, preview))
            .map_err(|e| ServiceError::Start("job thread", e))?
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
    let mut fatal: Option<ServiceError> = None;
    loop {
        tokio::select! {
            _ = term.recv() => stopping = stop(&shared),
            _ = int.recv() => stopping = stop(&shared),
            Some(_) = lost.next(), if fatal.is_none() => {
                let e = ServiceError::NameLost(BUS_NAME);
                tracing::error!("{e}");
                fatal = Some(e);
                stopping = stop(&shared);
            }
            _ = conn.closed(), if fatal.is_none() => {
                let e = ServiceError::BusClosed(opts.bus.clone());
                tracing::error!("{e}");
                fatal = Some(e);
                stopping = stop(&shared);
            }
            _ = hup.recv() => reload(&opts.config, &opts.bus, &shared),
            Some(g) = gestures.recv() => on_gesture(&shared, g),
            _ = tick.tick() => {
                if let Some((job, error)) = give_up_if_stalled(&shared) {
                    let _ = Focusd::failed(iface.signal_emitter(), &job, &error).await;
                    return Err(ServiceError::Stalled { job, error });
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
    worker.join().map_err(|_| ServiceError::WorkerPanicked)?;
    // The worker's last events (a cancelled job's Failed) go out before the service ends.
    relay.await?;
    fatal.map_or(Ok(()), Err)
}

/// Takes `BUS_NAME` without replacing its owner and without letting another take it over, and
/// returns the stream that says when it is lost all the same (the bus restarted, say).
pub(super) async fn own_name(
    conn: &zbus::Connection,
    bus: &Bus,
) -> Result<zbus::fdo::NameLostStream> {
    use zbus::fdo::{RequestNameFlags, RequestNameReply};
    let dbus = zbus::fdo::DBusProxy::new(conn).await?;
    let lost = dbus.receive_name_lost_with_args(&[(0, BUS_NAME)]).await?;
    let taken = || ServiceError::NameTaken {
        name: BUS_NAME,
        bus: bus.clone(),
    };
    match conn
        .request_name_with_flags(BUS_NAME, RequestNameFlags::DO_NOT_QUEUE)
        .await
    {
        Ok(RequestNameReply::PrimaryOwner) => Ok(lost),
        Ok(_) | Err(zbus::Error::NameTaken) => Err(taken()),
        Err(error) => Err(ServiceError::CannotOwn {
            name: BUS_NAME,
            bus: bus.clone(),
            error,
        }),
    }
}

/// SIGHUP: the new config replaces the old only if it is good.
pub(super) fn reload(path: &Option<PathBuf>, bus: &Bus, shared: &Shared) {
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
            clip::clip(&clip::chain(&e))
        ),
    }
}
