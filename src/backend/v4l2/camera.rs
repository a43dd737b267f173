//! The device side, through the v4l crate: the video node, the lens control and the stream.
//! Kept thin: the decisions are in the pure modules and in the small functions at the end.

use super::config::V4l2Config;
use super::exposure::{self, SensorTiming};
use super::format::{self, fourcc_str, PixelFormat};
use super::lens::{self, ControlInfo, ControlKind, ControlList, ControlSpec};
use crate::backend::sys::monotonic_now;
use crate::capture::{Camera, CaptureError, Nanos, Take};
use std::io;
use std::path::{Path, PathBuf};
use std::time::Duration;
use v4l::buffer::{Flags as BufferFlags, Type};
use v4l::control::{Control, Flags as ControlFlags, Type as ControlType, Value};
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::{CaptureStream, Stream};
// FOCUS_AUTO: continuous autofocus, switched off for the sweep (UVC webcams).
use v4l::v4l_sys::{
    V4L2_CAP_STREAMING as CAP_STREAMING, V4L2_CAP_VIDEO_CAPTURE as CAP_VIDEO_CAPTURE,
    V4L2_CAP_VIDEO_CAPTURE_MPLANE as CAP_VIDEO_CAPTURE_MPLANE,
    V4L2_CID_FOCUS_AUTO as CID_FOCUS_AUTO,
};
use v4l::video::Capture;
use v4l::{Device, Format, FourCC};

const ENODEV: i32 = 19;

/// A V4L2 capture node streaming memory-mapped buffers, and the control that moves its lens.
pub struct V4l2Camera {
    node: PathBuf,
    /// `None` once released.
    stream: Option<MmapStream<'static>>,
    lens: Lens,
    timing: Option<TimingSource>,
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: u32,
    /// From VIDIOC_G_PARM, when the driver reports one.
    frame_interval: Option<Nanos>,
    settle: Duration,
    drop_frames: u32,
    frame_timeout_ms: u64,
    /// CLOCK_MONOTONIC when the last move had settled: frames exposed from before are stale.
    settled_at: Option<Nanos>,
    /// The previous frame's timestamp, for the frame interval when the driver gives none.
    last_stamp: Option<Nanos>,
    /// A dequeue failed (timed out) after v4l's `next` had queued the previous buffer back, so
    /// the v4l stream's current buffer is already with the driver: the next `next` would queue
    /// it a second time, which the driver refuses (EINVAL). See [`lost_current_buffer`].
    resync: bool,
}

struct Lens {
    dev: Device,
    path: PathBuf,
    id: u32,
    range: (i32, i32),
    original: i64,
    /// FOCUS_AUTO's value before the sweep switched it off.
    autofocus: Option<i64>,
}

/// The device whose controls give the exposure time: the video node on video-node-centric
/// drivers, the sensor's sub-device on media-controller ones (rkisp1).
struct TimingSource {
    dev: Device,
    ids: Vec<u32>,
}

/// Opens the camera from `[camera]`: the node, the best format, the lens control, the buffers.
/// Streaming starts at the first capture.
pub fn open(cfg: &V4l2Config) -> Result<V4l2Camera, CaptureError> {
    cfg.validate()
        .map_err(|e| CaptureError::device("[camera] config", e.to_string()))?;
    let spec = ControlSpec::parse(cfg.focus_control.as_deref())
        .map_err(|e| CaptureError::device("[camera] config", format!("focus_control {e}")))?;
    let (node, dev) = open_node(cfg)?;
    let err = |what: &str, e: io::Error| device_error(&node, what, &e);

    let offered: Vec<[u8; 4]> = dev
        .enum_formats()
        .map_err(|e| err("cannot list its formats", e))?
        .iter()
        .map(|d| d.fourcc.repr)
        .collect();
    let chosen = format::choose(&offered, cfg.format.as_deref())
        .map_err(|e| CaptureError::device(node.display().to_string(), e))?;
    let asked = Format::new(cfg.width, cfg.height, FourCC::new(&chosen.fourcc()));
    let actual = dev
        .set_format(&asked)
        .map_err(|e| err("cannot set the format", e))?;
    if actual.fourcc.repr != chosen.fourcc() {
        return Err(CaptureError::device(
            node.display().to_string(),
            format!(
                "asked for {}, the driver set {}",
                fourcc_str(&chosen.fourcc()),
                fourcc_str(&actual.fourcc.repr)
            ),
        ));
    }
    let frame_interval = dev
        .params()
        .ok()
        .and_then(|p| exposure::interval_ns(p.interval.numerator, p.interval.denominator));

    let mut stream = MmapStream::with_buffers(&dev, Type::VideoCapture, cfg.buffers)
        .map_err(|e| err("cannot allocate the capture buffers", e))?;
    stream.set_timeout(Duration::from_millis(cfg.frame_timeout_ms));
    // Last of what can fail: it may switch autofocus off, which only `release` undoes.
    let lens = open_lens(cfg, &node, &dev, &spec)?;
    let timing = timing_source(cfg, &node, &dev, &lens.path);
    Ok(V4l2Camera {
        node,
        stream: Some(stream),
        lens,
        timing,
        format: chosen,
        width: actual.width,
        height: actual.height,
        stride: actual.stride,
        frame_interval,
        settle: Duration::from_millis(cfg.settle_ms),
        drop_frames: cfg.drop_frames,
        frame_timeout_ms: cfg.frame_timeout_ms,
        settled_at: None,
        last_stamp: None,
        resync: false,
    })
}

