//! Opening and reading the files focusd parses (configs, device profiles, bundle manifests, IMU
//! traces, image frames) so that no path can hang it or grow it without bound.
//!
//! A path may name a FIFO (whose open, and then every read, waits for a writer that may never
//! come), a device such as `/dev/zero` (endless), a socket or a directory, directly or through a
//! link. Only regular files are read: the file is opened without waiting (`O_NONBLOCK`, which a
//! regular file ignores) and refused by its kind before anything is read. Each kind of file has a
//! size cap, checked against the inode before reading and enforced while reading, since a file
//! may grow in between.

use std::fs::{File, FileType, OpenOptions};
use std::io::{self, Read, Take};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// Configs, device profiles and bundle manifests: hand-written files of a few KiB. A manifest
/// holds one short table per take, so even 10 000 takes stay far below this.
pub const TEXT_CAP: u64 = 1 << 20;

/// Opens `path` for reading if it is a regular file (links followed); anything else is refused
/// by its kind, without blocking.
pub fn open(path: &Path) -> io::Result<File> {
    let f = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let kind = f.metadata()?.file_type();
    if !kind.is_file() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{}, not a regular file", kind_name(kind)),
        ));
    }
    Ok(f)
}

fn kind_name(kind: FileType) -> &'static str {
    if kind.is_dir() {
        "a directory"
    } else if kind.is_fifo() {
        "a FIFO (named pipe)"
    } else if kind.is_char_device() {
        "a character device"
    } else if kind.is_block_device() {
        "a block device"
    } else if kind.is_socket() {
        "a socket"
    } else {
        "a special file"
    }
}

fn too_big(len: u64, cap: u64) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{len} bytes or more, over the {cap}-byte limit for this kind of file"),
    )
}

/// Opens a regular file to be streamed with at most `cap` bytes: a longer file is refused
/// before reading, and the reader stops one byte past the cap, so that a file that grew since
/// is caught by [`check_cap`] once read, not cut.
pub fn open_capped(path: &Path, cap: u64) -> io::Result<Take<File>> {
    let f = open(path)?;
    let len = f.metadata()?.len();
    if len > cap {
        return Err(too_big(len, cap));
    }
    Ok(f.take(cap + 1))
}

/// After reading an [`open_capped`] file: refuses it if it gave more than its cap.
pub fn check_cap(r: &Take<File>, cap: u64) -> io::Result<()> {
    match r.limit() {
        0 => Err(too_big(cap + 1, cap)),
        _ => Ok(()),
    }
}

/// Reads at most `cap` bytes of a regular file; a longer file is refused, not cut.
pub fn read(path: &Path, cap: u64) -> io::Result<Vec<u8>> {
    let mut r = open_capped(path, cap)?;
    let mut buf = Vec::with_capacity(r.get_ref().metadata()?.len() as usize);
    r.read_to_end(&mut buf)?;
    check_cap(&r, cap)?;
    Ok(buf)
}

/// [`read`] as UTF-8 text.
pub fn read_to_string(path: &Path, cap: u64) -> io::Result<String> {
    String::from_utf8(read(path, cap)?)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "not UTF-8 text"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::net::UnixListener;

    #[test]
    fn reads_a_regular_file_and_follows_links() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.toml");
        std::fs::write(&file, "x = 1\n").unwrap();
        let link = dir.path().join("link.toml");
        std::os::unix::fs::symlink(&file, &link).unwrap();
        assert_eq!(read_to_string(&link, TEXT_CAP).unwrap(), "x = 1\n");
    }

    #[test]
    fn refuses_what_is_not_a_regular_file_by_its_kind_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let sock = dir.path().join("sock");
        let _listener = UnixListener::bind(&sock).unwrap();
        // The FIFO has no writer: a blocking open would never return.
        let e = read(&fifo, TEXT_CAP).unwrap_err().to_string();
        assert!(e.contains("FIFO"), "{e}");
        let e = read(Path::new("/dev/zero"), TEXT_CAP)
            .unwrap_err()
            .to_string();
        assert!(e.contains("character device"), "{e}");
        let e = read(dir.path(), TEXT_CAP).unwrap_err().to_string();
        assert!(e.contains("directory"), "{e}");
        // A socket cannot even be opened (ENXIO): refused all the same.
        assert!(read(&sock, TEXT_CAP).is_err());
    }

    #[test]
    fn refuses_a_file_over_its_cap_and_takes_one_at_it() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("big");
        std::fs::write(&file, vec![b'a'; 101]).unwrap();
        let e = read(&file, 100).unwrap_err().to_string();
        assert!(e.contains("100-byte limit"), "{e}");
        assert_eq!(read(&file, 101).unwrap().len(), 101);
    }
}
