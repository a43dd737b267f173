//! Finding the gyroscope and the accelerometer under `<root>/bus/iio/devices`, reading and
//! writing their attributes, and turning raw readings into SI units in the device frame
//! (offset, scale, mount matrix), for the file layout the kernel's IIO core creates.

use crate::capture::{CaptureError, Sensor};
use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// One `iio:deviceN` directory.
#[derive(Clone, Debug, PartialEq)]
pub struct Device {
    pub dir: PathBuf,
    /// The contents of its `name` file (`mpu6500`, `lsm9ds1-imu_gyro`, ...).
    pub name: String,
}

impl Device {
    /// The device as errors name it: its directory and driver name.
    pub fn label(&self) -> String {
        format!("{} ({})", self.dir.display(), self.name)
    }

    pub fn path(&self, rel: &str) -> PathBuf {
        self.dir.join(rel)
    }

    pub fn has(&self, rel: &str) -> bool {
        self.path(rel).exists()
    }

    /// Its character device: `/dev/iio:deviceN` for the root `/sys`, and in general
    /// `<root>/../dev/iio:deviceN`, so a test tree `T/sys` has its buffers in `T/dev`.
    pub fn char_dev(&self, root: &Path) -> PathBuf {
        let parent = root.parent().unwrap_or(Path::new("/"));
        let node = self.dir.file_name().unwrap_or_default();
        parent.join("dev").join(node)
    }

    /// Whether it has all three axes of `sensor`, read by polling or through the buffer.
    pub fn has_sensor(&self, sensor: Sensor) -> bool {
        ["x", "y", "z"].iter().all(|a| {
            let ch = format!("in_{}_{a}", kind(sensor));
            self.has(&format!("{ch}_raw")) || self.has(&format!("scan_elements/{ch}_en"))
        })
    }
}

/// The IIO channel type of a sensor: `in_<kind>_x_raw`.
pub fn kind(sensor: Sensor) -> &'static str {
    match sensor {
        Sensor::Gyro => "anglvel",
        Sensor::Accel => "accel",
    }
}

/// What errors call a sensor.
pub fn describe(sensor: Sensor) -> &'static str {
    match sensor {
        Sensor::Gyro => "gyroscope",
        Sensor::Accel => "accelerometer",
    }
}

/// Why an I/O call on `path` failed, with the fix for the failures focusd can meet.
pub fn io_reason(e: &io::Error) -> String {
    match e.kind() {
        io::ErrorKind::ResourceBusy => format!(
            "{e}: the device's buffer is running (another program, e.g. iio-sensor-proxy, or \
             focusd's buffered mode is capturing from it), and the kernel refuses raw reads and \
             settings meanwhile"
        ),
        io::ErrorKind::PermissionDenied => format!(
            "{e}: focusd needs to read and write the IIO sysfs attributes and /dev/iio:device* \
             (run it as root or grant access with a udev rule)"
        ),
        _ => e.to_string(),
    }
}

fn file_error(path: &Path, reason: impl Into<String>) -> CaptureError {
    CaptureError::device(path.display().to_string(), reason)
}

/// An attribute's contents without the trailing newline.
pub fn read_attr(path: &Path) -> Result<String, CaptureError> {
    fs::read_to_string(path)
        .map(|s| s.trim().to_string())
        .map_err(|e| file_error(path, format!("cannot read: {}", io_reason(&e))))
}

pub fn write_attr(path: &Path, value: &str) -> Result<(), CaptureError> {
    fs::write(path, value)
        .map_err(|e| file_error(path, format!("cannot write {value:?}: {}", io_reason(&e))))
}

/// Attributes changed so far with their old values, to put back in reverse order.
pub type Undo = Vec<(PathBuf, String)>;

/// Sets `path` to `value`, remembering the old value in `undo` when it differs.
pub fn set_attr(path: &Path, value: &str, undo: &mut Undo) -> Result<(), CaptureError> {
    let old = read_attr(path)?;
    if old != value {
        write_attr(path, value)?;
        undo.push((path.to_path_buf(), old));
    }
    Ok(())
}

/// A finite number attribute (scales, offsets, frequencies).
pub fn read_f64(path: &Path) -> Result<f64, CaptureError> {
    let s = read_attr(path)?;
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(file_error(path, format!("{s:?} is not a finite number"))),
    }
}

