//! `focusd serve` on a private dbus-daemon, replaying the committed bundles: triggered from a
//! zbus client, from `focusd trigger --wait` and from `busctl`; busy, cancel, a bad bundle,
//! SIGHUP with a bad config, and SIGTERM mid-job.

use focusd::cli::serve::{FailedStream, FinishedStream, Focusd1Proxy};
use focusd::stack::image::Image;
use focusd::stack::metrics::psnr;
use futures_util::StreamExt;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tempfile::TempDir;

fn bundle_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sim-data/bundles")
        .join(name)
}

/// A private session bus, killed on drop.
struct Bus {
    child: Child,
    address: String,
}

impl Bus {
    fn start() -> Bus {
        let mut child = Command::new("dbus-daemon")
            .args(["--session", "--nofork", "--print-address=1"])
            .arg("--address=unix:tmpdir=/tmp")
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("dbus-daemon not found: install Debian's dbus package (CI does)");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        Bus {
            child,
            address: line.trim().to_string(),
        }
    }
}

impl Drop for Bus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `focusd serve` on a bus, with its output directory and its stderr in a file.
struct Daemon {
    child: Child,
    dir: TempDir,
    config: PathBuf,
}

impl Daemon {
    fn start(bus: &Bus, bundle: &Path, paced: bool) -> Daemon {
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("focusd.toml");
        std::fs::write(
            &config,
            format!("[output]\ndir = {:?}\n", dir.path().join("out")),
        )
        .unwrap();
        let log = std::fs::File::create(dir.path().join("serve.log")).unwrap();
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_focusd"));
        cmd.args(["serve", "--address", &bus.address, "--replay"])
            .arg(bundle)
            .arg("--config")
            .arg(&config)
            .stderr(log);
        if paced {
            cmd.arg("--paced");
        }
        let child = cmd.spawn().unwrap();
        let d = Daemon { child, dir, config };
        d.wait_for_log("serving org.focusd.Focusd");
        d
    }

