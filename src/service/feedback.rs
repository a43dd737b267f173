//! Telling the person holding the phone what a capture needs of them, through the session's own
//! services: feedbackd (`org.sigxcpu.Feedback`: haptics and sound) says "hold still" when the
//! sweep starts and "you may move" when its last plane is taken; a desktop notification
//! (`org.freedesktop.Notifications`) shows the picture, or why there is none.
//!
//! Both are optional: a phone without feedbackd or a notification daemon still captures, and a
//! call that fails is logged once, not retried. Both live on the session bus: the system service
//! has none to call. The calls go out in the order of the moments that caused them (a capture
//! that fails at once must not buzz "failed" before "hold still"), one after another from a
//! task of their own, so a slow or absent service never delays a signal; a call gets
//! [`CALL_TIMEOUT`] before the next one goes.

use crate::capture::Stage;
use std::collections::HashMap;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use zbus::Variant;

/// How long one call may hold up the calls queued after it: feedbackd and notification daemons
/// answer in milliseconds; one that hangs must not keep the next capture's feedback back.
const CALL_TIMEOUT: Duration = Duration::from_secs(5);

/// A queued call to a session service.
type Call = Pin<Box<dyn Future<Output = ()> + Send>>;

/// The app id feedbackd keys per-application settings on, and the notification's desktop entry:
/// the launcher is the viewfinder app's, `org.focusd.Viewfinder.desktop`.
pub const APP_ID: &str = "org.focusd.Viewfinder";

/// Feedback events, named by feedbackd's Event naming spec; the stock theme gives each a sound.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Moment {
    /// The sweep starts: hold still ("camera-focus").
    HoldStill,
    /// The last plane is taken: the phone may move ("camera-shutter").
    Taken,
    /// The capture failed. The spec has no camera failure for applications; "phone-failure"
    /// (a call ended by a failure) is the failure sound every stock theme has.
    Failed,
}

impl Moment {
    pub fn event(self) -> &'static str {
        match self {
            Moment::HoldStill => "camera-focus",
            Moment::Taken => "camera-shutter",
            Moment::Failed => "phone-failure",
        }
    }
}

/// Follows a job's progress reports and says when a moment has come, once each.
#[derive(Default)]
pub struct Moments {
    job: String,
    sweeping: bool,
    taken: bool,
}

impl Moments {
    /// The moment a progress report of `job` marks, if any.
    pub fn progress(&mut self, job: &str, stage: Stage, done: u32, total: u32) -> Option<Moment> {
        if self.job != job {
            *self = Moments {
                job: job.to_string(),
                ..Moments::default()
            };
        }
        if stage != Stage::Sweeping {
            return None;
        }
        if !self.sweeping {
            self.sweeping = true;
            return Some(Moment::HoldStill);
        }
        if total > 0 && done >= total && !self.taken {
            self.taken = true;
            return Some(Moment::Taken);
        }
        None
    }
}

/// The session services a job's moments and results go to.
#[derive(Clone)]
pub struct Desk {
    /// The session bus and the queue of calls to it.
    session: Option<(zbus::Connection, mpsc::UnboundedSender<Call>)>,
    /// Logged once each: an absent service is normal.
    feedback_missing: Arc<AtomicBool>,
    notifications_missing: Arc<AtomicBool>,
}

impl Desk {
    /// On the session bus (or a private one in tests); `None` on the system bus.
    pub fn new(session: Option<zbus::Connection>) -> Desk {
        if session.is_none() {
            tracing::info!(
                "on the system bus: no haptic feedback or notifications to give (feedbackd and \
                 the notification daemon are session services)"
            );
        }
        let session = session.map(|conn| {
            let (tx, mut rx) = mpsc::unbounded_channel::<Call>();
            tokio::spawn(async move {
                while let Some(call) = rx.recv().await {
                    call.await;
                }
            });
            (conn, tx)
        });
        Desk {
            session,
            feedback_missing: Arc::default(),
            notifications_missing: Arc::default(),
        }
    }

    /// Triggers feedbackd's feedback for `moment`.
    pub fn feedback(&self, moment: Moment) {
        let hints: HashMap<&str, Variant> = HashMap::new();
        // timeout -1: each feedback runs once.
        let body = (APP_ID, moment.event(), hints, -1i32);
        let missing = &self.feedback_missing;
        self.call(
            "org.sigxcpu.Feedback",
            "TriggerFeedback",
            body,
            missing,
            "haptic feedback",
        );
    }

    /// A desktop notification: the finished picture (`Ok(path)`) or why it failed.
    pub fn notify(&self, result: Result<&str, &str>) {
        let mut hints: HashMap<&str, Variant> = HashMap::new();
        hints.insert("desktop-entry", Variant::from(APP_ID));
        let (summary, body) = match result {
            Ok(path) => {
                hints.insert("image-path", Variant::from(format!("file://{path}")));
                ("Focus stack saved", path.to_string())
            }
            Err(e) => ("Focus stack failed", e.to_string()),
        };
        let actions: Vec<&str> = Vec::new();
        // app name, replaces id, icon, summary, body, actions, hints, expire (-1: the server's
        // default).
        let body = ("focusd", 0u32, APP_ID, summary, body, actions, hints, -1i32);
        let missing = &self.notifications_missing;
        self.call(
            "org.freedesktop.Notifications",
            "Notify",
            body,
            missing,
            "desktop notifications",
        );
    }

    /// Queues a call of `method` of a session service (its interface named as the service, at
    /// the object path its name spells); a failure is logged the first time only.
    fn call<B>(
        &self,
        service: &'static str,
        method: &'static str,
        body: B,
        missing: &Arc<AtomicBool>,
        what: &'static str,
    ) where
        B: serde::Serialize + zbus::zvariant::DynamicType + Send + Sync + 'static,
    {
        let Some((conn, queue)) = &self.session else {
            return;
        };
        let (conn, missing) = (conn.clone(), missing.clone());
        let call = async move {
            let path = format!("/{}", service.replace('.', "/"));
            let call = conn.call_method(Some(service), path.as_str(), Some(service), method, &body);
            let error = match tokio::time::timeout(CALL_TIMEOUT, call).await {
                Ok(Ok(_)) => return,
                Ok(Err(e)) => e.to_string(),
                Err(_) => format!("no answer in {} s", CALL_TIMEOUT.as_secs()),
            };
            if !missing.swap(true, Ordering::Relaxed) {
                tracing::info!("no {what} ({service}: {error})");
            }
        };
        // The queue's task ends only with the runtime; a call queued after that is moot.
        let _ = queue.send(Box::pin(call));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_moment_comes_once_per_job() {
        let mut m = Moments::default();
        let seen: Vec<_> = [
            ("a", Stage::WaitingStill, 0, 0),
            ("a", Stage::Sweeping, 0, 3),
            ("a", Stage::Sweeping, 1, 3),
            ("a", Stage::Sweeping, 3, 3),
            ("a", Stage::Sweeping, 3, 3),
            ("b", Stage::Sweeping, 0, 2),
            ("b", Stage::Sweeping, 2, 2),
        ]
        .into_iter()
        .filter_map(|(j, s, d, t)| m.progress(j, s, d, t).map(|x| (j, x)))
        .collect();
        assert_eq!(
            seen,
            [
                ("a", Moment::HoldStill),
                ("a", Moment::Taken),
                ("b", Moment::HoldStill),
                ("b", Moment::Taken)
            ]
        );
    }
}
