//! The preview's shared memory: a memfd holding a header and three frame slots, written by the
//! daemon and read by any number of clients, who hold the same file.
//!
//! Layout (native-endian, offsets in bytes; docs/guide.md describes it for client authors):
//!
//! ```text
//! 0    [u8; 8] magic b"FOCUSPV1"        28   u32 reserved
//! 8    u32 version (1)                   32   u64 slot_bytes (each slot's pixel capacity)
//! 12   u32 slots (3)                     40   u64 pixels_at (offset of slot 0's pixels)
//! 16   u32 format (1 = RGB, 8 bits)      48   u64 sequence (frames published; 0 = none yet)
//! 20   u32 max_width (640)               56   u32 newest (slot of the newest frame)
//! 24   u32 max_height (960)              60   u32 state (0 running, 1 paused, 2 stopped, 3 failed)
//! 64 + 32 i: slot i's u64 lock (odd while written), u64 frame (its sequence number),
//!            u32 width, u32 height, u32 stride, u32 reserved
//! 1024 u32 error_len, 1028 [u8; error_len] error (UTF-8, at most 1020 bytes): why the
//!            preview failed, written before `state` becomes 3
//! pixels_at + i * slot_bytes: slot i's rows, `stride` bytes apart
//! ```
//!
//! A new file is running with `sequence` 0 while the camera opens; it fails (state 3, the
//! reason in `error`) when the camera cannot be opened or read.
//!
//! A frame goes into the slot after the newest, under that slot's lock (a seqlock: the lock is
//! odd while the slot is written, and a reader that saw it change copies again), so a reader
//! never waits on the writer and the writer never waits on a reader: a stuck client costs
//! nothing. The file's size is sealed (`F_SEAL_SHRINK`, `F_SEAL_GROW`), and so are writes
//! through any mapping made after the daemon's own (`F_SEAL_FUTURE_WRITE`) and the seals
//! themselves (`F_SEAL_SEAL`): a client can read, and nothing else.

use crate::capture::preview::{MAX_HEIGHT, MAX_WIDTH};
use crate::stack::image::Image;
use rustix::fs::{MemfdFlags, SealFlags};
use rustix::mm::{MapFlags, ProtFlags};
use std::io;
use std::os::fd::{AsFd, OwnedFd};
use std::sync::atomic::{fence, AtomicU32, AtomicU64, Ordering};

pub const MAGIC: [u8; 8] = *b"FOCUSPV1";
pub const VERSION: u32 = 1;
pub const SLOTS: usize = 3;
/// `format`: RGB, one byte a channel, what GTK calls `GDK_MEMORY_R8G8B8`.
pub const FORMAT_RGB8: u32 = 1;
const HEADER_BYTES: usize = 4096;
const SLOT_BYTES: usize = MAX_WIDTH * MAX_HEIGHT * 3;
const SIZE: usize = HEADER_BYTES + SLOTS * SLOT_BYTES;

const AT_VERSION: usize = 8;
const AT_SLOTS: usize = 12;
const AT_FORMAT: usize = 16;
const AT_MAX_WIDTH: usize = 20;
const AT_MAX_HEIGHT: usize = 24;
const AT_SLOT_BYTES: usize = 32;
const AT_PIXELS: usize = 40;
const AT_SEQUENCE: usize = 48;
const AT_NEWEST: usize = 56;
const AT_STATE: usize = 60;
const AT_SLOT_HEADERS: usize = 64;
const SLOT_HEADER_BYTES: usize = 32;
const AT_ERROR: usize = 1024;
const ERROR_BYTES: usize = 1020;

/// What the preview is doing, as the header's `state` says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum State {
    Running = 0,
    /// A capture has the camera; frames come back when it ends.
    Paused = 1,
    /// The last client left, or the preview timed out: this file gets no more frames.
    Stopped = 2,
    /// The camera failed; the daemon's log says why. No more frames.
    Failed = 3,
}

impl State {
    fn from_u32(v: u32) -> Option<State> {
        [State::Running, State::Paused, State::Stopped, State::Failed]
            .into_iter()
            .find(|s| *s as u32 == v)
    }
}

/// A shared mapping, unmapped on drop.
struct Map {
    ptr: *mut u8,
    len: usize,
}

