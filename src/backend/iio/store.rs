//! The samples the reader threads deliver, kept for a while so the sweep can ask for windows
//! that already passed (a frame's exposure, known only once the frame arrived).

use super::sysfs::describe;
use crate::capture::{CaptureError, ImuSample, Nanos, Sensor};
use std::collections::VecDeque;
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// How much history is kept, behind the newest sample.
const KEEP: Nanos = 60_000_000_000;
/// The longest `samples` waits for a `to` still in the future, on top of the timeout.
const MAX_AHEAD: Nanos = 60_000_000_000;

struct Stream {
    sensor: Sensor,
    /// In time order.
    samples: VecDeque<ImuSample>,
    /// Its source's label and why it stopped delivering, once it has.
    stopped: Option<(String, String)>,
}

impl Stream {
    fn latest(&self) -> Option<Nanos> {
        self.samples.back().map(|s| s.t)
    }
}

/// One stream per sensor, shared by the readers (writing) and `Imu::samples` (waiting).
pub struct Store {
    streams: Mutex<Vec<Stream>>,
    arrived: Condvar,
}

impl Default for Store {
    fn default() -> Self {
        Self::new()
    }
}

impl Store {
    pub fn new() -> Store {
        let stream = |sensor| Stream {
            sensor,
            samples: VecDeque::new(),
            stopped: None,
        };
        Store {
            streams: Mutex::new(vec![stream(Sensor::Gyro), stream(Sensor::Accel)]),
            arrived: Condvar::new(),
        }
    }

    /// A reader that panicked cannot leave the samples half-written, so a poisoned lock is
    /// still good.
    fn lock(&self) -> MutexGuard<'_, Vec<Stream>> {
        self.streams.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn push(&self, batch: &[ImuSample]) {
        let mut streams = self.lock();
        for s in batch {
            let Some(stream) = streams.iter_mut().find(|x| x.sensor == s.sensor) else {
                continue;
            };
            let q = &mut stream.samples;
            if q.back().is_none_or(|b| b.t <= s.t) {
                q.push_back(*s);
            } else {
                let at = q.partition_point(|x| x.t <= s.t);
                q.insert(at, *s);
            }
            let newest = q.back().map_or(s.t, |b| b.t);
            while q.front().is_some_and(|f| f.t < newest.saturating_sub(KEEP)) {
                q.pop_front();
            }
        }
        drop(streams);
        self.arrived.notify_all();
    }

    /// Marks `sensors` as no longer delivering, for the reason given.
    pub fn stop(&self, sensors: &[Sensor], source: &str, reason: String) {
        for s in self
            .lock()
            .iter_mut()
            .filter(|s| sensors.contains(&s.sensor))
        {
            s.stopped = Some((source.to_string(), reason.clone()));
        }
        self.arrived.notify_all();
    }

    /// Waits until both sensors delivered samples up to `to` (for `timeout`, plus however far
    /// `to` is ahead of `now`), then returns those in `[from, to]` in time order.
    pub fn wait(
        &self,
        from: Nanos,
        to: Nanos,
        now: Nanos,
        timeout: Duration,
    ) -> Result<Vec<ImuSample>, CaptureError> {
        let ahead = Duration::from_nanos(to.saturating_sub(now).clamp(0, MAX_AHEAD) as u64);
        let start = Instant::now();
        let mut streams = self.lock();
        loop {
            let behind = streams.iter().find(|s| s.latest().is_none_or(|t| t < to));
            let Some(s) = behind else { break };
            let last = s
                .latest()
                .map_or("none yet".to_string(), |t| format!("the last at {t} ns"));
            if let Some((source, why)) = &s.stopped {
                return Err(CaptureError::device(
                    source.clone(),
                    format!(
                        "{why}: the {} stopped delivering before {to} ns ({last})",
                        describe(s.sensor)
                    ),
                ));
            }
            let waited = start.elapsed();
            if waited >= timeout + ahead {
                return Err(CaptureError::Timeout {
                    what: format!(
                        "waiting for IIO {} samples up to {to} ns ({last})",
                        describe(s.sensor)
                    ),
                    ms: (timeout + ahead).as_millis() as u64,
                });
            }
            streams = self
                .arrived
                .wait_timeout(streams, timeout + ahead - waited)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
        let mut out: Vec<ImuSample> = streams
            .iter()
            .flat_map(|s| {
                let lo = s.samples.partition_point(|x| x.t < from);
                let hi = s.samples.partition_point(|x| x.t <= to);
                s.samples.range(lo..hi.max(lo)).copied()
            })
            .collect();
        out.sort_by_key(|s| s.t);
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    fn s(t: Nanos, sensor: Sensor) -> ImuSample {
        ImuSample {
            t,
            sensor,
            v: [t as f64, f64::NAN, 0.0],
        }
    }

    #[test]
    fn returns_the_window_of_both_sensors_in_time_order() {
        let store = Store::new();
        store.push(&[
            s(10, Sensor::Gyro),
            s(30, Sensor::Gyro),
            s(20, Sensor::Gyro),
        ]);
        store.push(&[s(15, Sensor::Accel), s(35, Sensor::Accel)]);
        let got = store.wait(12, 30, 0, Duration::from_millis(10)).unwrap();
        let ts: Vec<Nanos> = got.iter().map(|s| s.t).collect();
        assert_eq!(ts, [15, 20, 30]);
        assert!(store.wait(31, 30, 0, Duration::ZERO).unwrap().is_empty());
    }

    #[test]
    fn waits_for_late_samples_then_times_out() {
        let store = Arc::new(Store::new());
        store.push(&[s(10, Sensor::Gyro), s(10, Sensor::Accel)]);
        let writer = store.clone();
        let t = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(30));
            writer.push(&[s(50, Sensor::Gyro), s(50, Sensor::Accel)]);
        });
        let got = store.wait(0, 50, 0, Duration::from_secs(5)).unwrap();
        assert_eq!(got.len(), 4);
        t.join().unwrap();
        let e = store.wait(0, 60, 0, Duration::from_millis(20)).unwrap_err();
        assert!(matches!(e, CaptureError::Timeout { ms: 20, .. }), "{e}");
        assert!(e
            .to_string()
            .contains("gyroscope samples up to 60 ns (the last at 50 ns)"));
    }

    #[test]
    fn a_stopped_sensor_fails_at_once_naming_its_source() {
        let store = Store::new();
        store.push(&[s(10, Sensor::Gyro), s(100, Sensor::Accel)]);
        store.stop(&[Sensor::Gyro], "/dev/iio:device1", "end of data".into());
        // Samples up to where it stopped are still served.
        assert_eq!(store.wait(0, 10, 0, Duration::ZERO).unwrap().len(), 1);
        let e = store.wait(0, 20, 0, Duration::from_secs(60)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "/dev/iio:device1: end of data: the gyroscope stopped delivering before 20 ns (the last \
             at 10 ns)"
        );
    }

    #[test]
    fn forgets_old_samples() {
        let store = Store::new();
        store.push(&[s(0, Sensor::Gyro), s(KEEP + 1, Sensor::Gyro)]);
        store.push(&[s(KEEP + 1, Sensor::Accel)]);
        let got = store.wait(0, KEEP + 1, 0, Duration::ZERO).unwrap();
        assert_eq!(got.len(), 2);
    }
}
