//! Memory-mapped streaming from a capture node, single- or multi-planar: buffers requested and
//! mapped, all queued, streaming started at the first dequeue; each dequeued buffer is read in
//! place and queued back by the caller.

use super::abi::{self, zeroed};
use super::device::{BufType, Device};
use crate::backend::sys::wait_readable;
use std::ffi::c_void;
use std::io;
use std::ptr::NonNull;
use std::time::{Duration, Instant};

const EAGAIN: i32 = 11;

/// One plane of one buffer, mapped into our memory.
struct Mapping {
    ptr: NonNull<c_void>,
    len: usize,
}

// SAFETY: the mapping is owned by one `Stream` and only read through `&Stream`; moving it to
// another thread moves that ownership.
unsafe impl Send for Mapping {}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: `ptr`/`len` are exactly what mmap returned, and no slice of it outlives the
        // `Stream` (slices borrow it).
        let _ = unsafe { rustix::mm::munmap(self.ptr.as_ptr(), self.len) };
    }
}

/// A buffer the driver has filled: which, its flags and timestamp, and its planes' data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Dequeued {
    pub index: u32,
    /// `V4L2_BUF_FLAG_*`.
    pub flags: u32,
    /// The buffer's timestamp (`struct timeval`).
    pub sec: i64,
    pub usec: i64,
    pub sequence: u32,
    /// Per plane: the data's start and end within the plane's mapping.
    spans: Vec<(usize, usize)>,
}

/// A streaming capture queue on one node.
pub struct Stream {
    dev: Device,
    buf: BufType,
    buffers: Vec<Vec<Mapping>>,
    streaming: bool,
}

impl Stream {
    /// Requests `count` buffers (the driver may give a few more or fewer), maps and queues them.
    pub fn new(dev: Device, buf: BufType, count: u32) -> io::Result<Stream> {
        let mut r: abi::RequestBuffers = zeroed();
        r.count = count;
        r.type_ = buf.raw();
        r.memory = abi::MEMORY_MMAP;
        // SAFETY: VIDIOC_REQBUFS takes a v4l2_requestbuffers.
        unsafe { dev.ioctl::<{ abi::VIDIOC_REQBUFS }, _>(&mut r)? };
        if r.count == 0 {
            return Err(io::Error::other("the driver gave no buffers"));
        }
        let mut stream = Stream {
            dev,
            buf,
            buffers: Vec::new(),
            streaming: false,
        };
        for index in 0..r.count {
            let maps = stream.map(index)?;
            stream.buffers.push(maps);
        }
        for index in 0..r.count {
            stream.queue(index)?;
        }
        Ok(stream)
    }

    /// The node the stream is on.
    pub fn device(&self) -> &Device {
        &self.dev
    }

    /// A v4l2_buffer for `index`, with `planes` attached on the multi-planar API.
    fn buffer(&self, index: u32, planes: &mut [abi::Plane; abi::VIDEO_MAX_PLANES]) -> abi::Buffer {
        let mut b: abi::Buffer = zeroed();
        b.index = index;
        b.type_ = self.buf.raw();
        b.memory = abi::MEMORY_MMAP;
        if self.buf == BufType::CaptureMplane {
            b.length = abi::VIDEO_MAX_PLANES as u32;
            b.m.planes = planes.as_mut_ptr();
        }
        b
    }

    fn map(&self, index: u32) -> io::Result<Vec<Mapping>> {
        let mut planes = [zeroed::<abi::Plane>(); abi::VIDEO_MAX_PLANES];
        let mut b = self.buffer(index, &mut planes);
        // SAFETY: VIDIOC_QUERYBUF takes a v4l2_buffer; its planes pointer (multi-planar) points
        // at VIDEO_MAX_PLANES planes that outlive the call.
        unsafe { self.dev.ioctl::<{ abi::VIDIOC_QUERYBUF }, _>(&mut b)? };
        let places: Vec<(u64, usize)> = match self.buf {
            // SAFETY: the kernel sets `offset` for MMAP buffers.
            BufType::Capture => vec![(u64::from(unsafe { b.m.offset }), b.length as usize)],
            BufType::CaptureMplane => planes[..(b.length as usize).min(abi::VIDEO_MAX_PLANES)]
                .iter()
                // SAFETY: the kernel sets `mem_offset` for MMAP planes.
                .map(|p| (u64::from(unsafe { p.m.mem_offset }), p.length as usize))
                .collect(),
        };
        places
            .into_iter()
            .map(|(offset, len)| {
                // SAFETY: a new shared read-only mapping of the driver's buffer, at the offset
                // and length the driver gave; nothing else maps this address range.
                let ptr = unsafe {
                    rustix::mm::mmap(
                        std::ptr::null_mut(),
                        len,
                        rustix::mm::ProtFlags::READ,
                        rustix::mm::MapFlags::SHARED,
                        &self.dev,
                        offset,
                    )?
                };
                let ptr = NonNull::new(ptr).ok_or_else(|| io::Error::other("mmap gave null"))?;
                Ok(Mapping { ptr, len })
            })
            .collect()
    }

