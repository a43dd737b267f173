//! Buffered capture through `/dev/iio:deviceN`: the kernel stamps every sample, so windows in
//! the past (a frame's exposure, known once the frame arrived) are exact and complete.

use super::scan::{decode_record, parse_scan_type, Layout};
use super::store::Store;
use super::sysfs::{io_reason, read_attr, set_attr, Channels, Device, Undo};
use crate::backend::sys::wait_readable;
use crate::capture::{CaptureError, ImuSample, Sensor};
use std::fs::File;
use std::io::{ErrorKind, Read};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// Kernel buffer length, in records: a second at 256 Hz, so a busy system loses nothing.
const BUFFER_LENGTH: &str = "256";
/// How often the reader checks whether it should stop, ms.
const WAKE_MS: i32 = 100;
const TIMESTAMP: &str = "in_timestamp";

/// Sets the device up for buffered capture of `channels` with monotonic timestamps, enables
/// the buffer and starts a reader thread. Returns the thread and what to put back once it has
/// stopped; on an error, everything changed so far is already put back.
pub fn start(
    root: &Path,
    dev: &Device,
    channels: Vec<Channels>,
    store: Arc<Store>,
    stop: Arc<AtomicBool>,
) -> Result<(JoinHandle<()>, Undo), CaptureError> {
    let mut undo = Vec::new();
    let started = prepare(root, dev, &channels, &mut undo).and_then(|(file, layout)| {
        let decoder =
            Decoder::new(&layout, &channels).map_err(|e| CaptureError::device(dev.label(), e))?;
        let source = dev.char_dev(root).display().to_string();
        std::thread::Builder::new()
            .name("iio-buffer".into())
            .spawn(move || read_loop(file, decoder, &source, &store, &stop))
            .map_err(|e| CaptureError::device(dev.label(), format!("cannot start a thread: {e}")))
    });
    match started {
        Ok(thread) => Ok((thread, undo)),
        Err(e) => {
            super::put_back(&undo);
            Err(e)
        }
    }
}

fn prepare(
    root: &Path,
    dev: &Device,
    channels: &[Channels],
    undo: &mut Undo,
) -> Result<(File, Layout), CaptureError> {
    let enable = dev.path("buffer/enable");
    if !enable.exists() {
        return Err(CaptureError::device(
            dev.label(),
            "has no buffer (its driver has no interrupt to trigger one); set [imu] mode = \"poll\"",
        ));
    }
    if read_attr(&enable)? == "1" {
        return Err(CaptureError::device(
            dev.label(),
            "its buffer is already running: another program (iio-sensor-proxy?) is capturing \
             from it; stop it, or set [imu] mode = \"poll\"",
        ));
    }
    let clock = dev.path("current_timestamp_clock");
    if !clock.exists() {
        return Err(CaptureError::device(
            dev.label(),
            "has no current_timestamp_clock, so its buffer timestamps are on CLOCK_REALTIME and \
             cannot be matched to the camera's CLOCK_MONOTONIC",
        ));
    }
    set_attr(&clock, "monotonic", undo)?;
    let wanted = channels
        .iter()
        .flat_map(|c| c.axes.iter().map(|a| a.channel.as_str()))
        .chain([TIMESTAMP]);
    for ch in wanted {
        let en = dev.path(&format!("scan_elements/{ch}_en"));
        if !en.exists() {
            return Err(CaptureError::device(
                dev.label(),
                format!("has no scan element {ch} (scan_elements/{ch}_en)"),
            ));
        }
        set_attr(&en, "1", undo)?;
    }
    let layout = enabled_layout(dev)?;
    set_attr(&dev.path("buffer/length"), BUFFER_LENGTH, undo)?;
    let node = dev.char_dev(root);
    let file = File::open(&node).map_err(|e| {
        CaptureError::device(
            node.display().to_string(),
            format!("cannot open: {}", io_reason(&e)),
        )
    })?;
    set_attr(&enable, "1", undo)?;
    Ok((file, layout))
}

