//! `focusd serve` on a private dbus-daemon, replaying the committed bundles: triggered from a
//! zbus client, from `focusd trigger --wait` and from `busctl`; busy, cancel, a bad bundle,
//! SIGHUP with a bad config, and SIGTERM mid-job.

mod common;

use common::daemon::{
    busctl, capture_and_wait, connect, dbus_error, outcome, runtime, subscribe, Bus, Daemon,
};
use common::stacks::{bundle_dir, load};
use common::system::is_root;
use focusd::stack::psnr;
use futures_util::StreamExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// A person at a terminal: `trigger --wait` under a pseudo-terminal (util-linux `script`) draws
/// a progress bar from the Progress signals instead of one line per stage, then the path.
#[test]
fn trigger_at_a_terminal_shows_a_progress_bar() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("shaken"), false);
    let command = format!(
        "'{}' trigger --wait --address '{}'",
        env!("CARGO_BIN_EXE_focusd"),
        bus.address
    );
    let o = Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .output()
        .expect("script not found: it is in Debian's bsdutils (essential)");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}\n{}", d.log());
    // The path comes after the bar is cleared (a carriage return and an erase-line sequence).
    let last = out.split(['\r', '\n']).rfind(|l| !l.trim().is_empty());
    let path = last
        .unwrap_or_default()
        .trim_start_matches("\x1b[2K")
        .trim();
    assert!(Path::new(path).starts_with(d.out()), "{out:?}");
    assert!(
        !out.contains("focusd: sweeping"),
        "lines instead of a bar: {out}"
    );
    // The bar: a stage name, then `[====>   ] done/total`.
    let bar = out
        .split(['\r', '\n'])
        .find(|l| l.contains("sweeping") && l.contains(" [") && l.contains("] "))
        .unwrap_or_else(|| panic!("no bar drawn: {out:?}"));
    assert!(bar.contains('/'), "{bar}");
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
        let (finished, failed) = subscribe(&proxy).await;
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
        for s in [
            "waiting-still",
            "sweeping",
            "register",
            "labels",
            "spill",
            "compose",
        ] {
            assert!(stages.iter().any(|x| x == s), "{s} missing from {stages:?}");
        }

        // 3. busctl.
        let earlier_job = job;
        let (finished, failed) = subscribe(&proxy).await;
        let o = busctl(&bus, &["Capture"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let reply = String::from_utf8_lossy(&o.stdout);
        let job = reply
            .trim()
            .trim_start_matches("s ")
            .trim_matches('"')
            .to_string();
        // Job ids are 128 random bits: no caller can guess another's.
        assert!(
            job.len() == 32 && job.chars().all(|c| c.is_ascii_hexdigit()),
            "{reply}"
        );
        assert_ne!(job, earlier_job);
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
        let (finished, failed) = subscribe(&proxy).await;
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
        let path = capture_and_wait(&proxy).await.unwrap();
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
    std::fs::write(&frame, &saved[..saved.len() / 3]).unwrap();
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = subscribe(&proxy).await;
        let job = proxy.capture().await.unwrap();
        let e = outcome(&job, finished, failed).await.unwrap_err();
        assert!(
            e.contains("frame_03.jpg")
                && e.contains("truncated")
                && e.contains("take 0 of plane 3"),
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
        let path = capture_and_wait(&proxy).await.unwrap();
        // Still the old config's output directory.
        assert_eq!(Path::new(&path).parent(), Some(d.out().as_path()));
    });
}

#[test]
fn sigterm_mid_sweep_or_mid_fuse_cancels_the_job_and_exits_zero() {
    for stage in ["sweeping", "register"] {
        sigterm_at(stage);
    }
}

/// Sends SIGTERM when the job reaches `stage`.
fn sigterm_at(stage: &str) {
    let bus = Bus::start();
    let mut d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = subscribe(&proxy).await;
        let mut progress = proxy.receive_progress().await.unwrap();
        let job = proxy.capture().await.unwrap();
        while let Some(s) = progress.next().await {
            if s.args().unwrap().stage == stage {
                break;
            }
        }
        d.signal("-TERM");
        let e = outcome(&job, finished, failed).await.unwrap_err();
        assert_eq!(e, "cancelled", "at {stage}");
    });
    let status = d.wait_exit(Duration::from_secs(20));
    assert_eq!(status.code(), Some(0), "{}", d.log());
    assert!(d.outputs().is_empty(), "at {stage}: {:?}", d.outputs());
    assert!(d.log().contains("replay camera released"), "{}", d.log());
}

