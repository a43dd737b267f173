//! The app as a person sees it: on a headless X server (Xvfb), against `focusd serve --replay`
//! on a private session bus. Its window's screenshots (kept under the target directory's
//! `tmp/viewfinder/`) show the bundle's reference frame in the preview, and a synthetic X click
//! on the shutter takes a stack whose picture appears as the thumbnail.
//!
//! Needs Xvfb, xdotool, xwd (x11-apps) and dbus-daemon, and the focusd binary built beside this
//! test (`cargo test --workspace` builds it).

use image::imageops::FilterType;
use image::{GrayImage, RgbImage};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const WIDTH: u32 = 360;
const HEIGHT: u32 = 720;

/// Children killed on drop, last started first; their logs are printed if the test failed.
#[derive(Default)]
struct Children(Vec<Child>, Vec<PathBuf>);

impl Drop for Children {
    fn drop(&mut self) {
        if std::thread::panicking() {
            for log in &self.1 {
                let text = std::fs::read_to_string(log).unwrap_or_default();
                eprintln!("--- {}:\n{text}", log.display());
            }
        }
        for c in self.0.iter_mut().rev() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn tool(name: &str, package: &str) -> Command {
    let found = Command::new("sh")
        .args(["-c", &format!("command -v {name}")])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        found,
        "{name} not found: install Debian's {package} package"
    );
    Command::new(name)
}

fn until<T>(what: &str, within: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let t = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(t.elapsed() < within, "never: {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The workspace's binaries sit beside the `deps/` folder this test runs from.
fn focusd_binary() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let bin = exe.parent().unwrap().parent().unwrap().join("focusd");
    assert!(
        bin.exists(),
        "{} is missing: build it first (cargo test --workspace does)",
        bin.display()
    );
    bin
}

/// A window's pixels through xwd (32-bit TrueColor, ZPixmap), as RGB.
fn screenshot(display: &str, window: &str) -> RgbImage {
    let o = tool("xwd", "x11-apps")
        .args(["-silent", "-id", window, "-display", display])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    decode_xwd(&o.stdout)
}

/// The X Window Dump format (X11/XWDFile.h): a header of 25 big-endian u32 fields, the window
/// name, a colour map of 12-byte entries, then the image.
fn decode_xwd(b: &[u8]) -> RgbImage {
    let field = |i: usize| u32::from_be_bytes(b[i * 4..i * 4 + 4].try_into().unwrap());
    let (header, format, depth, width, height) = (field(0), field(2), field(3), field(4), field(5));
    let (byte_order, bits_per_pixel, bytes_per_line) = (field(7), field(11), field(12));
    let (red_mask, colours) = (field(14), field(19));
    assert_eq!(
        (format, bits_per_pixel),
        (2, 32),
        "not a 32-bit ZPixmap (depth {depth})"
    );
    let pixels = &b[header as usize + 12 * colours as usize..];
    let red_shift = red_mask.trailing_zeros();
    RgbImage::from_fn(width, height, |x, y| {
        let at = (y * bytes_per_line + x * 4) as usize;
        let raw: [u8; 4] = pixels[at..at + 4].try_into().unwrap();
        let v = if byte_order == 0 {
            u32::from_le_bytes(raw)
        } else {
            u32::from_be_bytes(raw)
        };
        // TrueColor with 8 bits a channel: red at red_shift, then green and blue below it.
        let c = |shift: u32| ((v >> shift) & 0xff) as u8;
        image::Rgb([c(red_shift), c(red_shift - 8), c(red_shift - 16)])
    })
}

fn luma(img: &RgbImage) -> GrayImage {
    image::DynamicImage::ImageRgb8(img.clone()).to_luma8()
}

/// Normalised cross-correlation of two same-sized grey images.
fn correlation(a: &GrayImage, b: &GrayImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let n = a.len() as f64;
    let mean = |i: &GrayImage| i.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let (ma, mb) = (mean(a), mean(b));
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (&x, &y) in a.iter().zip(b.iter()) {
        let (x, y) = (f64::from(x) - ma, f64::from(y) - mb);
        ab += x * y;
        aa += x * x;
        bb += y * y;
    }
    ab / (aa * bb).sqrt().max(1e-9)
}

/// Where the preview is in a screenshot: the window's frame (lit, at the edges) is found on a
/// dark row above the preview, and the preview's rows are those with anything lit between.
fn preview_box(shot: &GrayImage) -> Option<(u32, u32, u32, u32)> {
    let (w, h) = shot.dimensions();
    let lit = |x: u32, y: u32| shot.get_pixel(x, y)[0] > 24;
    let y = h / 8;
    let left = (0..w / 2).find(|&x| !lit(x, y))?;
    let right = (w / 2..w).rev().find(|&x| !lit(x, y))?;
    let rows: Vec<u32> = (h / 8..h * 3 / 4)
        .filter(|&y| (left..=right).any(|x| lit(x, y)))
        .collect();
    let (top, bottom) = (*rows.first()?, *rows.last()?);
    Some((left, top, right - left + 1, bottom - top + 1))
}

/// The shutter's centre: the middle of the white disc on the window's centre column.
fn shutter_centre(shot: &GrayImage) -> Option<(u32, u32)> {
    let (w, h) = shot.dimensions();
    let rows: Vec<u32> = (h * 3 / 4..h)
        .filter(|&y| shot.get_pixel(w / 2, y)[0] > 240)
        .collect();
    Some((w / 2, (rows.first()? + rows.last()?) / 2))
}

fn crop(img: &RgbImage, x: u32, y: u32, w: u32, h: u32) -> RgbImage {
    image::imageops::crop_imm(img, x, y, w, h).to_image()
}

#[test]
fn the_preview_shows_the_reference_frame_and_the_shutter_takes_a_stack() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let bundle = root.join("sim-data/bundles/calm");
    let shots = Path::new(env!("CARGO_TARGET_TMPDIR")).join("viewfinder");
    std::fs::create_dir_all(&shots).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut children = Children::default();

    // A display of its own: Xvfb picks a free number and writes it to the pipe.
    let mut xvfb = tool("Xvfb", "xvfb")
        .args([
            "-displayfd",
            "1",
            "-screen",
            "0",
            "1024x768x24",
            "-nolisten",
            "tcp",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut number = String::new();
    BufReader::new(xvfb.stdout.take().unwrap())
        .read_line(&mut number)
        .unwrap();
    children.0.push(xvfb);
    let display = format!(":{}", number.trim());

    let mut bus = tool("dbus-daemon", "dbus")
        .args([
            "--session",
            "--nofork",
            "--print-address=1",
            "--address=unix:tmpdir=/tmp",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut address = String::new();
    BufReader::new(bus.stdout.take().unwrap())
        .read_line(&mut address)
        .unwrap();
    children.0.push(bus);
    let address = address.trim().to_string();

    // The daemon, paced so the stages are on screen for a while.
    let out = dir.path().join("out");
    let config = dir.path().join("focusd.toml");
    std::fs::write(&config, format!("[output]\ndir = {out:?}\n")).unwrap();
    let log = dir.path().join("serve.log");
    children.0.push(
        Command::new(focusd_binary())
            .args(["serve", "--paced", "--address", &address, "--replay"])
            .arg(&bundle)
            .arg("--config")
            .arg(&config)
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    children.1.push(log.clone());
    let serve_log = || std::fs::read_to_string(&log).unwrap_or_default();
    until("the daemon serving", Duration::from_secs(30), || {
        serve_log().contains("serving").then_some(())
    });

    let runtime = dir.path().join("runtime");
    std::fs::create_dir_all(&runtime).unwrap();
    let app_log = dir.path().join("app.log");
    children.0.push(
        Command::new(env!("CARGO_BIN_EXE_focusd-viewfinder"))
            .env("DISPLAY", &display)
            .env("DBUS_SESSION_BUS_ADDRESS", &address)
            .env("GDK_BACKEND", "x11")
            .env("GSK_RENDERER", "cairo")
            .env("XDG_RUNTIME_DIR", &runtime)
            .env("NO_AT_BRIDGE", "1")
            .env("LANG", "C.UTF-8")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&app_log).unwrap())
            .spawn()
            .unwrap(),
    );
    children.1.push(app_log.clone());
    let window = until("the window", Duration::from_secs(30), || {
        let o = Command::new("xdotool")
            .args(["search", "--onlyvisible", "--name", "^Viewfinder$"])
            .env("DISPLAY", &display)
            .output()
            .ok()?;
        let id = String::from_utf8_lossy(&o.stdout)
            .lines()
            .next()?
            .to_string();
        (!id.is_empty()).then_some(id)
    });

    // The preview: the calm bundle's reference frame (frame_02.jpg, 480x360, landscape)
    // fitted to the window's width and centred, scaled to the size it has on screen.
    let reference = image::open(bundle.join("frame_02.jpg")).unwrap().to_rgb8();
    let (shot, r, at) = until("the preview on screen", Duration::from_secs(20), || {
        let shot = screenshot(&display, &window);
        // Kept as it is, for a look when the preview never comes.
        shot.save(shots.join("preview.png")).unwrap();
        if shot.dimensions() != (WIDTH, HEIGHT) {
            return None;
        }
        let (x, y, w, h) = preview_box(&luma(&shot))?;
        // The frame's shape, within a pixel: it is neither cropped nor stretched.
        let expected_h = w as f64 * 360.0 / 480.0;
        if (h as f64 - expected_h).abs() > 2.0 {
            return None;
        }
        let expected = luma(&image::imageops::resize(
            &reference,
            w,
            h,
            FilterType::Triangle,
        ));
        let r = correlation(&luma(&crop(&shot, x, y, w, h)), &expected);
        (r >= 0.9).then_some((shot, r, (x, y, w, h)))
    });
    eprintln!("preview at {at:?} against the reference frame: correlation {r:.3}");
    let (x, y) = shutter_centre(&luma(&shot)).expect("no shutter on screen");
    // The bottom row is three equal thirds within 24 px margins: the thumbnail is centred in
    // the first.
    let third = (at.2 - 2 * 24) / 3;
    let thumbnail = (x - third, y);

    // The shutter: a synthetic click at its centre.
    let click = Command::new("xdotool")
        .args([
            "mousemove",
            "--window",
            &window,
            &x.to_string(),
            &y.to_string(),
            "click",
            "1",
        ])
        .env("DISPLAY", &display)
        .status()
        .unwrap();
    assert!(click.success());
    // Mid-job: the stage on top, the preview paused.
    until("a stage on screen", Duration::from_secs(20), || {
        serve_log().contains("capture requested").then_some(())
    });
    std::thread::sleep(Duration::from_millis(700));
    screenshot(&display, &window)
        .save(shots.join("stage.png"))
        .unwrap();
    let picture = until("the fused picture", Duration::from_secs(90), || {
        std::fs::read_dir(&out)
            .ok()?
            .flatten()
            .map(|e| e.path())
            .find(|p| p.extension().is_some_and(|x| x == "jpg"))
    });
    // The thumbnail (the picture fitted into 64x64, centred in the bottom row's first third)
    // shows it; its middle 48x48, the picture's middle square, is compared.
    let fused = image::open(&picture).unwrap().to_rgb8();
    let (fw, fh) = fused.dimensions();
    let side = fw.min(fh);
    let cover = crop(&fused, (fw - side) / 2, (fh - side) / 2, side, side);
    // At 16x16: GTK scales a thumbnail with a filter of its own, and the finest texture of a
    // 64-pixel picture says more about that filter than about which picture it is.
    let expected = luma(&image::imageops::resize(
        &cover,
        16,
        16,
        FilterType::Triangle,
    ));
    let (_, r) = until("the thumbnail", Duration::from_secs(20), || {
        let shot = screenshot(&display, &window);
        shot.save(shots.join("result.png")).unwrap();
        let (tx, ty) = thumbnail;
        let seen = crop(&shot, tx - 24, ty - 24, 48, 48);
        let seen = image::imageops::resize(&seen, 16, 16, FilterType::Triangle);
        let r = correlation(&luma(&seen), &expected);
        (r >= 0.8).then_some((shot, r))
    });
    eprintln!("thumbnail against the picture: correlation {r:.3}");

    // Landscape: the controls move to a column right of the picture, off it. On the middle
    // row, from the right: the shutter's white disc, its grey ring, a dark gap, then the
    // picture (480x360 fitted to the window's height), which ends right of the middle.
    let turned = Command::new("xdotool")
        .args([
            "windowsize",
            &window,
            &HEIGHT.to_string(),
            &WIDTH.to_string(),
        ])
        .env("DISPLAY", &display)
        .status()
        .unwrap();
    assert!(turned.success());
    let (ring, picture_end) = until("the landscape layout", Duration::from_secs(20), || {
        let shot = screenshot(&display, &window);
        shot.save(shots.join("landscape.png")).unwrap();
        if shot.dimensions() != (HEIGHT, WIDTH) {
            return None;
        }
        let shot = luma(&shot);
        let y = WIDTH / 2;
        let at = |x: u32| shot.get_pixel(x, y)[0];
        let disc = (0..HEIGHT).rev().find(|&x| at(x) > 240)?;
        let disc_left = (0..disc).rev().find(|&x| at(x) <= 240)?;
        let ring = (0..disc_left).rev().find(|&x| at(x) <= 24)?;
        let end = (0..ring).rev().find(|&x| at(x) > 24)?;
        (disc > HEIGHT * 3 / 4 && end + 8 < ring && end > HEIGHT / 2).then_some((ring, end))
    });
    eprintln!("landscape: the picture ends at x = {picture_end}, the shutter's ring at {ring}");
    let text = std::fs::read_to_string(&app_log).unwrap();
    assert!(!text.contains("CRITICAL"), "GTK criticals: {text}");
}
