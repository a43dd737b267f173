//! The trigger keys against the kernel's real evdev: run inside a VM by `tests/kernel/run-keys`
//! (any machine with the uinput and evdev modules, as root, and with `dbus-daemon` and a built
//! `focusd` at the paths given).
//!
//! `keys FOCUSD BUNDLE` starts a private bus and `FOCUSD serve --replay BUNDLE --paced` on it,
//! makes virtual camera keys with uinput and checks, one `ok: ...` line each, then
//! `KEYS-RESULT: PASS` or `FAIL`:
//! - a press lands a picture in the Pictures folder of the session it serves (`$HOME/Pictures`);
//! - a long press during a job cancels it (`Failed(job, "cancelled")`, nothing written);
//! - a press during a job is ignored; the device destroyed mid-job leaves the job to finish and
//!   the daemon serving; a new device appearing afterwards is picked up and its press works.

use focusd::backend::input::abi::{InputEvent, EV_KEY, EV_SYN, SYN_REPORT};
use focusd::service::daemon::Bus;
use focusd::service::proxy::Focusd1Proxy;
use futures_util::StreamExt;
use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::os::fd::AsRawFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

#[macro_use]
mod support;
use support::{ok, report, Check};

const KEY_CAMERA: u16 = 212;
const LONG_PRESS_MS: u64 = 300;
const TMP: &str = "/tmp/focusd-keys";

fn main() {
    report("KEYS", || {
        let args: Vec<String> = std::env::args().collect();
        let [_, focusd, bundle] = &args[..] else {
            return Err("usage: keys FOCUSD BUNDLE".into());
        };
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| e.to_string())?
            .block_on(run(Path::new(focusd), Path::new(bundle)))
    });
}

/// A virtual input device with the camera key (uinput), destroyed when dropped.
struct VirtualKey {
    file: File,
}

/// `struct uinput_setup` (linux/uinput.h).
#[repr(C)]
struct UinputSetup {
    bustype: u16,
    vendor: u16,
    product: u16,
    version: u16,
    name: [u8; 80],
    ff_effects_max: u32,
}

mod ui {
    use rustix::ioctl::{opcode, Opcode};
    pub const DEV_CREATE: Opcode = opcode::none(b'U', 1);
    pub const DEV_DESTROY: Opcode = opcode::none(b'U', 2);
    pub const DEV_SETUP: Opcode = opcode::write::<super::UinputSetup>(b'U', 3);
    pub const SET_EVBIT: Opcode = opcode::write::<i32>(b'U', 100);
    pub const SET_KEYBIT: Opcode = opcode::write::<i32>(b'U', 101);
}

impl VirtualKey {
    fn create(name: &str) -> Result<VirtualKey, String> {
        let file = OpenOptions::new()
            .write(true)
            .custom_flags(libc::O_NONBLOCK)
            .open("/dev/uinput")
            .map_err(|e| format!("/dev/uinput: {e}"))?;
        let fd = file.as_raw_fd();
        let mut setup = UinputSetup {
            bustype: 0x06, // BUS_VIRTUAL
            vendor: 0x1234,
            product: 0x5678,
            version: 1,
            name: [0; 80],
            ff_effects_max: 0,
        };
        setup.name[..name.len()].copy_from_slice(name.as_bytes());
        let check = |what: &str, r: libc::c_int| {
            if r < 0 {
                Err(format!("{what}: {}", std::io::Error::last_os_error()))
            } else {
                Ok(())
            }
        };
        // SAFETY: each request takes the argument given: an int by value (the SET_*BIT ones,
        // which uinput reads as the bit number), a uinput_setup by pointer, or nothing.
        unsafe {
            check(
                "UI_SET_EVBIT",
                libc::ioctl(fd, ui::SET_EVBIT as _, EV_KEY as libc::c_int),
            )?;
            check(
                "UI_SET_KEYBIT",
                libc::ioctl(fd, ui::SET_KEYBIT as _, KEY_CAMERA as libc::c_int),
            )?;
            check(
                "UI_DEV_SETUP",
                libc::ioctl(fd, ui::DEV_SETUP as _, &setup as *const UinputSetup),
            )?;
            check("UI_DEV_CREATE", libc::ioctl(fd, ui::DEV_CREATE as _))?;
        }
        Ok(VirtualKey { file })
    }

    fn emit(&mut self, type_: u16, code: u16, value: i32) -> Result<(), String> {
        let e = InputEvent {
            type_,
            code,
            value,
            ..InputEvent::default()
        };
        self.file
            .write_all(&e.to_bytes())
            .map_err(|e| format!("writing to /dev/uinput: {e}"))
    }

    fn key(&mut self, down: bool) -> Result<(), String> {
        self.emit(EV_KEY, KEY_CAMERA, down as i32)?;
        self.emit(EV_SYN, SYN_REPORT, 0)
    }

