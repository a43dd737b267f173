//! The IIO backend on fake sysfs trees laid out as the kernel lays them out: the PinePhone
//! Pro's inv_mpu6050 (one device, buffered, big-endian samples) and the Librem 5's st_lsm6dsx
//! (two devices, no buffer, polled).

use focusd::backend::iio::{IioConfig, IioImu, Mode};
use focusd::backend::sys::monotonic_now;
use focusd::capture::{Imu, ImuSample, Sensor};
use std::fs;
use std::path::{Path, PathBuf};

mod common;
use common::iio::{write, Tree};

fn read(path: &Path) -> String {
    fs::read_to_string(path).unwrap().trim().to_string()
}

const MPU_GYRO_SCALE: f64 = 0.001064724;
const MPU_FINEST: f64 = 0.000133090;
const MPU_ACCEL_SCALE: f64 = 0.000598;
/// The PinePhone Pro's IMU is mounted rotated: device x = sensor y, device y = −sensor x.
const MOUNT: &str = "0, 1, 0; -1, 0, 0; 0, 0, 1";

/// An mpu6500 as inv_mpu6050 lays it out: accel 0–2, temp 3, gyro 4–6, timestamp 7.
fn mpu6500(tree: &Tree, records: &[u8]) -> PathBuf {
    let mut files: Vec<(String, String)> = [
        ("in_accel_scale", MPU_ACCEL_SCALE.to_string()),
        ("in_anglvel_scale", MPU_GYRO_SCALE.to_string()),
        (
            "in_anglvel_scale_available",
            "0.000133090 0.000266181 0.000532362 0.001064724".into(),
        ),
        ("in_accel_mount_matrix", MOUNT.into()),
        ("in_anglvel_mount_matrix", MOUNT.into()),
        ("sampling_frequency", "50".into()),
        (
            "sampling_frequency_available",
            "10 20 50 100 200 500".into(),
        ),
        ("current_timestamp_clock", "realtime".into()),
        ("buffer/enable", "0".into()),
        ("buffer/length", "1".into()),
    ]
    .map(|(f, c): (&str, String)| (f.to_string(), c))
    .to_vec();
    let channels = [
        "in_accel_x",
        "in_accel_y",
        "in_accel_z",
        "in_temp",
        "in_anglvel_x",
        "in_anglvel_y",
        "in_anglvel_z",
        "in_timestamp",
    ];
    for (i, ch) in channels.iter().enumerate() {
        files.push((format!("{ch}_raw"), "0".into()));
        let se = |s: &str| format!("scan_elements/{ch}_{s}");
        files.push((se("en"), "0".into()));
        files.push((se("index"), i.to_string()));
        let ty = if *ch == "in_timestamp" {
            "le:s64/64>>0"
        } else {
            "be:s16/16>>0"
        };
        files.push((se("type"), ty.into()));
    }
    let files: Vec<(&str, &str)> = files
        .iter()
        .map(|(a, b)| (a.as_str(), b.as_str()))
        .collect();
    let d = tree.device(0, "mpu6500", &files);
    fs::write(tree.dir.path().join("dev/iio:device0"), records).unwrap();
    d
}

/// One 24-byte record without temp: accel x,y,z, gyro x,y,z (big-endian s16), padding to 16,
/// the timestamp (little-endian s64).
fn record(accel: [i16; 3], gyro: [i16; 3], t: i64) -> Vec<u8> {
    let mut r = Vec::with_capacity(24);
    for v in accel.iter().chain(&gyro) {
        r.extend_from_slice(&v.to_be_bytes());
    }
    r.extend_from_slice(&[0xEE; 4]);
    r.extend_from_slice(&t.to_le_bytes());
    r
}

fn of(samples: &[ImuSample], sensor: Sensor) -> Vec<ImuSample> {
    samples
        .iter()
        .filter(|s| s.sensor == sensor)
        .copied()
        .collect()
}

fn close(a: [f64; 3], b: [f64; 3]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9)
}

