//! Runs that are stopped or whose last writes fail leave nothing behind: Ctrl-C and SIGTERM
//! remove the temporary files, a SIGKILLed run's are removed by the next run into that folder,
//! and a rename that fails (injected with strace) undoes the outputs already renamed.

mod common;

use common::stacks::bundle_dir;
use common::system::is_root;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

fn focusd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_focusd"))
}

/// Every name in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn temporaries(dir: &Path) -> Vec<String> {
    names(dir)
        .into_iter()
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

/// A stack big enough that fusing it takes a while: the child is stopped mid-work.
fn big_stack(dir: &Path) -> Vec<PathBuf> {
    let st = focusd()
        .args([
            "simulate", "--width", "1600", "--height", "1200", "--planes", "8",
        ])
        .arg("-o")
        .arg(dir)
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(st.success());
    (0..8)
        .map(|i| dir.join(format!("frame_{i:02}.jpg")))
        .collect()
}

/// Waits until `child` has made a temporary file in `dir`, then sends it `signal`.
fn stop_mid_work(child: &mut Child, dir: &Path, signal: &str) -> ExitStatus {
    let t = Instant::now();
    while temporaries(dir).is_empty() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before it made a temporary file"
        );
        assert!(t.elapsed() < Duration::from_secs(60), "no temporary file");
        std::thread::sleep(Duration::from_millis(5));
    }
    let st = Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    child.wait().unwrap()
}

fn fuse_into(frames: &[PathBuf], out: &Path) -> Command {
    let mut c = focusd();
    c.arg("fuse")
        .args(frames)
        .arg("-o")
        .arg(out.join("out.jpg"));
    c.arg("--depthmap").arg(out.join("depth.png"));
    c.stdout(Stdio::null()).stderr(Stdio::piped());
    c
}

#[test]
fn ctrl_c_and_sigterm_mid_fuse_remove_the_temporary_files() {
    let d = tempfile::tempdir().unwrap();
    let frames = big_stack(&d.path().join("stack"));
    for (signal, code) in [("INT", 130), ("TERM", 143)] {
        let out = d.path().join(signal);
        fs::create_dir(&out).unwrap();
        let mut child = fuse_into(&frames, &out).spawn().unwrap();
        let st = stop_mid_work(&mut child, &out, signal);
        let mut err = String::new();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
        assert_eq!(st.code(), Some(code), "SIG{signal}: {err}");
        assert!(err.contains(&format!("SIG{signal}")), "{err}");
        assert!(names(&out).is_empty(), "SIG{signal} left {:?}", names(&out));
    }
}