    fn out(&self) -> PathBuf {
        self.dir.path().join("out")
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("serve.log")).unwrap_or_default()
    }

    fn wait_for_log(&self, what: &str) {
        let t = Instant::now();
        while !self.log().contains(what) {
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "no {what:?} in:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn signal(&self, sig: &str) {
        let ok = Command::new("kill")
            .args([sig, &self.child.id().to_string()])
            .status()
            .unwrap();
        assert!(ok.success());
    }

    /// Files in the output directory, temporary ones included.
    fn outputs(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(self.out())
            .map(|r| {
                r.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        v.sort();
        v
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn load(path: &Path) -> Image<u8> {
    let img = image::open(path).unwrap().to_rgb8();
    let (w, h) = img.dimensions();
    Image::from_vec(w as usize, h as usize, 3, img.into_raw())
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

async fn connect(bus: &Bus) -> (zbus::Connection, Focusd1Proxy<'static>) {
    let addr: zbus::Address = bus.address.parse().unwrap();
    let conn = zbus::connection::Builder::address(addr)
        .build()
        .await
        .unwrap();
    let proxy = Focusd1Proxy::new(&conn).await.unwrap();
    (conn, proxy)
}

/// The D-Bus error name and message of a failed call.
fn dbus_error(e: zbus::Error) -> (String, String) {
    match e {
        zbus::Error::MethodError(name, msg, _) => (name.to_string(), msg.unwrap_or_default()),
        e => panic!("not a method error: {e}"),
    }
}

/// Waits for job `job` to end: `Ok(path)` on Finished, `Err(error)` on Failed.
async fn outcome(
    job: &str,
    mut finished: FinishedStream,
    mut failed: FailedStream,
) -> Result<String, String> {
    let wait = async {
        loop {
            tokio::select! {
                Some(s) = finished.next() => {
                    let a = s.args().unwrap();
                    if a.job == job { return Ok(a.path.to_string()); }
                }
                Some(s) = failed.next() => {
                    let a = s.args().unwrap();
                    if a.job == job { return Err(a.error.to_string()); }
                }
            }
        }
    };
    tokio::time::timeout(Duration::from_secs(60), wait)
        .await
        .expect("no Finished or Failed within 60 s")
}

#[test]
fn captures_from_zbus_trigger_and_busctl_are_fused_close_to_the_truth() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("shaken"), false);
    let truth = load(&bundle_dir("shaken").join("truth.png"));

    // 1. focusd trigger --wait prints the image's path.
    let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["trigger", "--wait", "--address", &bus.address])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}\n{}", d.log());
    let path = PathBuf::from(String::from_utf8_lossy(&o.stdout).trim());
    assert_eq!(path.parent(), Some(d.out().as_path()));
    assert!(path
        .file_name()
        .unwrap()
        .to_string_lossy()
        .starts_with("focus-"));
    let db = psnr(&load(&path), &truth, 0);
    assert!(db > 24.0, "{db:.2} dB");
    assert!(err.contains("sweeping") && err.contains("compose"), "{err}");
    // Its report says which takes were rejected.
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(path.with_extension("json")).unwrap()).unwrap();
    let p2: Vec<bool> = r["planes"][2]["takes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["accepted"].as_bool().unwrap())
        .collect();
    assert_eq!(p2, [false, false, true]);

    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        assert_eq!(proxy.version().await.unwrap(), env!("CARGO_PKG_VERSION"));
        assert_eq!(proxy.state().await.unwrap(), "idle");
        assert_eq!(
            proxy.last_result().await.unwrap(),
            path.display().to_string()
        );

        // 2. A zbus client, with progress through every stage.
        let (finished, failed) = (
            proxy.receive_finished().await.unwrap(),
            proxy.receive_failed().await.unwrap(),
        );
        // Read concurrently: an unread signal stream holds up the whole connection.
        let mut progress = proxy.receive_progress().await.unwrap();
        let stages = std::sync::Arc::new(std::sync::Mutex::new(Vec::<(String, String)>::new()));
        let seen = stages.clone();
        let reader = tokio::spawn(async move {
            while let Some(s) = progress.next().await {
                let a = s.args().unwrap();
                let x = (a.job.to_string(), a.stage.to_string());
                let mut v = seen.lock().unwrap();
                if v.last() != Some(&x) {
                    v.push(x);
                }
            }
        });
        let job = proxy.capture().await.unwrap();
        let second = outcome(&job, finished, failed).await.unwrap();
        assert_ne!(PathBuf::from(&second), path);
        assert!(psnr(&load(Path::new(&second)), &truth, 0) > 24.0);
        tokio::time::sleep(Duration::from_millis(200)).await;
        reader.abort();
        let stages: Vec<String> = stages
            .lock()
            .unwrap()
            .iter()
            .filter(|(j, _)| *j == job)
            .map(|(_, s)| s.clone())
            .collect();
        for s in ["waiting-still", "sweeping", "register", "labels", "compose"] {
            assert!(stages.iter().any(|x| x == s), "{s} missing from {stages:?}");
        }

        // 3. busctl.
        let (finished, failed) = (
            proxy.receive_finished().await.unwrap(),
            proxy.receive_failed().await.unwrap(),
        );
        let o = Command::new("busctl")
            .arg(format!("--address={}", bus.address))
            .args([
                "call",
                "org.focusd.Focusd",
                "/org/focusd/Focusd",
                "org.focusd.Focusd1",
                "Capture",
            ])
            .output()
            .expect("busctl not found: install Debian's systemd package (CI does)");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let reply = String::from_utf8_lossy(&o.stdout);
        let job = reply
            .trim()
            .trim_start_matches("s ")
            .trim_matches('"')
            .to_string();
        assert_eq!(job, "3", "{reply}");
        let third = outcome(&job, finished, failed).await.unwrap();
        assert!(psnr(&load(Path::new(&third)), &truth, 0) > 24.0);
    });
    // Three images and three reports, nothing else.
    assert_eq!(d.outputs().len(), 6, "{:?}", d.outputs());
}