#[test]
fn only_the_user_who_started_a_job_or_root_may_cancel_it() {
    if !is_root() {
        eprintln!("skipped: calling as another user needs root (CI runs as root)");
        return;
    }
    let (bus, _config) = Bus::start_open();
    let _d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = subscribe(&proxy).await;
        let job = proxy.capture().await.unwrap();
        // The same call as user nobody: refused, and the job runs on.
        let o = Command::new("setpriv")
            .args(["--reuid=65534", "--regid=65534", "--clear-groups", "busctl"])
            .arg(format!("--address={}", bus.address))
            .args(["call", "org.focusd.Focusd", "/org/focusd/Focusd"])
            .args(["org.focusd.Focusd1", "Cancel", "s", &job])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "nobody cancelled root's job");
        assert!(
            err.contains("uid 0") && err.contains("only that user or root"),
            "{err}"
        );
        assert_ne!(proxy.state().await.unwrap(), "idle");
        // Its owner may.
        proxy.cancel(&job).await.unwrap();
        assert_eq!(
            outcome(&job, finished, failed).await.unwrap_err(),
            "cancelled"
        );
    });
}

/// What the fake feedbackd and notification daemon were asked, in order.
type Calls = std::sync::Arc<std::sync::Mutex<Vec<String>>>;

struct FakeFeedbackd(Calls);

#[zbus::interface(name = "org.sigxcpu.Feedback")]
impl FakeFeedbackd {
    fn trigger_feedback(
        &self,
        app_id: &str,
        event: &str,
        _hints: std::collections::HashMap<String, zbus::OwnedVariant>,
        timeout: i32,
    ) -> u32 {
        let mut c = self.0.lock().unwrap();
        c.push(format!("feedback {app_id} {event} {timeout}"));
        c.len() as u32
    }
}

struct FakeNotifications(Calls);

#[zbus::interface(name = "org.freedesktop.Notifications")]
impl FakeNotifications {
    #[allow(clippy::too_many_arguments)]
    fn notify(
        &self,
        app_name: &str,
        _replaces_id: u32,
        _app_icon: &str,
        summary: &str,
        body: &str,
        _actions: Vec<String>,
        hints: std::collections::HashMap<String, zbus::OwnedVariant>,
        _expire_timeout: i32,
    ) -> u32 {
        let image = hints
            .get("image-path")
            .and_then(|v| String::try_from(v.clone()).ok())
            .unwrap_or_default();
        let mut c = self.0.lock().unwrap();
        c.push(format!("notify {app_name} {summary} | {body} | {image}"));
        c.len() as u32
    }
}

/// Serves the fakes on `bus` under their real names, recording into one list.
async fn fake_desktop(bus: &Bus) -> (Calls, Vec<zbus::Connection>) {
    let calls = Calls::default();
    let mut conns = Vec::new();
    for (name, path) in [
        ("org.sigxcpu.Feedback", "/org/sigxcpu/Feedback"),
        (
            "org.freedesktop.Notifications",
            "/org/freedesktop/Notifications",
        ),
    ] {
        let addr: zbus::Address = bus.address.parse().unwrap();
        let b = zbus::connection::Builder::address(addr).name(name);
        let b = if name == "org.sigxcpu.Feedback" {
            b.serve_at(path, FakeFeedbackd(calls.clone()))
        } else {
            b.serve_at(path, FakeNotifications(calls.clone()))
        };
        conns.push(b.build().await.unwrap());
    }
    (calls, conns)
}