// SAFETY: the mapping is plain memory; every shared field is reached through atomics, and the
// pixels only under the slot's seqlock.
unsafe impl Send for Map {}
// SAFETY: as for Send.
unsafe impl Sync for Map {}

impl Map {
    fn new(fd: impl AsFd, len: usize, prot: ProtFlags) -> io::Result<Map> {
        // SAFETY: a fresh mapping at an address the kernel picks; nothing else refers to it.
        let ptr =
            unsafe { rustix::mm::mmap(std::ptr::null_mut(), len, prot, MapFlags::SHARED, fd, 0) }?;
        Ok(Map {
            ptr: ptr.cast(),
            len,
        })
    }

    fn u32_at(&self, at: usize) -> &AtomicU32 {
        assert!(at + 4 <= HEADER_BYTES && at.is_multiple_of(4));
        // SAFETY: in bounds and aligned (the mapping is page-aligned), and only ever accessed
        // atomically.
        unsafe { &*self.ptr.add(at).cast::<AtomicU32>() }
    }

    fn u64_at(&self, at: usize) -> &AtomicU64 {
        assert!(at + 8 <= HEADER_BYTES && at.is_multiple_of(8));
        // SAFETY: as in `u32_at`.
        unsafe { &*self.ptr.add(at).cast::<AtomicU64>() }
    }
}

impl Drop for Map {
    fn drop(&mut self) {
        // SAFETY: the mapping made in `new`; nothing refers to it after the owner is gone.
        let _ = unsafe { rustix::mm::munmap(self.ptr.cast(), self.len) };
    }
}

fn slot_field(slot: usize, field: usize) -> usize {
    AT_SLOT_HEADERS + slot * SLOT_HEADER_BYTES + field
}

/// The daemon's side: creates the file and publishes frames.
pub struct RingWriter {
    map: Map,
    fd: OwnedFd,
}

impl RingWriter {
    pub fn create() -> io::Result<RingWriter> {
        let fd = rustix::fs::memfd_create(
            "focusd-preview",
            MemfdFlags::CLOEXEC | MemfdFlags::ALLOW_SEALING,
        )?;
        rustix::fs::ftruncate(&fd, SIZE as u64)?;
        // The daemon's writable mapping comes before the seal that forbids any later one.
        let map = Map::new(&fd, SIZE, ProtFlags::READ | ProtFlags::WRITE)?;
        rustix::fs::fcntl_add_seals(
            &fd,
            SealFlags::SHRINK | SealFlags::GROW | SealFlags::FUTURE_WRITE | SealFlags::SEAL,
        )?;
        // SAFETY: the header lies within the mapping, which nothing else uses yet.
        unsafe { std::ptr::copy_nonoverlapping(MAGIC.as_ptr(), map.ptr, MAGIC.len()) };
        for (at, v) in [
            (AT_VERSION, VERSION),
            (AT_SLOTS, SLOTS as u32),
            (AT_FORMAT, FORMAT_RGB8),
            (AT_MAX_WIDTH, MAX_WIDTH as u32),
            (AT_MAX_HEIGHT, MAX_HEIGHT as u32),
        ] {
            map.u32_at(at).store(v, Ordering::Relaxed);
        }
        map.u64_at(AT_SLOT_BYTES)
            .store(SLOT_BYTES as u64, Ordering::Relaxed);
        map.u64_at(AT_PIXELS)
            .store(HEADER_BYTES as u64, Ordering::Relaxed);
        Ok(RingWriter { map, fd })
    }

    /// A descriptor of the file for a client.
    pub fn share(&self) -> io::Result<OwnedFd> {
        self.fd.try_clone()
    }

    pub fn state(&self) -> Option<State> {
        State::from_u32(self.map.u32_at(AT_STATE).load(Ordering::Acquire))
    }

    pub fn set_state(&self, state: State) {
        self.map
            .u32_at(AT_STATE)
            .store(state as u32, Ordering::Release);
    }