/// A `*_raw` reading: an integer.
pub fn read_raw(path: &Path) -> Result<i64, CaptureError> {
    let s = read_attr(path)?;
    s.parse()
        .map_err(|_| file_error(path, format!("raw reading {s:?} is not an integer")))
}

/// `<root>/bus/iio/devices`.
pub fn devices_dir(root: &Path) -> PathBuf {
    root.join("bus/iio/devices")
}

/// The `iio:deviceN` directories, by N. Triggers and other entries are skipped.
pub fn list_devices(root: &Path) -> Result<Vec<Device>, CaptureError> {
    let dir = devices_dir(root);
    let entries = fs::read_dir(&dir).map_err(|e| {
        file_error(
            &dir,
            format!(
                "cannot list IIO devices: {} (is the IMU driver loaded?)",
                io_reason(&e)
            ),
        )
    })?;
    let mut found = Vec::new();
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(n) = file_name
            .to_str()
            .and_then(|s| s.strip_prefix("iio:device"))
            .and_then(|n| n.parse::<u32>().ok())
        else {
            continue;
        };
        let dir = entry.path();
        let name = read_attr(&dir.join("name"))?;
        found.push((n, Device { dir, name }));
    }
    found.sort_by_key(|(n, _)| *n);
    Ok(found.into_iter().map(|(_, d)| d).collect())
}

/// The devices to read and which sensors each serves: one device with both, or two.
pub fn find(
    root: &Path,
    gyro_name: Option<&str>,
    accel_name: Option<&str>,
) -> Result<Vec<(Device, Vec<Sensor>)>, CaptureError> {
    let devices = list_devices(root)?;
    let dir = devices_dir(root);
    let found = || {
        if devices.is_empty() {
            "none".to_string()
        } else {
            devices
                .iter()
                .map(|d| {
                    let n = d.dir.file_name().unwrap_or_default().to_string_lossy();
                    format!("{n} ({})", d.name)
                })
                .collect::<Vec<_>>()
                .join(", ")
        }
    };
    let named = |sensor: Sensor, name: &str| -> Result<usize, CaptureError> {
        let i = devices.iter().position(|d| d.name == name).ok_or_else(|| {
            file_error(
                &dir,
                format!("no IIO device is named {name:?}; found: {}", found()),
            )
        })?;
        if !devices[i].has_sensor(sensor) {
            return Err(CaptureError::device(
                devices[i].label(),
                format!(
                    "has no {} channels (in_{}_x_raw or scan_elements/in_{}_x_en)",
                    describe(sensor),
                    kind(sensor),
                    kind(sensor)
                ),
            ));
        }
        Ok(i)
    };
    let gyro = gyro_name.map(|n| named(Sensor::Gyro, n)).transpose()?;
    let accel = accel_name.map(|n| named(Sensor::Accel, n)).transpose()?;
    // Unnamed: the other sensor's device if it has this one too, else one with both, else any.
    let by_channels = |sensor: Sensor, other: Option<usize>| -> Result<usize, CaptureError> {
        let has = |i: &usize| devices[*i].has_sensor(sensor);
        other
            .filter(has)
            .or_else(|| {
                (0..devices.len()).find(|&i| {
                    devices[i].has_sensor(Sensor::Gyro) && devices[i].has_sensor(Sensor::Accel)
                })
            })
            .or_else(|| (0..devices.len()).find(has))
            .ok_or_else(|| {
                file_error(
                    &dir,
                    format!(
                        "no IIO device has a {} (in_{}_{{x,y,z}}_raw); found: {}",
                        describe(sensor),
                        kind(sensor),
                        found()
                    ),
                )
            })
    };
    let gyro = match gyro {
        Some(g) => g,
        None => by_channels(Sensor::Gyro, accel)?,
    };
    let accel = match accel {
        Some(a) => a,
        None => by_channels(Sensor::Accel, Some(gyro))?,
    };
    Ok(if gyro == accel {
        vec![(devices[gyro].clone(), vec![Sensor::Gyro, Sensor::Accel])]
    } else {
        vec![
            (devices[gyro].clone(), vec![Sensor::Gyro]),
            (devices[accel].clone(), vec![Sensor::Accel]),
        ]
    })
}

/// A 3×3 matrix, rows first.
pub type Matrix = [[f64; 3]; 3];