/// The calls recorded once `n` have come (they are sent beside the signals, not before them).
async fn calls_after(calls: &Calls, n: usize) -> Vec<String> {
    for _ in 0..200 {
        if calls.lock().unwrap().len() >= n {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    calls.lock().unwrap().clone()
}

#[test]
fn the_person_holding_the_phone_is_told_to_hold_still_and_when_it_is_done() {
    let bus = Bus::start();
    let _d = Daemon::start(&bus, &bundle_dir("calm"), false);
    runtime().block_on(async {
        let (calls, _fakes) = fake_desktop(&bus).await;
        let (_conn, proxy) = connect(&bus).await;
        let path = capture_and_wait(&proxy).await.unwrap();
        let seen = calls_after(&calls, 3).await;
        assert_eq!(
            seen,
            [
                "feedback org.focusd.Viewfinder camera-focus -1".to_string(),
                "feedback org.focusd.Viewfinder camera-shutter -1".to_string(),
                format!("notify focusd Focus stack saved | {path} | file://{path}"),
            ]
        );
    });
}

#[test]
fn a_failed_capture_gives_the_failure_feedback_and_says_why() {
    let bus = Bus::start();
    let _d = Daemon::start_with(
        &bus,
        &bundle_dir("calm"),
        false,
        &["--fault", "camera-gone:2"],
    );
    runtime().block_on(async {
        let (calls, _fakes) = fake_desktop(&bus).await;
        let (_conn, proxy) = connect(&bus).await;
        let error = capture_and_wait(&proxy).await.unwrap_err();
        let seen = calls_after(&calls, 3).await;
        // In the order of their moments, though the camera fails as soon as the sweep starts.
        assert_eq!(
            seen,
            [
                "feedback org.focusd.Viewfinder camera-focus -1".to_string(),
                "feedback org.focusd.Viewfinder phone-failure -1".to_string(),
                format!("notify focusd Focus stack failed | {error} | "),
            ]
        );
    });
}

#[test]
fn without_an_output_dir_pictures_land_in_the_users_localised_pictures_folder() {
    let home = tempfile::tempdir().unwrap();
    let config = home.path().join(".config");
    std::fs::create_dir_all(&config).unwrap();
    std::fs::write(
        config.join("user-dirs.dirs"),
        "# written by xdg-user-dirs-update\nXDG_PICTURES_DIR=\"$HOME/Bilder\"\n",
    )
    .unwrap();
    let bus = Bus::start();
    let home_str = home.path().to_str().unwrap();
    let _d = Daemon::start_full(
        &bus,
        Some(&bundle_dir("calm")),
        false,
        &[],
        "[output]\nreport = false\n",
        &[("HOME", home_str), ("XDG_CONFIG_HOME", "")],
    );
    // The folder is created when the service starts, before any capture.
    assert!(home.path().join("Bilder/focusd").is_dir());
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let path = capture_and_wait(&proxy).await.unwrap();
        assert_eq!(
            Path::new(&path).parent(),
            Some(home.path().join("Bilder/focusd").as_path())
        );
    });
}

/// A relative `[output] dir` (from the service's working directory) is made absolute at start:
/// `Finished`, `LastResult`, `trigger --wait` and the report give paths a client in any
/// directory can open.
#[test]
fn a_relative_output_dir_is_reported_as_absolute_paths() {
    let tmp = tempfile::tempdir().unwrap();
    let cwd = std::env::current_dir().unwrap();
    let up: PathBuf = cwd.components().skip(1).map(|_| "..").collect();
    let relative = up.join(tmp.path().strip_prefix("/").unwrap()).join("out");
    let bus = Bus::start();
    let d = Daemon::start_full(
        &bus,
        Some(&bundle_dir("calm")),
        false,
        &[],
        &format!("[output]\ndir = {relative:?}\n"),
        &[],
    );
    let absolute = |p: &str| {
        assert!(Path::new(p).is_absolute() && Path::new(p).is_file(), "{p}");
        assert!(Path::new(p).starts_with(cwd.join(&relative)), "{p}");
    };
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let path = capture_and_wait(&proxy).await.unwrap();
        absolute(&path);
        assert_eq!(proxy.last_result().await.unwrap(), path);
        let r: serde_json::Value = serde_json::from_slice(
            &std::fs::read(Path::new(&path).with_extension("json")).unwrap(),
        )
        .unwrap();
        assert_eq!(r["output"].as_str(), Some(path.as_str()));
    });
    let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["trigger", "--wait", "--address", &bus.address])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", d.log());
    absolute(String::from_utf8_lossy(&o.stdout).trim());
}