#[test]
fn a_killed_runs_temporary_files_are_removed_by_the_next_run_and_no_others() {
    let d = tempfile::tempdir().unwrap();
    let frames = big_stack(&d.path().join("stack"));
    let out = d.path().join("out");
    fs::create_dir(&out).unwrap();
    // Another program's hidden temporary file, and a name that only looks like ours.
    let theirs = [".out.jpg.1234.tmp", ".notes.focusd-x.tmp"];
    for n in theirs {
        fs::write(out.join(n), "keep").unwrap();
    }
    let mut child = fuse_into(&frames, &out).spawn().unwrap();
    let st = stop_mid_work(&mut child, &out, "KILL");
    assert!(!st.success());
    let left = temporaries(&out);
    assert!(left.iter().any(|n| n.contains(".focusd-")), "{left:?}");
    // The next run into that folder (a small one) sweeps them.
    let small: Vec<PathBuf> = frames.iter().take(2).cloned().collect();
    let small_dir = d.path().join("small");
    fs::create_dir(&small_dir).unwrap();
    let st = focusd()
        .args(["simulate", "--planes", "2", "-o"])
        .arg(&small_dir)
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(st.success());
    drop(small);
    let small = [
        small_dir.join("frame_00.jpg"),
        small_dir.join("frame_01.jpg"),
    ];
    let o = fuse_into(&small, &out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut want = vec!["depth.png".to_string(), "out.jpg".to_string()];
    want.extend(theirs.iter().map(|s| s.to_string()));
    want.sort();
    assert_eq!(names(&out), want);
}

#[test]
fn sigterm_mid_capture_leaves_neither_picture_nor_report_nor_temporary_file() {
    let d = tempfile::tempdir().unwrap();
    let mut child = focusd()
        .args(["capture", "--replay"])
        .arg(bundle_dir("shaken"))
        .arg("-o")
        .arg(d.path().join("pic.jpg"))
        .arg("--report")
        .arg(d.path().join("report.json"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let st = stop_mid_work(&mut child, d.path(), "TERM");
    assert_eq!(st.code(), Some(143));
    assert!(names(d.path()).is_empty(), "{:?}", names(d.path()));
}

/// `focusd fuse` with the `n`th rename failing (EROFS, injected by strace), or None where
/// strace cannot inject here.
fn fuse_with_failing_rename(frames: &[PathBuf], out: &Path, n: usize) -> Option<String> {
    let mut c = Command::new("strace");
    c.args(["-f", "-qq", "-o", "/dev/null", "-e", "trace=rename", "-e"]);
    c.arg(format!("inject=rename:error=EROFS:when={n}"));
    c.arg(env!("CARGO_BIN_EXE_focusd")).arg("fuse").args(frames);
    for (flag, name) in [
        ("-o", "out.jpg"),
        ("--depthmap", "depth.png"),
        ("--save-transforms", "t.json"),
    ] {
        c.arg(flag).arg(out.join(name));
    }
    let o = c.output().ok()?;
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    if err.contains("PTRACE") || err.contains("ptrace") {
        return None;
    }
    assert!(!o.status.success(), "the run succeeded: {err}");
    Some(err)
}

#[test]
fn a_failed_rename_lands_no_output_and_puts_back_what_it_replaced() {
    if Command::new("strace").arg("-V").output().is_err() {
        panic!("strace is needed for this test (apt-get install strace)");
    }
    let d = tempfile::tempdir().unwrap();
    let stack = d.path().join("stack");
    let st = focusd()
        .args([
            "simulate", "--width", "96", "--height", "64", "--planes", "3",
        ])
        .arg("-o")
        .arg(&stack)
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(st.success());
    let frames: Vec<PathBuf> = (0..3)
        .map(|i| stack.join(format!("frame_{i:02}.jpg")))
        .collect();
    for n in [1, 2, 3] {
        // Into an empty folder: nothing lands.
        let out = d.path().join(format!("new{n}"));
        fs::create_dir(&out).unwrap();
        let Some(err) = fuse_with_failing_rename(&frames, &out, n) else {
            eprintln!("skipped: strace cannot trace here");
            return;
        };
        assert!(err.contains("Read-only file system"), "{err}");
        assert!(names(&out).is_empty(), "rename {n}: {:?}", names(&out));
        // Over earlier outputs: they are all as they were.
        let out = d.path().join(format!("old{n}"));
        fs::create_dir(&out).unwrap();
        for name in ["out.jpg", "depth.png", "t.json"] {
            fs::write(out.join(name), format!("earlier {name}")).unwrap();
        }
        fuse_with_failing_rename(&frames, &out, n).unwrap();
        assert_eq!(names(&out), ["depth.png", "out.jpg", "t.json"]);
        for name in ["out.jpg", "depth.png", "t.json"] {
            assert_eq!(
                fs::read_to_string(out.join(name)).unwrap(),
                format!("earlier {name}"),
                "rename {n}"
            );
        }
    }
}

#[test]
fn a_recording_on_a_full_disk_leaves_no_half_bundle() {
    if !is_root() {
        eprintln!("skipped: mounting a small tmpfs needs root (CI runs as root)");
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let mnt = d.path().join("small");
    fs::create_dir(&mnt).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=512k", "tmpfs"])
        .arg(&mnt)
        .status()
        .unwrap();
    assert!(mounted.success(), "mount tmpfs");
    let o = focusd()
        .args(["record", "--replay"])
        .arg(bundle_dir("shaken"))
        .arg("-o")
        .arg(mnt.join("bundle"))
        .output()
        .unwrap();
    let left = names(&mnt);
    let _ = Command::new("umount").arg(&mnt).status();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("No space left"), "{err}");
    assert!(left.is_empty(), "{left:?}");
}