    /// Marks the preview failed, saying why (clipped to the header's room).
    pub fn fail(&self, reason: &str) {
        let mut len = reason.len().min(ERROR_BYTES);
        while !reason.is_char_boundary(len) {
            len -= 1;
        }
        // SAFETY: the text's room lies within the header; readers read it only after they
        // see the failed state, stored below with release ordering, and it is written once.
        unsafe {
            std::ptr::copy_nonoverlapping(reason.as_ptr(), self.map.ptr.add(AT_ERROR + 4), len)
        };
        self.map
            .u32_at(AT_ERROR)
            .store(len as u32, Ordering::Relaxed);
        self.set_state(State::Failed);
    }

    /// Copies `image` (RGB, within the preview's size) into the slot after the newest and
    /// makes it the newest.
    pub fn publish(&self, image: &Image<u8>) {
        let (w, h) = (image.width(), image.height());
        assert!(image.channels() == 3 && w <= MAX_WIDTH && h <= MAX_HEIGHT);
        let m = &self.map;
        let sequence = m.u64_at(AT_SEQUENCE).load(Ordering::Relaxed) + 1;
        let slot = (m.u32_at(AT_NEWEST).load(Ordering::Relaxed) as usize + 1) % SLOTS;
        let lock = m.u64_at(slot_field(slot, 0));
        lock.fetch_add(1, Ordering::Relaxed);
        fence(Ordering::Release);
        m.u64_at(slot_field(slot, 8))
            .store(sequence, Ordering::Relaxed);
        for (at, v) in [(16, w), (20, h), (24, w * 3)] {
            m.u32_at(slot_field(slot, at))
                .store(v as u32, Ordering::Relaxed);
        }
        // SAFETY: the slot's pixels lie within the mapping (w * h * 3 <= SLOT_BYTES); readers
        // copy them only under the lock, and discard what they copied while it was odd.
        unsafe {
            std::ptr::copy_nonoverlapping(
                image.data().as_ptr(),
                m.ptr.add(HEADER_BYTES + slot * SLOT_BYTES),
                w * h * 3,
            )
        };
        lock.fetch_add(1, Ordering::Release);
        m.u32_at(AT_NEWEST).store(slot as u32, Ordering::Release);
        m.u64_at(AT_SEQUENCE).store(sequence, Ordering::Release);
        self.set_state(State::Running);
    }
}

/// Why a client cannot read a preview file.
#[derive(Debug, thiserror::Error)]
pub enum RingError {
    #[error("cannot map the preview's shared memory: {0}")]
    Io(#[from] io::Error),
    #[error("the preview file is not one (size {size} bytes, magic {magic:?}, version {version})")]
    NotAPreview {
        size: u64,
        magic: [u8; 8],
        version: u32,
    },
}

/// One frame as a client copied it: RGB rows `stride` bytes apart.
#[derive(Clone, Debug)]
pub struct Frame {
    pub sequence: u64,
    pub width: u32,
    pub height: u32,
    pub stride: u32,
    pub pixels: Vec<u8>,
}

/// A client's side: maps the file read-only and copies the newest frame out.
pub struct RingReader {
    map: Map,
    slot_bytes: usize,
    pixels_at: usize,
}

impl RingReader {
    pub fn new(fd: impl AsFd) -> Result<RingReader, RingError> {
        let size = rustix::fs::fstat(&fd).map_err(io::Error::from)?.st_size as u64;
        let mut magic = [0u8; 8];
        let (mut version, mut slot_bytes, mut pixels_at) = (0, 0, 0);
        let map = if size >= HEADER_BYTES as u64 {
            let map = Map::new(&fd, size as usize, ProtFlags::READ)?;
            // SAFETY: the magic lies within the mapping; it is written before the file is
            // shared and never changes.
            unsafe { std::ptr::copy_nonoverlapping(map.ptr, magic.as_mut_ptr(), 8) };
            version = map.u32_at(AT_VERSION).load(Ordering::Relaxed);
            slot_bytes = map.u64_at(AT_SLOT_BYTES).load(Ordering::Relaxed);
            pixels_at = map.u64_at(AT_PIXELS).load(Ordering::Relaxed);
            Some(map)
        } else {
            None
        };
        let fits = pixels_at
            .checked_add(slot_bytes.saturating_mul(SLOTS as u64))
            .is_some_and(|end| end <= size);
        match map {
            Some(map) if magic == MAGIC && version == VERSION && fits => Ok(RingReader {
                map,
                slot_bytes: slot_bytes as usize,
                pixels_at: pixels_at as usize,
            }),
            _ => Err(RingError::NotAPreview {
                size,
                magic,
                version,
            }),
        }
    }

