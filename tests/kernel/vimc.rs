//! The media-controller path against the kernel's vimc test driver: run inside a VM by
//! `tests/kernel/run-vimc` (vimc built out of tree; any machine with `modprobe vimc`, as root).
//!
//! `vimc` (no arguments). One `ok: ...` line per passed check, `FAIL: ...` at the first failed
//! one, then `VIMC-RESULT: PASS` or `VIMC-RESULT: FAIL` (exit status 0 or 1). Checks, in order
//! (the first needs vimc as loaded, unconfigured):
//! - an unconfigured pipeline fails to stream with EPIPE, and the error says why;
//! - profiles that do not match the graph fail naming the link or the pad;
//! - with no profile configured, vimc's is chosen by its media model and streams;
//! - with Debayer B's link into the scaler enabled instead of Debayer A's, the profile's link
//!   replaces it (the other enabled link into the same pad is disabled first) and streams;
//! - the shipped `vimc` profile streams RGB through debayer and scaler, a variant of it the raw
//!   Bayer path, another a scaled frame, each printing how far apart its takes came;
//! - Sensor A set to GRBG, BGGR and GBRG at run time: focusd takes each order from the sensor,
//!   and its own demosaic of the raw node's frames gives the test pattern's colour bars;
//! - the lens is found through the graph (Lens A, ancillary link to Sensor A), swept across a
//!   whole capture with its position read back at every plane, its node held open by the same
//!   descriptor throughout, and restored; the IMU is a fake IIO tree polled on the guest's
//!   monotonic clock.

use focusd::backend::iio::{IioConfig, IioImu, Mode};
use focusd::backend::sys::{monotonic_now, MonotonicClock};
use focusd::backend::v4l2::pipeline;
use focusd::backend::v4l2::profile::{LinkSpec, Names, PadRef, PadSpec, Profile};
use focusd::backend::v4l2::{self, V4l2Camera, V4l2Config};
use focusd::backend::videodev::abi::{
    MbusFramefmt, CID_FOCUS_ABSOLUTE, FIELD_NONE, MEDIA_LNK_FL_ENABLED,
};
use focusd::backend::videodev::media::{self, Topology};
use focusd::backend::videodev::subdev;
use focusd::backend::videodev::{BufType, Device};
use focusd::capture::sweep::{sweep, SweepConfig, Unmonitored};
use focusd::capture::{Camera, CaptureError, Frame, Imu, Sensor, Take};
use focusd::develop::{BayerOrder, Developer, StackDeveloper, IDENTITY};
use focusd::stack::Image;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[macro_use]
mod support;
use support::{ok, report, Check};

const TMP: &str = "/tmp/focusd-vimc";

fn main() {
    report("VIMC", run);
}

fn run() -> Check {
    fs::create_dir_all(TMP).map_err(|e| format!("{TMP}: {e}"))?;
    unconfigured()?;
    mismatches()?;
    detected()?;
    rival_link()?;
    let rgb = streams("RGB through debayer and scaler", shipped()?, (640, 480))?;
    let mut raw = shipped()?;
    raw.capture = "Raw Capture 0".into();
    raw.format.fourcc = "BAYER8".into();
    streams("raw Bayer (the sensor's order)", raw, (640, 480))?;
    bayer_orders()?;
    let mut scaled = shipped()?;
    scaled.pads.last_mut().expect("pads").width = Some(320);
    scaled.pads.last_mut().expect("pads").height = Some(240);
    streams("RGB scaled to 320x240", scaled, (320, 240))?;
    lens_sweep(&rgb)
}

fn shipped() -> Result<Profile, String> {
    Profile::load("vimc")
}

/// The device node whose sysfs name is `name`.
fn node(name: &str) -> Result<PathBuf, String> {
    let dir = Path::new("/sys/class/video4linux");
    let entries = fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for e in entries.flatten() {
        let n = fs::read_to_string(e.path().join("name")).unwrap_or_default();
        if n.trim() == name {
            return Ok(Path::new("/dev").join(e.file_name()));
        }
    }
    Err(format!("no video4linux node is named {name:?}"))
}

/// A profile written to a file, as a user would give it.
fn write_profile(p: &Profile, file: &str) -> Result<String, String> {
    let path = format!("{TMP}/{file}.toml");
    let text = toml::to_string(p).map_err(|e| format!("serialising the profile: {e}"))?;
    fs::write(&path, text).map_err(|e| format!("{path}: {e}"))?;
    Ok(path)
}