pub const IDENTITY: Matrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// Parses a mount matrix, `"x, y, z; x, y, z; x, y, z"` by rows.
pub fn parse_mount_matrix(s: &str) -> Result<Matrix, String> {
    let bad =
        || format!("bad mount matrix {s:?}: expected 3 rows like \"1, 0, 0; 0, 1, 0; 0, 0, 1\"");
    let rows: Vec<&str> = s.split(';').collect();
    if rows.len() != 3 {
        return Err(bad());
    }
    let mut m = [[0.0; 3]; 3];
    for (row, text) in m.iter_mut().zip(rows) {
        let cells: Vec<&str> = text.split(',').collect();
        if cells.len() != 3 {
            return Err(bad());
        }
        for (cell, text) in row.iter_mut().zip(cells) {
            *cell = text
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(bad)?;
        }
    }
    Ok(m)
}

/// The device-frame vector: `m · v`, the convention of the kernel's ABI and iio-sensor-proxy.
pub fn apply(m: &Matrix, v: [f64; 3]) -> [f64; 3] {
    m.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
}

/// One axis: its channel prefix and its calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// `in_accel_x`: the prefix of `_raw` and of the scan element files.
    pub channel: String,
    pub scale: f64,
    pub offset: f64,
}

/// The three axes of one sensor on one device, and how to bring them to SI units in the
/// device frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Channels {
    pub sensor: Sensor,
    pub axes: [Axis; 3],
    pub mount: Matrix,
}

impl Channels {
    /// Reads scale (per axis or shared), offset (optional) and mount matrix (optional: the
    /// identity) of `sensor` on `dev`.
    pub fn load(dev: &Device, sensor: Sensor) -> Result<Channels, CaptureError> {
        let k = kind(sensor);
        let first = |names: &[String]| names.iter().map(|n| dev.path(n)).find(|p| p.exists());
        let axis = |a: &str| -> Result<Axis, CaptureError> {
            let channel = format!("in_{k}_{a}");
            let scale = first(&[format!("{channel}_scale"), format!("in_{k}_scale")])
                .ok_or_else(|| CaptureError::device(dev.label(), format!("has no in_{k}_scale")))?;
            let offset = first(&[format!("{channel}_offset"), format!("in_{k}_offset")]);
            Ok(Axis {
                scale: read_f64(&scale)?,
                offset: offset.map_or(Ok(0.0), |p| read_f64(&p))?,
                channel,
            })
        };
        let mount = match first(&[format!("in_{k}_mount_matrix"), "mount_matrix".into()]) {
            Some(p) => parse_mount_matrix(&read_attr(&p)?).map_err(|e| file_error(&p, e))?,
            None => IDENTITY,
        };
        Ok(Channels {
            sensor,
            axes: [axis("x")?, axis("y")?, axis("z")?],
            mount,
        })
    }

    /// `(raw + offset) × scale` per axis, then the mount matrix.
    pub fn to_si(&self, raw: [i64; 3]) -> [f64; 3] {
        let v = [0, 1, 2].map(|i| (raw[i] as f64 + self.axes[i].offset) * self.axes[i].scale);
        apply(&self.mount, v)
    }
}

/// Sets the sampling frequency when `hz` is given and returns the device's rate afterwards,
/// if it has a readable one (`sampling_frequency`, or `in_<kind>_sampling_frequency`).
pub fn sampling_frequency(
    dev: &Device,
    sensors: &[Sensor],
    hz: Option<f64>,
) -> Result<Option<f64>, CaptureError> {
    let mut files = vec![dev.path("sampling_frequency")];
    if !files[0].exists() {
        files = sensors
            .iter()
            .map(|&s| dev.path(&format!("in_{}_sampling_frequency", kind(s))))
            .filter(|p| p.exists())
            .collect();
    }
    let mut rate: Option<f64> = None;
    for file in files {
        if let Some(hz) = hz {
            if let Err(e) = fs::write(&file, format!("{hz}")) {
                let available = file.with_file_name(format!(
                    "{}_available",
                    file.file_name().unwrap_or_default().to_string_lossy()
                ));
                let accepted = read_attr(&available)
                    .map(|a| format!("; it accepts {a}"))
                    .unwrap_or_default();
                return Err(file_error(
                    &file,
                    format!("cannot set {hz} Hz: {}{accepted}", io_reason(&e)),
                ));
            }
        }
        let r = read_f64(&file)?;
        rate = Some(rate.map_or(r, |q| q.max(r)));
    }
    Ok(rate)
}
