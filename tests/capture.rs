//! The sweep with its motion gate, run on the committed replay bundles: exactly the shaken
//! takes are rejected, exhausted retries do what the config says, and `focusd capture` turns a
//! bundle (of pictures or of raw DNGs) into a fused image and a report.

use focusd::backend::replay::{self, Bundle, BundleWriter};
use focusd::capture::sweep::{sweep, OnExhausted, Sweep, SweepConfig, Unmonitored};
use focusd::capture::{CaptureError, ImuSample, Sensor};
use focusd::files::dng;
use focusd::stack::psnr;
use std::path::Path;
use std::process::Command;

mod common;
use common::stacks::{bundle_dir, load};

fn config(planes: usize, on_exhausted: OnExhausted) -> SweepConfig {
    SweepConfig {
        planes,
        on_exhausted,
        ..SweepConfig::default()
    }
}

fn replay(name: &str, cfg: &SweepConfig) -> Result<Sweep, CaptureError> {
    let (mut cam, mut imu, clock) = replay::open(Bundle::open(&bundle_dir(name)).unwrap());
    sweep(&mut cam, &mut imu, &clock, cfg, &Unmonitored)
}

/// (plane, take, accepted) of every take tried.
fn verdicts(s: &Sweep) -> Vec<(usize, usize, bool)> {
    s.planes
        .iter()
        .flat_map(|p| p.takes.iter().map(move |t| (p.plane, t.take, t.accepted)))
        .collect()
}

#[test]
fn calm_bundle_takes_one_shot_per_plane() {
    let s = replay("calm", &config(6, OnExhausted::Fail)).unwrap();
    assert_eq!(
        verdicts(&s),
        (0..6).map(|p| (p, 0, true)).collect::<Vec<_>>()
    );
    assert_eq!(s.frames.len(), 6);
    // Lens positions run from the nearest (top of the range) to the farthest.
    let lens: Vec<i32> = s.planes.iter().map(|p| p.lens).collect();
    assert_eq!((lens[0], lens[5]), (1023, 0));
    assert!(lens.windows(2).all(|w| w[0] > w[1]));
}

#[test]
fn exactly_the_shaken_takes_are_rejected_and_reshot() {
    let s = replay("shaken", &config(6, OnExhausted::Fail)).unwrap();
    let mut expected: Vec<(usize, usize, bool)> = (0..6).map(|p| (p, 0, true)).collect();
    expected.splice(2..3, [(2, 0, false), (2, 1, false), (2, 2, true)]);
    assert_eq!(verdicts(&s), expected);
    // The steady third take is what goes into the stack, not a shaken one.
    let steady = load(&bundle_dir("shaken").join("frame_02.jpg"));
    assert_eq!(s.frames[2].data(), steady.data());
    // Shaken takes carry a blur estimate well above a pixel, steady ones below.
    let p2 = &s.planes[2].takes;
    assert!(p2[0].blur_px > 2.0 && p2[1].blur_px > 2.0, "{p2:?}");
    assert!(p2[2].blur_px < 1.0, "{p2:?}");
}

#[test]
fn exhausted_retries_fail_or_keep_the_least_shaken_as_configured() {
    match replay("stuck", &config(6, OnExhausted::Fail)) {
        Err(CaptureError::Shaken { plane, takes, .. }) => assert_eq!((plane, takes), (3, 3)),
        other => panic!("expected Shaken, got {:?}", other.map(|s| verdicts(&s))),
    }
    let s = replay("stuck", &config(6, OnExhausted::KeepLeastShaken)).unwrap();
    let p3 = &s.planes[3];
    assert!(p3.takes.iter().all(|t| !t.accepted));
    assert_eq!(p3.takes.iter().filter(|t| t.kept_shaken).count(), 1);
    assert_eq!(s.frames.len(), 6);
    // Fewer reshoots allowed: the gate gives up after two takes.
    let cfg = SweepConfig {
        max_reshoots: 1,
        ..config(6, OnExhausted::Fail)
    };
    assert!(matches!(
        replay("stuck", &cfg),
        Err(CaptureError::Shaken { takes: 2, .. })
    ));
}

#[test]
fn a_plane_count_the_bundle_lacks_is_named() {
    let err = replay("calm", &config(8, OnExhausted::Fail)).err().unwrap();
    assert!(
        err.to_string()
            .contains("asks for plane 6, the bundle has 6 planes"),
        "{err}"
    );
}

/// A bundle with one plane-0 take whose IMU trace is `gyro(t)` at 200 Hz from t = 0.
fn synthetic(dir: &Path, end_ns: i64, gyro: impl Fn(i64) -> f64) {
    let mut w = BundleWriter::create(dir, (0, 1023)).unwrap();
    let img = image::RgbImage::from_pixel(32, 24, image::Rgb([90, 120, 150]));
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    w.add_take(0, 1023, (500_000_000, 533_000_000), "png", &png)
        .unwrap();
    w.add_take(1, 0, (600_000_000, 633_000_000), "png", &png)
        .unwrap();
    let imu: Vec<ImuSample> = (0..=end_ns / 5_000_000)
        .flat_map(|i| {
            let t = i * 5_000_000;
            [
                ImuSample {
                    t,
                    sensor: Sensor::Gyro,
                    v: [gyro(t), 0.0, 0.0],
                },
                ImuSample {
                    t,
                    sensor: Sensor::Accel,
                    v: [0.0, 9.81, 0.0],
                },
            ]
        })
        .collect();
    w.finish(&imu).unwrap();
}

