//! One V4L2 device node, a video node or a sub-device: its capabilities, pixel formats, frame
//! interval and controls. Controls work the same on both kinds of node (a lens or a sensor is a
//! sub-device on the phones).

use super::abi::{self, zeroed};
use rustix::ioctl::{Opcode, Updater};
use std::io;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd, RawFd};
use std::path::Path;

/// A buffer queue's type: the single-planar or the multi-planar capture API. A node offers one
/// of them (vivid either, by its `multiplanar` parameter; rkisp1 and camss only multi-planar).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BufType {
    Capture,
    CaptureMplane,
}

impl BufType {
    pub fn raw(self) -> u32 {
        match self {
            BufType::Capture => abi::BUF_TYPE_VIDEO_CAPTURE,
            BufType::CaptureMplane => abi::BUF_TYPE_VIDEO_CAPTURE_MPLANE,
        }
    }
}

/// What VIDIOC_QUERYCAP says about a node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Capabilities {
    pub driver: String,
    pub card: String,
    pub bus_info: String,
    /// The node's own capabilities (`device_caps`, else the device's).
    pub caps: u32,
}

/// The layout of one plane of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlaneLayout {
    pub bytesperline: u32,
    pub sizeimage: u32,
}

/// A negotiated frame format: one plane on the single-planar API, one per memory plane on the
/// multi-planar one (NV12 as `NM12` has two).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameFormat {
    pub width: u32,
    pub height: u32,
    pub fourcc: [u8; 4],
    pub planes: Vec<PlaneLayout>,
}

/// A control as VIDIOC_QUERY_EXT_CTRL describes it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ControlDesc {
    pub id: u32,
    /// `V4L2_CTRL_TYPE_*`.
    pub kind: u32,
    pub name: String,
    pub min: i64,
    pub max: i64,
    pub step: u64,
    pub default: i64,
    /// `V4L2_CTRL_FLAG_*`.
    pub flags: u32,
}

/// An open device node.
#[derive(Debug)]
pub struct Device {
    fd: OwnedFd,
}

const EINVAL: i32 = 22;
const ENOTTY: i32 = 25;

impl Device {
    /// Opens `path` read-write and non-blocking (a dequeue waits with `poll`, with a timeout):
    /// a video, sub-device or media node, and nothing else (`sys::open_device`).
    pub fn open(path: &Path) -> io::Result<Device> {
        let file = crate::backend::sys::open_device(
            path,
            true,
            &["video4linux", "media"],
            "a V4L2 video, sub-device or media node",
        )?;
        Ok(Device { fd: file.into() })
    }

    /// One ioctl on `arg`, retried when a signal interrupts it.
    ///
    /// # Safety
    /// `OP` must be an ioctl whose argument is a `T`, as the kernel headers define it.
    pub(super) unsafe fn ioctl<const OP: Opcode, T>(&self, arg: &mut T) -> io::Result<()> {
        loop {
            // SAFETY: the caller guarantees that `OP` takes a `T`; `arg` is valid for the call.
            match unsafe { rustix::ioctl::ioctl(&self.fd, Updater::<OP, T>::new(arg)) } {
                Err(rustix::io::Errno::INTR) => continue,
                r => return r.map_err(io::Error::from),
            }
        }
    }

    pub fn capabilities(&self) -> io::Result<Capabilities> {
        let mut c: abi::Capability = zeroed();
        // SAFETY: VIDIOC_QUERYCAP takes a v4l2_capability.
        unsafe { self.ioctl::<{ abi::VIDIOC_QUERYCAP }, _>(&mut c)? };
        Ok(Capabilities {
            driver: abi::c_str(&c.driver),
            card: abi::c_str(&c.card),
            bus_info: abi::c_str(&c.bus_info),
            caps: if c.capabilities & abi::CAP_DEVICE_CAPS != 0 {
                c.device_caps
            } else {
                c.capabilities
            },
        })
    }

    /// The pixel formats the node offers for `buf`, as fourccs.
    pub fn formats(&self, buf: BufType) -> io::Result<Vec<[u8; 4]>> {
        let mut out = Vec::new();
        for index in 0.. {
            let mut d: abi::FmtDesc = zeroed();
            d.index = index;
            d.type_ = buf.raw();
            // SAFETY: VIDIOC_ENUM_FMT takes a v4l2_fmtdesc.
            match unsafe { self.ioctl::<{ abi::VIDIOC_ENUM_FMT }, _>(&mut d) } {
                Ok(()) => out.push(d.pixelformat.to_le_bytes()),
                // The end of the list.
                Err(e) if e.raw_os_error() == Some(EINVAL) => break,
                Err(e) => return Err(e),
            }
        }
        Ok(out)
    }