    /// Gives buffer `index` back to the driver to fill.
    pub fn queue(&mut self, index: u32) -> io::Result<()> {
        let mut planes = [zeroed::<abi::Plane>(); abi::VIDEO_MAX_PLANES];
        let mut b = self.buffer(index, &mut planes);
        if self.buf == BufType::CaptureMplane {
            b.length = self.buffers[index as usize].len() as u32;
        }
        // SAFETY: VIDIOC_QBUF takes a v4l2_buffer; planes as in `map`.
        unsafe { self.dev.ioctl::<{ abi::VIDIOC_QBUF }, _>(&mut b) }
    }

    fn start(&mut self) -> io::Result<()> {
        if !self.streaming {
            let mut t = self.buf.raw() as i32;
            // SAFETY: VIDIOC_STREAMON takes an int, the buffer type.
            unsafe { self.dev.ioctl::<{ abi::VIDIOC_STREAMON }, _>(&mut t)? };
            self.streaming = true;
        }
        Ok(())
    }

    /// Stops streaming; the driver takes all buffers back. Streaming restarts at the next
    /// dequeue only after the buffers are queued again, so this ends the stream's use.
    pub fn stop(&mut self) -> io::Result<()> {
        if self.streaming {
            self.streaming = false;
            let mut t = self.buf.raw() as i32;
            // SAFETY: VIDIOC_STREAMOFF takes an int, the buffer type.
            unsafe { self.dev.ioctl::<{ abi::VIDIOC_STREAMOFF }, _>(&mut t)? };
        }
        Ok(())
    }

    /// The next filled buffer, starting the stream first if needed; `TimedOut` after `timeout`.
    /// The caller reads it with [`Stream::planes`] and gives it back with [`Stream::queue`].
    pub fn dequeue(&mut self, timeout: Duration) -> io::Result<Dequeued> {
        self.start()?;
        let deadline = Instant::now() + timeout;
        loop {
            let mut planes = [zeroed::<abi::Plane>(); abi::VIDEO_MAX_PLANES];
            let mut b = self.buffer(0, &mut planes);
            // SAFETY: VIDIOC_DQBUF takes a v4l2_buffer; planes as in `map`.
            match unsafe { self.dev.ioctl::<{ abi::VIDIOC_DQBUF }, _>(&mut b) } {
                Ok(()) => return self.dequeued(&b, &planes),
                Err(e) if e.raw_os_error() == Some(EAGAIN) => {}
                Err(e) => return Err(e),
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF"));
            }
            let ms = left.as_millis().clamp(1, i32::MAX as u128) as i32;
            if wait_readable(&self.dev, ms)? {
                // Readable but nothing to dequeue (an error state the next DQBUF reports, or
                // a wake-up for another event): do not spin.
                std::thread::sleep(Duration::from_millis(1));
            }
        }
    }

    fn dequeued(
        &self,
        b: &abi::Buffer,
        planes: &[abi::Plane; abi::VIDEO_MAX_PLANES],
    ) -> io::Result<Dequeued> {
        let maps = self
            .buffers
            .get(b.index as usize)
            .ok_or_else(|| io::Error::other(format!("the driver returned buffer {}", b.index)))?;
        let spans = match self.buf {
            BufType::Capture => vec![(0, b.bytesused as usize)],
            BufType::CaptureMplane => planes[..maps.len()]
                .iter()
                .map(|p| (p.data_offset as usize, p.bytesused as usize))
                .collect(),
        };
        let spans = spans
            .into_iter()
            .zip(maps)
            .map(|((start, end), m)| (start.min(m.len), end.min(m.len)))
            .map(|(start, end)| (start, end.max(start)))
            .collect();
        Ok(Dequeued {
            index: b.index,
            flags: b.flags,
            sec: b.timestamp.tv_sec,
            usec: b.timestamp.tv_usec,
            sequence: b.sequence,
            spans,
        })
    }

    /// The data of a dequeued buffer, one slice per plane, valid until it is queued again.
    pub fn planes(&self, d: &Dequeued) -> Vec<&[u8]> {
        self.buffers[d.index as usize]
            .iter()
            .zip(&d.spans)
            .map(|(m, &(start, end))| {
                // SAFETY: the mapping is `m.len` readable bytes for as long as `self` lives,
                // and the span lies within it; the driver does not write a dequeued buffer.
                let all = unsafe { std::slice::from_raw_parts(m.ptr.as_ptr().cast::<u8>(), m.len) };
                &all[start..end]
            })
            .collect()
    }
}

impl Drop for Stream {
    fn drop(&mut self) {
        let _ = self.stop();
        self.buffers.clear();
        let mut r: abi::RequestBuffers = zeroed();
        r.type_ = self.buf.raw();
        r.memory = abi::MEMORY_MMAP;
        // SAFETY: VIDIOC_REQBUFS takes a v4l2_requestbuffers; count 0 frees the buffers, which
        // are unmapped above.
        let _ = unsafe { self.dev.ioctl::<{ abi::VIDIOC_REQBUFS }, _>(&mut r) };
    }
}
