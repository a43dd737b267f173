//! What the daemon tests share: a private bus, `focusd serve` on it, a zbus client.
#![allow(dead_code)] // each test crate uses a part

use focusd::service::proxy::{FailedStream, FinishedStream, Focusd1Proxy};
use focusd::stack::Image;
use futures_util::StreamExt;
use std::io::{BufRead, BufReader};
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
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

/// A private bus that other users may connect to too (a session bus takes only its own user).
const OPEN_BUS: &str = r#"<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-BUS Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>session</type>
  <listen>unix:tmpdir=/tmp</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow user="*"/>
    <allow own="*"/>
    <allow send_destination="*" eavesdrop="true"/>
    <allow eavesdrop="true"/>
    <allow receive_sender="*"/>
  </policy>
</busconfig>
"#;

impl Bus {
    pub fn start() -> Bus {
        Bus::spawn(&["--session", "--address=unix:tmpdir=/tmp"])
    }

    /// A bus every user may connect to.
    pub fn start_open() -> (Bus, tempfile::NamedTempFile) {
        let mut config = tempfile::NamedTempFile::new().unwrap();
        std::io::Write::write_all(&mut config, OPEN_BUS.as_bytes()).unwrap();
        let arg = format!("--config-file={}", config.path().display());
        (Bus::spawn(&[&arg]), config)
    }

    fn spawn(args: &[&str]) -> Bus {
        let mut child = Command::new("dbus-daemon")
            .args(["--nofork", "--print-address=1"])
            .args(args)
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
        Daemon::start_full(bus, Some(bundle), paced, extra, "", &[])
    }

    /// With more arguments, more config tables after `[output]` (tables with an `[output]` of
    /// their own replace it), and environment variables; without a bundle it serves the devices
    /// the config names.
    pub fn start_full(
        bus: &Bus,
        bundle: Option<&Path>,
        paced: bool,
        extra: &[&str],
        config_tables: &str,
        env: &[(&str, &str)],
    ) -> Daemon {
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("focusd.toml");
        let output = if config_tables.contains("[output]") {
            String::new()
        } else {
            format!("[output]\ndir = {:?}\n", dir.path().join("out"))
        };
        std::fs::write(&config, format!("{output}{config_tables}")).unwrap();
        let log = std::fs::File::create(dir.path().join("serve.log")).unwrap();
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_focusd"));
        cmd.args(["serve", "--address", &bus.address]);
        if let Some(bundle) = bundle {
            cmd.arg("--replay").arg(bundle);
        }
        cmd.arg("--config").arg(&config).stderr(log);
        if paced {
            cmd.arg("--paced");
        }
        cmd.args(extra).envs(env.iter().copied());
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

    /// Waits for the daemon to exit, for at most `within`.
    pub fn wait_exit(&mut self, within: Duration) -> std::process::ExitStatus {
        let t = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return s;
            }
            assert!(t.elapsed() < within, "still running:\n{}", self.log());
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

/// A socket standing in for systemd's `NOTIFY_SOCKET`: it records every sd_notify message
/// (`READY=1`, `WATCHDOG=1`, `STATUS=...`) with the time it came.
pub struct Notify {
    pub path: PathBuf,
    messages: Arc<Mutex<Vec<(Instant, String)>>>,
    stop: Arc<AtomicBool>,
    _dir: TempDir,
}

impl Notify {
    pub fn listen() -> Notify {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notify");
        let socket = UnixDatagram::bind(&path).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        let messages = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (m, s) = (messages.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut buf = vec![0u8; 4096];
            while !s.load(Ordering::Relaxed) {
                if let Ok(n) = socket.recv(&mut buf) {
                    let text = String::from_utf8_lossy(&buf[..n]);
                    let mut m = m.lock().unwrap();
                    for line in text.lines() {
                        m.push((Instant::now(), line.to_string()));
                    }
                }
            }
        });
        Notify {
            path,
            messages,
            stop,
            _dir: dir,
        }
    }

    /// Every message so far, each line on its own.
    pub fn messages(&self) -> Vec<(Instant, String)> {
        self.messages.lock().unwrap().clone()
    }

    /// Waits for a message starting with `prefix`, for at most `within`; returns its index.
    pub fn wait_for(&self, prefix: &str, within: Duration) -> usize {
        let t = Instant::now();
        loop {
            let m = self.messages();
            if let Some(i) = m.iter().position(|(_, m)| m.starts_with(prefix)) {
                return i;
            }
            assert!(t.elapsed() < within, "no {prefix:?} in {m:?}");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// When the messages starting with `prefix` came.
    pub fn times(&self, prefix: &str) -> Vec<Instant> {
        self.messages()
            .into_iter()
            .filter(|(_, m)| m.starts_with(prefix))
            .map(|(t, _)| t)
            .collect()
    }
}

impl Drop for Notify {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}
