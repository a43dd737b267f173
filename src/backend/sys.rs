//! What std does not expose, for the V4L2, IIO and input backends: a device node's kernel class
//! (from sysfs), and two C library calls:
//! `clock_gettime(CLOCK_MONOTONIC)` (std's `Instant` reads that clock but never shows its value,
//! and IIO and V4L2 timestamps are compared against it) and `poll(2)` (a blocking read of
//! /dev/iio:deviceN cannot be interrupted, so the reader waits for readability with a timeout
//! and can be stopped). Through the libc crate, whose `timespec` and `pollfd` follow each
//! target's ABI (a 64-bit `time_t` on 32-bit targets that have one).

use crate::capture::{Clock, Nanos};
use std::ffi::c_int;
use std::io;
use std::os::fd::AsRawFd;

/// Now on CLOCK_MONOTONIC, the clock of V4L2 buffer timestamps and (once
/// `current_timestamp_clock` says `monotonic`) of IIO timestamps.
pub fn monotonic_now() -> Nanos {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec and the call writes only it.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    // It fails only for a bad clock id or pointer, neither of which can happen here.
    assert_eq!(r, 0, "clock_gettime(CLOCK_MONOTONIC) failed");
    ts.tv_sec as Nanos * 1_000_000_000 + ts.tv_nsec as Nanos
}

/// Waits up to `timeout_ms` for `fd` to be readable (or at end of file, or in error: the next
/// read says which); `Ok(false)` on timeout or signal.
pub fn wait_readable(fd: &impl AsRawFd, timeout_ms: c_int) -> io::Result<bool> {
    let mut p = libc::pollfd {
        fd: fd.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one valid pollfd, and the count says one.
    let r = unsafe { libc::poll(&mut p, 1, timeout_ms) };
    match r {
        0 => Ok(false),
        r if r > 0 => Ok(true),
        _ => {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                Ok(false)
            } else {
                Err(e)
            }
        }
    }
}

/// Opens the device node `path` non-blocking (`write`: read-write, else read-only), refusing
/// anything but a character device of one of the kernel `classes` before any ioctl: a config
/// naming a regular file, a FIFO or another kind of device (`/dev/zero`) gets an error saying
/// what it names (`what`: "a V4L2 video, sub-device or media node"), not a confusing ioctl
/// failure or a hang.
pub fn open_device(
    path: &std::path::Path,
    write: bool,
    classes: &[&str],
    what: &str,
) -> io::Result<std::fs::File> {
    use std::os::unix::fs::{FileTypeExt, MetadataExt, OpenOptionsExt};
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(write)
        .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
        .open(path)?;
    let meta = file.metadata()?;
    if !meta.file_type().is_char_device() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("not a character device ({what})"),
        ));
    }
    match device_class(meta.rdev()) {
        Some(class) if !classes.contains(&class.as_str()) => Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("a {class} device, not {what}"),
        )),
        _ => Ok(file),
    }
}

/// The kernel class of a character device (`video4linux`, `media`, `mem`...), from sysfs; `None`
/// where sysfs does not say (then the ioctls will).
fn device_class(rdev: u64) -> Option<String> {
    let (major, minor) = (libc::major(rdev), libc::minor(rdev));
    let link = std::fs::read_link(format!("/sys/dev/char/{major}:{minor}/subsystem")).ok()?;
    Some(link.file_name()?.to_string_lossy().into_owned())
}

/// The real clock of a phone's sweep.
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    fn now(&self) -> Nanos {
        monotonic_now()
    }

    fn sleep_until(&self, t: Nanos) {
        let ahead = t - monotonic_now();
        if ahead > 0 {
            std::thread::sleep(std::time::Duration::from_nanos(ahead as u64));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_moves_with_instant() {
        let (a, i) = (monotonic_now(), std::time::Instant::now());
        std::thread::sleep(std::time::Duration::from_millis(20));
        let (b, d) = (monotonic_now(), i.elapsed());
        assert!(a > 0 && b > a);
        let diff = (b - a) - d.as_nanos() as i64;
        assert!(diff.abs() < 5_000_000, "{diff} ns apart");
    }

    #[test]
    fn a_plain_file_is_readable() {
        let f = tempfile::tempfile().unwrap();
        assert!(wait_readable(&f, 10).unwrap());
    }
}
