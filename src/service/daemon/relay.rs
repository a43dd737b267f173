//! Worker events to D-Bus signals, property changes, systemd status and the phone's feedback.

use super::interface::Focusd;
use super::worker::Event;
use crate::service::feedback::{Desk, Moment, Moments};
use tokio::sync::mpsc::UnboundedReceiver;
use zbus::object_server::InterfaceRef;

/// Turns worker events into signals and property changes.
/// Also tells the person holding the phone (`feedback`): hold still, done, failed.
pub(super) async fn relay(
    iface: InterfaceRef<Focusd>,
    mut events: UnboundedReceiver<Event>,
    desk: Desk,
) {
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

pub(super) fn notify_status(state: &str) {
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(state)]);
}