impl V4l2Camera {
    /// What is being driven, for the log: node, format and size, lens device and control.
    pub fn describe(&self) -> String {
        format!(
            "{} {} {}x{}, lens {} control 0x{:08x} {}..={}",
            self.node.display(),
            fourcc_str(&self.format.fourcc()),
            self.width,
            self.height,
            self.lens.path.display(),
            self.lens.id,
            self.lens.range.0,
            self.lens.range.1
        )
    }

    fn label(&self) -> String {
        self.node.display().to_string()
    }

    /// Puts the lens back; both settings are tried even if the first fails.
    fn restore_lens(&mut self) -> Result<(), CaptureError> {
        let l = &self.lens;
        let set = |id: u32, v: i64| {
            l.dev
                .set_control(Control {
                    id,
                    value: Value::Integer(v),
                })
                .map_err(|e| device_error(&l.path, "cannot restore the lens", &e))
        };
        let position = set(l.id, l.original);
        let autofocus = l.autofocus.map_or(Ok(()), |v| set(CID_FOCUS_AUTO, v));
        position.and(autofocus)
    }

    fn stop_stream(&mut self) -> Result<(), CaptureError> {
        let Some(mut stream) = self.stream.take() else {
            return Ok(());
        };
        match stream.stop() {
            Ok(()) => Ok(()),
            Err(e) if e.raw_os_error() == Some(ENODEV) => Ok(()),
            Err(e) => {
                // v4l's Drop would stop it again and panic on the error: leak the buffers
                // instead (the process is ending this capture anyway).
                std::mem::forget(stream);
                Err(device_error(&self.node, "cannot stop streaming", &e))
            }
        }
    }
}

impl Camera for V4l2Camera {
    fn lens_range(&self) -> (i32, i32) {
        self.lens.range
    }

    fn focus(&mut self, _plane: usize, position: i32) -> Result<(), CaptureError> {
        if self.stream.is_none() {
            return Err(CaptureError::device(self.label(), "focus after release"));
        }
        let (lo, hi) = self.lens.range;
        if !(lo..=hi).contains(&position) {
            return Err(CaptureError::device(
                self.lens.path.display().to_string(),
                format!("lens position {position} is outside its range {lo}..={hi}"),
            ));
        }
        self.lens
            .dev
            .set_control(Control {
                id: self.lens.id,
                value: Value::Integer(position.into()),
            })
            .map_err(|e| device_error(&self.lens.path, "cannot move the lens", &e))?;
        std::thread::sleep(self.settle);
        self.settled_at = Some(monotonic_now());
        Ok(())
    }