    /// Asks for `width`×`height` in `fourcc`; the driver adjusts what it cannot do, and the
    /// result says what it set.
    pub fn set_format(
        &self,
        buf: BufType,
        width: u32,
        height: u32,
        fourcc: [u8; 4],
    ) -> io::Result<FrameFormat> {
        let mut f: abi::Format = zeroed();
        f.type_ = buf.raw();
        let code = u32::from_le_bytes(fourcc);
        match buf {
            BufType::Capture => {
                f.fmt.pix = abi::PixFormat {
                    width,
                    height,
                    pixelformat: code,
                    field: abi::FIELD_NONE,
                    ..zeroed()
                };
            }
            BufType::CaptureMplane => {
                let mut mp: abi::PixFormatMplane = zeroed();
                mp.width = width;
                mp.height = height;
                mp.pixelformat = code;
                mp.field = abi::FIELD_NONE;
                f.fmt.pix_mp = mp;
            }
        }
        // SAFETY: VIDIOC_S_FMT takes a v4l2_format.
        unsafe { self.ioctl::<{ abi::VIDIOC_S_FMT }, _>(&mut f)? };
        Ok(frame_format(buf, &f))
    }

    /// The current format for `buf`.
    pub fn format(&self, buf: BufType) -> io::Result<FrameFormat> {
        let mut f: abi::Format = zeroed();
        f.type_ = buf.raw();
        // SAFETY: VIDIOC_G_FMT takes a v4l2_format.
        unsafe { self.ioctl::<{ abi::VIDIOC_G_FMT }, _>(&mut f)? };
        Ok(frame_format(buf, &f))
    }

    /// The time per frame (VIDIOC_G_PARM), a fraction of a second.
    pub fn frame_interval(&self, buf: BufType) -> io::Result<abi::Fract> {
        let mut p: abi::StreamParm = zeroed();
        p.type_ = buf.raw();
        // SAFETY: VIDIOC_G_PARM takes a v4l2_streamparm.
        unsafe { self.ioctl::<{ abi::VIDIOC_G_PARM }, _>(&mut p)? };
        // SAFETY: the capture member is the one the kernel fills for a capture type.
        Ok(unsafe { p.parm.capture.timeperframe })
    }

    /// Asks for a time per frame (VIDIOC_S_PARM); returns what the driver set.
    pub fn set_frame_interval(&self, buf: BufType, interval: abi::Fract) -> io::Result<abi::Fract> {
        let mut p: abi::StreamParm = zeroed();
        p.type_ = buf.raw();
        p.parm.capture.timeperframe = interval;
        // SAFETY: VIDIOC_S_PARM takes a v4l2_streamparm.
        unsafe { self.ioctl::<{ abi::VIDIOC_S_PARM }, _>(&mut p)? };
        // SAFETY: as in `frame_interval`.
        Ok(unsafe { p.parm.capture.timeperframe })
    }

    /// Every control of the node (none is an empty list, also on a sub-device without a control
    /// handler).
    pub fn controls(&self) -> io::Result<Vec<ControlDesc>> {
        let mut out = Vec::new();
        let mut id = 0;
        loop {
            let mut q: abi::QueryExtCtrl = zeroed();
            q.id = id | abi::CTRL_FLAG_NEXT_CTRL;
            // SAFETY: VIDIOC_QUERY_EXT_CTRL takes a v4l2_query_ext_ctrl.
            match unsafe { self.ioctl::<{ abi::VIDIOC_QUERY_EXT_CTRL }, _>(&mut q) } {
                Ok(()) => {}
                Err(e) if matches!(e.raw_os_error(), Some(EINVAL | ENOTTY)) => return Ok(out),
                Err(e) => return Err(e),
            }
            id = q.id;
            out.push(describe(&q));
        }
    }