fn cfg(profile: Option<String>) -> V4l2Config {
    V4l2Config {
        profile,
        ..V4l2Config::default()
    }
}

fn capture(cam: &mut V4l2Camera) -> Result<Take, String> {
    cam.capture().map_err(|e| format!("capture: {e}"))
}

/// A take's picture: raw takes developed as after a sweep.
fn picture(t: Take, stack: &mut StackDeveloper) -> Result<Image<u8>, String> {
    match t.frame {
        Frame::Picture(img) => Ok(img),
        Frame::Raw(raw) => stack.develop(&raw),
    }
}

fn luma_spread(img: &Image<u8>) -> f64 {
    let l: Vec<f64> = img
        .data()
        .chunks_exact(3)
        .map(|p| 0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2]))
        .collect();
    let mean = l.iter().sum::<f64>() / l.len() as f64;
    (l.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / l.len() as f64).sqrt()
}

// ---------------------------------------------------------------------------------------------

fn unconfigured() -> Check {
    let c = V4l2Config {
        device: Some(node("Raw Capture 0")?),
        // Unset, the vimc profile would be chosen by the media model and set the graph up.
        profile: Some("none".into()),
        lens: Some("Lens A".into()),
        format: Some("RGGB".into()),
        width: 640,
        height: 480,
        ..V4l2Config::default()
    };
    let mut cam = v4l2::open(&c).map_err(|e| format!("open without a profile: {e}"))?;
    let e = match cam.capture() {
        Ok(_) => return Err("an unconfigured vimc pipeline streamed".into()),
        Err(e) => e.to_string(),
    };
    ensure!(
        e.contains("os error 32") && e.contains("media pipeline cannot stream"),
        "unconfigured: expected EPIPE with the reason, got: {e}"
    );
    cam.release().map_err(|e| format!("release: {e}"))?;
    ok(format!("an unconfigured pipeline does not stream: {e}"));
    Ok(())
}

fn expect_error(p: &Profile, file: &str, want: &str) -> Check {
    let path = write_profile(p, file)?;
    match v4l2::open(&cfg(Some(path))) {
        Ok(_) => Err(format!(
            "profile {file} opened; expected an error with {want:?}"
        )),
        Err(e) => {
            let msg = e.to_string();
            ensure!(
                msg.contains(want),
                "profile {file}: expected {want:?} in the error, got: {msg}"
            );
            ok(format!("profile {file}: {msg}"));
            Ok(())
        }
    }
}

fn mismatches() -> Check {
    let mut p = shipped()?;
    p.links.push(LinkSpec {
        source: PadRef("Sensor A".into(), 0),
        sink: PadRef("Scaler".into(), 0),
    });
    expect_error(
        &p,
        "no-such-link",
        "link \"Sensor A\":0 -> \"Scaler\":0: the graph has no such link",
    )?;
    let mut p = shipped()?;
    p.pads[0].pad = PadRef("Sensor Z".into(), 0);
    expect_error(
        &p,
        "no-such-entity",
        "pad \"Sensor Z\":0: no entity is named \"Sensor Z\"",
    )?;
    let mut p = shipped()?;
    p.pads.push(PadSpec {
        pad: PadRef("Scaler".into(), 1),
        code: "YUYV8_2X8".into(),
        width: None,
        height: None,
        crop: None,
    });
    expect_error(
        &p,
        "wrong-code",
        "pad \"Scaler\":1: asked for YUYV8_2X8/640x480, the driver set RGB888_1X24/640x480",
    )?;
    let mut p = shipped()?;
    p.sensor = Names::One("imx258".into());
    expect_error(
        &p,
        "other-sensor",
        "(\"VIMC MDEV\", but sensor \"imx258\": no entity is named \"imx258\"",
    )?;
    let mut p = shipped()?;
    p.media_model = "rkisp1".into();
    expect_error(
        &p,
        "other-device",
        "no media device has the model \"rkisp1\"",
    )
}