    /// Frames are dropped while they began exposing before the last move settled (the frames
    /// already queued or in exposure then); the computed exposure start is compared with the
    /// monotonic time when `focus` returned. `drop_frames` caps this: past it the estimate or
    /// the timestamps cannot be right, and the take fails rather than return a smeared frame.
    /// The exposure controls are read once per take (a change within the auto-exposure's
    /// pipeline delay is not seen). With neither controls nor a frame interval from the driver,
    /// the interval is measured between frames, so the stream's first frame is dropped.
    fn capture(&mut self) -> Result<Take, CaptureError> {
        let label = self.label();
        let timing = self
            .timing
            .as_ref()
            .map_or_else(SensorTiming::default, |t| t.read());
        let readout = timing.readout_ns(self.width, self.height);
        let stream = self
            .stream
            .as_mut()
            .ok_or_else(|| CaptureError::device(&label, "capture after release"))?;
        let dequeue_error = |e: &io::Error| {
            if e.kind() == io::ErrorKind::TimedOut {
                CaptureError::Timeout {
                    what: format!("{label}: waiting for a frame"),
                    ms: self.frame_timeout_ms,
                }
            } else {
                device_error(&self.node, "cannot dequeue a frame", e)
            }
        };
        if self.resync {
            // Take a filled buffer back first (its frame is dropped): `next` then queues that
            // one, and the stream's bookkeeping matches the driver's again.
            CaptureStream::dequeue(stream).map_err(|e| dequeue_error(&e))?;
            self.resync = false;
        }
        let mut dropped = 0u32;
        loop {
            let (buf, meta) = match stream.next() {
                Ok(next) => next,
                Err(e) => {
                    self.resync = lost_current_buffer(&e);
                    return Err(dequeue_error(&e));
                }
            };
            let stamp = exposure::timeval_ns(meta.timestamp.sec, meta.timestamp.usec);
            let measured = self.last_stamp.map(|t| stamp - t).filter(|&d| d > 0);
            self.last_stamp = Some(stamp);
            let window = timing
                .exposure_ns(self.width, self.frame_interval.or(measured))
                .map(|exp| exposure::window(meta.flags.into(), stamp, exp, readout))
                .transpose()
                .map_err(|e| CaptureError::device(&label, e))?;
            let corrupt = meta.flags.contains(BufferFlags::ERROR);
            let Some((start, end)) =
                window.filter(|&(s, _)| !corrupt && !stale(s, self.settled_at))
            else {
                dropped += 1;
                if dropped > self.drop_frames {
                    return Err(CaptureError::device(
                        &label,
                        format!(
                            "{dropped} frames in a row were corrupt or began exposing before \
                             the lens settled: the driver's timestamps or the exposure estimate \
                             are off (raise [camera] drop_frames if the stream is just deep)"
                        ),
                    ));
                }
                continue;
            };
            let used = (meta.bytesused as usize).min(buf.len());
            let image = format::to_rgb(
                self.format,
                self.width as usize,
                self.height as usize,
                self.stride as usize,
                &buf[..used],
            )
            .map_err(|e| CaptureError::device(&label, e))?;
            return Ok(Take {
                image,
                exposure_start: start,
                exposure_end: end,
            });
        }
    }

    fn release(&mut self) -> Result<(), CaptureError> {
        if self.stream.is_none() {
            return Ok(());
        }
        let lens = self.restore_lens();
        let stream = self.stop_stream();
        lens.and(stream)
    }
}

impl Drop for V4l2Camera {
    /// The sweep releases explicitly and sees the errors; here they have nowhere to go.
    fn drop(&mut self) {
        let _ = self.release();
    }
}

/// The node from `device`, else the first capture node matching `card` (or any).
fn open_node(cfg: &V4l2Config) -> Result<(PathBuf, Device), CaptureError> {
    let nodes = lens::list_nodes(&cfg.sysfs_root, "video");
    let probe = |path: &Path| -> Result<(Device, String), String> {
        let dev = Device::with_path(path).map_err(|e| io_reason(&e))?;
        let caps = dev
            .query_caps()
            .map_err(|e| format!("cannot query it: {}", io_reason(&e)))?;
        capture_caps(caps.capabilities.bits())?;
        Ok((dev, format!("{} {}", caps.card, caps.driver)))
    };
    if let Some(path) = &cfg.device {
        return match probe(path) {
            Ok((dev, _)) => Ok((path.clone(), dev)),
            Err(reason) if !path.exists() => Err(CaptureError::device(
                path.display().to_string(),
                format!(
                    "{reason}; video nodes found: {} (set [camera] device to one of them)",
                    lens::describe(&nodes)
                ),
            )),
            Err(reason) => Err(CaptureError::device(path.display().to_string(), reason)),
        };
    }
    let mut skipped = Vec::new();
    for node in &nodes {
        match probe(&node.dev) {
            Ok((dev, names)) if matches(cfg.card.as_deref(), &format!("{names} {}", node.name)) => {
                return Ok((node.dev.clone(), dev));
            }
            Ok((_, names)) => skipped.push(format!("{} ({names})", node.dev.display())),
            Err(reason) => skipped.push(format!("{}: {reason}", node.label())),
        }
    }
    let dir = cfg.sysfs_root.join("class/video4linux");
    let reason = match (&cfg.card, nodes.is_empty()) {
        (_, true) => "no video nodes: is the camera driver loaded?".to_string(),
        (Some(card), false) => format!(
            "no capture node's card or driver is like {card:?}; found: {}",
            skipped.join("; ")
        ),
        (None, false) => format!("no usable capture node; found: {}", skipped.join("; ")),
    };
    Err(CaptureError::device(dir.display().to_string(), reason))
}

