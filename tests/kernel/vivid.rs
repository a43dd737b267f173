//! The V4L2 backend against the kernel's vivid test driver: run inside a VM by
//! `tests/kernel/run-vivid` (or on any machine with `modprobe vivid`, as root).
//!
//! `vivid [/dev/videoN]` (default `/dev/video0`, vivid-000-vid-cap). Prints the device's formats
//! and controls, then one `ok: ...` line per passed check; stops at the first failed check with
//! `FAIL: ...`. Ends with `VIVID-RESULT: PASS` or `VIVID-RESULT: FAIL` (exit status 0 or 1).
//!
//! vivid has no focus control, so the sweep drives `Brightness` instead (`focus_control`), which
//! also makes every move visible in the frames.
//!
//! A node of vivid loaded with `multiplanar=2` (its capture node has only the multi-planar API)
//! gets the checks that go through that API: YUYV (one plane), NV12 (one plane) and NM12 (luma
//! and chroma in two planes), streaming, timestamps, the control put back, stale frames dropped
//! and a whole sweep.

use focusd::backend::sys::{monotonic_now, MonotonicClock};
use focusd::backend::v4l2::{self, V4l2Camera, V4l2Config};
use focusd::backend::videodev::abi::{self, Fract};
use focusd::backend::videodev::{BufType, ControlDesc, Device, Stream};
use focusd::capture::sweep::{sweep, SweepConfig, Unmonitored};
use focusd::capture::{Camera, CaptureError, Frame, Imu, ImuSample, Nanos, Sensor, Take};
use focusd::develop::StackDeveloper;
use focusd::service::config::Config;
use focusd::service::job::Source;
use focusd::service::preview::ring::{RingReader, State};
use focusd::service::preview::{self, Preview};
use focusd::stack::Image;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[macro_use]
mod support;
use support::{ok, report, Check};

const MS: Nanos = 1_000_000;
const BAYER: [&str; 4] = ["RGGB", "BA81", "GBRG", "GRBG"];

fn main() {
    let node = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "/dev/video0".into()),
    );
    report("VIVID", || run(&node));
}

/// What the raw device says, through the videodev layer (not the camera backend).
struct Info {
    /// The node's capture API.
    buf: BufType,
    formats: Vec<String>,
    controls: Vec<ControlDesc>,
}

impl Info {
    fn control(&self, name: &str) -> Result<&ControlDesc, String> {
        self.controls
            .iter()
            .find(|c| c.name.eq_ignore_ascii_case(name))
            .ok_or_else(|| format!("vivid has no \"{name}\" control"))
    }
}

fn run(node: &Path) -> Check {
    let info = inspect(node)?;
    let brightness = info.control("Brightness")?;
    ensure!(
        brightness.kind == abi::CTRL_TYPE_INTEGER && brightness.min < brightness.max,
        "Brightness is not an integer control with a range: {brightness:?}"
    );
    let range = (brightness.min as i32, brightness.max as i32);
    let raw = Device::open(node).map_err(|e| format!("{}: {e}", node.display()))?;
    set(&raw, brightness.id, brightness.default)?;

    if info.buf == BufType::CaptureMplane {
        formats(node, &info, &raw, &["YUYV", "NV12", "NM12"], &[(640, 480)])?;
        streaming(node)?;
        timestamps(node, &info, &raw)?;
        lens_restored(node, &raw, brightness.id, range)?;
        stale_frames_dropped(node, range)?;
        whole_sweep(node, range)?;
        return set(&raw, brightness.id, brightness.default);
    }
    ensure!(
        !info.formats.iter().any(|f| f == "NM12"),
        "the single-planar node offers the two-plane NM12: {:?}",
        info.formats
    );
    no_focus_control(node)?;
    open_by_card()?;
    lens_is_the_control(node, range)?;
    let mut wanted: Vec<&str> = vec!["YUYV", "UYVY", "RGB3", "NV12"];
    wanted.extend(
        BAYER
            .iter()
            .filter(|b| info.formats.iter().any(|f| f == *b)),
    );
    ensure!(
        wanted.len() > 4,
        "vivid offers none of the Bayer formats {BAYER:?}: {:?}",
        info.formats
    );
    formats(node, &info, &raw, &wanted, &[(640, 480), (320, 240)])?;
    streaming(node)?;
    timestamps(node, &info, &raw)?;
    lens_restored(node, &raw, brightness.id, range)?;
    stale_frames_dropped(node, range)?;
    whole_sweep(node, range)?;
    set(&raw, brightness.id, brightness.default)?;
    live_preview(node, "YUYV", (640, 360))?;
    // A raw stream gets the cheap development: one pixel a 2x2 cell.
    let bayer = BAYER.iter().find(|b| info.formats.iter().any(|f| f == *b));
    live_preview(node, bayer.ok_or("no Bayer format")?, (320, 180))?;
    busy(node)?;
    timeout(node, &info, &raw)?;
    error_frames(node, &info, &raw)?;
    set(&raw, brightness.id, brightness.default)?;
    // Last: vivid unregisters its nodes.
    disconnect(node, &info, &raw)?;
    Ok(())
}