#[test]
fn mpu6500_buffered_decodes_scales_and_rotates_then_puts_everything_back() {
    let tree = Tree::new();
    let mut records = Vec::new();
    for k in 0..10i64 {
        let k16 = k as i16;
        records.extend(record(
            [100 + k16, -200, 16384],
            [-32768, 7 * k16, 32767],
            1_000_000_000 + k * 5_000_000,
        ));
    }
    let d = mpu6500(&tree, &records);
    let mut imu = IioImu::open(&tree.config()).unwrap();
    assert_eq!(imu.description.len(), 1);
    assert!(
        imu.description[0].contains("gyroscope and accelerometer: buffered"),
        "{:?}",
        imu.description
    );
    // While capturing: monotonic stamps, finest gyro scale, our elements enabled, temp not.
    assert_eq!(read(&d.join("current_timestamp_clock")), "monotonic");
    assert_eq!(read(&d.join("in_anglvel_scale")), "0.000133090");
    assert_eq!(read(&d.join("buffer/enable")), "1");
    assert_eq!(read(&d.join("buffer/length")), "256");
    assert_eq!(read(&d.join("scan_elements/in_anglvel_z_en")), "1");
    assert_eq!(read(&d.join("scan_elements/in_temp_en")), "0");

    let got = imu.samples(1_010_000_000, 1_020_000_000).unwrap();
    let (gyro, accel) = (of(&got, Sensor::Gyro), of(&got, Sensor::Accel));
    let ts: Vec<i64> = gyro.iter().map(|s| s.t).collect();
    assert_eq!(ts, [1_010_000_000, 1_015_000_000, 1_020_000_000]);
    assert_eq!(accel.len(), 3);
    // Record k = 2: sensor (x, y, z) → device (y, −x, z).
    let (ax, ay, az) = (
        102.0 * MPU_ACCEL_SCALE,
        -200.0 * MPU_ACCEL_SCALE,
        16384.0 * MPU_ACCEL_SCALE,
    );
    assert!(close(accel[0].v, [ay, -ax, az]), "{:?}", accel[0].v);
    let (gx, gy, gz) = (
        -32768.0 * MPU_FINEST,
        14.0 * MPU_FINEST,
        32767.0 * MPU_FINEST,
    );
    assert!(close(gyro[0].v, [gy, -gx, gz]), "{:?}", gyro[0].v);

    // The file ends after 10 records: the stream has stopped, and a later window says so.
    let e = imu
        .samples(1_040_000_000, 1_060_000_000)
        .unwrap_err()
        .to_string();
    assert!(e.contains("dev/iio:device0: end of data"), "{e}");
    assert!(
        e.contains("stopped delivering before 1060000000 ns (the last at 1045000000 ns)"),
        "{e}"
    );

    drop(imu);
    assert_eq!(read(&d.join("buffer/enable")), "0");
    assert_eq!(read(&d.join("buffer/length")), "1");
    assert_eq!(read(&d.join("current_timestamp_clock")), "realtime");
    assert_eq!(
        read(&d.join("in_anglvel_scale")),
        MPU_GYRO_SCALE.to_string()
    );
    for ch in ["in_accel_x", "in_anglvel_z", "in_timestamp"] {
        assert_eq!(read(&d.join(format!("scan_elements/{ch}_en"))), "0", "{ch}");
    }
}

#[test]
fn a_partial_record_waits_for_the_rest() {
    let tree = Tree::new();
    let mut records = record([1, 2, 3], [4, 5, 6], 10);
    records.extend(&record([7, 8, 9], [10, 11, 12], 20)[..20]);
    mpu6500(&tree, &records);
    let mut imu = IioImu::open(&tree.config()).unwrap();
    assert_eq!(imu.samples(0, 10).unwrap().len(), 2);
    let e = imu.samples(0, 20).unwrap_err().to_string();
    assert!(e.contains("the last at 10 ns"), "{e}");
}

#[test]
fn a_running_buffer_is_not_taken_over() {
    let tree = Tree::new();
    let d = mpu6500(&tree, &[]);
    write(&d.join("buffer/enable"), "1");
    let cfg = IioConfig {
        mode: Mode::Buffered,
        ..tree.config()
    };
    let e = IioImu::open(&cfg).err().unwrap().to_string();
    assert!(e.contains("its buffer is already running"), "{e}");
    // Nothing was left changed.
    assert_eq!(
        read(&d.join("in_anglvel_scale")),
        MPU_GYRO_SCALE.to_string()
    );
    assert_eq!(read(&d.join("current_timestamp_clock")), "realtime");
}

#[test]
fn without_a_monotonic_timestamp_clock_auto_mode_polls() {
    let tree = Tree::new();
    let d = mpu6500(&tree, &[]);
    fs::remove_file(d.join("current_timestamp_clock")).unwrap();
    write(&d.join("in_anglvel_x_raw"), "1000");
    let mut imu = IioImu::open(&tree.config()).unwrap();
    let why = &imu.description[0];
    assert!(
        why.contains("buffer refused") && why.contains("CLOCK_REALTIME"),
        "{why}"
    );
    assert!(why.contains("polling sysfs at 50 Hz"), "{why}");
    // The buffer setup was undone; the gyro scale stays finest for the polling.
    assert_eq!(read(&d.join("scan_elements/in_accel_x_en")), "0");
    assert_eq!(read(&d.join("buffer/enable")), "0");
    let now = monotonic_now();
    let got = imu.samples(now, now + 30_000_000).unwrap();
    let gyro = of(&got, Sensor::Gyro);
    assert!(!gyro.is_empty());
    // Sensor x = 1000 LSB → device y = −x.
    assert!(
        close(gyro[0].v, [0.0, -1000.0 * MPU_FINEST, 0.0]),
        "{:?}",
        gyro[0].v
    );
}

