//! The app's link to the daemon: a session-bus connection on a small tokio runtime of its own
//! (zbus runs on tokio; GTK on its main loop), the generated `Focusd1Proxy`, and the daemon's
//! signals turned into [`Event`]s the window reads on the main loop.

use focusd::service::proxy::{Focusd1Proxy, FocusdError};
use futures_util::StreamExt;
use gettextrs::gettext;
use std::future::Future;
use std::os::fd::OwnedFd;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};

/// What the daemon said, for the window.
#[derive(Debug)]
pub enum Event {
    Progress {
        job: String,
        stage: String,
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

pub struct Link {
    runtime: tokio::runtime::Runtime,
    proxy: tokio::sync::OnceCell<Focusd1Proxy<'static>>,
    events: UnboundedSender<Event>,
}

impl Link {
    pub fn new() -> std::io::Result<(Link, UnboundedReceiver<Event>)> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()?;
        let (events, rx) = unbounded_channel();
        Ok((
            Link {
                runtime,
                proxy: tokio::sync::OnceCell::new(),
                events,
            },
            rx,
        ))
    }

    /// Runs `f` on the link's runtime; the result can be awaited on GTK's main loop.
    async fn run<T: Send + 'static>(
        &self,
        f: impl Future<Output = Result<T, String>> + Send + 'static,
    ) -> Result<T, String> {
        self.runtime
            .spawn(f)
            .await
            .unwrap_or_else(|e| Err(e.to_string()))
    }

    /// The proxy, connecting the first time (and subscribing to the signals).
    async fn proxy(&self) -> Result<Focusd1Proxy<'static>, String> {
        if let Some(p) = self.proxy.get() {
            return Ok(p.clone());
        }
        let events = self.events.clone();
        let proxy = self
            .run(async move {
                let unreachable =
                    |e: zbus::Error| format!("{}: {e}", gettext("Cannot reach the session bus"));
                let conn = zbus::connection::Builder::session()
                    .build()
                    .await
                    .map_err(unreachable)?;
                let proxy = Focusd1Proxy::new(&conn).await.map_err(|e| e.to_string())?;
                forward(&proxy, events).await.map_err(|e| e.to_string())?;
                Ok(proxy)
            })
            .await?;
        let _ = self.proxy.set(proxy.clone());
        Ok(proxy)
    }

    /// Starts or renews the preview; the ring's descriptor.
    pub async fn start_preview(&self) -> Result<OwnedFd, String> {
        let proxy = self.proxy().await?;
        self.run(async move {
            proxy
                .start_preview()
                .await
                .map(Into::into)
                .map_err(|e| explain(&e))
        })
        .await
    }

    /// Starts a capture; its job id.
    pub async fn capture(&self) -> Result<String, String> {
        let proxy = self.proxy().await?;
        self.run(async move { proxy.capture().await.map_err(|e| explain(&e)) })
            .await
    }

    pub async fn cancel(&self, job: String) -> Result<(), String> {
        let proxy = self.proxy().await?;
        self.run(async move { proxy.cancel(&job).await.map_err(|e| explain(&e)) })
            .await
    }
}

/// Sends the daemon's Progress, Finished and Failed signals to `events` as they come.
async fn forward(
    proxy: &Focusd1Proxy<'static>,
    events: UnboundedSender<Event>,
) -> zbus::Result<()> {
    let mut progress = proxy.receive_progress().await?;
    let mut finished = proxy.receive_finished().await?;
    let mut failed = proxy.receive_failed().await?;
    tokio::spawn(async move {
        loop {
            let event = tokio::select! {
                Some(s) = progress.next() => s.args().ok().map(|a| Event::Progress {
                    job: a.job.to_string(),
                    stage: a.stage.to_string(),
                    done: a.done,
                    total: a.total,
                }),
                Some(s) = finished.next() => s.args().ok().map(|a| Event::Finished {
                    job: a.job.to_string(),
                    path: a.path.to_string(),
                }),
                Some(s) = failed.next() => s.args().ok().map(|a| Event::Failed {
                    job: a.job.to_string(),
                    error: a.error.to_string(),
                }),
                else => break,
            };
            if let Some(e) = event {
                if events.send(e).is_err() {
                    break;
                }
            }
        }
    });
    Ok(())
}

/// A daemon error in words for the person holding the phone.
fn explain(e: &FocusdError) -> String {
    use zbus::DBusError;
    let text = e.description().unwrap_or_default().to_string();
    match e {
        FocusdError::ZBus(z) => {
            let s = z.to_string();
            if s.contains("ServiceUnknown") || s.contains("NameHasNoOwner") {
                gettext(
                    // One line: po/update-pot reads it with xgettext's C lexer.
                    "focusd is not running. Start it with “systemctl --user start focusd”; the preview appears here when it runs.",
                )
            } else {
                format!("{}: {s}", gettext("The daemon cannot be reached"))
            }
        }
        FocusdError::Busy(_) => format!("{}: {text}", gettext("A capture is already running")),
        FocusdError::Preview(_) => format!("{}: {text}", gettext("No preview")),
        FocusdError::Output(_) => format!("{}: {text}", gettext("Cannot save pictures")),
        _ => text,
    }
}