fn inspect(node: &Path) -> Result<Info, String> {
    let dev = Device::open(node).map_err(|e| format!("{}: {e}", node.display()))?;
    let caps = dev
        .capabilities()
        .map_err(|e| format!("VIDIOC_QUERYCAP: {e}"))?;
    println!(
        "device: {} card {:?} driver {:?} caps 0x{:08x}",
        node.display(),
        caps.card,
        caps.driver,
        caps.caps
    );
    let buf = if caps.caps & abi::CAP_VIDEO_CAPTURE != 0 {
        BufType::Capture
    } else {
        BufType::CaptureMplane
    };
    let formats: Vec<String> = dev
        .formats(buf)
        .map_err(|e| format!("VIDIOC_ENUM_FMT: {e}"))?
        .iter()
        .map(|f| {
            let name = String::from_utf8_lossy(f).trim_end().to_string();
            println!("format: {name}");
            name
        })
        .collect();
    let controls = dev
        .controls()
        .map_err(|e| format!("VIDIOC_QUERY_EXT_CTRL: {e}"))?;
    for c in &controls {
        println!(
            "control: 0x{:08x} {:?} type {} {}..={} step {} default {} flags 0x{:x}",
            c.id, c.name, c.kind, c.min, c.max, c.step, c.default, c.flags
        );
    }
    if let Ok(p) = dev.frame_interval(buf) {
        println!("interval: {}/{} s", p.numerator, p.denominator);
    }
    Ok(Info {
        buf,
        formats,
        controls,
    })
}

fn cfg(node: &Path, format: Option<&str>, (width, height): (u32, u32)) -> V4l2Config {
    V4l2Config {
        device: Some(node.to_path_buf()),
        focus_control: Some("Brightness".into()),
        format: format.map(str::to_string),
        width,
        height,
        ..V4l2Config::default()
    }
}

fn open(cfg: &V4l2Config) -> Result<V4l2Camera, String> {
    let cam = v4l2::open(cfg).map_err(|e| format!("open: {e}"))?;
    println!("opened: {}", cam.describe());
    Ok(cam)
}

fn capture(cam: &mut V4l2Camera) -> Result<Take, String> {
    cam.capture().map_err(|e| format!("capture: {e}"))
}

fn set(dev: &Device, id: u32, v: i64) -> Check {
    dev.set_control(id, v)
        .map_err(|e| format!("setting control 0x{id:08x} to {v}: {e}"))
}

fn get(dev: &Device, id: u32) -> Result<i64, String> {
    dev.control(id)
        .map_err(|e| format!("reading 0x{id:08x}: {e}"))
}

/// Presses a button control.
fn press(dev: &Device, info: &Info, name: &str) -> Check {
    set(dev, info.control(name)?.id, 0).map_err(|e| format!("pressing {name}: {e}"))
}

/// A take's picture: a Bayer frame (vivid offers them too) developed as a capture's are.
fn picture(t: &Take) -> Result<Image<u8>, String> {
    match &t.frame {
        Frame::Picture(img) => Ok(img.clone()),
        Frame::Raw(raw) => StackDeveloper::default().develop(raw),
    }
}

fn mean_luma(img: &Image<u8>) -> f64 {
    let sum: f64 = img
        .data()
        .chunks_exact(3)
        .map(|p| 0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2]))
        .sum();
    sum / img.pixels() as f64
}

/// The 75% colour bars of vivid's default pattern, as high/low per channel.
const BARS: [(&str, [bool; 3]); 8] = [
    ("white", [true, true, true]),
    ("yellow", [true, true, false]),
    ("cyan", [false, true, true]),
    ("green", [false, true, false]),
    ("magenta", [true, false, true]),
    ("red", [true, false, false]),
    ("blue", [false, false, true]),
    ("black", [false, false, false]),
];

