//! The device side, through [`crate::backend::videodev`]: the video node, the lens control and
//! the stream. Kept thin: the decisions are in the pure modules and in the small functions at
//! the end.

use super::config::V4l2Config;
use super::config::NO_PROFILE;
use super::detect;
use super::exposure::{self, SensorTiming};
use super::format::{self, fourcc_str, PixelFormat};
use super::lens::{self, ControlInfo, ControlKind, ControlList, ControlSpec};
use super::pipeline;
use super::profile::Profile;
use crate::backend::sys::monotonic_now;
use crate::backend::videodev::abi::{
    self,
    CAP_STREAMING,
    CAP_VIDEO_CAPTURE,
    CAP_VIDEO_CAPTURE_MPLANE,
    // Continuous autofocus, switched off for the sweep (UVC webcams).
    CID_FOCUS_AUTO,
};
use crate::backend::videodev::{BufType, Device, PlaneLayout, Stream};
use crate::capture::{Camera, CaptureError, Frame, Nanos, Take};
use crate::develop::{Developer, IDENTITY};
use std::io;
use std::path::{Path, PathBuf};
use std::time::Duration;

const ENODEV: i32 = 19;
const EPIPE: i32 = 32;

/// A V4L2 capture node streaming memory-mapped buffers, and the control that moves its lens.
pub struct V4l2Camera {
    node: PathBuf,
    /// `None` once released.
    stream: Option<Stream>,
    lens: Lens,
    timing: Option<TimingSource>,
    format: PixelFormat,
    width: u32,
    height: u32,
    planes: Vec<PlaneLayout>,
    /// From VIDIOC_G_PARM, when the driver reports one.
    frame_interval: Option<Nanos>,
    settle: Duration,
    drop_frames: u32,
    frame_timeout: Duration,
    /// CLOCK_MONOTONIC when the last move had settled: frames exposed from before are stale.
    settled_at: Option<Nanos>,
    /// The previous frame's timestamp, for the frame interval when the driver gives none.
    last_stamp: Option<Nanos>,
    /// The sensor's rotation control (degrees counter-clockwise), 0 without a profile.
    rotation: i64,
    /// Converts frames an ISP made; for raw Bayer frames, the black level and colour matrix
    /// they carry to their development after the sweep.
    developer: Developer,
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
    let profiled;
    let mut rotation = 0;
    // Raw frames are developed with the profile's black level and colour matrix.
    let mut developer = Developer::new(0, IDENTITY);
    let cfg = match profile_of(cfg)? {
        None => cfg,
        Some((profile, chosen_by)) => {
            let p =
                pipeline::apply(&profile, &cfg.sysfs_root).map_err(|e| match (e, chosen_by) {
                    (CaptureError::Device { device, reason }, Some(why)) => CaptureError::Device {
                        device: format!(
                            "{device} (chosen by {why}; set [camera] profile to another, or to \
                         \"none\")"
                        ),
                        reason,
                    },
                    (e, _) => e,
                })?;
            for note in &p.notes {
                tracing::info!("device profile {}: {note}", profile.name);
            }
            rotation = p.rotation.unwrap_or(0);
            let named = lens::named_lenses(&cfg.sysfs_root);
            pipeline::check_lens(&p, cfg.lens.as_deref(), &named)
                .map_err(|e| CaptureError::device(format!("device profile {}", profile.name), e))?;
            let black = p
                .format
                .raw_bits()
                .map_or(0, |bits| profile.black_level_at(bits));
            developer = Developer::new(black, profile.colour_matrix);
            profiled = V4l2Config {
                device: Some(p.capture),
                format: Some(fourcc_str(&p.format.fourcc())),
                width: p.width,
                height: p.height,
                lens: cfg
                    .lens
                    .clone()
                    .or_else(|| p.lens.map(|l| l.display().to_string())),
                profile: Some(profile.name),
                ..cfg.clone()
            };
            &profiled
        }
    };
    let (node, dev, buf) = open_node(cfg)?;
    let err = |what: &str, e: io::Error| device_error(&node, what, &e);

