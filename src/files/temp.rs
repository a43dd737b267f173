//! The temporary files and folders outputs are written through: their names, the ones this
//! process has open (removed when it is interrupted), and stale ones a killed run left behind.
//!
//! A temporary name is `.NAME.focusd-PID.tmp` beside the final NAME: hidden, and tied to the
//! process that made it, so a later run can tell that its maker is gone and remove it without
//! ever touching a file of another program's.

use super::error::{shown, FileError};
use std::ffi::{OsStr, OsString};
use std::fs;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};
use std::time::SystemTime;

/// Bytes of the final name kept in a temporary name: with the dot, the tag, the process id
/// and `.tmp` it stays under the 255 bytes a file name may have.
const NAME_BYTES_KEPT: usize = 200;

/// What sets focusd's temporary names apart: `.NAME` + this + `PID.tmp`.
const TAG: &str = ".focusd-";

/// The temporary files and folders this process has made and not yet renamed or removed, and
/// whether it is being interrupted (then no new one may be made).
struct Live {
    paths: Vec<PathBuf>,
    closed: bool,
}

static LIVE: Mutex<Live> = Mutex::new(Live {
    paths: Vec::new(),
    closed: false,
});

/// The registry of live temporary paths. Held while outputs are renamed into place, so an
/// interruption waits for the renames and never removes a file mid-commit.
pub(super) fn live() -> LiveGuard {
    LiveGuard(LIVE.lock().unwrap_or_else(|e| e.into_inner()))
}