fn replay_dir(dir: &Path, cfg: &SweepConfig) -> Result<Sweep, CaptureError> {
    let (mut cam, mut imu, clock) = replay::open(Bundle::open(dir).unwrap());
    sweep(&mut cam, &mut imu, &clock, cfg, &Unmonitored)
}

#[test]
fn never_still_and_a_trace_that_stops_are_clear_errors() {
    let cfg = SweepConfig {
        planes: 2,
        still_timeout_ms: 1000,
        ..SweepConfig::default()
    };
    let dir = tempfile::tempdir().unwrap();
    synthetic(dir.path(), 2_000_000_000, |t| (t as f64 * 1e-7).sin() * 0.3);
    let err = replay_dir(dir.path(), &cfg).err().unwrap();
    assert!(matches!(err, CaptureError::NotStill { .. }), "{err}");
    assert!(err.to_string().contains("did not hold still"), "{err}");

    let dir = tempfile::tempdir().unwrap();
    synthetic(dir.path(), 550_000_000, |_| 0.0);
    let err = replay_dir(dir.path(), &cfg).err().unwrap();
    assert!(
        err.to_string().contains("the sensor stopped delivering"),
        "{err}"
    );

    let dir = tempfile::tempdir().unwrap();
    synthetic(dir.path(), 1_000_000_000, |_| 0.001);
    let s = replay_dir(dir.path(), &cfg).unwrap();
    assert_eq!(verdicts(&s), vec![(0, 0, true), (1, 0, true)]);
}

#[test]
fn capture_replays_a_bundle_into_an_image_and_a_report() {
    let dir = tempfile::tempdir().unwrap();
    let (out, report) = (dir.path().join("out.png"), dir.path().join("r.json"));
    let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["capture", "--replay"])
        .arg(bundle_dir("shaken"))
        .arg("-o")
        .arg(&out)
        .arg("--report")
        .arg(&report)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let planes = r["planes"].as_array().unwrap();
    assert_eq!(planes.len(), 6);
    let p2 = planes[2]["takes"].as_array().unwrap();
    let accepted: Vec<bool> = p2
        .iter()
        .map(|t| t["accepted"].as_bool().unwrap())
        .collect();
    assert_eq!(accepted, [false, false, true]);
    assert_eq!(p2[0]["gyro_sum"].as_array().unwrap().len(), 3);
    assert!(p2[0]["blur_px"].as_f64().unwrap() > 0.0);
    for stage in ["capture", "register", "fuse"] {
        assert!(r["timings_ms"][stage].as_f64().is_some(), "{stage}: {r}");
    }
    assert_eq!(r["output"], out.display().to_string());
    assert_eq!(r["memory"]["budget_mib"], 512, "{r}");
    assert_eq!(r["memory"]["within_budget"], true, "{r}");
    let peak = r["memory"]["estimated_peak_mib"].as_u64().unwrap();
    assert!(peak > 0 && peak <= 512, "{r}");
    // The sweep runs nearest first, and the occlusion edges say so.
    let order = r["focus_order"].as_str().unwrap();
    assert!(order.starts_with("nearest focus first ("), "{r}");
    // The fused image is close to the truth, and closer than a stack with the shaken take in it.
    let truth = load(&bundle_dir("shaken").join("truth.png"));
    let fused = psnr(&load(&out), &truth, 0);
    let shaken = load(&bundle_dir("shaken").join("plane02_take0.jpg"));
    let steady = load(&bundle_dir("shaken").join("frame_02.jpg"));
    assert!(psnr(&shaken, &truth, 0) < psnr(&steady, &truth, 0));
    assert!(fused > 24.0, "fused {fused:.2} dB against the truth");
}

#[test]
fn stuck_bundle_fails_capture_by_default_naming_the_plane() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.jpg");
    let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["capture", "--replay"])
        .arg(bundle_dir("stuck"))
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("plane 3: all 3 takes were shaken"), "{err}");
    assert!(!out.exists());
}