    /// One control's description.
    pub fn control_desc(&self, id: u32) -> io::Result<ControlDesc> {
        let mut q: abi::QueryExtCtrl = zeroed();
        q.id = id;
        // SAFETY: VIDIOC_QUERY_EXT_CTRL takes a v4l2_query_ext_ctrl.
        unsafe { self.ioctl::<{ abi::VIDIOC_QUERY_EXT_CTRL }, _>(&mut q)? };
        Ok(describe(&q))
    }

    /// A control's current value (32- or 64-bit integer, boolean, menu index).
    pub fn control(&self, id: u32) -> io::Result<i64> {
        let wide = self.control_desc(id)?.kind == abi::CTRL_TYPE_INTEGER64;
        let mut c: abi::ExtControl = zeroed();
        c.id = id;
        self.ext_controls::<{ abi::VIDIOC_G_EXT_CTRLS }>(&mut c)?;
        // SAFETY: the kernel wrote `value64` for a 64-bit control and `value` for the others.
        Ok(unsafe {
            if wide {
                c.value.value64
            } else {
                i64::from(c.value.value)
            }
        })
    }

    /// Sets a control (a button is pressed by setting it to anything).
    pub fn set_control(&self, id: u32, value: i64) -> io::Result<()> {
        let desc = self.control_desc(id)?;
        let mut c: abi::ExtControl = zeroed();
        c.id = id;
        c.value = if desc.kind == abi::CTRL_TYPE_INTEGER64 {
            abi::ExtControlValue { value64: value }
        } else {
            let v = i32::try_from(value).map_err(|_| {
                io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!("{value} does not fit the 32-bit control {:?}", desc.name),
                )
            })?;
            abi::ExtControlValue { value: v }
        };
        self.ext_controls::<{ abi::VIDIOC_S_EXT_CTRLS }>(&mut c)
    }

    fn ext_controls<const OP: Opcode>(&self, c: &mut abi::ExtControl) -> io::Result<()> {
        let mut cs: abi::ExtControls = zeroed();
        cs.which = abi::CTRL_WHICH_CUR_VAL;
        cs.count = 1;
        cs.controls = c;
        // SAFETY: OP is VIDIOC_G_EXT_CTRLS or VIDIOC_S_EXT_CTRLS, which take a
        // v4l2_ext_controls; it points at one v4l2_ext_control that outlives the call.
        unsafe { self.ioctl::<OP, _>(&mut cs) }
    }
}

impl AsFd for Device {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.fd.as_fd()
    }
}

impl AsRawFd for Device {
    fn as_raw_fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }
}

fn describe(q: &abi::QueryExtCtrl) -> ControlDesc {
    let name: Vec<u8> = q.name.iter().map(|&c| c as u8).collect();
    ControlDesc {
        id: q.id,
        kind: q.type_,
        name: abi::c_str(&name),
        min: q.minimum,
        max: q.maximum,
        step: q.step,
        default: q.default_value,
        flags: q.flags,
    }
}

/// The format the kernel filled in for `buf`.
fn frame_format(buf: BufType, f: &abi::Format) -> FrameFormat {
    match buf {
        BufType::Capture => {
            // SAFETY: the kernel fills `pix` for the single-planar type.
            let p = unsafe { f.fmt.pix };
            FrameFormat {
                width: p.width,
                height: p.height,
                fourcc: p.pixelformat.to_le_bytes(),
                planes: vec![PlaneLayout {
                    bytesperline: p.bytesperline,
                    sizeimage: p.sizeimage,
                }],
            }
        }
        BufType::CaptureMplane => {
            // SAFETY: the kernel fills `pix_mp` for the multi-planar type.
            let p = unsafe { f.fmt.pix_mp };
            let n = usize::from(p.num_planes).min(abi::VIDEO_MAX_PLANES);
            FrameFormat {
                width: p.width,
                height: p.height,
                fourcc: { p.pixelformat }.to_le_bytes(),
                planes: p.plane_fmt[..n]
                    .iter()
                    .map(|pl| PlaneLayout {
                        bytesperline: pl.bytesperline,
                        sizeimage: pl.sizeimage,
                    })
                    .collect(),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_video_and_media_nodes_are_opened() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("video0");
        std::fs::write(&file, "not a device").unwrap();
        let e = Device::open(&file).err().unwrap().to_string();
        assert!(e.contains("not a character device"), "{e}");
        // /dev/zero is a character device of class mem.
        let e = Device::open(Path::new("/dev/zero"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("a mem device"), "{e}");
    }
}