/// With no profile in the config, vimc's is chosen by its media model and streams.
fn detected() -> Check {
    let choice = v4l2::detect::detect(Path::new("/sys"))
        .map_err(|e| format!("detect: {e}"))?
        .ok_or("no profile chosen for vimc")?;
    ensure!(
        choice.profile.name == "vimc" && choice.reason == "the media device model \"VIMC MDEV\"",
        "chose {} by {}",
        choice.profile.name,
        choice.reason
    );
    let order = raw_node_follows_sensor()?;
    let mut cam = v4l2::open(&cfg(None)).map_err(|e| format!("open, profile chosen: {e}"))?;
    let take = picture(capture(&mut cam)?, &mut StackDeveloper::default())?;
    cam.release().map_err(|e| format!("release: {e}"))?;
    ensure!(
        (take.width(), take.height()) == (640, 480),
        "the chosen profile captured {}x{}",
        take.width(),
        take.height()
    );
    ok(format!(
        "no profile configured: {} chosen by {}, streams 640x480 (Sensor A in {order})",
        choice.profile.name, choice.reason
    ));
    Ok(())
}

/// vimc 6.1 validates every enabled link of the graph before streaming, so Raw Capture 0's
/// format must match Sensor A's code even when capturing RGB; vimc's sensor offers every
/// order, and from an RGB format focusd takes the first 8-bit Bayer code it lists. Sets Raw
/// Capture 0 to that order (what another program would have had to do), and names it.
fn raw_node_follows_sensor() -> Result<String, String> {
    let sensor = node("Sensor A")?;
    let s = Device::open(&sensor).map_err(|e| format!("{}: {e}", sensor.display()))?;
    let codes = subdev::codes(&s, 0).map_err(|e| format!("Sensor A's codes: {e}"))?;
    let current = subdev::format(&s, 0).ok().map(|f| f.code);
    let code = v4l2::sensor::choose_code(&codes, current, 8)?;
    let (order, bits) = v4l2::sensor::bayer_of(code).ok_or("not a Bayer code")?;
    let fourcc = v4l2::sensor::capture_format(order, bits).fourcc();
    let raw = node("Raw Capture 0")?;
    Device::open(&raw)
        .and_then(|d| d.set_format(BufType::Capture, 640, 480, fourcc))
        .map_err(|e| format!("{}: {e}", raw.display()))?;
    Ok(v4l2::profile::mbus_name(code))
}

/// vimc's media device and its graph.
fn vimc_media() -> Result<(Device, Topology), String> {
    let entries = fs::read_dir("/dev").map_err(|e| format!("/dev: {e}"))?;
    for e in entries.flatten() {
        if !e.file_name().to_string_lossy().starts_with("media") {
            continue;
        }
        let Ok(dev) = Device::open(&e.path()) else {
            continue;
        };
        if media::info(&dev).is_ok_and(|i| i.model == "VIMC MDEV") {
            let topo = media::topology(&dev).map_err(|e| format!("topology: {e}"))?;
            return Ok((dev, topo));
        }
    }
    Err("no media device has the model \"VIMC MDEV\"".into())
}

/// A link's end: an entity and its pad's index.
type End = (u32, u16);

/// The data link from `source`'s pad 1 into the scaler's pad 0: (its ends, whether enabled).
fn into_scaler(topo: &Topology, source: &str) -> Result<(End, End, bool), String> {
    let entity = |name: &str| {
        topo.entities
            .iter()
            .find(|e| e.name == name)
            .map(|e| e.id)
            .ok_or(format!("no entity {name:?}"))
    };
    let pad = |entity: u32, index: u32| {
        topo.pads
            .iter()
            .find(|p| p.entity == entity && p.index == index)
            .map(|p| p.id)
            .ok_or(format!("entity {entity} has no pad {index}"))
    };
    let (src, sca) = (entity(source)?, entity("Scaler")?);
    let (src_pad, sca_pad) = (pad(src, 1)?, pad(sca, 0)?);
    let link = topo
        .links
        .iter()
        .find(|l| l.source == src_pad && l.sink == sca_pad)
        .ok_or(format!("no link {source}:1 -> Scaler:0"))?;
    Ok(((src, 1), (sca, 0), link.flags & MEDIA_LNK_FL_ENABLED != 0))
}