/// The lens: the video node's own control unless `lens` names a device, else the candidate
/// sub-devices in order.
fn open_lens(
    cfg: &V4l2Config,
    node: &Path,
    node_dev: &Device,
    spec: &ControlSpec,
) -> Result<Lens, CaptureError> {
    let mut searched: Vec<(String, ControlList)> = Vec::new();
    if cfg.lens.is_none() {
        let controls = controls_of(node_dev).map_err(|e| io_reason(&e));
        if let Some(c) = controls.as_ref().ok().and_then(|c| lens::pick(c, spec)) {
            let dev = Device::with_path(node)
                .map_err(|e| device_error(node, "cannot open it for the lens", &e))?;
            return Lens::new(dev, node, c, controls.as_deref().unwrap_or_default());
        }
        searched.push((node.display().to_string(), controls));
    }
    for path in lens::lens_candidates(&cfg.sysfs_root, cfg.lens.as_deref())? {
        let label = path.display().to_string();
        let dev = match Device::with_path(&path) {
            Ok(dev) => dev,
            Err(e) if cfg.lens.is_some() => return Err(device_error(&path, "cannot open", &e)),
            Err(e) => {
                searched.push((label, Err(io_reason(&e))));
                continue;
            }
        };
        let controls = controls_of(&dev).map_err(|e| io_reason(&e));
        if let Some(c) = controls.as_ref().ok().and_then(|c| lens::pick(c, spec)) {
            return Lens::new(dev, &path, c, controls.as_deref().unwrap_or_default());
        }
        searched.push((label, controls));
    }
    let device = searched
        .first()
        .map_or_else(String::new, |(l, _)| l.clone());
    let detail = lens::missing_detail(&searched);
    Err(match spec {
        ControlSpec::Focus => CaptureError::NoFocusControl { device, detail },
        _ => CaptureError::device(
            device,
            format!(
                "has no settable integer {} (set [camera] focus_control){detail}",
                spec.describe()
            ),
        ),
    })
}

impl Lens {
    /// Takes the lens control over: switches continuous autofocus off and remembers what to
    /// put back.
    fn new(
        dev: Device,
        path: &Path,
        c: &ControlInfo,
        controls: &[ControlInfo],
    ) -> Result<Lens, CaptureError> {
        let err = |what: &str, e: io::Error| device_error(path, what, &e);
        let range = match (i32::try_from(c.min), i32::try_from(c.max)) {
            (Ok(lo), Ok(hi)) => (lo, hi),
            _ => {
                return Err(CaptureError::device(
                    path.display().to_string(),
                    format!("{}: range {}..={} exceeds i32", c.name, c.min, c.max),
                ))
            }
        };
        let original = integer(&dev, c.id).map_err(|e| err("cannot read the lens position", e))?;
        let mut autofocus = None;
        if c.id == lens::CID_FOCUS_ABSOLUTE && controls.iter().any(|c| c.id == CID_FOCUS_AUTO) {
            let on = integer(&dev, CID_FOCUS_AUTO).map_err(|e| err("cannot read autofocus", e))?;
            if on != 0 {
                dev.set_control(Control {
                    id: CID_FOCUS_AUTO,
                    value: Value::Integer(0),
                })
                .map_err(|e| err("cannot switch continuous autofocus off", e))?;
                autofocus = Some(on);
            }
        }
        Ok(Lens {
            dev,
            path: path.to_path_buf(),
            id: c.id,
            range,
            original,
            autofocus,
        })
    }
}

