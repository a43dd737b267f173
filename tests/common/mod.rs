//! What the daemon tests share: a private bus, `focusd serve` on it, a zbus client.
#![allow(dead_code)] // each test crate uses a part

use focusd::service::proxy::{FailedStream, FinishedStream, Focusd1Proxy};
use focusd::stack::image::Image;
use futures_util::StreamExt;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tempfile::TempDir;

pub fn bundle_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sim-data/bundles")
        .join(name)
}

/// `busctl call` of a Focusd1 method on `bus`: `args` are the method, signature and values.
pub fn busctl(bus: &Bus, args: &[&str]) -> std::process::Output {
    Command::new("busctl")
        .arg(format!("--address={}", bus.address))
        .args([
            "call",
            "org.focusd.Focusd",
            "/org/focusd/Focusd",
            "org.focusd.Focusd1",
        ])
        .args(args)
        .output()
        .expect("busctl not found: install Debian's systemd package (CI does)")
}

/// A private session bus, killed on drop.
pub struct Bus {
    pub child: Child,
    pub address: String,
}

impl Bus {
    pub fn start() -> Bus {
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
pub struct Daemon {
    pub child: Child,
    pub dir: TempDir,
    pub config: PathBuf,
}

impl Daemon {
    pub fn start(bus: &Bus, bundle: &Path, paced: bool) -> Daemon {
        Daemon::start_with(bus, bundle, paced, &[])
    }

    /// With more `focusd serve` arguments (`--fault ...`).
    pub fn start_with(bus: &Bus, bundle: &Path, paced: bool, extra: &[&str]) -> Daemon {
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
        cmd.args(extra);
        let child = cmd.spawn().unwrap();
        let d = Daemon { child, dir, config };
        d.wait_for_log("serving org.focusd.Focusd");
        d
    }

    pub fn out(&self) -> PathBuf {
        self.dir.path().join("out")
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("serve.log")).unwrap_or_default()
    }

    pub fn wait_for_log(&self, what: &str) {
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

    pub fn signal(&self, sig: &str) {
        let ok = Command::new("kill")
            .args([sig, &self.child.id().to_string()])
            .status()
            .unwrap();
        assert!(ok.success());
    }

    /// Files in the output directory, temporary ones included.
    pub fn outputs(&self) -> Vec<String> {
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

pub fn load(path: &Path) -> Image<u8> {
    let img = image::open(path).unwrap().to_rgb8();
    let (w, h) = img.dimensions();
    Image::from_vec(w as usize, h as usize, 3, img.into_raw())
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

pub async fn connect(bus: &Bus) -> (zbus::Connection, Focusd1Proxy<'static>) {
    let addr: zbus::Address = bus.address.parse().unwrap();
    let conn = zbus::connection::Builder::address(addr)
        .build()
        .await
        .unwrap();
    let proxy = Focusd1Proxy::new(&conn).await.unwrap();
    (conn, proxy)
}

/// The D-Bus error name and message of a failed call.
pub fn dbus_error(e: zbus::Error) -> (String, String) {
    match e {
        zbus::Error::MethodError(name, msg, _) => (name.to_string(), msg.unwrap_or_default()),
        e => panic!("not a method error: {e}"),
    }
}

/// Waits for job `job` to end: `Ok(path)` on Finished, `Err(error)` on Failed.
pub async fn outcome(
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

/// The Finished and Failed streams, subscribed before a call so no signal is missed.
pub async fn subscribe(proxy: &Focusd1Proxy<'_>) -> (FinishedStream, FailedStream) {
    (
        proxy.receive_finished().await.unwrap(),
        proxy.receive_failed().await.unwrap(),
    )
}

/// One capture through `proxy`, to its end: the image's path, or the job's error.
pub async fn capture_and_wait(proxy: &Focusd1Proxy<'_>) -> Result<String, String> {
    let (finished, failed) = subscribe(proxy).await;
    let job = proxy.capture().await.unwrap();
    outcome(&job, finished, failed).await
}