    pub fn state(&self) -> Option<State> {
        State::from_u32(self.map.u32_at(AT_STATE).load(Ordering::Acquire))
    }

    /// Why the preview failed, once it has.
    pub fn error(&self) -> Option<String> {
        if self.state() != Some(State::Failed) {
            return None;
        }
        let len = (self.map.u32_at(AT_ERROR).load(Ordering::Relaxed) as usize).min(ERROR_BYTES);
        let mut text = vec![0u8; len];
        // SAFETY: within the header, written before the failed state this thread saw.
        unsafe {
            std::ptr::copy_nonoverlapping(self.map.ptr.add(AT_ERROR + 4), text.as_mut_ptr(), len)
        };
        Some(String::from_utf8_lossy(&text).into_owned())
    }

    /// Frames published so far.
    pub fn sequence(&self) -> u64 {
        self.map.u64_at(AT_SEQUENCE).load(Ordering::Acquire)
    }

    /// A copy of the newest frame, or `None` before the first (or if the writer kept
    /// overtaking the copy, which at the preview's rate means a stalled reader).
    pub fn latest(&self) -> Option<Frame> {
        let m = &self.map;
        for _ in 0..8 {
            if m.u64_at(AT_SEQUENCE).load(Ordering::Acquire) == 0 {
                return None;
            }
            let slot = m.u32_at(AT_NEWEST).load(Ordering::Acquire) as usize % SLOTS;
            let lock = m.u64_at(slot_field(slot, 0));
            let before = lock.load(Ordering::Acquire);
            if !before.is_multiple_of(2) {
                std::thread::yield_now();
                continue;
            }
            let field = |at| m.u32_at(slot_field(slot, at)).load(Ordering::Relaxed);
            let sequence = m.u64_at(slot_field(slot, 8)).load(Ordering::Relaxed);
            let (width, height, stride) = (field(16), field(20), field(24));
            let len = (stride as usize).saturating_mul(height as usize);
            if len > self.slot_bytes || (width as usize) * 3 > stride as usize {
                continue;
            }
            let mut pixels = vec![0u8; len];
            // SAFETY: the slot lies within the mapping (checked in `new`) and len is within the
            // slot; a copy torn by the writer is discarded below.
            unsafe {
                std::ptr::copy_nonoverlapping(
                    m.ptr.add(self.pixels_at + slot * self.slot_bytes),
                    pixels.as_mut_ptr(),
                    len,
                )
            };
            fence(Ordering::Acquire);
            if lock.load(Ordering::Relaxed) == before {
                return Some(Frame {
                    sequence,
                    width,
                    height,
                    stride,
                    pixels,
                });
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reader_sees_the_newest_frame_and_the_state() {
        let ring = RingWriter::create().unwrap();
        let reader = RingReader::new(ring.share().unwrap()).unwrap();
        assert!(reader.latest().is_none());
        for k in 1..=5u8 {
            ring.publish(&Image::from_fn(4, 2, 3, |x, y, c| {
                k + (x + 4 * y + c) as u8
            }));
        }
        let f = reader.latest().unwrap();
        assert_eq!((f.sequence, f.width, f.height, f.stride), (5, 4, 2, 12));
        assert_eq!(&f.pixels[..4], &[5, 6, 7, 6]);
        assert_eq!(reader.state(), Some(State::Running));
        ring.set_state(State::Paused);
        assert_eq!(reader.state(), Some(State::Paused));
        assert_eq!(reader.error(), None);
        // A reason longer than the room is clipped at a character's boundary.
        let long = "é".repeat(600);
        ring.fail(&long);
        assert_eq!(reader.state(), Some(State::Failed));
        assert_eq!(reader.error().unwrap(), "é".repeat(510));
    }

    #[test]
    fn a_file_that_is_not_a_preview_is_refused_by_name() {
        let file = tempfile::tempfile().unwrap();
        file.set_len(SIZE as u64).unwrap();
        let e = RingReader::new(&file).err().unwrap();
        assert!(e.to_string().contains("is not one"), "{e}");
    }
}