    /// Down, `held`, up.
    async fn press(&mut self, held: Duration) -> Result<(), String> {
        self.key(true)?;
        tokio::time::sleep(held).await;
        self.key(false)
    }
}

impl Drop for VirtualKey {
    fn drop(&mut self) {
        // SAFETY: UI_DEV_DESTROY takes no argument.
        unsafe { libc::ioctl(self.file.as_raw_fd(), ui::DEV_DESTROY as _) };
    }
}

/// A process killed when dropped.
struct Kill(Child);

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

const BUS_CONFIG: &str = r#"<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-BUS Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>session</type>
  <listen>unix:path=/tmp/focusd-keys/bus</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow user="*"/>
    <allow own="*"/>
    <allow send_destination="*"/>
    <allow receive_sender="*"/>
  </policy>
</busconfig>
"#;

struct Setup {
    _bus: Kill,
    _daemon: Kill,
    log: PathBuf,
    out: PathBuf,
    proxy: Focusd1Proxy<'static>,
}

impl Setup {
    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Waits until the daemon's log has `what` `count` times.
    async fn wait_log(&self, what: &str, count: usize) -> Check {
        let start = Instant::now();
        while self.log().matches(what).count() < count {
            ensure!(
                start.elapsed() < Duration::from_secs(60),
                "the daemon did not log {what:?} ({count} times); its log:\n{}",
                self.log()
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        Ok(())
    }

    fn pictures(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(&self.out)
            .map(|d| {
                d.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.ends_with(".jpg"))
                    .collect()
            })
            .unwrap_or_default();
        v.sort();
        v
    }
}

async fn start(focusd: &Path, bundle: &Path) -> Result<Setup, String> {
    let tmp = PathBuf::from(TMP);
    std::fs::create_dir_all(&tmp).map_err(|e| e.to_string())?;
    std::fs::write(tmp.join("bus.conf"), BUS_CONFIG).map_err(|e| e.to_string())?;
    let mut bus = Command::new("dbus-daemon")
        .arg(format!("--config-file={TMP}/bus.conf"))
        .args(["--nofork", "--print-address=1"])
        .stdout(Stdio::piped())
        .spawn()
        .map_err(|e| format!("dbus-daemon: {e}"))?;
    let mut address = String::new();
    BufReader::new(bus.stdout.take().expect("piped"))
        .read_line(&mut address)
        .map_err(|e| e.to_string())?;
    let address = address.trim().to_string();
    ensure!(!address.is_empty(), "dbus-daemon printed no address");
    let bus = Kill(bus);
    // No [output] dir: a session's service writes to focusd/ in the user's Pictures folder.
    let home = tmp.join("home");
    let out = home.join("Pictures/focusd");
    let config = tmp.join("focusd.toml");
    std::fs::write(
        &config,
        format!("[trigger]\nkeys = [\"KEY_CAMERA\"]\nlong_press_ms = {LONG_PRESS_MS}\n"),
    )
    .map_err(|e| e.to_string())?;
    let log = tmp.join("focusd.log");
    let daemon = Command::new(focusd)
        .args(["serve", "--paced", "--address", &address, "--replay"])
        .arg(bundle)
        .arg("--config")
        .arg(&config)
        .env("HOME", &home)
        .env_remove("XDG_CONFIG_HOME")
        .stderr(File::create(&log).map_err(|e| e.to_string())?)
        .spawn()
        .map_err(|e| format!("{}: {e}", focusd.display()))?;
    let daemon = Kill(daemon);
    let conn = Bus::Address(address.clone())
        .builder()
        .map_err(|e| e.to_string())?
        .build()
        .await
        .map_err(|e| format!("connecting to the bus: {e}"))?;
    let proxy = Focusd1Proxy::new(&conn).await.map_err(|e| e.to_string())?;
    let setup = Setup {
        _bus: bus,
        _daemon: daemon,
        log,
        out,
        proxy,
    };
    setup.wait_log("serving org.focusd.Focusd", 1).await?;
    Ok(setup)
}

/// The job signals, subscribed before a press so that none is missed.
struct Signals {
    progress: focusd::service::proxy::ProgressStream,
    finished: focusd::service::proxy::FinishedStream,
    failed: focusd::service::proxy::FailedStream,
}

impl Signals {
    async fn subscribe(proxy: &Focusd1Proxy<'_>) -> Result<Signals, String> {
        let e = |e: zbus::Error| e.to_string();
        Ok(Signals {
            progress: proxy.receive_progress().await.map_err(e)?,
            finished: proxy.receive_finished().await.map_err(e)?,
            failed: proxy.receive_failed().await.map_err(e)?,
        })
    }