    let offered = dev
        .formats(buf)
        .map_err(|e| err("cannot list its formats", e))?;
    let chosen = format::choose(&offered, cfg.format.as_deref())
        .map_err(|e| CaptureError::device(node.display().to_string(), e))?;
    let actual = dev
        .set_format(buf, cfg.width, cfg.height, chosen.fourcc())
        .map_err(|e| err("cannot set the format", e))?;
    if actual.fourcc != chosen.fourcc() {
        return Err(CaptureError::device(
            node.display().to_string(),
            format!(
                "asked for {}, the driver set {}",
                fourcc_str(&chosen.fourcc()),
                fourcc_str(&actual.fourcc)
            ),
        ));
    }
    let profiled = matches!(cfg.profile.as_deref(), Some(p) if p != NO_PROFILE);
    if profiled && (actual.width, actual.height) != (cfg.width, cfg.height) {
        // The capture node's size must equal its source pad's, or the stream fails with EPIPE.
        return Err(CaptureError::device(
            node.display().to_string(),
            format!(
                "the profile's capture size is {}x{}, the driver set {}x{}",
                cfg.width, cfg.height, actual.width, actual.height
            ),
        ));
    }
    let frame_interval = dev
        .frame_interval(buf)
        .ok()
        .and_then(|p| exposure::interval_ns(p.numerator, p.denominator));

    let stream = Stream::new(dev, buf, cfg.buffers)
        .map_err(|e| err("cannot allocate the capture buffers", e))?;
    // Last of what can fail: it may switch autofocus off, which only `release` undoes.
    let lens = open_lens(cfg, &node, stream.device(), &spec)?;
    let timing = timing_source(cfg, &node, stream.device(), &lens.path);
    Ok(V4l2Camera {
        node,
        stream: Some(stream),
        lens,
        timing,
        format: chosen,
        width: actual.width,
        height: actual.height,
        planes: actual.planes,
        frame_interval,
        settle: Duration::from_millis(cfg.settle_ms),
        drop_frames: cfg.drop_frames,
        frame_timeout: Duration::from_millis(cfg.frame_timeout_ms),
        settled_at: None,
        last_stamp: None,
        developer,
        rotation,
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
                .set_control(id, v)
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
            Err(e) => Err(device_error(&self.node, "cannot stop streaming", &e)),
        }
    }
}

impl Camera for V4l2Camera {
    fn lens_range(&self) -> (i32, i32) {
        self.lens.range
    }

