//! The job thread: runs one capture at a time, and its reporter, which turns the sweep's and
//! the engine's progress into the `State` property, heartbeats and events for the relay.

use super::state::Shared;
use crate::backend::replay::faults::Fault;
use crate::base::clip;
use crate::capture::sweep::Monitor;
use crate::capture::Stage;
use crate::service::config::Config;
use crate::service::job::{self, Rig, Source};
use crate::service::preview::Preview;
use crate::service::ServiceError;
use crate::stack::Progress;
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::mpsc::UnboundedSender;

/// What the worker reports; the event task turns it into signals.
pub(super) enum Event {
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

pub(super) struct Request {
    pub(super) id: String,
    pub(super) faults: Vec<Fault>,
    pub(super) config: Config,
    pub(super) output: PathBuf,
    pub(super) report: Option<PathBuf>,
    pub(super) cancel: Arc<AtomicBool>,
}

/// Relays a job's progress to the event task, and its cancel flag to the sweep and the engine.
pub(super) struct Reporter {
    pub(super) job: String,
    pub(super) shared: Arc<Shared>,
    pub(super) events: UnboundedSender<Event>,
    pub(super) cancel: Arc<AtomicBool>,
    /// The engine's current stage, its steps and the steps done.
    pub(super) stage: Mutex<(Stage, usize)>,
    pub(super) done: AtomicUsize,
}

/// The `State` property while a job is in `stage`.
pub(super) fn state_of(stage: Stage) -> &'static str {
    match stage {
        Stage::WaitingStill | Stage::Sweeping | Stage::Developing => stage.name(),
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
            crate::base::malloc::release_freed_memory();
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
pub(super) fn worker(
    shared: Arc<Shared>,
    requests: crossbeam_channel::Receiver<Request>,
    events: UnboundedSender<Event>,
    preview: Arc<Preview>,
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
        // The live preview pauses while the job has the camera.
        let hold = preview.hold_camera();
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
                    r.config.output.keep_raw,
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
            Err(ServiceError::Panicked(what))
        });
        drop(hold);
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
                    let error = if e.is_cancel() {
                        "cancelled".to_string()
                    } else {
                        clip::clip(&clip::chain(&e))
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