/// Checks the eight bars along a row near the bottom (vivid writes its OSD text over the top
/// rows, down past the middle of a 320x180 frame): each bar's centre (averaged over a few
/// pixels) has the bar's channels high (> 140) and the others low (< 70).
fn colour_bars(img: &Image<u8>) -> Result<Vec<[u8; 3]>, String> {
    let y = img.height() * 7 / 8;
    let bar = img.width() / 8;
    let mut seen = Vec::new();
    for (i, (name, want)) in BARS.iter().enumerate() {
        let cx = i * bar + bar / 2;
        let span = (bar / 4).max(1);
        let mut sum = [0u32; 3];
        for x in cx - span / 2..cx - span / 2 + span {
            for (c, s) in sum.iter_mut().enumerate() {
                *s += u32::from(img.at(x, y, c));
            }
        }
        let px = sum.map(|s| (s / span as u32) as u8);
        seen.push(px);
        let good = (0..3).all(|c| if want[c] { px[c] > 140 } else { px[c] < 70 });
        ensure!(
            good,
            "bar {i} ({name}) at x = {cx}, y = {y} is {px:?}; the bars along the row are {:?}",
            row_summary(img, y)
        );
    }
    let mut distinct = seen.clone();
    distinct.sort();
    distinct.dedup();
    ensure!(
        distinct.len() == 8,
        "only {} distinct bar colours",
        distinct.len()
    );
    Ok(seen)
}