/// The Librem 5: st_lsm6dsx as two devices, no buffer, per-axis offsets, and a light sensor
/// and a trigger beside them.
fn librem5(tree: &Tree) -> (PathBuf, PathBuf) {
    tree.device(0, "stk3310", &[("in_illuminance_raw", "12")]);
    let accel = tree.device(
        2,
        "lsm9ds1-imu_accel",
        &[
            ("in_accel_x_raw", "100"),
            ("in_accel_y_raw", "-50"),
            ("in_accel_z_raw", "16000"),
            ("in_accel_scale", "0.000598"),
            ("in_accel_z_offset", "-10"),
            ("in_accel_mount_matrix", "-1, 0, 0; 0, 1, 0; 0, 0, -1"),
            ("sampling_frequency", "238"),
        ],
    );
    let gyro = tree.device(
        3,
        "lsm9ds1-imu_gyro",
        &[
            ("in_anglvel_x_raw", "20"),
            ("in_anglvel_y_raw", "0"),
            ("in_anglvel_z_raw", "-40"),
            ("in_anglvel_scale", "0.000153"),
            ("sampling_frequency", "238"),
        ],
    );
    (accel, gyro)
}

#[test]
fn librem5_two_devices_polled_with_offsets_and_mount_matrix() {
    let tree = Tree::new();
    let (_, gyro_dir) = librem5(&tree);
    let mut imu = IioImu::open(&tree.config()).unwrap();
    assert_eq!(imu.description.len(), 2, "{:?}", imu.description);
    assert!(imu.description[0]
        .contains("iio:device3 (lsm9ds1-imu_gyro) for the gyroscope: polling sysfs at 238 Hz"));
    assert!(imu.description[1].contains("(lsm9ds1-imu_accel) for the accelerometer: polling"));
    let now = monotonic_now();
    let got = imu.samples(now, now + 40_000_000).unwrap();
    let (gyro, accel) = (of(&got, Sensor::Gyro), of(&got, Sensor::Accel));
    assert!(
        gyro.len() >= 3 && accel.len() >= 3,
        "{} {}",
        gyro.len(),
        accel.len()
    );
    assert!(got.windows(2).all(|w| w[0].t <= w[1].t));
    assert!(close(gyro[0].v, [20.0 * 0.000153, 0.0, -40.0 * 0.000153]));
    assert!(close(
        accel[0].v,
        [-100.0 * 0.000598, -50.0 * 0.000598, -15990.0 * 0.000598]
    ));

    // Garbage in a raw file stops the gyroscope with the file and the value named.
    write(&gyro_dir.join("in_anglvel_y_raw"), "nonsense");
    let now = monotonic_now();
    let e = imu
        .samples(now, now + 2_000_000_000)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("in_anglvel_y_raw: raw reading \"nonsense\" is not an integer"),
        "{e}"
    );
    assert!(e.contains("the gyroscope stopped delivering"), "{e}");
}

#[test]
fn devices_are_found_by_name_and_missing_ones_are_named() {
    let tree = Tree::new();
    librem5(&tree);
    let cfg = IioConfig {
        gyro_device: Some("mpu6500".into()),
        ..tree.config()
    };
    let e = IioImu::open(&cfg).err().unwrap().to_string();
    assert!(e.contains("no IIO device is named \"mpu6500\"; found: iio:device0 (stk3310), iio:device2 (lsm9ds1-imu_accel), iio:device3 (lsm9ds1-imu_gyro)"), "{e}");
    let cfg = IioConfig {
        gyro_device: Some("lsm9ds1-imu_accel".into()),
        ..tree.config()
    };
    let e = IioImu::open(&cfg).err().unwrap().to_string();
    assert!(e.contains("has no gyroscope channels"), "{e}");
    let cfg = IioConfig {
        mode: Mode::Buffered,
        ..tree.config()
    };
    let e = IioImu::open(&cfg).err().unwrap().to_string();
    assert!(e.contains("has no buffer"), "{e}");

    let empty = Tree::new();
    let e = IioImu::open(&empty.config()).err().unwrap().to_string();
    assert!(e.contains("no IIO device has a gyroscope"), "{e}");
    let none = IioConfig {
        sysfs_root: empty.dir.path().join("nowhere"),
        ..IioConfig::default()
    };
    let e = IioImu::open(&none).err().unwrap().to_string();
    assert!(
        e.contains("cannot list IIO devices") && e.contains("is the IMU driver loaded?"),
        "{e}"
    );
}

#[test]
fn odd_attribute_files_are_refused_by_name() {
    for (file, content, why) in [
        (
            "in_anglvel_scale",
            "fast",
            "\"fast\" is not a finite number",
        ),
        ("in_anglvel_mount_matrix", "1, 0; 0, 1", "bad mount matrix"),
        (
            "in_anglvel_mount_matrix",
            "1, 0, 0; 0, 1, 0; 0, 0, nan",
            "bad mount matrix",
        ),
        (
            "scan_elements/in_anglvel_x_type",
            "be:s16/12>>0",
            "storage of 12 bits",
        ),
        (
            "scan_elements/in_anglvel_x_index",
            "-1",
            "scan index \"-1\"",
        ),
    ] {
        let tree = Tree::new();
        let d = mpu6500(&tree, &[]);
        write(&d.join(file), content);
        let cfg = IioConfig {
            mode: Mode::Buffered,
            finest_gyro_scale: false,
            ..tree.config()
        };
        let e = IioImu::open(&cfg).err().unwrap().to_string();
        assert!(e.contains(file) && e.contains(why), "{file}: {e}");
    }
}
