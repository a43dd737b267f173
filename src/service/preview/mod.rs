//! The live preview: who is watching, the thread that writes frames into the shared ring
//! (`ring`), and the hand-over of the camera to a capture and back.
//!
//! The preview runs while it has a client: the first `StartPreview` creates the ring and starts
//! the preview's thread, which opens the frame source (a camera may take a while, and the bus
//! does not wait for it: a source that cannot open fails the ring, saying why). The preview
//! stops, closing both, when the last client calls `StopPreview`,
//! leaves the bus, or has not renewed it with a `StartPreview` for `[service]
//! preview_timeout_s`. A capture job takes the camera with [`Preview::hold_camera`]: the
//! preview thread closes its source, marks the ring paused and waits until the job is over.

pub mod ring;

use crate::backend::replay::preview::ReplayPreview;
use crate::backend::replay::Bundle;
use crate::backend::v4l2;
use crate::capture::preview::{CameraPreview, FrameSource, FPS};
use crate::service::config::Config;
use crate::service::job::Source;
use crate::service::ServiceError;
use futures_util::StreamExt;
use ring::{RingWriter, State};
use std::collections::HashSet;
use std::os::fd::OwnedFd;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Opens the preview's frame source: the replay's reference frame, or the camera.
pub fn open_source(config: &Config, source: &Source) -> Result<Box<dyn FrameSource>, ServiceError> {
    Ok(match source {
        Source::Replay { dir, .. } => Box::new(ReplayPreview::open(&Bundle::open(dir)?)?),
        Source::Device => Box::new(CameraPreview::new(v4l2::preview::open_preview(
            &config.camera,
        )?)?),
    })
}

type Opener = Arc<dyn Fn() -> Result<Box<dyn FrameSource>, ServiceError> + Send + Sync>;

/// What the preview thread and the capture worker agree on, under one lock.
#[derive(Default)]
struct Camera {
    /// A capture holds the camera.
    held: bool,
    /// The preview thread has its source open.
    open: bool,
    /// Which preview thread may run: a stop moves it on, and the running thread ends.
    generation: u64,
}

#[derive(Default)]
struct Gate {
    camera: Mutex<Camera>,
    changed: Condvar,
}

impl Gate {
    fn lock(&self) -> MutexGuard<'_, Camera> {
        lock(&self.camera)
    }

    fn wait<'a>(&self, c: MutexGuard<'a, Camera>) -> MutexGuard<'a, Camera> {
        self.changed.wait(c).unwrap_or_else(|e| e.into_inner())
    }
}

#[derive(Default)]
struct Clients {
    /// Unique bus names of the clients.
    names: HashSet<String>,
    ring: Option<Arc<RingWriter>>,
    deadline: Option<Instant>,
}

pub struct Preview {
    open: Opener,
    gate: Arc<Gate>,
    clients: Mutex<Clients>,
}

