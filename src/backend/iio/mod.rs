//! The IIO gyroscope and accelerometer (Linux industrial I/O, through sysfs and /dev/iio:deviceN).
//!
//! One reader thread per device feeds a [`store::Store`]; `Imu::samples` waits on it. A device
//! is read through its buffer when it has one (timestamps from the kernel, no missed samples),
//! else by polling its `*_raw` files (the Librem 5's IMU has no interrupt, so no buffer).

pub mod buffered;
pub mod polled;
pub mod scan;
pub mod store;
pub mod sysfs;

use crate::base::setting::{Bounds, Invalid};
use crate::capture::{CaptureError, Imu, ImuSample, Nanos, Sensor};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;
use store::Store;
use sysfs::{Channels, Device, Undo};

/// How a device is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// The buffer when the device has one and it starts, else polling.
    Auto,
    Buffered,
    Poll,
}

/// The `[imu]` table of the config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IioConfig {
    /// The sysfs mount: devices are under `<root>/bus/iio/devices`, and their character devices
    /// in `<root>/../dev` (so a test tree `T/sys` keeps them in `T/dev`).
    pub sysfs_root: PathBuf,
    /// IIO device names (the `name` file) of the gyroscope and the accelerometer; unset: found
    /// by their channels, preferring one device with both.
    pub gyro_device: Option<String>,
    pub accel_device: Option<String>,
    pub mode: Mode,
    /// Rate to set, Hz; unset: the device's current rate.
    pub sampling_hz: Option<f64>,
    /// Switch the gyroscope to its finest scale (smallest full-scale range) while capturing:
    /// at ±2000 °/s one LSB (1 mrad/s) is too coarse for the motion gate.
    pub finest_gyro_scale: bool,
    /// How long `samples` waits for a window's samples beyond its end before failing.
    pub timeout_ms: u64,
}

impl Default for IioConfig {
    fn default() -> Self {
        Self {
            sysfs_root: PathBuf::from("/sys"),
            gyro_device: None,
            accel_device: None,
            mode: Mode::Auto,
            sampling_hz: None,
            finest_gyro_scale: true,
            timeout_ms: 1000,
        }
    }
}

impl IioConfig {
    pub fn validate(&self) -> Result<(), Invalid> {
        if let Some(hz) = self.sampling_hz {
            Bounds::new(1.0, 8000.0).check("sampling_hz", hz)?;
        }
        Bounds::new(10, 60_000).check("timeout_ms", self.timeout_ms)
    }
}

/// Rate polled when a device reports none, Hz.
const DEFAULT_POLL_HZ: f64 = 100.0;

/// A running reader and how to undo what it changed.
struct Reader {
    thread: Option<JoinHandle<()>>,
    restore: Undo,
}

/// The gyroscope and accelerometer of a phone, read in the background from the moment it is
/// opened until it is dropped.
pub struct IioImu {
    store: Arc<Store>,
    stop: Arc<AtomicBool>,
    readers: Vec<Reader>,
    timeout: Duration,
    /// One line per device: which it is and how it is read (for the log).
    pub description: Vec<String>,
}

impl IioImu {
    pub fn open(cfg: &IioConfig) -> Result<IioImu, CaptureError> {
        cfg.validate()
            .map_err(|e| CaptureError::device("[imu] config", e.to_string()))?;
        let devices = sysfs::find(
            &cfg.sysfs_root,
            cfg.gyro_device.as_deref(),
            cfg.accel_device.as_deref(),
        )?;
        let mut imu = IioImu {
            store: Arc::new(Store::new()),
            stop: Arc::new(AtomicBool::new(false)),
            readers: Vec::new(),
            timeout: Duration::from_millis(cfg.timeout_ms),
            description: Vec::new(),
        };
        for (dev, sensors) in devices {
            // On an error `imu` drops, which stops and restores the readers started so far.
            imu.start(cfg, dev, sensors)?;
        }
        Ok(imu)
    }

