//! Whether the daemon's job still makes progress. systemd restarts a service that stops sending
//! `WATCHDOG=1`; focusd sends it only while its worker is idle or its job beats, so a job blocked
//! in a read (a camera driver that never returns a buffer, a FIFO, a hung network file system)
//! is seen. A thread blocked in a read cannot be killed and may still hold the camera, so the
//! daemon then reports the job as failed and exits for systemd to restart it clean.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// When the job last showed it was alive: every call of its progress and cancel hooks (the sweep
/// and the engine make them between and within stages).
#[derive(Debug)]
pub struct Heartbeat {
    epoch: Instant,
    /// Milliseconds from `epoch` to the last beat.
    last_ms: AtomicU64,
}

impl Default for Heartbeat {
    fn default() -> Self {
        Self {
            epoch: Instant::now(),
            last_ms: AtomicU64::new(0),
        }
    }
}

impl Heartbeat {
    pub fn beat(&self) {
        let now = u64::try_from(self.epoch.elapsed().as_millis()).unwrap_or(u64::MAX);
        self.last_ms.store(now, Ordering::Relaxed);
    }

    /// How long since the last beat.
    pub fn silence(&self) -> Duration {
        let last = Duration::from_millis(self.last_ms.load(Ordering::Relaxed));
        self.epoch.elapsed().saturating_sub(last)
    }
}

/// A running job that counts as stuck.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stall {
    /// Since its last beat.
    pub silence: Duration,
    /// Cancel or SIGTERM asked it to stop.
    pub cancelled: bool,
}

/// The verdict on a running job: `silence` since its last beat, `since_cancel` since it was
/// cancelled (if it was), against the stall timeout. A job is stuck when it has not beaten for
/// the timeout, or has not ended that long after a cancel: its beats do not count then, since a
/// job that still beats sees its cancel flag at its next check.
pub fn stall(
    silence: Duration,
    since_cancel: Option<Duration>,
    timeout: Duration,
) -> Option<Stall> {
    let stuck = silence >= timeout || since_cancel.is_some_and(|c| c >= timeout);
    stuck.then_some(Stall {
        silence,
        cancelled: since_cancel.is_some(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_is_stuck_after_the_timeout_without_a_beat_or_after_a_cancel() {
        let s = Duration::from_secs;
        let stuck = |silence, cancelled| Some(Stall { silence, cancelled });
        assert_eq!(stall(s(1), None, s(20)), None);
        assert_eq!(stall(s(20), None, s(20)), stuck(s(20), false));
        // Beating, but cancelled too long ago.
        assert_eq!(stall(s(0), Some(s(19)), s(20)), None);
        assert_eq!(stall(s(0), Some(s(21)), s(20)), stuck(s(0), true));
        assert_eq!(stall(s(25), Some(s(3)), s(20)), stuck(s(25), true));
    }

    #[test]
    fn a_beat_resets_the_silence() {
        let h = Heartbeat::default();
        std::thread::sleep(Duration::from_millis(30));
        assert!(h.silence() >= Duration::from_millis(30));
        h.beat();
        assert!(h.silence() < Duration::from_millis(30));
    }
}
