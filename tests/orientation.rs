//! Pictures come out upright as the phone was held: the committed calm bundle replayed with its
//! IMU trace turned (gravity along +x, -x, -y, or out of the screen) and a sensor rotation in
//! `bundle.toml`; the JPEG's EXIF Orientation is read back with an independent reader
//! (kamadak-exif), the PNG's pixels compared with the plain replay's turned.

use focusd::files::orientation::Orientation;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::stacks::{bundle_dir, exif_orientation, load};

/// How a hold maps the upright phone's gravity.
type Turn = fn([f64; 3]) -> [f64; 3];

/// The calm bundle copied to `dir`, its accelerometer readings mapped by `turn` and its
/// sensor rotation set.
fn bundle(dir: &Path, turn: Turn, rotation: i64) -> PathBuf {
    let src = bundle_dir("calm");
    let out = dir.join("bundle");
    std::fs::create_dir_all(&out).unwrap();
    for e in std::fs::read_dir(&src).unwrap().flatten() {
        std::fs::copy(e.path(), out.join(e.file_name())).unwrap();
    }
    let csv = std::fs::read_to_string(src.join("imu.csv")).unwrap();
    let turned: Vec<String> = csv
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            if f.get(1) != Some(&"accel") {
                return l.to_string();
            }
            let v: Vec<f64> = f[2..5].iter().map(|x| x.parse().unwrap()).collect();
            let t = turn([v[0], v[1], v[2]]);
            format!("{},accel,{},{},{}", f[0], t[0], t[1], t[2])
        })
        .collect();
    std::fs::write(out.join("imu.csv"), turned.join("\n") + "\n").unwrap();
    let toml = std::fs::read_to_string(src.join("bundle.toml")).unwrap();
    let toml = toml.replace(
        "lens_max = 1023\n",
        &format!("lens_max = 1023\nrotation = {rotation}\n"),
    );
    std::fs::write(out.join("bundle.toml"), toml).unwrap();
    out
}

/// `focusd capture --replay` into `out`; the report.
fn capture(bundle: &Path, out: &Path) -> serde_json::Value {
    let report = out.with_extension("json");
    let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["capture", "--replay"])
        .arg(bundle)
        .arg("-o")
        .arg(out)
        .arg("--report")
        .arg(&report)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(report).unwrap()).unwrap()
}

#[test]
fn pictures_are_upright_for_each_hold_and_sensor_rotation() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain");
    std::fs::create_dir_all(&plain).unwrap();
    let upright = bundle(&plain, |a| a, 0);
    let r = capture(&upright, &plain.join("out.png"));
    assert_eq!(r["orientation"]["exif"], 1, "{r}");
    assert_eq!(r["orientation"]["hold"]["source"], "measured", "{r}");
    let reference = load(&plain.join("out.png"));
    // (name, gravity as held, sensor rotation, EXIF expected, report's hold source)
    type Case = (&'static str, Turn, i64, u32, &'static str);
    let cases: [Case; 5] = [
        ("90", |[x, y, z]| [y, -x, z], 0, 8, "measured"),
        ("270", |[x, y, z]| [-y, x, z], 0, 6, "measured"),
        ("180", |[x, y, z]| [-x, -y, z], 0, 3, "measured"),
        ("flat", |[x, y, z]| [x, z, y], 0, 1, "flat-portrait"),
        ("sensor 270", |a| a, 270, 6, "measured"),
    ];
    for (name, turn, rotation, want, source) in cases {
        let d = dir.path().join(name.replace(' ', "-"));
        std::fs::create_dir_all(&d).unwrap();
        let b = bundle(&d, turn, rotation);
        let r = capture(&b, &d.join("out.jpg"));
        assert_eq!(exif_orientation(&d.join("out.jpg")), Some(want), "{name}");
        assert_eq!(r["orientation"]["exif"], want, "{name}: {r}");
        assert_eq!(r["orientation"]["hold"]["source"], source, "{name}: {r}");
        assert_eq!(r["orientation"]["sensor_rotation"], rotation, "{name}: {r}");
        // PNG: the same picture, its pixels turned as the tag says.
        let r = capture(&b, &d.join("out.png"));
        assert_eq!(r["orientation"]["exif"], want, "{name}");
        let turns = match want {
            1 => 0,
            6 => 1,
            3 => 2,
            _ => 3,
        };
        let expected = Orientation::clockwise(turns).turn(&reference);
        let got = load(&d.join("out.png"));
        assert_eq!(
            (got.width(), got.height()),
            (expected.width(), expected.height()),
            "{name}"
        );
        assert!(got.data() == expected.data(), "{name}: pixels differ");
    }
}
