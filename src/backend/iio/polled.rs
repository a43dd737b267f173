//! Polling the `*_raw` files: for devices without a buffer (no interrupt wired, as on the
//! Librem 5) or with one that will not start. Each reading is stamped when it was read.

use super::store::Store;
use super::sysfs::{read_raw, Channels, Device};
use crate::backend::sys::monotonic_now;
use crate::capture::{CaptureError, ImuSample};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Reads every axis of `channels` once.
pub fn read_once(dev: &Device, channels: &[Channels]) -> Result<Vec<ImuSample>, CaptureError> {
    channels
        .iter()
        .map(|c| {
            let mut raw = [0i64; 3];
            for (r, axis) in raw.iter_mut().zip(&c.axes) {
                *r = read_raw(&dev.path(&format!("{}_raw", axis.channel)))?;
            }
            Ok(ImuSample {
                t: monotonic_now(),
                sensor: c.sensor,
                v: c.to_si(raw),
            })
        })
        .collect()
}

/// Polls at `hz` until `stop` is set or a read fails (then the store says why).
pub fn start(
    dev: Device,
    channels: Vec<Channels>,
    hz: f64,
    store: Arc<Store>,
    stop: Arc<AtomicBool>,
) -> JoinHandle<()> {
    let period = Duration::from_secs_f64(1.0 / hz.clamp(1.0, 8000.0));
    std::thread::spawn(move || {
        let mut next = Instant::now();
        while !stop.load(Ordering::SeqCst) {
            match read_once(&dev, &channels) {
                Ok(batch) => store.push(&batch),
                Err(e) => {
                    let sensors: Vec<_> = channels.iter().map(|c| c.sensor).collect();
                    store.stop(&sensors, &dev.label(), e.to_string());
                    return;
                }
            }
            next += period;
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            } else {
                next = now;
            }
        }
    })
}