fn rival_link() -> Check {
    let (dev, topo) = vimc_media()?;
    let (a, scaler, _) = into_scaler(&topo, "Debayer A")?;
    let (b, _, _) = into_scaler(&topo, "Debayer B")?;
    media::setup_link(&dev, a, scaler, false).map_err(|e| format!("disable A: {e}"))?;
    media::setup_link(&dev, b, scaler, true).map_err(|e| format!("enable B: {e}"))?;
    let (_, after) = vimc_media()?;
    ensure!(
        !into_scaler(&after, "Debayer A")?.2 && into_scaler(&after, "Debayer B")?.2,
        "could not switch the scaler's input to Debayer B"
    );
    streams("RGB after Debayer B fed the scaler", shipped()?, (640, 480))?;
    let (_, after) = vimc_media()?;
    ensure!(
        into_scaler(&after, "Debayer A")?.2 && !into_scaler(&after, "Debayer B")?.2,
        "the profile left Debayer B's link into the scaler enabled"
    );
    ok("the profile's link replaced Debayer B's enabled link into the scaler");
    Ok(())
}

/// Streams three frames with `profile`; returns its file path.
fn streams(what: &str, profile: Profile, size: (usize, usize)) -> Result<String, String> {
    let path = write_profile(&profile, &what.replace([' ', '(', ')'], "-"))?;
    let mut cam = v4l2::open(&cfg(Some(path.clone()))).map_err(|e| format!("{what}: open: {e}"))?;
    let d = cam.describe();
    let mut spreads = Vec::new();
    let mut stack = StackDeveloper::default();
    let (mut takes, mut apart) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        let t0 = Instant::now();
        takes.push(capture(&mut cam).map_err(|e| format!("{what}: {e}"))?);
        apart.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    // Developed once the takes are in, as after a sweep.
    for t in takes {
        let t = picture(t, &mut stack).map_err(|e| format!("{what}: {e}"))?;
        ensure!(
            (t.width(), t.height()) == size,
            "{what}: frame {}x{}, expected {size:?}",
            t.width(),
            t.height()
        );
        spreads.push(luma_spread(&t));
    }
    cam.release().map_err(|e| format!("{what}: release: {e}"))?;
    ensure!(
        spreads.iter().all(|&s| s > 20.0),
        "{what}: flat frames (luma spread {spreads:.1?}): not the test pattern"
    );
    ok(format!(
        "{what}: {d}: 3 frames of {size:?} with the test pattern (luma spread {spreads:.0?}), \
         takes {apart:.0?} ms apart"
    ));
    Ok(path)
}

/// Sets Sensor A to several Bayer orders at run time (as `media-ctl -V` would), then captures
/// from the raw node with the raw profile: focusd must take each order from the sensor and its
/// demosaic must give the 75% colour bars (white, yellow, cyan, green, magenta, red, blue,
/// black; v4l2-tpg-core.c's `bars[0]`) their colours.
fn bayer_orders() -> Check {
    let sensor = node("Sensor A")?;
    let dev = Device::open(&sensor).map_err(|e| format!("{}: {e}", sensor.display()))?;
    let mut raw = shipped()?;
    raw.capture = "Raw Capture 0".into();
    raw.format.fourcc = "BAYER8".into();
    let path = write_profile(&raw, "orders")?;
    const BARS: [[bool; 3]; 8] = [
        [true, true, true],
        [true, true, false],
        [false, true, true],
        [false, true, false],
        [true, false, true],
        [true, false, false],
        [false, false, true],
        [false, false, false],
    ];
    for (name, code, order) in [
        ("SGRBG8_1X8", 0x3002, BayerOrder::Grbg),
        ("SBGGR8_1X8", 0x3001, BayerOrder::Bggr),
        ("SGBRG8_1X8", 0x3013, BayerOrder::Gbrg),
    ] {
        let f = MbusFramefmt {
            code,
            width: 640,
            height: 480,
            field: FIELD_NONE,
            ..MbusFramefmt::default()
        };
        subdev::set_format(&dev, 0, f).map_err(|e| format!("setting Sensor A to {name}: {e}"))?;
        let mut cam =
            v4l2::open(&cfg(Some(path.clone()))).map_err(|e| format!("{name}: open: {e}"))?;
        let d = cam.describe();
        let take = capture(&mut cam).map_err(|e| format!("{name}: {e}"))?;
        cam.release().map_err(|e| format!("{name}: release: {e}"))?;
        let Frame::Raw(r) = take.frame else {
            return Err(format!("{name}: the raw node gave a converted frame"));
        };
        ensure!(
            r.order == order,
            "{name}: focusd took the order {:?}",
            r.order
        );
        // Unit gains: grey-world would pull the bars towards grey.
        let mut dev = Developer {
            white_balance: Some([1.0; 3]),
            ..Developer::new(0, IDENTITY)
        };
        let img = dev.develop(r.mosaic().map_err(|e| format!("{name}: {e}"))?);
        let mut seen = Vec::new();
        for (i, want) in BARS.iter().enumerate() {
            let bar = img.width() / 8;
            let (x0, y0) = (i * bar + bar / 4, img.height() / 2 - 20);
            let mut mean = [0.0f64; 3];
            for y in y0..y0 + 40 {
                for x in x0..x0 + bar / 2 {
                    for (c, m) in mean.iter_mut().enumerate() {
                        *m += f64::from(img.at(x, y, c));
                    }
                }
            }
            let n = (40 * (bar / 2)) as f64;
            let mean = mean.map(|m| m / n);
            seen.push(mean.map(|m| m.round() as u8));
            let right = (0..3).all(|c| {
                if want[c] {
                    mean[c] > 128.0
                } else {
                    mean[c] < 64.0
                }
            });
            ensure!(
                right,
                "{name}: bar {i} is {mean:.0?}, expected high channels {want:?}"
            );
        }
        ok(format!(
            "{name} set at run time: {d}: focusd took {order:?} and its demosaic gives the 8 \
             colour bars {seen:?}"
        ));
    }
    Ok(())
}

