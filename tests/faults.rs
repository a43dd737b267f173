//! The fault battery, each fault driven end to end through `focusd serve` on a private bus:
//! the job ends with Failed and a clear reason, the camera is released (lens back), nothing is
//! left in the output directory, the daemon keeps serving and the next capture succeeds.

mod common;

use common::{
    bundle_dir, busctl, capture_and_wait, connect, outcome, runtime, subscribe, Bus, Daemon,
};
use futures_util::StreamExt;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// One capture on `d`: its path, or its error.
async fn capture(bus: &Bus) -> Result<String, String> {
    let (_conn, proxy) = connect(bus).await;
    capture_and_wait(&proxy).await
}

#[test]
fn injected_device_faults_fail_the_job_clearly_and_the_next_capture_succeeds() {
    for (fault, why) in [
        (
            "camera-gone:2",
            "replay camera: No such device (os error 19)",
        ),
        (
            "frame-timeout:1",
            "waiting for a frame of plane 1 from the replay camera timed out",
        ),
        ("imu-stops:3", "replay IMU: no samples after"),
        ("imu-nan:2", "reading at"),
    ] {
        let bus = Bus::start();
        let d = Daemon::start_with(&bus, &bundle_dir("calm"), false, &["--fault", fault]);
        runtime().block_on(async {
            let e = capture(&bus).await.unwrap_err();
            assert!(e.contains(why), "{fault}: {e}");
            assert!(d.outputs().is_empty(), "{fault}: {:?}", d.outputs());
            assert_eq!(
                d.log().matches("replay camera released").count(),
                1,
                "{fault}: the lens was not put back:\n{}",
                d.log()
            );
            let path = capture(&bus).await.unwrap();
            assert!(Path::new(&path).exists(), "{fault}");
        });
    }
}

#[test]
fn a_panicking_job_fails_and_the_service_lives_on() {
    let bus = Bus::start();
    let d = Daemon::start_with(&bus, &bundle_dir("calm"), false, &["--fault", "panic:1"]);
    runtime().block_on(async {
        let e = capture(&bus).await.unwrap_err();
        assert!(
            e.contains("internal error: injected fault at plane 1"),
            "{e}"
        );
        assert!(d.outputs().is_empty(), "{:?}", d.outputs());
        let path = capture(&bus).await.unwrap();
        assert!(Path::new(&path).exists());
    });
}

#[test]
fn a_removed_output_directory_fails_the_job_and_is_made_again_for_the_next() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = subscribe(&proxy).await;
        let mut progress = proxy.receive_progress().await.unwrap();
        let job = proxy.capture().await.unwrap();
        while let Some(s) = progress.next().await {
            if s.args().unwrap().stage == "sweeping" {
                break;
            }
        }
        drop(progress);
        std::fs::remove_dir_all(d.out()).unwrap();
        let e = outcome(&job, finished, failed).await.unwrap_err();
        assert!(e.contains("cannot write"), "{e}");
        assert!(
            !d.out().exists() || d.outputs().is_empty(),
            "{:?}",
            d.outputs()
        );
        let path = capture(&bus).await.unwrap();
        assert!(Path::new(&path).exists());
    });
}

#[test]
fn a_full_disk_fails_the_job_without_leaving_a_partial_file() {
    if is_root() {
        let bus = Bus::start();
        let d = Daemon::start(&bus, &bundle_dir("calm"), false);
        // A 256 KiB filesystem under the output directory, nearly filled.
        let out = d.out();
        std::fs::create_dir_all(&out).unwrap();
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", "size=256k", "tmpfs"])
            .arg(&out)
            .status()
            .unwrap();
        assert!(mounted.success(), "mount tmpfs");
        let filler = out.join("filler");
        std::fs::write(&filler, vec![0u8; 240 * 1024]).unwrap();
        runtime().block_on(async {
            let e = capture(&bus).await.unwrap_err();
            assert!(e.contains("No space left on device"), "{e}");
            assert_eq!(d.outputs(), ["filler"]);
            std::fs::remove_file(&filler).unwrap();
            let path = capture(&bus).await.unwrap();
            assert!(Path::new(&path).exists());
        });
        let _ = Command::new("umount").arg(&out).status();
    } else {
        eprintln!("skipped: mounting a small tmpfs needs root (CI runs as root)");
    }
}

/// Whether this process runs as root, without a libc binding: `id -u`.
fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

#[test]
fn two_triggers_at_once_get_one_job_and_one_busy() {
    let bus = Bus::start();
    let _d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    let spawn = || {
        Command::new(env!("CARGO_BIN_EXE_focusd"))
            .args(["trigger", "--wait", "--address", &bus.address])
            .output()
    };
    let (a, b) = std::thread::scope(|s| {
        let a = s.spawn(spawn);
        let b = s.spawn(spawn);
        (a.join().unwrap().unwrap(), b.join().unwrap().unwrap())
    });
    let ok = [&a, &b].iter().filter(|o| o.status.success()).count();
    assert_eq!(ok, 1, "{a:?}\n{b:?}");
    let busy = if a.status.success() { &b } else { &a };
    let err = String::from_utf8_lossy(&busy.stderr);
    assert!(
        err.contains("org.focusd.Error.Busy: job 1 is running"),
        "{err}"
    );
}

#[test]
fn a_client_that_disconnects_mid_job_does_not_stop_it() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    runtime().block_on(async {
        let (_conn, watcher) = connect(&bus).await;
        let (finished, failed) = subscribe(&watcher).await;
        let job = {
            let (conn, proxy) = connect(&bus).await;
            let job = proxy.capture().await.unwrap();
            drop(proxy);
            conn.close().await.unwrap();
            job
        };
        tokio::time::sleep(Duration::from_millis(100)).await;
        let path = outcome(&job, finished, failed).await.unwrap();
        assert!(Path::new(&path).exists());
        assert_eq!(watcher.last_result().await.unwrap(), path);
        assert!(capture(&bus).await.is_ok());
    });
    assert!(!d.log().contains("panicked"));
}

#[test]
fn calls_with_wrong_arguments_are_refused_and_the_daemon_keeps_serving() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("calm"), false);
    for args in [
        &["Cancel", "i", "5"][..],
        &["Cancel"][..],
        &["Capture", "s", "x"][..],
        &["Cancel", "ss", "a", "b"][..],
    ] {
        let o = busctl(&bus, args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} was accepted");
        let clear = err.contains("Signature mismatch") || err.contains("takes no arguments");
        assert!(clear, "{args:?}: {err}");
    }
    let huge = "j".repeat(100_000);
    let o = busctl(&bus, &["Cancel", "s", &huge]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.len() < 1000 && err.contains("is not running"),
        "{}",
        &err[..err.len().min(300)]
    );
    runtime().block_on(async {
        assert!(capture(&bus).await.is_ok());
    });
    assert!(!d.log().contains("panicked"));
}