#[test]
fn busy_while_a_job_runs_and_cancel_leaves_nothing_behind() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = (
            proxy.receive_finished().await.unwrap(),
            proxy.receive_failed().await.unwrap(),
        );
        let job = proxy.capture().await.unwrap();
        let (name, msg) = dbus_error(proxy.capture().await.unwrap_err());
        assert_eq!(name, "org.focusd.Error.Busy");
        assert!(msg.contains(&format!("job {job} is running")), "{msg}");
        assert_ne!(proxy.state().await.unwrap(), "idle");
        let (name, _) = dbus_error(proxy.cancel("no-such-job").await.unwrap_err());
        assert_eq!(name, "org.focusd.Error.NoSuchJob");
        proxy.cancel(&job).await.unwrap();
        let e = outcome(&job, finished, failed).await.unwrap_err();
        assert_eq!(e, "cancelled");
        assert_eq!(proxy.state().await.unwrap(), "idle");
        assert!(d.outputs().is_empty(), "{:?}", d.outputs());

        // The next capture runs to the end.
        let (finished, failed) = (
            proxy.receive_finished().await.unwrap(),
            proxy.receive_failed().await.unwrap(),
        );
        let job = proxy.capture().await.unwrap();
        let path = outcome(&job, finished, failed).await.unwrap();
        assert!(Path::new(&path).exists());
    });
}

#[test]
fn a_bad_bundle_fails_clearly_and_the_daemon_keeps_serving_and_keeps_a_good_config() {
    let bus = Bus::start();
    let copy = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(bundle_dir("calm")).unwrap().flatten() {
        std::fs::copy(e.path(), copy.path().join(e.file_name())).unwrap();
    }
    let d = Daemon::start(&bus, copy.path(), false);
    let frame = copy.path().join("frame_03.jpg");
    let saved = std::fs::read(&frame).unwrap();
    std::fs::write(&frame, b"this is not a JPEG").unwrap();
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = (
            proxy.receive_finished().await.unwrap(),
            proxy.receive_failed().await.unwrap(),
        );
        let job = proxy.capture().await.unwrap();
        let e = outcome(&job, finished, failed).await.unwrap_err();
        assert!(
            e.contains("frame_03.jpg") && e.contains("not a readable image"),
            "{e}"
        );
        assert!(d.outputs().is_empty(), "{:?}", d.outputs());

        // SIGHUP with a broken config file: refused, the old one kept.
        let good = std::fs::read_to_string(&d.config).unwrap();
        std::fs::write(&d.config, "[fuse]\nlambda = 99\n").unwrap();
        d.signal("-HUP");
        d.wait_for_log("keeping the old config");
        assert!(
            d.log().contains(":2: [fuse] lambda = 99 is out of range"),
            "{}",
            d.log()
        );
        std::fs::write(&d.config, good).unwrap();

        std::fs::write(&frame, &saved).unwrap();
        let (finished, failed) = (
            proxy.receive_finished().await.unwrap(),
            proxy.receive_failed().await.unwrap(),
        );
        let job = proxy.capture().await.unwrap();
        let path = outcome(&job, finished, failed).await.unwrap();
        // Still the old config's output directory.
        assert_eq!(Path::new(&path).parent(), Some(d.out().as_path()));
    });
}

#[test]
fn sigterm_mid_job_cancels_it_and_exits_zero() {
    let bus = Bus::start();
    let mut d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = (
            proxy.receive_finished().await.unwrap(),
            proxy.receive_failed().await.unwrap(),
        );
        let mut progress = proxy.receive_progress().await.unwrap();
        let job = proxy.capture().await.unwrap();
        while let Some(s) = progress.next().await {
            if s.args().unwrap().stage == "sweeping" {
                break;
            }
        }
        d.signal("-TERM");
        assert_eq!(
            outcome(&job, finished, failed).await.unwrap_err(),
            "cancelled"
        );
    });
    let t = Instant::now();
    let status = loop {
        if let Some(s) = d.child.try_wait().unwrap() {
            break s;
        }
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "still running:\n{}",
            d.log()
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(0), "{}", d.log());
    assert!(d.outputs().is_empty(), "{:?}", d.outputs());
}