/// A bundle of raw DNG takes replays as a camera's raw frames: the gate rejects the same
/// shaken takes, each kept take is developed after the sweep, and `capture` fuses them.
#[test]
fn raw_bundle_develops_its_takes_after_the_sweep() {
    let s = replay("raw", &config(6, OnExhausted::Fail)).unwrap();
    let mut expected: Vec<(usize, usize, bool)> = (0..6).map(|p| (p, 0, true)).collect();
    expected.splice(2..3, [(2, 0, false), (2, 1, false), (2, 2, true)]);
    assert_eq!(verdicts(&s), expected);
    // Each developed frame is its picture again, less what the mosaic does not sample.
    for (i, frame) in s.frames.iter().enumerate() {
        let picture = load(&bundle_dir("raw").join(format!("frame_{i:02}.jpg")));
        let db = psnr(frame, &picture, 0);
        assert!(db > 28.0, "frame {i}: {db:.2} dB against its picture");
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.png");
    let report = dir.path().join("report.json");
    capture_raw(&[Path::new("--report"), &report], &out);
    let truth = load(&bundle_dir("raw").join("truth.png"));
    let fused = psnr(&load(&out), &truth, 0);
    assert!(fused > 24.0, "fused {fused:.2} dB against the truth");
    // Developed in full only where the picture keeps a frame: some, not all of the six.
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let developed = &r["developed_in_full"];
    let worth = developed["frames"].as_f64().unwrap();
    assert!(developed["pixels"].as_u64().unwrap() > 0, "{r}");
    assert!(worth > 0.0 && worth < 6.0, "{r}");
    // By default the raw takes are not kept: the picture and the report are all there is.
    assert_eq!(names(dir.path()), ["out.png", "report.json"]);
}

/// A raw take says its white balance, and the development keeps to it: the simulator's takes
/// need none (camera RGB is the scene's linear sRGB), so a warm scene captured raw, and its DNGs
/// fused, keep the truth's colour, where grey-world would have made it neutral.
#[test]
fn a_raw_capture_keeps_the_scenes_colour() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = dir.path().join("warm");
    let focusd = || Command::new(env!("CARGO_BIN_EXE_focusd"));
    let o = focusd()
        .args([
            "simulate", "--width", "320", "--height", "240", "--planes", "4",
        ])
        .args(["--seed", "46", "--handheld", "--bundle", "--raw", "-o"])
        .arg(&bundle)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mean = |p: &Path| {
        let img = load(p);
        let mut sum = [0f64; 3];
        for px in img.data().chunks_exact(3) {
            for c in 0..3 {
                sum[c] += f64::from(px[c]);
            }
        }
        sum.map(|s| s / (img.width() * img.height()) as f64)
    };
    let truth = mean(&bundle.join("truth.png"));
    assert!(truth[0] - truth[2] > 12.0, "not a warm scene: {truth:?}");
    let captured = dir.path().join("captured.png");
    let o = focusd()
        .args(["capture", "--replay"])
        .arg(&bundle)
        .arg("-o")
        .arg(&captured)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let fused = dir.path().join("fused.png");
    let o = focusd()
        .args(["fuse", "-o"])
        .arg(&fused)
        .args((0..4).map(|p| bundle.join(format!("plane{p:02}_take0.dng"))))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for out in [&captured, &fused] {
        let m = mean(out);
        assert!(
            m.iter().zip(truth).all(|(a, b)| (a - b).abs() < 2.0),
            "{}: mean colour {m:?}, the truth's {truth:?}",
            out.display()
        );
    }
}

/// `focusd capture ARGS --replay` of the raw bundle into `out`, which must succeed.
fn capture_raw(args: &[&Path], out: &Path) {
    let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .arg("capture")
        .args(args)
        .arg("--replay")
        .arg(bundle_dir("raw"))
        .arg("-o")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The files in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// `[output] keep_raw = true`: the take the gate kept of each plane lands beside the picture
/// as a DNG named after it, holding exactly the mosaic the camera gave, as focusd's reader and
/// LibRaw's read it.
#[test]
fn keep_raw_keeps_each_kept_take_beside_the_picture_as_a_dng() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("focusd.toml");
    std::fs::write(&config, "[output]\nkeep_raw = true\n").unwrap();
    let out = dir.path().join("stack.jpg");
    capture_raw(&[Path::new("--config"), &config], &out);
    let kept: Vec<String> = (0..6).map(|p| format!("stack-raw-{p:02}.dng")).collect();
    let mut expected = vec!["focusd.toml".to_string(), "stack.jpg".to_string()];
    expected.extend(kept.iter().cloned());
    expected.sort();
    assert_eq!(names(dir.path()), expected);
    let libraw = common::libraw::libraw();
    for (plane, name) in kept.iter().enumerate() {
        // Plane 2's first two takes were shaken; its third was kept.
        let take = if plane == 2 { 2 } else { 0 };
        let original = bundle_dir("raw").join(format!("plane{plane:02}_take{take}.dng"));
        let (a, b) = (
            dng::load(&dir.path().join(name)).unwrap(),
            dng::load(&original).unwrap(),
        );
        assert_eq!(
            (&a.raw.bytes, a.raw.width, a.raw.order, a.raw.black_level),
            (&b.raw.bytes, b.raw.width, b.raw.order, b.raw.black_level),
            "{name} against {}",
            original.display()
        );
        if libraw {
            let samples = |dng: &Path| {
                let copy = dir.path().join("libraw.dng");
                std::fs::copy(dng, &copy).unwrap();
                common::libraw::run("unprocessed_raw", &["-T"], &copy);
                common::libraw::read_tiff(&copy.with_extension("dng.tiff"))
            };
            assert_eq!(
                samples(&dir.path().join(name)),
                samples(&original),
                "{name}"
            );
        }
    }
}