    fn sensor_rotation(&self) -> i64 {
        self.rotation
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
            .set_control(self.lens.id, position.into())
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
                    ms: self.frame_timeout.as_millis() as u64,
                }
            } else {
                device_error(&self.node, "cannot dequeue a frame", e)
            }
        };
        let mut dropped = 0u32;
        loop {
            let d = stream
                .dequeue(self.frame_timeout)
                .map_err(|e| dequeue_error(&e))?;
            let stamp = exposure::timeval_ns(d.sec, d.usec);
            let measured = self.last_stamp.map(|t| stamp - t).filter(|&d| d > 0);
            self.last_stamp = Some(stamp);
            let window = timing
                .exposure_ns(self.width, self.frame_interval.or(measured))
                .map(|exp| exposure::window(d.flags, stamp, exp, readout))
                .transpose();
            let corrupt = d.flags & abi::BUF_FLAG_ERROR != 0;
            // `None`: the frame is dropped and the next one tried.
            let outcome = match window {
                Err(e) => Some(Err(CaptureError::device(&label, e))),
                Ok(Some((start, end))) if !corrupt && !stale(start, self.settled_at) => Some(
                    frame_of(
                        self.format,
                        (self.width as usize, self.height as usize),
                        &stream
                            .planes(&d)
                            .into_iter()
                            .zip(&self.planes)
                            .map(|(bytes, p)| (bytes, p.bytesperline as usize))
                            .collect::<Vec<_>>(),
                        &mut self.developer,
                    )
                    .map(|frame| Take {
                        frame,
                        exposure_start: start,
                        exposure_end: end,
                    })
                    .map_err(|e| CaptureError::device(&label, e)),
                ),
                Ok(_) => {
                    dropped += 1;
                    (dropped > self.drop_frames).then(|| {
                        Err(CaptureError::device(
                            &label,
                            format!(
                                "{dropped} frames in a row were corrupt or began exposing \
                                 before the lens settled: the driver's timestamps or the \
                                 exposure estimate are off (raise [camera] drop_frames if the \
                                 stream is just deep)"
                            ),
                        ))
                    })
                }
            };
            // The frame is converted (or dropped): its buffer goes back to the driver.
            let queued = stream
                .queue(d.index)
                .map_err(|e| device_error(&self.node, "cannot queue a buffer back", &e));
            match (outcome, queued) {
                (Some(Err(e)), _) => return Err(e),
                (_, Err(e)) => return Err(e),
                (Some(take), Ok(())) => return take,
                (None, Ok(())) => {}
            }
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

/// The device profile to set the pipeline up with: the one `[camera] profile` names, none for
/// `"none"`, else the shipped one this machine's device tree (or media model) chooses, with
/// what chose it.
fn profile_of(cfg: &V4l2Config) -> Result<Option<(Profile, Option<String>)>, CaptureError> {
    let err = |e| CaptureError::device("[camera] profile", e);
    match cfg.profile.as_deref() {
        Some(NO_PROFILE) => Ok(None),
        Some(spec) => Ok(Some((Profile::load(spec).map_err(err)?, None))),
        None => Ok(detect::detect(&cfg.sysfs_root)
            .map_err(err)?
            .map(|c| (c.profile, Some(c.reason)))),
    }
}

/// The node from `device`, else the first capture node matching `card` (or any).
fn open_node(cfg: &V4l2Config) -> Result<(PathBuf, Device, BufType), CaptureError> {
    let nodes = lens::list_nodes(&cfg.sysfs_root, "video");
    let probe = |path: &Path| -> Result<(Device, BufType, String), String> {
        let dev = Device::open(path).map_err(|e| io_reason(&e))?;
        let caps = dev
            .capabilities()
            .map_err(|e| format!("cannot query it: {}", io_reason(&e)))?;
        let buf = capture_caps(caps.caps)?;
        Ok((dev, buf, format!("{} {}", caps.card, caps.driver)))
    };
    if let Some(path) = &cfg.device {
        return match probe(path) {
            Ok((dev, buf, _)) => Ok((path.clone(), dev, buf)),
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
            Ok((dev, buf, names))
                if matches(cfg.card.as_deref(), &format!("{names} {}", node.name)) =>
            {
                return Ok((node.dev.clone(), dev, buf));
            }
            Ok((_, _, names)) => skipped.push(format!("{} ({names})", node.dev.display())),
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
            let dev = Device::open(node)
                .map_err(|e| device_error(node, "cannot open it for the lens", &e))?;
            return Lens::new(dev, node, c, controls.as_deref().unwrap_or_default());
        }
        searched.push((node.display().to_string(), controls));
    }
    for path in lens::lens_candidates(&cfg.sysfs_root, cfg.lens.as_deref())? {
        let label = path.display().to_string();
        let dev = match Device::open(&path) {
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
        let original = dev
            .control(c.id)
            .map_err(|e| err("cannot read the lens position", e))?;
        let mut autofocus = None;
        if c.id == lens::CID_FOCUS_ABSOLUTE && controls.iter().any(|c| c.id == CID_FOCUS_AUTO) {
            let on = dev
                .control(CID_FOCUS_AUTO)
                .map_err(|e| err("cannot read autofocus", e))?;
            if on != 0 {
                dev.set_control(CID_FOCUS_AUTO, 0)
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
        let dev = Device::open(node).ok()?;
        return Some(TimingSource { dev, ids });
    }
    lens::list_nodes(&cfg.sysfs_root, "v4l-subdev")
        .into_iter()
        .filter(|n| n.dev != lens)
        .find_map(|n| {
            let dev = Device::open(&n.dev).ok()?;
            has_timing(&dev).map(|ids| TimingSource { dev, ids })
        })
}

impl TimingSource {
    /// The current values; a control that fails to read counts as absent.
    fn read(&self) -> SensorTiming {
        let get = |id: u32| {
            self.ids
                .contains(&id)
                .then(|| self.dev.control(id).ok())
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

/// The device's controls.
fn controls_of(dev: &Device) -> io::Result<Vec<ControlInfo>> {
    Ok(dev
        .controls()?
        .into_iter()
        .map(|d| ControlInfo {
            id: d.id,
            kind: match d.kind {
                abi::CTRL_TYPE_INTEGER | abi::CTRL_TYPE_INTEGER64 => ControlKind::Integer,
                _ => ControlKind::Other,
            },
            // INACTIVE is allowed: FOCUS_ABSOLUTE is inactive while autofocus runs, which
            // `Lens::new` switches off.
            writable: d.flags & (abi::CTRL_FLAG_DISABLED | abi::CTRL_FLAG_READ_ONLY) == 0,
            name: d.name,
            min: d.min,
            max: d.max,
            step: d.step,
            default: d.default,
        })
        .collect())
}

/// A frame's pixels: a raw Bayer buffer copied as it is (developed after the sweep), any other
/// format converted to RGB now.
fn frame_of(
    format: PixelFormat,
    (width, height): (usize, usize),
    planes: &[(&[u8], usize)],
    developer: &mut Developer,
) -> Result<Frame, String> {
    match (format, planes) {
        (PixelFormat::Bayer(order, packing), &[plane]) => {
            format::copy_raw((order, packing), (width, height), plane, developer).map(Frame::Raw)
        }
        _ => format::to_rgb_planes(format, width, height, planes, developer).map(Frame::Picture),
    }
}

fn stale(exposure_start: Nanos, settled_at: Option<Nanos>) -> bool {
    settled_at.is_some_and(|t| exposure_start < t)
}

/// Whether a node named `names` (card, driver, sysfs name) is the one `card` asks for.
fn matches(card: Option<&str>, names: &str) -> bool {
    card.is_none_or(|c| names.to_lowercase().contains(&c.to_lowercase()))
}

/// The capture API a node with these device capabilities streams with (single-planar where
/// it has both), or why it cannot be streamed from.
fn capture_caps(caps: u32) -> Result<BufType, String> {
    let buf = if caps & CAP_VIDEO_CAPTURE != 0 {
        BufType::Capture
    } else if caps & CAP_VIDEO_CAPTURE_MPLANE != 0 {
        BufType::CaptureMplane
    } else {
        return Err("not a video capture node (an output, metadata or statistics node?)".into());
    };
    if caps & CAP_STREAMING == 0 {
        return Err("it cannot stream (no V4L2_CAP_STREAMING)".to_string());
    }
    Ok(buf)
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
        _ if e.raw_os_error() == Some(EPIPE) => format!(
            "{e}: the media pipeline cannot stream: its links or pad formats do not match the \
             capture format (set [camera] profile to the device's profile, or correct it)"
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
        assert_eq!(
            capture_caps(CAP_VIDEO_CAPTURE | CAP_STREAMING),
            Ok(BufType::Capture)
        );
        assert_eq!(
            capture_caps(CAP_VIDEO_CAPTURE_MPLANE | CAP_STREAMING),
            Ok(BufType::CaptureMplane)
        );
        assert_eq!(
            capture_caps(CAP_VIDEO_CAPTURE_MPLANE | CAP_VIDEO_CAPTURE | CAP_STREAMING),
            Ok(BufType::Capture)
        );
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
    fn the_pinephone_profile_fails_at_once_with_the_reason() {
        // No media device, no video node: the profile stops before it looks for any.
        let t = tempfile::tempdir().expect("tempdir");
        let cfg = V4l2Config {
            profile: Some("pinephone".into()),
            sysfs_root: t.path().join("sys"),
            ..V4l2Config::default()
        };
        let msg = open(&cfg).err().expect("no lens").to_string();
        assert!(
            msg.starts_with("device profile pinephone: this camera has no lens focusd can move")
                && msg.contains("firmware autofocus")
                && msg.contains("`focusd fuse` still fuses stacks taken elsewhere"),
            "{msg}"
        );
    }

    #[test]
    fn a_pinephone_found_by_its_device_tree_fails_at_once_and_says_why() {
        let t = tempfile::tempdir().expect("tempdir");
        let dt = t.path().join("sys/firmware/devicetree/base");
        std::fs::create_dir_all(&dt).expect("mkdir");
        std::fs::write(
            dt.join("compatible"),
            b"pine64,pinephone-1.2\0pine64,pinephone\0allwinner,sun50i-a64\0",
        )
        .expect("write");
        let cfg = V4l2Config {
            sysfs_root: t.path().join("sys"),
            ..V4l2Config::default()
        };
        let msg = open(&cfg).err().expect("no lens").to_string();
        assert!(
            msg.starts_with(
                "device profile pinephone (chosen by the device-tree compatible \
                 \"pine64,pinephone-1.2\"; set [camera] profile to another, or to \"none\"): \
                 this camera has no lens focusd can move"
            ) && msg.contains("firmware autofocus"),
            "{msg}"
        );
        // "none" turns the choice off: focusd then looks for a capture node as on any machine.
        let none = V4l2Config {
            profile: Some(NO_PROFILE.into()),
            ..cfg
        };
        let msg = open(&none).err().expect("no nodes").to_string();
        assert!(msg.contains("no video nodes"), "{msg}");
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