pub(super) struct LiveGuard(MutexGuard<'static, Live>);

impl LiveGuard {
    /// Records a temporary path made under this guard; refused once the process is
    /// interrupted, so nothing is made after the clean-up.
    pub(super) fn add(&mut self, tmp: &Path) -> Result<(), FileError> {
        if self.0.closed {
            return Err(FileError::Write {
                path: shown(tmp),
                error: std::io::Error::new(std::io::ErrorKind::Interrupted, "interrupted"),
            });
        }
        self.0.paths.push(tmp.to_path_buf());
        Ok(())
    }

    /// Forgets a temporary path that was renamed into place or removed.
    pub(super) fn forget(&mut self, tmp: &Path) {
        self.0.paths.retain(|p| p != tmp);
    }
}

/// Removes every temporary file and folder this process has open and refuses new ones: what
/// an interrupted command does before it exits (SIGINT, SIGTERM), so it leaves nothing behind.
/// Renames under way finish first.
pub fn abandon() {
    let mut live = live();
    live.0.closed = true;
    for p in std::mem::take(&mut live.0.paths) {
        remove_any(&p);
    }
}

/// Makes `path`'s temporary (a file or a folder, by `make`) and records it as live: a stale one
/// of this process's id (a crash of an earlier process with the same id) is removed first, and
/// nothing is left if the process is being interrupted.
pub(super) fn claim<T>(
    path: &Path,
    make: impl FnOnce(&Path) -> std::io::Result<T>,
) -> Result<(PathBuf, T), FileError> {
    let tmp = temp_path(path)?;
    let mut live = live();
    remove_any(&tmp);
    let made = make(&tmp).map_err(|error| FileError::Write {
        path: shown(path),
        error,
    })?;
    if let Err(e) = live.add(&tmp) {
        remove_any(&tmp);
        return Err(e);
    }
    Ok((tmp, made))
}

/// The temporary path `path` is written through, beside it: `.NAME.focusd-PID.tmp`, with NAME
/// cut to [`NAME_BYTES_KEPT`] bytes.
pub fn temp_path(path: &Path) -> Result<PathBuf, FileError> {
    let name = path
        .file_name()
        .ok_or_else(|| FileError::NotAFilePath { path: shown(path) })?
        .as_bytes();
    let mut end = name.len().min(NAME_BYTES_KEPT);
    // A UTF-8 name is cut between characters, so the temporary name stays readable.
    if let Ok(s) = std::str::from_utf8(name) {
        while !s.is_char_boundary(end) {
            end -= 1;
        }
    }
    let mut tmp = OsString::from(".");
    tmp.push(OsStr::from_bytes(&name[..end]));
    tmp.push(format!("{TAG}{}.tmp", std::process::id()));
    Ok(dir_of(path).join(tmp))
}

/// The directory `path` is in; `.` for a bare name.
pub(super) fn dir_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The process id in a temporary name of focusd's, if `name` is one.
fn maker(name: &OsStr) -> Option<u32> {
    let name = name.to_str()?;
    let rest = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let (stem, pid) = rest.rsplit_once(TAG)?;
    if stem.is_empty() || pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// Whether process `pid` still runs (signal 0 reaches it, or it exists under another user).
fn alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: signal 0 checks for the process and sends nothing.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// When this process first looked for stale temporary paths: one made since, even by a
/// process this one cannot see (another PID namespace), is left alone.
fn started() -> SystemTime {
    static STARTED: std::sync::OnceLock<SystemTime> = std::sync::OnceLock::new();
    *STARTED.get_or_init(SystemTime::now)
}

/// Removes from `dir` the temporary files and folders of focusd's naming whose maker no longer
/// runs and that are older than this run: what a killed run (SIGKILL, a crash, the
/// battery) left. Nothing else is touched; what cannot be removed is left as it is. Returns
/// how many were removed.
pub(super) fn sweep_stale(dir: &Path) -> usize {
    let me = std::process::id();
    let Ok(entries) = fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let Some(pid) = maker(&e.file_name()) else {
            continue;
        };
        let Ok(meta) = e.path().symlink_metadata() else {
            continue;
        };
        let old = meta.modified().is_ok_and(|t| t < started());
        if pid == me || !old || alive(pid) {
            continue;
        }
        remove_any(&e.path());
        removed += 1;
    }
    if removed > 0 {
        tracing::info!(
            "removed {removed} temporary file(s) a killed run left in {}",
            dir.display()
        );
    }
    removed
}

/// Removes a file, a link, or a folder with what is in it (never following a link).
pub(super) fn remove_any(p: &Path) {
    match p.symlink_metadata() {
        Ok(m) if m.is_dir() => {
            let _ = fs::remove_dir_all(p);
        }
        Ok(_) => {
            let _ = fs::remove_file(p);
        }
        Err(_) => {}
    }
}

/// Whether two paths name one file (by device and inode).
pub(super) fn same_file(a: &Path, b: &Path) -> bool {
    match (fs::metadata(a), fs::metadata(b)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporary_names_fit_in_255_bytes() {
        // 251 bytes, and byte 200 falls inside an "é".
        let long = Path::new("/tmp").join(format!("x{}", "é".repeat(125)));
        let tmp = temp_path(&long).unwrap();
        assert!(tmp.file_name().unwrap().len() <= 255);
        let tmp = tmp.to_str().expect("cut between characters");
        assert!(
            tmp.starts_with("/tmp/.xé") && tmp.ends_with(".tmp"),
            "{tmp}"
        );
        assert_eq!(
            maker(Path::new(tmp).file_name().unwrap()),
            Some(std::process::id())
        );
    }

    #[test]
    fn only_focusd_names_tell_a_maker() {
        for name in [".out.jpg.focusd-12.tmp", "..focusd-7.tmp.focusd-99.tmp"] {
            assert!(maker(OsStr::new(name)).is_some(), "{name}");
        }
        for name in [
            "out.jpg.focusd-12.tmp",
            ".out.jpg.12.tmp",
            ".out.jpg.focusd-.tmp",
            ".out.jpg.focusd-1x.tmp",
            ".focusd-12.tmp",
            ".out.jpg.focusd-12.tmp~",
        ] {
            assert_eq!(maker(OsStr::new(name)), None, "{name}");
        }
    }

    #[test]
    fn stale_temporaries_of_dead_makers_go_and_nothing_else() {
        let d = tempfile::tempdir().unwrap();
        // A pid past the kernel's limit never runs.
        let dead = 1 << 23;
        let stale = d.path().join(format!(".a.jpg{TAG}{dead}.tmp"));
        fs::write(&stale, "").unwrap();
        let stale_dir = d.path().join(format!(".bundle{TAG}{dead}.tmp"));
        fs::create_dir(&stale_dir).unwrap();
        fs::write(stale_dir.join("plane00_take0.png"), "x").unwrap();
        // A live maker's (pid 1), our own, another program's, and a fresh one of a dead maker.
        let keep = [
            format!(".b.jpg{TAG}1.tmp"),
            format!(".c.jpg{TAG}{}.tmp", std::process::id()),
            ".d.jpg.123.tmp".to_string(),
            "e.jpg".to_string(),
        ];
        for k in &keep {
            fs::write(d.path().join(k), "").unwrap();
        }
        let old = SystemTime::now() - std::time::Duration::from_secs(3600);
        for p in [&stale, &stale_dir] {
            fs::File::open(p).unwrap().set_modified(old).unwrap();
        }
        let fresh = d.path().join(format!(".f.jpg{TAG}{dead}.tmp"));
        fs::write(&fresh, "").unwrap();
        fs::File::options()
            .write(true)
            .open(&fresh)
            .unwrap()
            .set_modified(SystemTime::now() + std::time::Duration::from_secs(3600))
            .unwrap();
        assert_eq!(sweep_stale(d.path()), 2);
        let mut left: Vec<String> = fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        let mut want: Vec<String> = keep.to_vec();
        want.push(format!(".f.jpg{TAG}{dead}.tmp"));
        want.sort();
        assert_eq!(left, want);
    }
}
