//! The fault battery, each fault driven end to end through `focusd serve` on a private bus:
//! the job ends with Failed and a clear reason, the camera is released (lens back), nothing is
//! left in the output directory, the daemon keeps serving and the next capture succeeds. A job
//! blocked in a read is the exception: the service reports it and exits for systemd to restart.

mod common;

use common::daemon::{
    busctl, capture_and_wait, connect, outcome, runtime, subscribe, Bus, Daemon, Notify,
};
use common::iio::Tree;
use common::stacks::bundle_dir;
use common::system::is_root;
use futures_util::StreamExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

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
    // The running job is named by its id: 32 hex digits, not a counter another caller could
    // guess.
    let id = err
        .split("org.focusd.Error.Busy: job ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .unwrap_or_default();
    assert!(
        id.len() == 32 && id.chars().all(|c| c.is_ascii_hexdigit()) && err.contains("is running"),
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

/// A sysfs tree with one IIO device whose `name` attribute is a FIFO, held open for writing
/// (with nothing written) by the returned file: the job's read of it blocks for as long as the
/// test keeps it, as a read of a hung driver's attribute does. (The files focusd parses, a
/// bundle's, are refused when they are FIFOs; an attribute is the kernel's.)
fn sysfs_with_a_blocking_attribute() -> (Tree, std::fs::File) {
    let tree = Tree::new();
    let name = tree.device_dir(0).join("name");
    let made = Command::new("mkfifo").arg(&name).status().unwrap();
    assert!(made.success(), "mkfifo");
    // Read and write: opening a FIFO so does not wait for a reader.
    let writer = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&name)
        .unwrap();
    (tree, writer)
}

/// How a test meets a job blocked in a read.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Blocked {
    /// Leaves it to the watchdog.
    Waits,
    /// Cancels it over the bus.
    Cancels,
    /// Stops the service with SIGTERM.
    Terminates,
}

/// A capture whose read of an IIO attribute blocks as the job opens the IMU, on a daemon with a
/// 2 s stall timeout and a 1 s systemd watchdog: whatever the test does, the job is reported
/// Failed naming the stage, the watchdog pings stop, and the service exits non-zero (for
/// systemd to restart it).
fn blocked_job(how: Blocked) {
    let (sysfs, _writer) = sysfs_with_a_blocking_attribute();
    let notify = Notify::listen();
    let socket = notify.path.to_str().unwrap().to_string();
    let bus = Bus::start();
    let tables = format!(
        "[imu]\nsysfs_root = {:?}\n[service]\nstall_timeout_s = 2\n",
        sysfs.sys()
    );
    let mut d = Daemon::start_full(
        &bus,
        None,
        false,
        &[],
        &tables,
        &[("NOTIFY_SOCKET", &socket), ("WATCHDOG_USEC", "1000000")],
    );
    // Idle, the service pings every half period.
    std::thread::sleep(Duration::from_millis(1200));
    assert!(
        notify.times("WATCHDOG=1").len() >= 2,
        "{:?}",
        notify.messages()
    );
    let (job, error, blocked_at, failed_at) = runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = subscribe(&proxy).await;
        let job = proxy.capture().await.unwrap();
        let blocked_at = Instant::now();
        assert_eq!(proxy.state().await.unwrap(), "waiting-still");
        match how {
            Blocked::Waits => {}
            Blocked::Cancels => proxy.cancel(&job).await.unwrap(),
            Blocked::Terminates => d.signal("-TERM"),
        }
        let error = outcome(&job, finished, failed).await.unwrap_err();
        (job, error, blocked_at, Instant::now())
    });
    let expected = match how {
        Blocked::Waits => "stalled: no progress for 2 s in stage waiting-still",
        _ => "cancelled, but the job is blocked in stage waiting-still",
    };
    assert!(error.contains(expected), "{how:?}: {error}");
    assert!(error.contains("exits for systemd to restart it"), "{error}");
    let waited = failed_at - blocked_at;
    assert!(
        waited >= Duration::from_millis(1800),
        "{how:?}: failed after {waited:?}"
    );
    let status = d.wait_exit(Duration::from_secs(10));
    assert_eq!(status.code(), Some(1), "{how:?}: {}", d.log());
    assert!(
        d.log().contains(&format!("focusd: error: job {job}: ")),
        "{}",
        d.log()
    );
    // In the order sent: pings until the job is given up (a STATUS saying so), none after.
    let given_up = notify.wait_for(
        &format!("STATUS=job {job} failed: "),
        Duration::from_secs(5),
    );
    let messages = notify.messages();
    let after: Vec<_> = messages[given_up..]
        .iter()
        .filter(|(_, m)| m == "WATCHDOG=1")
        .collect();
    assert!(
        after.is_empty(),
        "{how:?}: pinged after giving up: {messages:?}"
    );
    // Pings went on while the job was stuck but not yet for the timeout.
    let pings = notify.times("WATCHDOG=1");
    assert!(pings.iter().any(|&t| t > blocked_at), "{how:?}");
    assert!(pings.iter().all(|&t| t < failed_at), "{how:?}");
    assert!(d.outputs().is_empty(), "{:?}", d.outputs());
}