    /// The id of the job whose first Progress signal comes next (it has started).
    async fn started(&mut self) -> Result<String, String> {
        match tokio::time::timeout(Duration::from_secs(60), self.progress.next()).await {
            Ok(Some(s)) => Ok(s.args().map_err(|e| e.to_string())?.job.to_string()),
            _ => Err("no job started within 60 s of the press".into()),
        }
    }

    /// How the next job to end ended: its id and `Ok(path)` or `Err(error)`.
    async fn ended(&mut self) -> Result<(String, Result<String, String>), String> {
        let e = |e: zbus::Error| e.to_string();
        let deadline = tokio::time::sleep(Duration::from_secs(120));
        tokio::pin!(deadline);
        loop {
            tokio::select! {
                Some(_) = self.progress.next() => {}
                Some(s) = self.finished.next() => {
                    let a = s.args().map_err(e)?;
                    return Ok((a.job.to_string(), Ok(a.path.to_string())));
                }
                Some(s) = self.failed.next() => {
                    let a = s.args().map_err(e)?;
                    return Ok((a.job.to_string(), Err(a.error.to_string())));
                }
                _ = &mut deadline => return Err("no job ended within 120 s".into()),
            }
        }
    }
}

async fn run(focusd: &Path, bundle: &Path) -> Check {
    let a = VirtualKey::create("focusd-test-key-a")?;
    let s = start(focusd, bundle).await?;
    let result = checks(a, &s).await;
    for line in s.log().lines() {
        println!("KEYS-GUEST: focusd: {line}");
    }
    result
}

async fn checks(mut a: VirtualKey, s: &Setup) -> Check {
    let t0 = Instant::now();
    let ok = |what: &str| ok(format!("[{:.1}s] {what}", t0.elapsed().as_secs_f64()));
    s.wait_log("trigger keys: KEY_CAMERA on", 1).await?;
    ok("the daemon found the uinput device by its KEY_CAMERA capability");

    let short = Duration::from_millis(50);
    // Each step subscribes anew, replacing (dropping) the last step's streams: a stream left
    // unread fills its queue and stops the connection from reading anything.
    // 1. A press takes a picture.
    let mut sig = Signals::subscribe(&s.proxy).await?;
    a.press(short).await?;
    let (job, result) = sig.ended().await?;
    let path = result.map_err(|e| format!("the pressed job {job} failed: {e}"))?;
    ensure!(
        Path::new(&path).is_file() && s.pictures().len() == 1,
        "the press's job finished with {path}, but the output directory has {:?}",
        s.pictures()
    );
    ok(&format!("a press took a picture: {path}"));

    // 2. A long press during a paced job cancels it.
    sig = Signals::subscribe(&s.proxy).await?;
    a.press(short).await?;
    let job = sig.started().await?;
    a.press(Duration::from_millis(LONG_PRESS_MS * 3)).await?;
    let (ended, result) = sig.ended().await?;
    ensure!(
        ended == job && result == Err("cancelled".to_string()),
        "the long press during job {job} ended job {ended} with {result:?}"
    );
    ensure!(
        s.pictures().len() == 1,
        "a cancelled job left {:?}",
        s.pictures()
    );
    s.wait_log("trigger key held: cancel requested", 1).await?;
    ok("a long press during a job cancelled it; nothing was written");

    // 3. A press during a job is ignored; the device destroyed mid-job leaves the job alone.
    sig = Signals::subscribe(&s.proxy).await?;
    a.press(short).await?;
    let job = sig.started().await?;
    a.press(short).await?;
    s.wait_log("trigger key pressed: ignored", 1).await?;
    drop(a);
    s.wait_log("went away", 1).await?;
    let state = s.proxy.state().await.map_err(|e| e.to_string())?;
    ensure!(
        state != "idle",
        "the job had ended before its key device was destroyed; the test proves nothing"
    );
    let (ended, result) = sig.ended().await?;
    ensure!(
        ended == job && result.is_ok(),
        "job {job}, whose key device was destroyed mid-job ({state}), ended as {ended}: {result:?}"
    );
    ensure!(s.pictures().len() == 2, "pictures: {:?}", s.pictures());
    let state = s.proxy.state().await.map_err(|e| e.to_string())?;
    ensure!(state == "idle", "state after the job: {state}");
    ok(
        "a press during a job was ignored; the key device destroyed mid-job left the job to \
         finish and the daemon serving",
    );

    // 4. A device that appears later is used.
    let mut b = VirtualKey::create("focusd-test-key-b")?;
    s.wait_log("(focusd-test-key-b)", 1).await?;
    sig = Signals::subscribe(&s.proxy).await?;
    b.press(short).await?;
    let (job, result) = sig.ended().await?;
    result.map_err(|e| format!("the new device's job {job} failed: {e}"))?;
    ensure!(s.pictures().len() == 3, "pictures: {:?}", s.pictures());
    ok("a key device created after the daemon started was found and its press took a picture");

    Ok(())
}
