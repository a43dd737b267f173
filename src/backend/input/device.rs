//! One evdev node (/dev/input/eventN), opened read-only and non-blocking: its name, the keys it
//! reports, and its key events with their times on CLOCK_MONOTONIC.

use super::abi::{self, InputEvent};
use crate::backend::videodev::abi::c_str;
use crate::capture::Nanos;
use rustix::ioctl::{Opcode, Setter, Updater};
use std::fs::File;
use std::io::{self, Read};
use std::os::fd::AsFd;
use std::path::{Path, PathBuf};

pub struct InputDevice {
    pub path: PathBuf,
    pub name: String,
    file: File,
    /// The kernel stamps events on CLOCK_MONOTONIC (else they are stamped when read).
    monotonic: bool,
}

/// What a read gave.
pub enum KeyRead {
    /// A key went down (`value` 1) or up (0); autorepeats (2) are left out.
    Key { code: u16, down: bool, at: Nanos },
    /// The kernel's buffer overflowed and events were dropped: the key state is unknown.
    Dropped,
}

impl InputDevice {
    pub fn open(path: &Path) -> io::Result<InputDevice> {
        let file = crate::backend::sys::open_device(
            path,
            false,
            &["input"],
            "an evdev node, /dev/input/eventN",
        )?;
        let name = c_str(&get::<{ abi::EVIOCGNAME }, 256>(&file)?);
        // SAFETY: EVIOCSCLOCKID takes an int by pointer; Setter passes a pointer to it.
        let monotonic = unsafe {
            rustix::ioctl::ioctl(
                &file,
                Setter::<{ abi::EVIOCSCLOCKID }, i32>::new(libc::CLOCK_MONOTONIC),
            )
        }
        .is_ok();
        Ok(InputDevice {
            path: path.to_path_buf(),
            name,
            file,
            monotonic,
        })
    }

    /// Whether the device can report key `code`.
    pub fn has_key(&self, code: u16) -> io::Result<bool> {
        let bits = get::<{ abi::EVIOCGBIT_KEY }, { abi::KEY_BITS_BYTES }>(&self.file)?;
        Ok(bits
            .get(code as usize / 8)
            .is_some_and(|b| b & (1 << (code % 8)) != 0))
    }

    /// The key events waiting, in order, with `Dropped` where the kernel dropped some. Empty
    /// when nothing waits; ENODEV once the device is gone.
    pub fn read(&mut self) -> io::Result<Vec<KeyRead>> {
        let mut buf = [0u8; 64 * InputEvent::SIZE];
        let n = match self.file.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(Vec::new()),
            Err(e) => return Err(e),
        };
        let stamped = crate::backend::sys::monotonic_now();
        Ok(buf[..n]
            .chunks_exact(InputEvent::SIZE)
            .map(InputEvent::from_bytes)
            .filter_map(|e| match (e.type_, e.code, e.value) {
                (abi::EV_SYN, abi::SYN_DROPPED, _) => Some(KeyRead::Dropped),
                (abi::EV_KEY, code, v @ (0 | 1)) => Some(KeyRead::Key {
                    code,
                    down: v == 1,
                    at: if self.monotonic { e.nanos() } else { stamped },
                }),
                _ => None,
            })
            .collect())
    }
}

impl AsFd for InputDevice {
    fn as_fd(&self) -> std::os::fd::BorrowedFd<'_> {
        self.file.as_fd()
    }
}

/// A read ioctl into a byte array, zeroed first (the kernel may fill only part of it: a name
/// is copied up to its NUL), retried when a signal interrupts it.
fn get<const OP: Opcode, const N: usize>(file: &File) -> io::Result<[u8; N]> {
    let mut bytes = [0u8; N];
    loop {
        // SAFETY: each opcode used here reads into a byte array of exactly its encoded size.
        match unsafe { rustix::ioctl::ioctl(file, Updater::<OP, [u8; N]>::new(&mut bytes)) } {
            Err(rustix::io::Errno::INTR) => continue,
            r => return r.map(|()| bytes).map_err(io::Error::from),
        }
    }
}