/// The layout of every enabled scan element (ours and any another program left enabled: the
/// kernel puts them all in the record).
fn enabled_layout(dev: &Device) -> Result<Layout, CaptureError> {
    let dir = dev.path("scan_elements");
    let entries = std::fs::read_dir(&dir).map_err(|e| {
        CaptureError::device(
            dir.display().to_string(),
            format!("cannot list: {}", io_reason(&e)),
        )
    })?;
    let mut elements = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(ch) = name.strip_suffix("_en") else {
            continue;
        };
        if read_attr(&entry.path())? != "1" {
            continue;
        }
        let index_file = dir.join(format!("{ch}_index"));
        let index = read_attr(&index_file)?;
        let index: u32 = index.parse().map_err(|_| {
            CaptureError::device(
                index_file.display().to_string(),
                format!("scan index {index:?} is not a non-negative integer"),
            )
        })?;
        let type_file = dir.join(format!("{ch}_type"));
        let ty = parse_scan_type(&read_attr(&type_file)?)
            .map_err(|e| CaptureError::device(type_file.display().to_string(), e))?;
        elements.push((ch.to_string(), index, ty));
    }
    Layout::new(elements).map_err(|e| CaptureError::device(dir.display().to_string(), e))
}

/// Turns records into samples: where each sensor's axes and the timestamp are in a record.
pub struct Decoder {
    layout: Layout,
    timestamp: usize,
    sensors: Vec<(Channels, [usize; 3])>,
}

impl Decoder {
    pub fn new(layout: &Layout, channels: &[Channels]) -> Result<Decoder, String> {
        let find = |ch: &str| {
            layout
                .value_of(ch)
                .ok_or_else(|| format!("scan element {ch} is not enabled"))
        };
        let timestamp = find(TIMESTAMP)?;
        let sensors = channels
            .iter()
            .map(|c| {
                let at = [
                    find(&c.axes[0].channel)?,
                    find(&c.axes[1].channel)?,
                    find(&c.axes[2].channel)?,
                ];
                Ok((c.clone(), at))
            })
            .collect::<Result<_, String>>()?;
        Ok(Decoder {
            layout: layout.clone(),
            timestamp,
            sensors,
        })
    }

    pub fn record_bytes(&self) -> usize {
        self.layout.bytes()
    }

    /// The samples of whole records in `bytes` (a multiple of the record size).
    pub fn decode(&self, bytes: &[u8], out: &mut Vec<ImuSample>) -> Result<(), String> {
        for record in bytes.chunks_exact(self.layout.bytes()) {
            let v = decode_record(&self.layout, record)?;
            for (c, at) in &self.sensors {
                out.push(ImuSample {
                    t: v[self.timestamp],
                    sensor: c.sensor,
                    v: c.to_si(at.map(|i| v[i])),
                });
            }
        }
        Ok(())
    }

    fn sensors(&self) -> Vec<Sensor> {
        self.sensors.iter().map(|(c, _)| c.sensor).collect()
    }
}

fn read_loop(mut file: File, decoder: Decoder, source: &str, store: &Store, stop: &AtomicBool) {
    let rb = decoder.record_bytes();
    let mut buf = vec![0u8; rb * 64];
    let mut filled = 0;
    let mut batch = Vec::new();
    let fail = |why: String| store.stop(&decoder.sensors(), source, why);
    while !stop.load(Ordering::SeqCst) {
        match wait_readable(&file, WAKE_MS) {
            Ok(false) => continue,
            Ok(true) => {}
            Err(e) => return fail(format!("poll failed: {}", io_reason(&e))),
        }
        let n = match file.read(&mut buf[filled..]) {
            Ok(0) => return fail("end of data (was the device removed?)".into()),
            Ok(n) => n,
            Err(e) if matches!(e.kind(), ErrorKind::Interrupted | ErrorKind::WouldBlock) => {
                continue
            }
            Err(e) => return fail(format!("read failed: {}", io_reason(&e))),
        };
        filled += n;
        let whole = filled / rb * rb;
        batch.clear();
        if let Err(e) = decoder.decode(&buf[..whole], &mut batch) {
            return fail(e);
        }
        store.push(&batch);
        buf.copy_within(whole..filled, 0);
        filled -= whole;
    }
}