/// Why a preview cannot start, in words for the caller.
#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    #[error("cannot create the preview's shared memory: {0}")]
    Memory(#[source] std::io::Error),
    #[error("cannot start the preview's thread: {0}")]
    Thread(#[source] std::io::Error),
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // Each field is set in one step: a panicked holder leaves nothing half-done.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The camera held by a capture; the preview comes back when it is dropped.
pub struct CameraHold(Arc<Gate>);

impl Drop for CameraHold {
    fn drop(&mut self) {
        self.0.lock().held = false;
        self.0.changed.notify_all();
    }
}

impl Preview {
    pub fn new(
        open: impl Fn() -> Result<Box<dyn FrameSource>, ServiceError> + Send + Sync + 'static,
    ) -> Preview {
        Preview {
            open: Arc::new(open),
            gate: Arc::default(),
            clients: Mutex::default(),
        }
    }

    /// For a capture: pauses the preview and waits until its thread has closed the camera
    /// (at most a frame's time).
    pub fn hold_camera(&self) -> CameraHold {
        let gate = &self.gate;
        let mut c = gate.lock();
        c.held = true;
        gate.changed.notify_all();
        while c.open {
            c = gate.wait(c);
        }
        CameraHold(gate.clone())
    }

    /// Adds `client` (a unique bus name) and renews the preview for `timeout`; the first client
    /// starts it. Returns a descriptor of the ring at once: the source opens on the preview's
    /// thread, and a failure to open shows in the ring's state.
    pub fn start(&self, client: &str, timeout: Duration) -> Result<OwnedFd, PreviewError> {
        let mut clients = lock(&self.clients);
        clients.deadline = Some(Instant::now() + timeout);
        // A ring whose thread failed is replaced: the new one tries the camera again.
        let live = clients
            .ring
            .take()
            .filter(|r| r.state() != Some(State::Failed));
        let ring = match live {
            Some(ring) => ring,
            None => {
                let ring = Arc::new(RingWriter::create().map_err(PreviewError::Memory)?);
                self.spawn(ring.clone())?;
                ring
            }
        };
        clients.ring = Some(ring.clone());
        clients.names.insert(client.to_string());
        drop(clients);
        let fd = ring.share().map_err(PreviewError::Memory)?;
        tracing::info!(client, "preview: client added");
        Ok(fd)
    }

    /// Removes `client`; the last one stops the preview. Returns whether it was a client.
    pub fn leave(&self, client: &str, why: &str) -> bool {
        let mut clients = lock(&self.clients);
        let was = clients.names.remove(client);
        let last = was && clients.names.is_empty();
        drop(clients);
        if was {
            tracing::info!(client, "preview: client {why}");
        }
        if last {
            self.stop(&format!("its last client {why}"));
        }
        was
    }

    /// Stops the preview if no client renewed it in time.
    pub fn expire(&self) {
        let late = lock(&self.clients)
            .deadline
            .is_some_and(|d| Instant::now() >= d);
        if late {
            self.stop("no client renewed it within [service] preview_timeout_s");
        }
    }

    /// Ends the preview thread, which closes the source and, with the last reference, the
    /// ring; clients see the ring stopped.
    fn stop(&self, why: &str) {
        let mut clients = lock(&self.clients);
        if clients.ring.take().is_none() {
            return;
        }
        clients.names.clear();
        clients.deadline = None;
        drop(clients);
        self.gate.lock().generation += 1;
        self.gate.changed.notify_all();
        tracing::info!("preview stopped: {why}");
    }

    /// Starts a preview thread writing into `ring`.
    fn spawn(&self, ring: Arc<RingWriter>) -> Result<(), PreviewError> {
        let runner = Runner {
            open: self.open.clone(),
            gate: self.gate.clone(),
            generation: self.gate.lock().generation,
            ring,
        };
        std::thread::Builder::new()
            .name("focusd-preview".into())
            .spawn(move || runner.run())
            .map(drop)
            .map_err(PreviewError::Thread)
    }
}

/// One preview thread: frames at [`FPS`] into the ring until its generation is over.
struct Runner {
    open: Opener,
    gate: Arc<Gate>,
    generation: u64,
    ring: Arc<RingWriter>,
}

impl Runner {
    fn run(self) {
        let period = Duration::from_secs(1) / FPS;
        let mut source: Option<Box<dyn FrameSource>> = None;
        let mut next = Instant::now();
        let gate = self.gate.clone();
        let end = loop {
            let mut c = gate.lock();
            if c.generation != self.generation {
                break Ok(());
            }
            if c.held {
                if source.take().is_some() {
                    c.open = false;
                    gate.changed.notify_all();
                }
                self.ring.set_state(State::Paused);
                drop(gate.wait(c));
                continue;
            }
            if source.is_none() {
                // Opened outside the lock, so a stop or a new client never waits for the
                // camera; a capture that wants it waits, as `open` says it is taken.
                c.open = true;
                drop(c);
                match (self.open)() {
                    Ok(s) => source = Some(s),
                    Err(e) => break self.fail(crate::base::clip::chain(&e)),
                }
                // A stop or a capture may have come meanwhile.
                continue;
            }
            drop(c);
            let Some(s) = source.as_mut() else { continue };
            match s.next_frame() {
                Ok(frame) => self.ring.publish(frame),
                Err(e) => break self.fail(crate::base::clip::chain(&e)),
            }
            self.ring.set_state(State::Running);
            // The next frame at the next tick, or sooner for a stop or a capture.
            next = (next + period).max(Instant::now());
            let mut c = gate.lock();
            while c.generation == self.generation && !c.held {
                let now = Instant::now();
                if now >= next {
                    break;
                }
                c = self
                    .gate
                    .changed
                    .wait_timeout(c, next - now)
                    .unwrap_or_else(|e| e.into_inner())
                    .0;
            }
        };
        drop(source);
        gate.lock().open = false;
        gate.changed.notify_all();
        match end {
            Err(error) => self.ring.fail(&error),
            Ok(()) => self.ring.set_state(State::Stopped),
        }
    }

    fn fail(&self, error: String) -> Result<(), String> {
        tracing::error!("preview failed: {error}");
        Err(error)
    }
}

/// Stops the preview when a client leaves the bus, and when it times out.
pub async fn watch(preview: Arc<Preview>, conn: zbus::Connection) {
    let left = async {
        zbus::fdo::DBusProxy::new(&conn)
            .await?
            .receive_name_owner_changed()
            .await
    };
    let mut left = match left.await {
        Ok(s) => s,
        Err(e) => {
            tracing::error!("preview: cannot watch clients leave: {e}");
            return;
        }
    };
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    loop {
        tokio::select! {
            Some(s) = left.next() => {
                if let Ok(a) = s.args() {
                    if a.new_owner().is_none() {
                        preview.leave(a.name(), "left the bus");
                    }
                }
            }
            _ = tick.tick() => preview.expire(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::CaptureError;
    use crate::stack::image::Image;
    use ring::RingReader;
    use std::sync::mpsc;

    struct Still(Image<u8>);

    impl FrameSource for Still {
        fn next_frame(&mut self) -> Result<&Image<u8>, CaptureError> {
            Ok(&self.0)
        }
    }

    fn until(what: &str, f: impl Fn() -> bool) {
        let t = Instant::now();
        while !f() {
            assert!(t.elapsed() < Duration::from_secs(20), "never: {what}");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn start_and_stop_do_not_wait_for_a_camera_that_is_opening() {
        // The camera opens when the test says so.
        let (go, opens) = mpsc::channel::<Result<(), String>>();
        let opens = Mutex::new(opens);
        let preview = Preview::new(move || {
            let r = lock(&opens).recv().expect("the test ended");
            r.map_err(|e| CaptureError::device("camera", e))?;
            Ok(Box::new(Still(Image::new(4, 2, 3))) as Box<dyn FrameSource>)
        });
        let minute = Duration::from_secs(60);
        // Returns while the camera is still opening: no frame, no failure yet.
        let ring = RingReader::new(preview.start(":1.1", minute).unwrap()).unwrap();
        assert_eq!((ring.sequence(), ring.state()), (0, Some(State::Running)));
        // A second client and a stop are answered meanwhile too.
        preview.start(":1.2", minute).unwrap();
        assert!(preview.leave(":1.2", "left"));
        go.send(Ok(())).unwrap();
        until("a frame", || ring.sequence() >= 1);
        // The last client stops it.
        assert!(preview.leave(":1.1", "left"));
        until("stopped", || ring.state() == Some(State::Stopped));

        // A camera that cannot open fails the ring, saying why; the next start tries again.
        let ring = RingReader::new(preview.start(":1.3", minute).unwrap()).unwrap();
        go.send(Err("camera busy: close the other app".into()))
            .unwrap();
        until("failed", || ring.state() == Some(State::Failed));
        let why = ring.error().unwrap();
        assert!(why.contains("camera busy: close the other app"), "{why}");
        let again = RingReader::new(preview.start(":1.3", minute).unwrap()).unwrap();
        assert_eq!(again.state(), Some(State::Running));
        go.send(Ok(())).unwrap();
        until("frames again", || again.sequence() >= 1);
        // A capture waits for the camera the preview holds, then has it.
        let hold = preview.hold_camera();
        until("paused", || again.state() == Some(State::Paused));
        drop(hold);
        go.send(Ok(())).unwrap();
        until("resumed", || again.state() == Some(State::Running));
        assert!(preview.leave(":1.3", "left"));
    }
}
