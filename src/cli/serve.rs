//! `focusd serve` (the D-Bus daemon) and `focusd trigger` (its one-button client).

use super::progress::Bar;
use anyhow::{bail, Context, Result};
use focusd::service::daemon::{self, Bus, ServeOptions, BUS_NAME, OBJECT_PATH};
use focusd::service::proxy::{
    FailedStream, FinishedStream, Focusd1Proxy, FocusdError, ProgressStream,
};
use futures_util::StreamExt;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Duration;

/// Which bus to use: the session bus unless told otherwise.
#[derive(clap::Args, Debug)]
pub struct BusArgs {
    /// The session bus (the default).
    #[arg(long, conflicts_with_all = ["system", "address"])]
    pub session: bool,
    /// The system bus.
    #[arg(long, conflicts_with = "address")]
    pub system: bool,
    /// A bus address, e.g. unix:path=/run/bus (a private bus).
    #[arg(long, value_name = "ADDRESS")]
    pub address: Option<String>,
}

impl BusArgs {
    fn bus(&self) -> Bus {
        match (&self.address, self.system) {
            (Some(a), _) => Bus::Address(a.clone()),
            (None, true) => Bus::System,
            (None, false) => Bus::Session,
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Configuration file (TOML); reread on SIGHUP.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Serve captures replayed from a recorded bundle instead of the camera and the IMU.
    #[arg(long, value_name = "DIR")]
    pub replay: Option<PathBuf>,
    /// With --replay: take as long as the recorded sweep did.
    #[arg(long, requires = "replay")]
    pub paced: bool,
    /// With --replay: inject a failure into the first job, for tests of the failure paths:
    /// camera-gone:P, frame-timeout:P, imu-stops:P, imu-nan:P, panic:P (P a plane) or
    /// develop-hold:P (the development of raw frame P waits for a Cancel).
    /// Repeatable.
    #[arg(long, requires = "replay", value_name = "FAULT")]
    pub fault: Vec<focusd::backend::replay::faults::Fault>,
    #[command(flatten)]
    pub bus: BusArgs,
}

/// Logs to journald when systemd started us with its journal on stderr, else to stderr.
fn init_logging() {
    use tracing_subscriber::prelude::*;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let registry = tracing_subscriber::registry().with(filter);
    let journald = std::env::var_os("JOURNAL_STREAM").and_then(|_| tracing_journald::layer().ok());
    match journald {
        Some(layer) => registry.with(layer).init(),
        None => registry
            .with(
                tracing_subscriber::fmt::layer()
                    .with_ansi(std::io::stderr().is_terminal())
                    .with_writer(std::io::stderr),
            )
            .init(),
    }
}

pub fn serve(a: &ServeArgs) -> Result<()> {
    init_logging();
    daemon::serve(ServeOptions {
        config: a.config.clone(),
        replay: a.replay.clone(),
        paced: a.paced,
        faults: a.fault.clone(),
        bus: a.bus.bus(),
    })?;
    Ok(())
}

#[derive(clap::Args, Debug)]
pub struct TriggerArgs {
    /// Wait for the job to end: print the image's path, or fail with the job's error.
    #[arg(long)]
    pub wait: bool,
    /// With --wait: give up after this many seconds.
    #[arg(long, default_value_t = 600, requires = "wait")]
    pub timeout: u64,
    #[command(flatten)]
    pub bus: BusArgs,
}

pub fn trigger(a: &TriggerArgs) -> Result<()> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?
        .block_on(trigger_async(a))
}

async fn trigger_async(a: &TriggerArgs) -> Result<()> {
    let bus = a.bus.bus();
    let conn = bus
        .builder()?
        .build()
        .await
        .with_context(|| format!("cannot connect to the {bus:?} bus"))?;
    let proxy = Focusd1Proxy::new(&conn)
        .await
        .with_context(|| format!("{BUS_NAME} at {OBJECT_PATH}"))?;
    // Subscribed before the call, so a fast job's signals are not missed.
    let (mut progress, mut finished, mut failed) = (
        proxy.receive_progress().await?,
        proxy.receive_finished().await?,
        proxy.receive_failed().await?,
    );
    let job = proxy.capture().await.map_err(|e| match e {
        FocusdError::ZBus(zbus::Error::MethodError(name, Some(msg), _)) => {
            anyhow::anyhow!("{name}: {msg}")
        }
        FocusdError::ZBus(zbus::Error::MethodError(name, None, _))
            if name.as_str().ends_with("ServiceUnknown") =>
        {
            anyhow::anyhow!("{BUS_NAME} is not running on the {bus:?} bus (start `focusd serve`)")
        }
        FocusdError::ZBus(e) => anyhow::anyhow!("Capture: {e}"),
        // The service's own errors, decoded: they print as `org.focusd.Error.NAME: message`.
        e => anyhow::anyhow!("{e}"),
    })?;
    if !a.wait {
        println!("{job}");
        return Ok(());
    }
    // The instance that took the job: a service started anew under the name has not got it.
    let owner = zbus::fdo::DBusProxy::new(&conn)
        .await?
        .get_name_owner(BUS_NAME.try_into()?)
        .await
        .with_context(|| format!("{BUS_NAME} is gone before job {job} ended"))?;
    let peer = zbus::fdo::PeerProxy::builder(&conn)
        .destination(owner.into_inner())
        .path(OBJECT_PATH)
        .build()
        .await?;
    // A person at a terminal sees a bar; a script's log gets one line per stage.
    let bar = std::io::stderr().is_terminal().then(Bar::stderr);
    let result = wait_for(
        a,
        &job,
        &peer,
        &mut progress,
        &mut finished,
        &mut failed,
        bar.as_ref(),
    )
    .await;
    if let Some(b) = &bar {
        b.finish();
    }
    println!("{}", result?);
    Ok(())
}

/// How often `trigger --wait` checks that the service is still there: a service that died or
/// a bus that closed ends the wait within about this (the bus answers for a dead service).
const ALIVE_EVERY: Duration = Duration::from_secs(1);
/// How long a live service may take to answer that check: a hung one ends the wait.
const ALIVE_ANSWER: Duration = Duration::from_secs(10);

/// Follows job `job` until it ends: the image's path, or why it failed. `peer` is the service
/// instance that runs it, pinged every [`ALIVE_EVERY`].
async fn wait_for(
    a: &TriggerArgs,
    job: &str,
    peer: &zbus::fdo::PeerProxy<'_>,
    progress: &mut ProgressStream,
    finished: &mut FinishedStream,
    failed: &mut FailedStream,
    bar: Option<&Bar>,
) -> Result<String> {
    let deadline = tokio::time::sleep(Duration::from_secs(a.timeout));
    tokio::pin!(deadline);
    let mut last_stage = String::new();
    let mut alive = tokio::time::interval(ALIVE_EVERY);
    loop {
        tokio::select! {
            _ = alive.tick() => {
                match tokio::time::timeout(ALIVE_ANSWER, peer.ping()).await {
                    Ok(Ok(())) => {}
                    Ok(Err(e)) => bail!(
                        "{BUS_NAME} is gone before job {job} ended ({e}); see the service's log"
                    ),
                    Err(_) => bail!(
                        "{BUS_NAME} stopped answering before job {job} ended; see the service's log"
                    ),
                }
            }
            Some(s) = progress.next() => {
                let args = s.args()?;
                if args.job != job {
                    continue;
                }
                match bar {
                    Some(b) => b.show(args.stage, args.done.into(), args.total.into()),
                    None if args.stage != last_stage => eprintln!("focusd: {}", args.stage),
                    None => {}
                }
                last_stage = args.stage.to_string();
            }
            Some(s) = finished.next() => {
                let args = s.args()?;
                if args.job == job {
                    return Ok(args.path.to_string());
                }
            }
            Some(s) = failed.next() => {
                let args = s.args()?;
                if args.job == job {
                    bail!("job {job} failed: {}", args.error);
                }
            }
            _ = &mut deadline => bail!("job {job} did not end within {} s", a.timeout),
            else => bail!("the connection to {BUS_NAME} closed before job {job} ended"),
        }
    }
}