/// A fake IIO device at rest, polled: its samples are stamped when read, on this machine's
/// CLOCK_MONOTONIC, the clock of the V4L2 buffers.
fn fake_imu() -> Result<IioConfig, String> {
    let sys = PathBuf::from(TMP).join("sys");
    let d = sys.join("bus/iio/devices/iio:device0");
    fs::create_dir_all(&d).map_err(|e| format!("{}: {e}", d.display()))?;
    fs::create_dir_all(PathBuf::from(TMP).join("dev")).map_err(|e| e.to_string())?;
    let files = [
        ("name", "fakeimu"),
        ("in_anglvel_x_raw", "0"),
        ("in_anglvel_y_raw", "0"),
        ("in_anglvel_z_raw", "0"),
        ("in_anglvel_scale", "0.001"),
        ("in_accel_x_raw", "0"),
        ("in_accel_y_raw", "1000"),
        ("in_accel_z_raw", "0"),
        ("in_accel_scale", "0.00981"),
        ("sampling_frequency", "100"),
    ];
    for (f, v) in files {
        fs::write(d.join(f), format!("{v}\n")).map_err(|e| format!("{f}: {e}"))?;
    }
    Ok(IioConfig {
        sysfs_root: sys,
        mode: Mode::Poll,
        ..IioConfig::default()
    })
}

/// The camera with the lens position read back from the lens sub-device after every move,
/// and the descriptors this process holds on the lens node at each move.
struct ReadBack {
    cam: V4l2Camera,
    lens: Device,
    lens_node: PathBuf,
    seen: Vec<(i32, i64)>,
    open: Vec<Vec<String>>,
}

