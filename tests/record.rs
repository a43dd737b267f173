//! `focusd record` writes a sweep as a bundle that replays to the same verdicts, also when the
//! sweep fails; `--config` and `check-config` refuse bad files naming the line.

use focusd::backend::replay::{self, Bundle};
use focusd::capture::sweep::{sweep, Sweep, Unmonitored};
use focusd::capture::CaptureError;
use std::path::Path;
use std::process::{Command, Output};

mod common;
use common::iio::Tree;
use common::stacks::bundle_dir;

fn focusd(args: &[&str], paths: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(args)
        .args(paths)
        .output()
        .unwrap()
}

fn replay(dir: &Path) -> Result<Sweep, CaptureError> {
    let bundle = Bundle::open(dir).unwrap();
    let cfg = focusd::service::job::defaults_for(&bundle);
    let (mut cam, mut imu, clock) = replay::open(bundle);
    sweep(&mut cam, &mut imu, &clock, &cfg, &Unmonitored)
}

/// Every take's (plane, take, accepted, gyro sums).
fn verdicts(s: &Sweep) -> Vec<(usize, usize, bool, [f64; 3])> {
    s.planes
        .iter()
        .flat_map(|p| {
            p.takes
                .iter()
                .map(|t| (p.plane, t.take, t.accepted, t.gyro_sum))
        })
        .collect()
}

/// Raw takes are recorded raw: DNGs that replay to the same verdicts and develop to the same
/// frames as the takes recorded (to a level: DNG keeps the colour matrix to four places).
#[test]
fn raw_takes_are_recorded_as_dngs() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let o = focusd(
        &["record", "--replay"],
        &[&bundle_dir("raw"), Path::new("-o"), &rec],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut names: Vec<String> = std::fs::read_dir(&rec)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.starts_with("plane"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 8, "{names:?}");
    assert!(names.iter().all(|n| n.ends_with(".dng")), "{names:?}");
    let original = replay(&bundle_dir("raw")).unwrap();
    let again = replay(&rec).unwrap();
    assert_eq!(verdicts(&again), verdicts(&original));
    assert_eq!(again.frames.len(), 6);
    for (a, b) in again.frames.iter().zip(&original.frames) {
        let most = a
            .data()
            .iter()
            .zip(b.data())
            .map(|(x, y)| x.abs_diff(*y))
            .max();
        assert!(most <= Some(1), "{most:?}");
    }
}

#[test]
fn a_recorded_sweep_replays_to_the_same_verdicts_and_frames() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let o = focusd(
        &["record", "--replay"],
        &[&bundle_dir("shaken"), Path::new("-o"), &rec],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("recorded 8 takes"), "{err}");
    let original = replay(&bundle_dir("shaken")).unwrap();
    let again = replay(&rec).unwrap();
    assert_eq!(verdicts(&again), verdicts(&original));
    assert_eq!(verdicts(&again).iter().filter(|v| !v.2).count(), 2);
    // Frames are stored losslessly.
    assert_eq!(again.frames.len(), original.frames.len());
    for (a, b) in again.frames.iter().zip(&original.frames) {
        assert_eq!(a.data(), b.data());
    }
    let kept = |s: &focusd::capture::sweep::Sweep| -> Vec<(i64, i64)> {
        s.planes
            .iter()
            .flat_map(|p| &p.takes)
            .map(|t| (t.exposure_start_ns, t.exposure_end_ns))
            .collect()
    };
    assert_eq!(kept(&again), kept(&original));
    // A second recording into the same directory is refused, and leaves it alone.
    let o = focusd(
        &["record", "--replay"],
        &[&bundle_dir("calm"), Path::new("-o"), &rec],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("the directory is not empty"), "{err}");
    assert_eq!(replay(&rec).unwrap().planes.len(), 6);
}

#[test]
fn a_failed_sweep_is_recorded_before_the_error() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let o = focusd(
        &["record", "--replay"],
        &[&bundle_dir("stuck"), Path::new("-o"), &rec],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("plane 3: all 3 takes were shaken"), "{err}");
    let b = Bundle::open(&rec).unwrap();
    // Planes 0-2 once, plane 3 three times: everything the sweep took before it gave up.
    assert_eq!(b.manifest.takes.len(), 6);
    assert_eq!(b.manifest.takes.iter().filter(|t| t.plane == 3).count(), 3);
    assert!(!b.imu.is_empty());
}

#[test]
fn config_files_are_checked_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/focusd.toml");
    let o = focusd(&["check-config"], &[&shipped]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (text, line, why) in [
        (
            "[sweep]\nplanes = 3\nmax_reshoots = 50\n",
            3,
            "[sweep] max_reshoots = 50 is out of range 0..=20",
        ),
        ("[fuse]\nlamda = 0.3\n", 2, "unknown field `lamda`"),
        (
            "\n[output]\nformat = \"webp\"\n",
            3,
            "format = \"webp\" is not one of",
        ),
        // What `serve` could not create, `check-config` refuses with the same message.
        (
            "[output]\ndir = \"out\\u0000put\"\n",
            2,
            "dir contains a NUL byte, which no path can hold",
        ),
    ] {
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, text).unwrap();
        for args in [
            &["check-config"][..],
            &["capture", "-o", "x.jpg", "--config"][..],
        ] {
            let o = focusd(args, &[&bad]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(1), "{err}");
            let at = format!("{}:{line}: ", bad.display());
            assert!(
                err.contains(&at) && err.contains(why),
                "{args:?} {text:?}: {err}"
            );
        }
    }
    // A config's [sweep] and [fuse] apply to a replay: keep the least shaken take of `stuck`.
    let cfg = dir.path().join("keep.toml");
    std::fs::write(
        &cfg,
        "[sweep]\nlens_near = 1023\nlens_far = 0\non_exhausted = \"keep-least-shaken\"\n\
         [fuse]\nmethod = \"pyramid\"\n",
    )
    .unwrap();
    let (out, report) = (dir.path().join("o.jpg"), dir.path().join("r.json"));
    let o = focusd(
        &["capture", "--replay"],
        &[
            &bundle_dir("stuck"),
            Path::new("--config"),
            &cfg,
            Path::new("-o"),
            &out,
            Path::new("--report"),
            &report,
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let kept: Vec<bool> = r["planes"][3]["takes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["kept_shaken"].as_bool().unwrap())
        .collect();
    assert_eq!(kept.iter().filter(|k| **k).count(), 1, "{kept:?}");
}

#[test]
fn without_a_camera_capture_names_what_is_missing() {
    let tree = Tree::new();
    let cfg = tree.dir.path().join("fake.toml");
    // An IMU tree with no devices: the error names the sysfs directory.
    std::fs::write(&cfg, format!("[imu]\nsysfs_root = {:?}\n", tree.sys())).unwrap();
    let o = focusd(&["capture", "-o", "x.jpg", "--config"], &[&cfg]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("no IIO device has a gyroscope"), "{err}");
}