/// A trigger key device that is not one (here /dev/null, then a path that does not exist) is a
/// log line naming it; the service serves D-Bus captures all the same.
#[test]
fn a_trigger_device_that_is_not_an_input_device_is_a_log_line_and_captures_still_work() {
    let bus = Bus::start();
    for (device, says) in [
        ("/dev/null", "/dev/null: a mem device, not an evdev node"),
        ("/nonexistent/event9", "/nonexistent/event9: No such file"),
    ] {
        let tables = format!("[trigger]\nkeys = [\"KEY_VOLUMEUP\"]\ndevice = {device:?}\n");
        let d = Daemon::start_full(&bus, Some(&bundle_dir("calm")), false, &[], &tables, &[]);
        d.wait_for_log(&format!(
            "trigger keys: input device {device} is not in use; cannot use"
        ));
        assert!(d.log().contains(says), "{}", d.log());
        runtime().block_on(async {
            let (_conn, proxy) = connect(&bus).await;
            let path = capture_and_wait(&proxy).await.unwrap();
            assert!(Path::new(&path).exists());
        });
    }
}

/// A raw replay's takes are developed after the sweep in a `developing` stage, frame by frame:
/// held there (an injected hold at frame 3), the State says so, Capture is Busy, and Cancel ends
/// the job with nothing written, not even the raw takes already kept. The next capture goes
/// through the stage to the end and keeps its raw takes beside the picture.
#[test]
fn developing_is_a_stage_that_is_busy_and_cancels_leaving_nothing() {
    let bus = Bus::start();
    let out = tempfile::tempdir().unwrap();
    let tables = format!("[output]\ndir = {:?}\nkeep_raw = true\n", out.path());
    let d = Daemon::start_full(
        &bus,
        Some(&bundle_dir("raw")),
        false,
        &["--fault", "develop-hold:3"],
        &tables,
        &[],
    );
    let outputs = || {
        let mut v: Vec<String> = std::fs::read_dir(out.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let (finished, failed) = subscribe(&proxy).await;
        let mut progress = proxy.receive_progress().await.unwrap();
        let job = proxy.capture().await.unwrap();
        let developing = developing_progress(&mut progress, &job, Some(3)).await;
        drop(progress);
        assert_eq!(developing, [(0, 6), (1, 6), (2, 6), (3, 6)]);
        assert_eq!(proxy.state().await.unwrap(), "developing");
        let (name, msg) = dbus_error(proxy.capture().await.unwrap_err());
        assert_eq!(name, "org.focusd.Error.Busy");
        assert!(msg.contains(&format!("job {job} is running")), "{msg}");
        proxy.cancel(&job).await.unwrap();
        assert_eq!(
            outcome(&job, finished, failed).await.unwrap_err(),
            "cancelled"
        );
        assert_eq!(proxy.state().await.unwrap(), "idle");
        assert!(outputs().is_empty(), "{:?}\n{}", outputs(), d.log());

        // The hold was for the first job only: this one develops every frame and finishes.
        let (finished, failed) = subscribe(&proxy).await;
        let mut progress = proxy.receive_progress().await.unwrap();
        let job = proxy.capture().await.unwrap();
        let developing = developing_progress(&mut progress, &job, None).await;
        // Unread, the stream would hold up the connection, and the Finished signal with it.
        drop(progress);
        assert_eq!(developing, (0..=6).map(|i| (i, 6)).collect::<Vec<_>>());
        let path = outcome(&job, finished, failed).await.unwrap();
        let stem = Path::new(&path)
            .file_stem()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let mut expected = vec![format!("{stem}.jpg"), format!("{stem}.json")];
        expected.extend((0..6).map(|p| format!("{stem}-raw-{p:02}.dng")));
        expected.sort();
        assert_eq!(outputs(), expected);
        let r: serde_json::Value = serde_json::from_slice(
            &std::fs::read(Path::new(&path).with_extension("json")).unwrap(),
        )
        .unwrap();
        assert!(r["timings_ms"]["develop"].as_f64().unwrap() > 0.0, "{r}");
    });
}

/// The (done, total) of `job`'s `developing` Progress signals, up to the one with done `until`,
/// or (`None`) up to the first of a later stage.
async fn developing_progress(
    progress: &mut focusd::service::proxy::ProgressStream,
    job: &str,
    until: Option<u32>,
) -> Vec<(u32, u32)> {
    let mut seen = Vec::new();
    while let Some(s) = progress.next().await {
        let a = s.args().unwrap();
        if a.job != job {
            continue;
        }
        if a.stage != "developing" {
            if seen.is_empty() {
                continue;
            }
            break;
        }
        seen.push((a.done, a.total));
        if Some(a.done) == until {
            break;
        }
    }
    seen
}