/// The first of the video node and the sub-devices other than the lens with an exposure
/// control; `None` falls back to the frame interval. Devices that fail are skipped: this only
/// refines the exposure window.
fn timing_source(
    cfg: &V4l2Config,
    node: &Path,
    node_dev: &Device,
    lens: &Path,
) -> Option<TimingSource> {
    let wanted = [
        exposure::CID_EXPOSURE_ABSOLUTE,
        exposure::CID_EXPOSURE,
        exposure::CID_HBLANK,
        exposure::CID_PIXEL_RATE,
    ];
    let has_timing = |dev: &Device| -> Option<Vec<u32>> {
        let ids: Vec<u32> = controls_of(dev)
            .ok()?
            .iter()
            .map(|c| c.id)
            .filter(|id| wanted.contains(id))
            .collect();
        let exposure = &wanted[..2];
        ids.iter().any(|id| exposure.contains(id)).then_some(ids)
    };
    if let Some(ids) = has_timing(node_dev) {
        let dev = Device::with_path(node).ok()?;
        return Some(TimingSource { dev, ids });
    }
    lens::list_nodes(&cfg.sysfs_root, "v4l-subdev")
        .into_iter()
        .filter(|n| n.dev != lens)
        .find_map(|n| {
            let dev = Device::with_path(&n.dev).ok()?;
            has_timing(&dev).map(|ids| TimingSource { dev, ids })
        })
}

impl TimingSource {
    /// The current values; a control that fails to read counts as absent.
    fn read(&self) -> SensorTiming {
        let get = |id: u32| {
            self.ids
                .contains(&id)
                .then(|| integer(&self.dev, id).ok())
                .flatten()
        };
        SensorTiming {
            exposure_absolute: get(exposure::CID_EXPOSURE_ABSOLUTE),
            exposure_lines: get(exposure::CID_EXPOSURE),
            hblank: get(exposure::CID_HBLANK),
            pixel_rate: get(exposure::CID_PIXEL_RATE),
        }
    }
}

fn integer(dev: &Device, id: u32) -> io::Result<i64> {
    match dev.control(id)?.value {
        Value::Integer(v) => Ok(v),
        Value::Boolean(b) => Ok(b.into()),
        _ => Err(io::Error::other("not an integer control")),
    }
}

/// The device's controls. v4l reports a device without any as EINVAL.
fn controls_of(dev: &Device) -> io::Result<Vec<ControlInfo>> {
    let described = match dev.query_controls() {
        Ok(d) => d,
        Err(e) if e.kind() == io::ErrorKind::InvalidInput => Vec::new(),
        Err(e) => return Err(e),
    };
    Ok(described
        .into_iter()
        .map(|d| ControlInfo {
            id: d.id,
            kind: match d.typ {
                ControlType::Integer | ControlType::Integer64 => ControlKind::Integer,
                _ => ControlKind::Other,
            },
            // INACTIVE is allowed: FOCUS_ABSOLUTE is inactive while autofocus runs, which
            // `Lens::new` switches off.
            writable: !d
                .flags
                .intersects(ControlFlags::DISABLED | ControlFlags::READ_ONLY),
            name: d.name,
            min: d.minimum,
            max: d.maximum,
            step: d.step,
            default: d.default,
        })
        .collect())
}

/// Whether a failed `next` of a started v4l stream left its current buffer queued with the
/// driver: it queues the previous buffer back and then waits, so a wait that timed out or was
/// interrupted fails after the queueing. Other errors (EIO, ENODEV) end the stream anyway.
fn lost_current_buffer(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
    )
}

fn stale(exposure_start: Nanos, settled_at: Option<Nanos>) -> bool {
    settled_at.is_some_and(|t| exposure_start < t)
}

/// Whether a node named `names` (card, driver, sysfs name) is the one `card` asks for.
fn matches(card: Option<&str>, names: &str) -> bool {
    card.is_none_or(|c| names.to_lowercase().contains(&c.to_lowercase()))
}

/// Why a node with these device capabilities cannot be streamed from, if it cannot.
fn capture_caps(caps: u32) -> Result<(), String> {
    if caps & CAP_VIDEO_CAPTURE == 0 {
        return Err(if caps & CAP_VIDEO_CAPTURE_MPLANE != 0 {
            "it supports only the multi-planar capture API (rkisp1 and other ISPs), which the \
             v4l crate focusd uses cannot stream"
                .to_string()
        } else {
            "not a video capture node (an output, metadata or statistics node?)".to_string()
        });
    }
    if caps & CAP_STREAMING == 0 {
        return Err("it cannot stream (no V4L2_CAP_STREAMING)".to_string());
    }
    Ok(())
}