/// This process's file descriptors open on `node` (a lens the camera closed and reopened
/// between moves would be powered down between them: the dw9714's runtime PM).
fn fds_on(node: &Path) -> Vec<String> {
    let mut fds: Vec<String> = fs::read_dir("/proc/self/fd")
        .map(|d| {
            d.flatten()
                .filter(|e| fs::read_link(e.path()).is_ok_and(|t| t == node))
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    fds.sort();
    fds
}

impl Camera for ReadBack {
    fn lens_range(&self) -> (i32, i32) {
        self.cam.lens_range()
    }

    fn focus(&mut self, plane: usize, position: i32) -> Result<(), CaptureError> {
        self.cam.focus(plane, position)?;
        let now = self
            .lens
            .control(CID_FOCUS_ABSOLUTE)
            .map_err(|e| CaptureError::device("Lens A", e.to_string()))?;
        self.seen.push((position, now));
        self.open.push(fds_on(&self.lens_node));
        Ok(())
    }

    fn capture(&mut self) -> Result<Take, CaptureError> {
        self.cam.capture()
    }

    fn release(&mut self) -> Result<(), CaptureError> {
        self.cam.release()
    }
}

fn lens_sweep(profile: &str) -> Check {
    let lens_node = node("Lens A")?;
    let lens = Device::open(&lens_node).map_err(|e| format!("{}: {e}", lens_node.display()))?;
    let before = 300;
    lens.set_control(CID_FOCUS_ABSOLUTE, before)
        .map_err(|e| format!("setting Lens A: {e}"))?;
    let cam = v4l2::open(&cfg(Some(profile.to_string()))).map_err(|e| format!("open: {e}"))?;
    let d = cam.describe();
    ensure!(
        d.contains(&format!(
            "lens {} control 0x009a090a 0..=1023",
            lens_node.display()
        )),
        "the lens is not Lens A's node {} with FOCUS_ABSOLUTE 0..=1023: {d}",
        lens_node.display()
    );
    let graph = pipeline::apply(&shipped()?, Path::new("/sys")).map_err(|e| e.to_string())?;
    ensure!(
        graph.lens.as_ref() == Some(&lens_node),
        "the graph's lens for Sensor A is {:?}, not Lens A's node {}",
        graph.lens,
        lens_node.display()
    );
    ok(format!(
        "the lens through the graph (ancillary link from Sensor A): {d}"
    ));

    let mut imu = IioImu::open(&fake_imu()?).map_err(|e| format!("fake IMU: {e}"))?;
    std::thread::sleep(std::time::Duration::from_millis(100));
    let now = monotonic_now();
    let samples = imu
        .samples(now - 50_000_000, now)
        .map_err(|e| format!("IMU samples: {e}"))?;
    ensure!(
        samples.iter().any(|s| s.sensor == Sensor::Gyro)
            && samples.iter().all(|s| (s.t - now).abs() < 200_000_000),
        "IMU samples are not on the monotonic clock around {now}: {:?}",
        samples.first()
    );
    ok(format!(
        "fake IIO IMU polled on CLOCK_MONOTONIC: {} samples in the last 50 ms",
        samples.len()
    ));

    let before_sweep = fds_on(&lens_node);
    let mut rb = ReadBack {
        cam,
        lens,
        lens_node: lens_node.clone(),
        seen: Vec::new(),
        open: Vec::new(),
    };
    let sc = SweepConfig {
        planes: 5,
        still_ms: 40,
        still_timeout_ms: 3000,
        ..SweepConfig::default()
    };
    let s = sweep(&mut rb, &mut imu, &MonotonicClock, &sc, &Unmonitored)
        .map_err(|e| format!("sweep: {e}"))?;
    let planes: Vec<i32> = s.planes.iter().map(|p| p.lens).collect();
    ensure!(
        s.frames.len() == 5 && planes.len() == 5,
        "{} frames, {} planes; 5 asked",
        s.frames.len(),
        planes.len()
    );
    ensure!(
        planes.first() == Some(&1023) && planes.last() == Some(&0),
        "the sweep did not span the lens range: {planes:?}"
    );
    let moves: Vec<i32> = rb.seen.iter().map(|&(p, _)| p).collect();
    ensure!(
        rb.seen.iter().all(|&(p, v)| i64::from(p) == v),
        "the lens read back differs from the sweep: (asked, read) {:?}",
        rb.seen
    );
    let mut distinct = moves.clone();
    distinct.dedup();
    ensure!(
        distinct == planes,
        "lens moves {moves:?} are not the planes {planes:?}"
    );
    // The test's own descriptor and the camera's one, the same at every move as before it.
    ensure!(
        before_sweep.len() == 2 && rb.open.iter().all(|o| *o == before_sweep),
        "descriptors on the lens node: {before_sweep:?} before the sweep, {:?} at the moves",
        rb.open
    );
    ok(format!(
        "the lens node stays open across the sweep (descriptors {before_sweep:?} at all {} \
         moves)",
        rb.open.len()
    ));
    for t in s.planes.iter().flat_map(|p| &p.takes) {
        let (start, end) = (t.exposure_start_ns, t.exposure_end_ns);
        ensure!(
            start < end && end <= monotonic_now(),
            "frame window [{start}, {end}] is not in the past of CLOCK_MONOTONIC"
        );
    }
    let after = rb
        .lens
        .control(CID_FOCUS_ABSOLUTE)
        .map_err(|e| format!("reading Lens A: {e}"))?;
    ensure!(
        after == before,
        "after the sweep Lens A is at {after}, it was {before}"
    );
    ok(format!(
        "sweep of 5 planes at {planes:?}, Lens A read back at each ({:?}), restored to {before}",
        rb.seen
    ));
    Ok(())
}
