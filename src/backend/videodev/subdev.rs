//! V4L2 sub-device pads: the codes and sizes a pad offers, and the media-bus format and the
//! crop of each pad, which must agree along every enabled link of a media pipeline before it
//! streams.

use super::abi::{self, zeroed, MbusFramefmt, Rect};
use super::device::Device;
use rustix::ioctl::Opcode;
use std::io;

/// The active format on `pad`.
pub fn format(dev: &Device, pad: u32) -> io::Result<MbusFramefmt> {
    pad_format::<{ abi::VIDIOC_SUBDEV_G_FMT }>(dev, pad, MbusFramefmt::default())
}

/// Sets the active format on `pad`; the driver adjusts what it cannot do and says what it set.
pub fn set_format(dev: &Device, pad: u32, format: MbusFramefmt) -> io::Result<MbusFramefmt> {
    pad_format::<{ abi::VIDIOC_SUBDEV_S_FMT }>(dev, pad, format)
}

/// The active crop rectangle on `pad`.
pub fn crop(dev: &Device, pad: u32) -> io::Result<Rect> {
    pad_crop::<{ abi::VIDIOC_SUBDEV_G_SELECTION }>(dev, pad, Rect::default())
}

/// Sets the active crop rectangle on `pad`; returns the rectangle the driver set.
pub fn set_crop(dev: &Device, pad: u32, r: Rect) -> io::Result<Rect> {
    pad_crop::<{ abi::VIDIOC_SUBDEV_S_SELECTION }>(dev, pad, r)
}

/// VIDIOC_SUBDEV_G_FMT or S_FMT (`OP`) on the active format of `pad`.
fn pad_format<const OP: Opcode>(
    dev: &Device,
    pad: u32,
    format: MbusFramefmt,
) -> io::Result<MbusFramefmt> {
    let mut f: abi::SubdevFormat = zeroed();
    f.which = abi::SUBDEV_FORMAT_ACTIVE;
    f.pad = pad;
    f.format = format;
    // SAFETY: both opcodes take a v4l2_subdev_format.
    unsafe { dev.ioctl::<OP, _>(&mut f)? };
    Ok(f.format)
}

/// VIDIOC_SUBDEV_G_SELECTION or S_SELECTION (`OP`) on the active crop of `pad`.
fn pad_crop<const OP: Opcode>(dev: &Device, pad: u32, r: Rect) -> io::Result<Rect> {
    let mut s: abi::SubdevSelection = zeroed();
    s.which = abi::SUBDEV_FORMAT_ACTIVE;
    s.pad = pad;
    s.target = abi::SEL_TGT_CROP;
    s.r = r;
    // SAFETY: both opcodes take a v4l2_subdev_selection.
    unsafe { dev.ioctl::<OP, _>(&mut s)? };
    Ok(s.r)
}

/// The media-bus codes `pad` offers (VIDIOC_SUBDEV_ENUM_MBUS_CODE), in the driver's order.
pub fn codes(dev: &Device, pad: u32) -> io::Result<Vec<u32>> {
    let mut out = Vec::new();
    for index in 0..256 {
        let mut e: abi::SubdevMbusCodeEnum = zeroed();
        e.which = abi::SUBDEV_FORMAT_ACTIVE;
        e.pad = pad;
        e.index = index;
        // SAFETY: VIDIOC_SUBDEV_ENUM_MBUS_CODE takes a v4l2_subdev_mbus_code_enum.
        match unsafe { dev.ioctl::<{ abi::VIDIOC_SUBDEV_ENUM_MBUS_CODE }, _>(&mut e) } {
            Ok(()) => out.push(e.code),
            Err(e) if e.raw_os_error() == Some(EINVAL) => break,
            Err(e) => return Err(e),
        }
    }
    Ok(out)
}

/// The frame sizes `pad` offers for `code` (VIDIOC_SUBDEV_ENUM_FRAME_SIZE), each as its
/// smallest and largest (width, height): a sensor lists its modes (both the same), a bridge,
/// an ISP or vimc's sensor a range.
pub fn sizes(dev: &Device, pad: u32, code: u32) -> io::Result<Vec<SizeRange>> {
    let mut out = Vec::new();
    for index in 0..256 {
        let mut e: abi::SubdevFrameSizeEnum = zeroed();
        e.which = abi::SUBDEV_FORMAT_ACTIVE;
        e.pad = pad;
        e.code = code;
        e.index = index;
        // SAFETY: VIDIOC_SUBDEV_ENUM_FRAME_SIZE takes a v4l2_subdev_frame_size_enum.
        match unsafe { dev.ioctl::<{ abi::VIDIOC_SUBDEV_ENUM_FRAME_SIZE }, _>(&mut e) } {
            Ok(()) => out.push(((e.min_width, e.min_height), (e.max_width, e.max_height))),
            Err(e) if e.raw_os_error() == Some(EINVAL) => break,
            Err(e) => return Err(e),
        }
    }
    Ok(out)
}

/// The smallest and the largest (width, height) of an enumerated frame size.
pub type SizeRange = ((u32, u32), (u32, u32));

const EINVAL: i32 = 22;