/// An I/O error with the fix for the failures a camera meets.
fn io_reason(e: &io::Error) -> String {
    match e.kind() {
        io::ErrorKind::NotFound => format!("{e}: no such device node"),
        io::ErrorKind::PermissionDenied => format!(
            "{e}: add the user to the video group (sudo usermod -aG video $USER, then log in \
             again) or run as root"
        ),
        io::ErrorKind::ResourceBusy => format!(
            "{e}: another program (a camera app, PipeWire/WirePlumber) is using the camera; \
             close it"
        ),
        _ if e.raw_os_error() == Some(ENODEV) => {
            format!("{e}: the device went away (unplugged, or its driver was unbound)")
        }
        _ => e.to_string(),
    }
}

fn device_error(path: &Path, what: &str, e: &io::Error) -> CaptureError {
    CaptureError::device(
        path.display().to_string(),
        format!("{what}: {}", io_reason(e)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capture_capabilities_are_checked() {
        assert_eq!(capture_caps(CAP_VIDEO_CAPTURE | CAP_STREAMING), Ok(()));
        let e = capture_caps(CAP_VIDEO_CAPTURE_MPLANE | CAP_STREAMING).expect_err("mplane");
        assert!(e.contains("multi-planar"), "{e}");
        assert!(capture_caps(CAP_VIDEO_CAPTURE)
            .expect_err("no streaming")
            .contains("cannot stream"));
        assert!(capture_caps(0x0080_0000)
            .expect_err("metadata")
            .contains("not a video capture node"));
    }

    #[test]
    fn card_matches_case_insensitively() {
        assert!(matches(None, "anything"));
        assert!(matches(Some("VIVID"), "vivid-000-vid-cap vivid"));
        assert!(!matches(Some("uvc"), "vivid-000-vid-cap vivid"));
    }

    #[test]
    fn a_timed_out_wait_needs_a_resync() {
        // What v4l's dequeue returns when poll() times out, and EINTR from poll or DQBUF.
        let timeout = io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF");
        assert!(lost_current_buffer(&timeout));
        assert!(lost_current_buffer(&io::Error::from_raw_os_error(4)));
        // EIO (a streaming error) and ENODEV (unplugged) end the stream; EINVAL is not a wait.
        for errno in [5, ENODEV, 22] {
            assert!(!lost_current_buffer(&io::Error::from_raw_os_error(errno)));
        }
    }

    #[test]
    fn frames_exposed_before_settling_are_stale() {
        assert!(stale(99, Some(100)));
        assert!(!stale(100, Some(100)));
        assert!(!stale(0, None));
    }

    #[test]
    fn io_errors_say_the_fix() {
        let denied = io_reason(&io::Error::from(io::ErrorKind::PermissionDenied));
        assert!(denied.contains("video group"), "{denied}");
        let busy = io_reason(&io::Error::from_raw_os_error(16));
        assert!(busy.contains("another program"), "{busy}");
        let gone = io_reason(&io::Error::from_raw_os_error(ENODEV));
        assert!(gone.contains("went away"), "{gone}");
        let e = device_error(
            Path::new("/dev/video3"),
            "cannot open",
            &io::Error::from(io::ErrorKind::NotFound),
        );
        assert!(
            e.to_string().starts_with("/dev/video3: cannot open: "),
            "{e}"
        );
    }

    #[test]
    fn a_missing_node_lists_the_nodes_found() {
        let t = tempfile::tempdir().expect("tempdir");
        let dir = t.path().join("sys/class/video4linux/video0");
        std::fs::create_dir_all(&dir).expect("mkdir");
        std::fs::write(dir.join("name"), "vivid-000-vid-cap\n").expect("write");
        let cfg = V4l2Config {
            device: Some(t.path().join("dev/video7")),
            sysfs_root: t.path().join("sys"),
            ..V4l2Config::default()
        };
        let msg = open(&cfg).err().expect("no such node").to_string();
        assert!(
            msg.contains("dev/video7: ")
                && msg.contains("no such device node")
                && msg.contains("video nodes found: ")
                && msg.contains("dev/video0 (vivid-000-vid-cap)"),
            "{msg}"
        );
    }

    #[test]
    fn no_video_nodes_says_so() {
        let t = tempfile::tempdir().expect("tempdir");
        let cfg = V4l2Config {
            sysfs_root: t.path().join("sys"),
            ..V4l2Config::default()
        };
        let msg = open(&cfg).err().expect("no nodes").to_string();
        assert!(
            msg.contains("no video nodes: is the camera driver loaded?"),
            "{msg}"
        );
        let bad = V4l2Config { buffers: 0, ..cfg };
        let msg = open(&bad).err().expect("invalid").to_string();
        assert!(msg.starts_with("[camera] config: buffers = 0"), "{msg}");
    }
}