fn row_summary(img: &Image<u8>, y: usize) -> Vec<[u8; 3]> {
    (0..16)
        .map(|i| {
            let x = i * img.width() / 16 + img.width() / 32;
            [img.at(x, y, 0), img.at(x, y, 1), img.at(x, y, 2)]
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------

fn no_focus_control(node: &Path) -> Check {
    let cfg = V4l2Config {
        device: Some(node.to_path_buf()),
        ..V4l2Config::default()
    };
    match v4l2::open(&cfg) {
        Err(e @ CaptureError::NoFocusControl { .. }) => {
            let msg = e.to_string();
            ensure!(
                msg.contains("a manual focus sweep is not possible")
                    && msg.contains(&node.display().to_string())
                    && msg.contains("Brightness (0x00980900)")
                    && !msg.contains("User Controls")
                    && !msg.contains("Button"),
                "the NoFocusControl message does not say what it should: {msg}"
            );
            ok(format!("default config: NoFocusControl: {msg}"));
            Ok(())
        }
        Err(e) => Err(format!("default config: expected NoFocusControl, got: {e}")),
        Ok(cam) => Err(format!(
            "default config: opened {} although vivid has no focus control",
            cam.describe()
        )),
    }
}

fn open_by_card() -> Check {
    let cfg = V4l2Config {
        card: Some("vivid".into()),
        focus_control: Some("Brightness".into()),
        width: 640,
        height: 480,
        ..V4l2Config::default()
    };
    let cam = open(&cfg)?;
    let d = cam.describe();
    ensure!(
        d.starts_with("/dev/video0 "),
        "card = \"vivid\" found {d}, not the capture node /dev/video0"
    );
    ok(format!("card = \"vivid\" finds the capture node: {d}"));
    Ok(())
}

fn lens_is_the_control(node: &Path, range: (i32, i32)) -> Check {
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    ensure!(
        cam.lens_range() == range,
        "lens_range {:?}, Brightness is {range:?}",
        cam.lens_range()
    );
    ok(format!(
        "focus_control = \"Brightness\": open succeeds, lens_range {range:?} is the control's"
    ));
    let mut luma = Vec::new();
    for p in [range.0, range.1] {
        cam.focus(0, p).map_err(|e| format!("focus {p}: {e}"))?;
        luma.push(mean_luma(&picture(&capture(&mut cam)?)?));
    }
    ensure!(
        luma[1] - luma[0] > 60.0,
        "Brightness {} and {} give mean luma {:.1} and {:.1}: the control does not reach the image",
        range.0,
        range.1,
        luma[0],
        luma[1]
    );
    ok(format!(
        "the lens control changes the image: mean luma {:.1} at {} and {:.1} at {}",
        luma[0], range.0, luma[1], range.1
    ));
    let err = cam.focus(0, range.1 + 1).err().map(|e| e.to_string());
    ensure!(
        err.as_deref()
            .is_some_and(|e| e.contains("outside its range")),
        "focus beyond the range: {err:?}"
    );
    cam.release().map_err(|e| format!("release: {e}"))?;
    ok("focus outside the range is refused");
    Ok(())
}

/// Each of `wanted` at each of `sizes` through the backend: the negotiated format and its
/// memory planes (two for NM12, luma then half-height chroma), the frame, the colour bars.
fn formats(node: &Path, info: &Info, raw: &Device, wanted: &[&str], sizes: &[(u32, u32)]) -> Check {
    for &size in sizes {
        for f in wanted {
            ensure!(
                info.formats.iter().any(|o| o == f),
                "vivid does not offer {f}: {:?}",
                info.formats
            );
            let mut cam = open(&cfg(node, Some(f), size))?;
            let take = capture(&mut cam)?;
            let g = raw.format(info.buf).map_err(|e| format!("G_FMT: {e}"))?;
            let img = &picture(&take)?;
            let fourcc = String::from_utf8_lossy(&g.fourcc).trim_end().to_string();
            ensure!(
                fourcc == *f,
                "{f}: the driver's format is {fourcc} after open"
            );
            let planes: Vec<(u32, u32)> = g
                .planes
                .iter()
                .map(|p| (p.bytesperline, p.sizeimage))
                .collect();
            if *f == "NM12" {
                let (w, h) = (g.width, g.height);
                ensure!(
                    planes.len() == 2
                        && planes[0].0 >= w
                        && planes[0].1 >= planes[0].0 * h
                        && planes[1].1 >= planes[1].0 * h / 2,
                    "NM12 {w}x{h}: planes (bytes per line, size) {planes:?}, expected luma and \
                     half-height chroma"
                );
            } else {
                ensure!(
                    planes.len() == 1,
                    "{f}: {} memory planes {planes:?}",
                    planes.len()
                );
            }
            ensure!(
                (img.width(), img.height(), img.channels())
                    == (g.width as usize, g.height as usize, 3),
                "{f} {size:?}: frame {}x{}x{}, the driver negotiated {}x{}",
                img.width(),
                img.height(),
                img.channels(),
                g.width,
                g.height
            );
            ensure!(
                size != (640, 480) || (g.width, g.height) == size,
                "{f}: asked for 640x480, got {}x{}",
                g.width,
                g.height
            );
            ensure!(
                cam.describe()
                    .contains(&format!(" {f} {}x{},", g.width, g.height)),
                "{f}: describe() says {}",
                cam.describe()
            );
            let bars =
                colour_bars(img).map_err(|e| format!("{f} {}x{}: {e}", g.width, g.height))?;
            let luma = mean_luma(img);
            ensure!(
                (40.0..220.0).contains(&luma),
                "{f}: implausible mean luma {luma:.1}"
            );
            cam.release().map_err(|e| format!("release: {e}"))?;
            ok(format!(
                "{f} asked {}x{}: negotiated {}x{} in {} plane(s) (bytes per line, size) \
                 {planes:?}, RGB frame of that size, 8 colour bars right (white {:?}, red {:?}, \
                 blue {:?}), mean luma {luma:.1}",
                size.0,
                size.1,
                g.width,
                g.height,
                planes.len(),
                bars[0],
                bars[5],
                bars[6]
            ));
        }
    }
    Ok(())
}

fn streaming(node: &Path) -> Check {
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    let mut prev: Option<(Nanos, Nanos)> = None;
    let mut lengths = Vec::new();
    for i in 0..6 {
        let t = capture(&mut cam)?;
        let now = monotonic_now();
        let (s, e) = (t.exposure_start, t.exposure_end);
        ensure!(s < e, "frame {i}: window [{s}, {e}] is empty");
        // vivid stamps an end-of-frame 0.9 frame periods after it fills the buffer, i.e. in
        // the future of the dequeue; a real sensor's end of frame is in the past.
        ensure!(
            e <= now + (e - s) && now - e < 1_000 * MS,
            "frame {i}: window ends at {e}, now is {now} ({} ms apart): not CLOCK_MONOTONIC?",
            (now - e) / MS
        );
        if let Some((ps, pe)) = prev {
            ensure!(
                s > ps,
                "frame {i} starts at {s}, before frame {} ({ps})",
                i - 1
            );
            // Under TCG on a loaded host vivid's frame thread runs tens of ms late or early,
            // and its stamps with it (seen: 42 ms of a 200 ms window): a misread timestamp
            // source or clock would be off by most of a period, not by that.
            ensure!(
                s >= pe - (e - s) / 2,
                "frame {i} [{s}, {e}] overlaps frame {} [{ps}, {pe}] by more than half",
                i - 1
            );
        }
        lengths.push((e - s) / 1000);
        prev = Some((s, e));
    }
    cam.release().map_err(|e| format!("release: {e}"))?;
    ok(format!(
        "mmap streaming: 6 frames in a row, increasing windows (overlapping by at most half) \
         on CLOCK_MONOTONIC (lengths {lengths:?} us)"
    ));
    Ok(())
}

/// A raw stream on the videodev layer (not the camera backend).
fn raw_stream(node: &Path, info: &Info) -> Result<Stream, String> {
    let dev = Device::open(node).map_err(|e| format!("{}: {e}", node.display()))?;
    Stream::new(dev, info.buf, 4).map_err(|e| format!("raw stream: {e}"))
}

/// The next raw buffer's flags and timestamp, the buffer queued back at once.
fn raw_frame(s: &mut Stream) -> Result<(u32, Nanos), String> {
    let d = s
        .dequeue(Duration::from_secs(5))
        .map_err(|e| format!("raw dequeue: {e}"))?;
    s.queue(d.index).map_err(|e| format!("raw queue: {e}"))?;
    Ok((d.flags, d.sec * 1_000_000_000 + d.usec * 1000))
}

/// Raw buffers: (flags, timestamp, monotonic time at dequeue).
fn raw_frames(node: &Path, info: &Info, n: usize) -> Result<Vec<(u32, Nanos, Nanos)>, String> {
    let mut s = raw_stream(node, info)?;
    let mut out = Vec::new();
    for _ in 0..n {
        let (flags, stamp) = raw_frame(&mut s)?;
        out.push((flags, stamp, monotonic_now()));
    }
    Ok(out)
}

fn timestamps(node: &Path, info: &Info, raw: &Device) -> Check {
    let src = info.control("Timestamp Source")?;
    let original = raw
        .frame_interval(info.buf)
        .map_err(|e| format!("G_PARM: {e}"))?;
    // Half a second per frame: the windows' placement against the dequeue time then tells the
    // two timestamp sources apart despite the VM's latencies.
    let period = 500 * MS;
    let c = cfg(node, Some("YUYV"), (640, 480));
    raw.set_format(info.buf, 640, 480, *b"YUYV")
        .map_err(|e| format!("S_FMT: {e}"))?;
    let half = Fract {
        numerator: 1,
        denominator: 2,
    };
    let p = raw
        .set_frame_interval(info.buf, half)
        .map_err(|e| format!("S_PARM: {e}"))?;
    ensure!(
        p == half,
        "vivid did not take 1/2 s per frame: {}/{}",
        p.numerator,
        p.denominator
    );
    let result = (|| {
        for (value, name, flag) in [(0, "end of frame", 0), (1, "start of exposure", 0x1_0000)] {
            set(raw, src.id, value)?;
            let frames = raw_frames(node, info, 2)?;
            for &(flags, stamp, now) in &frames {
                ensure!(
                    flags & 0xe000 == 0x2000 && flags & 0x7_0000 == flag,
                    "{name}: buffer flags 0x{flags:08x}, expected TIMESTAMP_MONOTONIC and \
                     source 0x{flag:05x}"
                );
                ensure!(
                    (now - stamp).abs() < period,
                    "{name}: buffer stamped {stamp}, dequeued at {now}"
                );
            }
            let (_, stamp, now) = frames[1];
            ok(format!(
                "raw buffers ({name}): flags MONOTONIC | source 0x{flag:05x}, stamp {} ms from \
                 the dequeue",
                (stamp - now) / MS
            ));
            let mut cam = open(&c)?;
            for i in 0..3 {
                let t = capture(&mut cam)?;
                let now = monotonic_now();
                let (s, e) = (t.exposure_start, t.exposure_end);
                ensure!(
                    e - s == period,
                    "{name}: window of {} ns, the frame interval (G_PARM) is {period} ns",
                    e - s
                );
                // vivid fills a buffer at f and stamps it f (SOE) or f + 0.9 period (EOF), then
                // hands it over at once: the exposure begins at f (SOE) or f - 0.1 period (EOF),
                // shortly before the dequeue. Reading one source as the other puts the start
                // 0.9 period later (after the dequeue) or one period earlier.
                ensure!(
                    s <= now && now - s < period / 2,
                    "{name}, frame {i}: window [{s}, {e}] starts {} ms before the dequeue at \
                     {now}: the timestamp source is misread",
                    (now - s) / MS
                );
                if i == 2 {
                    ok(format!(
                        "backend windows ({name}): start {} ms and end {} ms from the dequeue, \
                         length = the frame interval",
                        (s - now) / MS,
                        (e - now) / MS
                    ));
                }
            }
            cam.release().map_err(|e| format!("release: {e}"))?;
        }
        Ok(())
    })();
    set(raw, src.id, 0)?;
    raw.set_frame_interval(info.buf, original)
        .map_err(|e| format!("S_PARM: {e}"))?;
    result
}

fn lens_restored(node: &Path, raw: &Device, id: u32, range: (i32, i32)) -> Check {
    let before = i64::from(range.0 + (range.1 - range.0) / 3);
    set(raw, id, before)?;
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    cam.focus(0, range.1).map_err(|e| format!("focus: {e}"))?;
    capture(&mut cam)?;
    let moved = get(raw, id)?;
    ensure!(
        moved == i64::from(range.1),
        "after focus({}) the control reads {moved}",
        range.1
    );
    cam.release().map_err(|e| format!("release: {e}"))?;
    let after = get(raw, id)?;
    ensure!(
        after == before,
        "after release() the control is {after}, it was {before}"
    );
    cam.release()
        .map_err(|e| format!("a second release() failed: {e}"))?;
    ensure!(
        cam.capture().is_err() && cam.focus(0, range.0).is_err(),
        "capture or focus after release succeeded"
    );
    drop(cam);
    ok(format!(
        "the control is moved by focus() and back to {before} after release(); release() twice is fine"
    ));

    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    cam.focus(0, range.0).map_err(|e| format!("focus: {e}"))?;
    capture(&mut cam)?;
    ensure!(get(raw, id)? == i64::from(range.0), "focus did not move it");
    drop(cam);
    let after = get(raw, id)?;
    ensure!(
        after == before,
        "after drop the control is {after}, it was {before}"
    );
    ok(format!(
        "dropping the camera mid-stream restores the control to {before}"
    ));
    // Restarting: a new stream right after the old one was dropped.
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    capture(&mut cam)?;
    cam.release().map_err(|e| format!("release: {e}"))?;
    ok("the stream restarts after a dropped camera");
    Ok(())
}

fn stale_frames_dropped(node: &Path, range: (i32, i32)) -> Check {
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    capture(&mut cam)?;
    let mut lumas = Vec::new();
    for (i, p) in [range.0, range.1, range.0, range.1, range.0, range.1]
        .into_iter()
        .enumerate()
    {
        // Let the queue fill with frames of the old setting.
        std::thread::sleep(Duration::from_millis(200));
        cam.focus(i, p).map_err(|e| format!("focus: {e}"))?;
        let returned = monotonic_now();
        let t = capture(&mut cam)?;
        ensure!(
            t.exposure_start >= returned,
            "move {i} to {p}: the next frame began exposing at {}, {} us before focus() \
             returned at {returned}",
            t.exposure_start,
            (returned - t.exposure_start) / 1000
        );
        lumas.push(mean_luma(&picture(&t)?));
    }
    let dark = lumas.iter().step_by(2).fold(f64::MIN, |a, &b| a.max(b));
    let bright = lumas
        .iter()
        .skip(1)
        .step_by(2)
        .fold(f64::MAX, |a, &b| a.min(b));
    ensure!(
        bright - dark > 60.0,
        "the first frame after each move shows the old setting: mean luma {lumas:.1?}"
    );
    cam.release().map_err(|e| format!("release: {e}"))?;
    ok(format!(
        "after each of 6 moves the next frame began exposing after focus() returned and shows \
         the new setting (mean luma {lumas:.0?})"
    ));
    Ok(())
}

/// An IMU at rest: gyro zeros, gravity along y, a sample of each every 5 ms over any window.
struct StillImu;

impl Imu for StillImu {
    fn samples(&mut self, from: Nanos, to: Nanos) -> Result<Vec<ImuSample>, CaptureError> {
        let mut out = Vec::new();
        let mut t = from;
        loop {
            out.push(ImuSample {
                t,
                sensor: Sensor::Gyro,
                v: [0.0; 3],
            });
            out.push(ImuSample {
                t,
                sensor: Sensor::Accel,
                v: [0.0, 9.81, 0.0],
            });
            if t >= to {
                return Ok(out);
            }
            t = (t + 5 * MS).min(to);
        }
    }
}

fn whole_sweep(node: &Path, range: (i32, i32)) -> Check {
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    let sc = SweepConfig {
        planes: 4,
        still_ms: 40,
        still_timeout_ms: 2000,
        ..SweepConfig::default()
    };
    let s = sweep(&mut cam, &mut StillImu, &MonotonicClock, &sc, &Unmonitored)
        .map_err(|e| format!("sweep: {e}"))?;
    ensure!(s.frames.len() == 4, "{} frames, 4 planes", s.frames.len());
    let (lo, hi) = range;
    let want: Vec<i32> = (0..4)
        .map(|i| (f64::from(hi) - f64::from(hi - lo) * f64::from(i) / 3.0).round() as i32)
        .collect();
    let got: Vec<i32> = s.planes.iter().map(|p| p.lens).collect();
    ensure!(got == want, "lens positions {got:?}, expected {want:?}");
    for p in &s.planes {
        ensure!(
            p.takes.len() == 1 && p.takes[0].accepted,
            "plane {}: takes {:?}",
            p.plane,
            p.takes
        );
    }
    // As in `streaming`: vivid's end-of-frame stamps lie 0.9 nominal periods after the frame's
    // (jittery) start, so neighbours may overlap by a little (up to half under a loaded TCG).
    let kept: Vec<(Nanos, Nanos)> = s
        .planes
        .iter()
        .map(|p| (p.takes[0].exposure_start_ns, p.takes[0].exposure_end_ns))
        .collect();
    for w in kept.windows(2) {
        let len = w[0].1 - w[0].0;
        ensure!(
            w[1].0 > w[0].0 && w[1].0 >= w[0].1 - len / 2,
            "sweep frames overlap: [{}, {}] then [{}, {}]",
            w[0].0,
            w[0].1,
            w[1].0,
            w[1].1
        );
    }
    let lumas: Vec<f64> = s.frames.iter().map(mean_luma).collect();
    ensure!(
        lumas.windows(2).all(|w| w[0] > w[1] + 5.0),
        "mean luma over the planes {lumas:.1?} does not fall with the brightness {got:?}"
    );
    ensure!(
        cam.capture().is_err(),
        "the sweep did not release the camera"
    );
    ok(format!(
        "sweep: 4 planes at {got:?} (nearest first), every take accepted, mean luma {lumas:.0?} \
         falling with the lens position, camera released"
    ));
    Ok(())
}

/// Waits up to `within` for `ring` to satisfy `done`; says what it saw last otherwise.
fn await_ring(
    ring: &RingReader,
    within: Duration,
    what: &str,
    done: impl Fn(&RingReader) -> bool,
) -> Check {
    let end = Instant::now() + within;
    while !done(ring) {
        ensure!(
            Instant::now() < end,
            "{what}: not within {within:?} (state {:?}, sequence {})",
            ring.state(),
            ring.sequence()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

/// The daemon's live preview on the camera, without the bus: with a 1280x720 capture
/// configured, the preview streams `format` at vivid's 640x360 and its frames, of size `want`,
/// arrive in the ring; the camera is the preview's; a capture takes the camera (the preview
/// pauses, its sequence stops) and gives it back (the preview resumes); the last client
/// leaving closes the camera.
fn live_preview(node: &Path, format: &str, want: (usize, usize)) -> Check {
    let config = Config {
        camera: cfg(node, Some(format), (1280, 720)),
        ..Config::default()
    };
    let opener = config.clone();
    let preview = Preview::new(move || preview::open_source(&opener, &Source::Device));
    let fd = preview
        .start(":1.1", Duration::from_secs(600))
        .map_err(|e| format!("StartPreview: {e}"))?;
    let ring = RingReader::new(&fd).map_err(|e| format!("the preview's ring: {e}"))?;
    let started = Instant::now();
    await_ring(&ring, Duration::from_secs(30), "5 preview frames", |r| {
        r.sequence() >= 5
    })?;
    let rate = ring.sequence() as f64 / started.elapsed().as_secs_f64();
    ensure!(
        ring.state() == Some(State::Running),
        "state {:?} while streaming",
        ring.state()
    );
    let f = ring
        .latest()
        .ok_or("no frame in the ring after 5 were published")?;
    let img = Image::from_vec(
        f.width as usize,
        f.height as usize,
        3,
        f.pixels
            .chunks(f.stride as usize)
            .flat_map(|row| &row[..f.width as usize * 3])
            .copied()
            .collect(),
    );
    ensure!(
        (img.width(), img.height()) == want,
        "{format} preview frame {}x{}, expected {want:?}",
        img.width(),
        img.height()
    );
    let bars = colour_bars(&img).map_err(|e| format!("preview frame: {e}"))?;
    ensure!(
        v4l2::open(&config.camera).is_err(),
        "the camera opened beside the running preview: the preview does not hold it"
    );

    // A capture: the preview hands the camera over and pauses.
    let hold = preview.hold_camera();
    ensure!(
        ring.state() == Some(State::Paused),
        "state {:?} while held",
        ring.state()
    );
    let paused_at = ring.sequence();
    let mut cam = open(&config.camera)?;
    let mut takes = 0;
    while takes < 4 {
        capture(&mut cam)?;
        takes += 1;
    }
    cam.release().map_err(|e| format!("release: {e}"))?;
    drop(cam);
    ensure!(
        ring.sequence() == paused_at,
        "the preview published {} frames while the capture held the camera",
        ring.sequence() - paused_at
    );
    drop(hold);
    await_ring(
        &ring,
        Duration::from_secs(30),
        "the preview resuming",
        |r| r.sequence() >= paused_at + 3 && r.state() == Some(State::Running),
    )?;

    // The last client leaves: the preview stops and closes the camera.
    ensure!(preview.leave(":1.1", "left"), "the client was not known");
    await_ring(
        &ring,
        Duration::from_secs(10),
        "the preview stopping",
        |r| r.state() == Some(State::Stopped),
    )?;
    let mut cam = open(&config.camera).map_err(|e| format!("after the preview stopped: {e}"))?;
    capture(&mut cam)?;
    cam.release().map_err(|e| format!("release: {e}"))?;
    ok(format!(
        "live preview of {format}: frames in the ring ({rate:.1}/s, {want:?}, colour bars \
         {bars:?}), camera \
         refused to others; paused at frame {paused_at} through 4 captures, resumed after; \
         stopped with its last client, camera free"
    ));
    Ok(())
}

fn busy(node: &Path) -> Check {
    let mut first = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    capture(&mut first)?;
    let msg = match v4l2::open(&cfg(node, Some("YUYV"), (640, 480))) {
        Ok(_) => return Err("a second camera opened while the first streams".into()),
        Err(e) => e.to_string(),
    };
    ensure!(
        msg.contains("another program"),
        "a second open while streaming: {msg}"
    );
    capture(&mut first)?;
    first.release().map_err(|e| format!("release: {e}"))?;
    ok(format!("a second open while streaming is refused: {msg}"));
    Ok(())
}

fn timeout(node: &Path, info: &Info, raw: &Device) -> Check {
    let drop_pct = info.control("Percentage of Dropped Buffers")?.id;
    let c = V4l2Config {
        frame_timeout_ms: 700,
        ..cfg(node, Some("YUYV"), (640, 480))
    };
    let mut cam = open(&c)?;
    capture(&mut cam)?;
    set(raw, drop_pct, 100)?;
    // Frames already filled before the drops began may still come out of the queue (at most
    // one per buffer); after them the stream must time out.
    let mut r = cam.capture();
    let mut in_flight = 0;
    while r.is_ok() && in_flight < c.buffers {
        in_flight += 1;
        r = cam.capture();
    }
    set(raw, drop_pct, 0)?;
    match r {
        Err(e @ CaptureError::Timeout { ms: 700, .. }) => ok(format!(
            "a stalled stream times out ({in_flight} frame(s) filled before it): {e}"
        )),
        Err(e) => return Err(format!("a stalled stream: expected a timeout, got: {e}")),
        Ok(_) => {
            return Err(format!(
                "a stalled stream delivered {} frames, more than its {} buffers",
                in_flight + 1,
                c.buffers
            ))
        }
    }
    let t = cam
        .capture()
        .map_err(|e| format!("capture after a timeout, the stream running again: {e}"))?;
    ensure!(
        t.exposure_start < t.exposure_end,
        "bad window after a timeout"
    );
    cam.release().map_err(|e| format!("release: {e}"))?;
    ok("capture works again once the stream resumes after a timeout");
    Ok(())
}

fn error_frames(node: &Path, info: &Info, raw: &Device) -> Check {
    let press = || press(raw, info, "Inject V4L2_BUF_FLAG_ERROR");
    // The driver's side: the next buffer comes back flagged.
    {
        let mut s = raw_stream(node, info)?;
        raw_frame(&mut s)?;
        press()?;
        let (flags, _) = raw_frame(&mut s)?;
        ensure!(
            flags & abi::BUF_FLAG_ERROR != 0,
            "vivid did not flag the buffer after the injection: 0x{flags:08x}"
        );
    }
    // The backend skips it: the frame after the flagged one comes back, a period later.
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    capture(&mut cam)?;
    let b = capture(&mut cam)?;
    // The window is one frame interval long (vivid has no exposure control).
    let period = b.exposure_end - b.exposure_start;
    press()?;
    let c = capture(&mut cam)?;
    let gap = c.exposure_start - b.exposure_start;
    cam.release().map_err(|e| format!("release: {e}"))?;
    ensure!(
        gap > period * 3 / 2,
        "after an injected buffer error the next frame began {} ms after the previous one, \
         one period ({} ms): the corrupt frame was returned",
        gap / MS,
        period / MS
    );
    ok(format!(
        "a buffer flagged V4L2_BUF_FLAG_ERROR is skipped (next frame {} ms later, frame interval {} ms)",
        gap / MS,
        period / MS
    ));
    Ok(())
}

fn disconnect(node: &Path, info: &Info, raw: &Device) -> Check {
    let mut cam = open(&cfg(node, Some("YUYV"), (640, 480)))?;
    cam.focus(0, 10).map_err(|e| format!("focus: {e}"))?;
    capture(&mut cam)?;
    press(raw, info, "Disconnect")?;
    let e = match cam.capture() {
        Ok(_) => return Err("a frame came after the device was disconnected".into()),
        Err(e) => e.to_string(),
    };
    ensure!(
        e.contains("went away"),
        "capture after a disconnect: {e} (expected it to say the device went away)"
    );
    let r = cam
        .release()
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    drop(cam);
    ok(format!(
        "a disconnect mid-stream: capture fails with {e:?}; release: {r:?}; no panic"
    ));
    Ok(())
}