#[test]
fn a_job_blocked_in_a_read_is_failed_by_the_watchdog_and_the_service_exits() {
    blocked_job(Blocked::Waits);
}

#[test]
fn cancelling_a_job_blocked_in_a_read_fails_it_and_the_service_exits() {
    blocked_job(Blocked::Cancels);
}

#[test]
fn sigterm_with_a_job_blocked_in_a_read_fails_it_and_exits_non_zero() {
    blocked_job(Blocked::Terminates);
}

#[test]
fn a_second_serve_is_refused_and_the_first_keeps_the_name() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("calm"), false);
    let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["serve", "--address", &bus.address, "--replay"])
        .arg(bundle_dir("calm"))
        .arg("--config")
        .arg(&d.config)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("org.focusd.Focusd is already owned") && err.contains("another focusd"),
        "{err}"
    );
    // The first still answers, under the name.
    runtime().block_on(async {
        assert!(capture(&bus).await.is_ok());
    });
    assert!(!d.log().contains("lost the bus name"), "{}", d.log());
}

#[test]
fn a_dead_bus_ends_the_service_with_an_error() {
    let mut bus = Bus::start();
    let mut d = Daemon::start(&bus, &bundle_dir("calm"), false);
    bus.child.kill().unwrap();
    bus.child.wait().unwrap();
    let status = d.wait_exit(Duration::from_secs(10));
    assert_eq!(status.code(), Some(1), "{}", d.log());
    assert!(d.log().contains("bus closed"), "{}", d.log());
}

/// `trigger --wait` ends with an error as soon as the service that runs its job dies or the
/// bus closes, instead of waiting out its timeout.
#[test]
fn trigger_wait_ends_when_the_service_or_the_bus_dies() {
    for kill_bus in [false, true] {
        let mut bus = Bus::start();
        let d = Daemon::start(&bus, &bundle_dir("shaken"), true);
        let trigger = Command::new(env!("CARGO_BIN_EXE_focusd"))
            .args([
                "trigger",
                "--wait",
                "--timeout",
                "600",
                "--address",
                &bus.address,
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        d.wait_for_log("capture requested");
        std::thread::sleep(Duration::from_millis(200));
        if kill_bus {
            bus.child.kill().unwrap();
        } else {
            d.signal("-KILL");
        }
        let o = trigger.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{err}");
        assert!(
            err.contains("is gone before job"),
            "bus killed {kill_bus}: {err}"
        );
    }
}

/// The service's peak resident memory so far, kB.
fn peak_rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// `calls` Cancel calls sent on one connection without waiting for a single answer.
async fn pipelined_cancels(address: &str, calls: usize) {
    let addr: zbus::Address = address.parse().unwrap();
    let conn = zbus::connection::Builder::address(addr)
        .build()
        .await
        .unwrap();
    for _ in 0..calls {
        let msg = zbus::Message::method_call("/org/focusd/Focusd", "Cancel")
            .destination("org.focusd.Focusd")
            .interface("org.focusd.Focusd1")
            .build(&("no-such-job",))
            .unwrap();
        if conn.send(&msg).await.is_err() {
            break;
        }
    }
    // Still connected while the service works through them.
    tokio::time::sleep(Duration::from_secs(2)).await;
}

/// Clients that pipeline thousands of calls without reading an answer do not grow the service
/// (it handles one call at a time, so what waits, waits in the bus under the bus's limits; each
/// caller's uid is asked of the bus once), and another client's capture and property reads go
/// through meanwhile. How long they wait is the bus's: here dbus-daemon is the busy one.
#[test]
fn a_flood_of_pipelined_calls_does_not_grow_the_service_or_block_another_client() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("shaken"), false);
    let rt = runtime();
    let (_conn, proxy) = rt.block_on(connect(&bus));
    // What a capture alone takes, as the baseline.
    rt.block_on(capture_and_wait(&proxy)).expect("the capture");
    let alone = peak_rss_kb(d.child.id());
    let flooders: Vec<_> = (0..4)
        .map(|_| {
            let address = bus.address.clone();
            std::thread::spawn(move || runtime().block_on(pipelined_cancels(&address, 8_000)))
        })
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    rt.block_on(async {
        let t = Instant::now();
        let path = capture_and_wait(&proxy).await.expect("the capture");
        eprintln!("a capture during the flood took {:?}", t.elapsed());
        assert!(Path::new(&path).is_file());
        let state = tokio::time::timeout(Duration::from_secs(120), proxy.state())
            .await
            .expect("State answered");
        assert_eq!(state.unwrap(), "idle");
    });
    for f in flooders {
        f.join().unwrap();
    }
    let peak = peak_rss_kb(d.child.id());
    eprintln!("peak resident memory of the service: {alone} kB alone, {peak} kB with the flood");
    assert!(
        peak < alone + 30 * 1024,
        "the service grew from {alone} to {peak} kB"
    );
    // The service still serves.
    let o = busctl(&bus, &["Cancel", "s", "another"]);
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("not running"),
        "{o:?}"
    );
}