    /// Starts reading `sensors` from `dev`; on an error, whatever it changed is put back.
    fn start(
        &mut self,
        cfg: &IioConfig,
        dev: Device,
        sensors: Vec<Sensor>,
    ) -> Result<(), CaptureError> {
        let mut restore = Vec::new();
        match self.start_reader(cfg, dev, &sensors, &mut restore) {
            Ok(thread) => {
                self.readers.push(Reader {
                    thread: Some(thread),
                    restore,
                });
                Ok(())
            }
            Err(e) => {
                put_back(&restore);
                Err(e)
            }
        }
    }

    fn start_reader(
        &mut self,
        cfg: &IioConfig,
        dev: Device,
        sensors: &[Sensor],
        restore: &mut Undo,
    ) -> Result<JoinHandle<()>, CaptureError> {
        if cfg.finest_gyro_scale && sensors.contains(&Sensor::Gyro) {
            finest_scale(&dev, Sensor::Gyro, restore)?;
        }
        let rate = sysfs::sampling_frequency(&dev, sensors, cfg.sampling_hz)?;
        let channels = sensors
            .iter()
            .map(|&s| Channels::load(&dev, s))
            .collect::<Result<Vec<_>, _>>()?;
        let names: Vec<&str> = sensors.iter().map(|&s| sysfs::describe(s)).collect();
        let what = format!("{} for the {}", dev.label(), names.join(" and "));
        let buffered = || {
            buffered::start(
                &cfg.sysfs_root,
                &dev,
                channels.clone(),
                self.store.clone(),
                self.stop.clone(),
            )
        };
        let has_buffer = dev.has("buffer/enable") && dev.has("scan_elements");
        let started = match cfg.mode {
            Mode::Poll => None,
            Mode::Buffered => Some(buffered()?),
            Mode::Auto if has_buffer => match buffered() {
                Ok(started) => Some(started),
                Err(e) => {
                    self.description.push(format!(
                        "{what}: polling sysfs at {} Hz (buffer refused: {e})",
                        rate.unwrap_or(DEFAULT_POLL_HZ)
                    ));
                    return Ok(self.poll(dev, channels, rate));
                }
            },
            Mode::Auto => None,
        };
        match started {
            Some((thread, undo)) => {
                restore.extend(undo);
                self.description.push(format!("{what}: buffered"));
                Ok(thread)
            }
            None => {
                self.description.push(format!(
                    "{what}: polling sysfs at {} Hz",
                    rate.unwrap_or(DEFAULT_POLL_HZ)
                ));
                Ok(self.poll(dev, channels, rate))
            }
        }
    }

    fn poll(&self, dev: Device, channels: Vec<Channels>, rate: Option<f64>) -> JoinHandle<()> {
        let hz = rate.unwrap_or(DEFAULT_POLL_HZ);
        polled::start(dev, channels, hz, self.store.clone(), self.stop.clone())
    }
}

/// Writes attributes back, last changed first.
pub(crate) fn put_back(restore: &[(PathBuf, String)]) {
    for (path, value) in restore.iter().rev() {
        let _ = std::fs::write(path, value);
    }
}

/// Writes the smallest value of `in_<kind>_scale_available` to `in_<kind>_scale`, remembering
/// the old value in `undo`.
fn finest_scale(dev: &Device, sensor: Sensor, undo: &mut Undo) -> Result<(), CaptureError> {
    let k = sysfs::kind(sensor);
    let (file, available) = (
        dev.path(&format!("in_{k}_scale")),
        dev.path(&format!("in_{k}_scale_available")),
    );
    if !file.exists() || !available.exists() {
        return Ok(());
    }
    let list = sysfs::read_attr(&available)?;
    let finest = list
        .split_whitespace()
        .filter_map(|v| {
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x > 0.0)
                .map(|x| (x, v))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0));
    match finest {
        Some((_, text)) => sysfs::set_attr(&file, text, undo),
        None => Ok(()),
    }
}

impl Imu for IioImu {
    fn samples(&mut self, from: Nanos, to: Nanos) -> Result<Vec<ImuSample>, CaptureError> {
        self.store
            .wait(from, to, crate::backend::sys::monotonic_now(), self.timeout)
    }
}

impl Drop for IioImu {
    /// Stops the readers, then puts back every attribute they changed, in reverse order.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        for r in &mut self.readers {
            if let Some(t) = r.thread.take() {
                let _ = t.join();
            }
        }
        for r in self.readers.iter().rev() {
            put_back(&r.restore);
        }
    }
}
