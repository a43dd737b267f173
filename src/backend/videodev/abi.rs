//! The kernel's V4L2, sub-device and media-controller UAPI that focusd uses, written out by
//! hand from `linux/videodev2.h`, `linux/v4l2-subdev.h`, `linux/v4l2-mediabus.h` and
//! `linux/media.h` (Linux 6.1, the ABI is stable).
//!
//! Why by hand: every crate that covers these structures generates them with bindgen, which
//! needs libclang at build time (`v4l`, `linux-media`, `v4l2r`), and the `v4l` crate cannot
//! stream the multi-planar API the phones' ISPs use. The layouts are checked against the C
//! headers on x86-64 and arm64 by the test at the end of this file: it turns every size,
//! offset, ioctl number and constant below into a C `_Static_assert` and compiles it with the
//! system's gcc (and `aarch64-linux-gnu-gcc` when installed).
//!
//! 64-bit Linux (the phones are all arm64): `struct timeval` and the pointer-sized union
//! members are laid out for an LP64 ABI. On a 32-bit ABI `struct v4l2_buffer` would differ in
//! size, and so would the ioctl numbers that encode it: the kernel would refuse them (ENOTTY)
//! rather than misread them.

use rustix::ioctl::{opcode, Opcode};
use std::ffi::c_char;

pub const VIDEO_MAX_PLANES: usize = 8;

// ---- capabilities (struct v4l2_capability) ----
pub const CAP_VIDEO_CAPTURE: u32 = 0x0000_0001;
pub const CAP_VIDEO_CAPTURE_MPLANE: u32 = 0x0000_1000;
pub const CAP_STREAMING: u32 = 0x0400_0000;
pub const CAP_IO_MC: u32 = 0x2000_0000;
pub const CAP_DEVICE_CAPS: u32 = 0x8000_0000;

// ---- enum v4l2_buf_type, v4l2_memory, v4l2_field ----
pub const BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
pub const BUF_TYPE_VIDEO_CAPTURE_MPLANE: u32 = 9;
pub const MEMORY_MMAP: u32 = 1;
pub const FIELD_ANY: u32 = 0;
pub const FIELD_NONE: u32 = 1;

// ---- buffer flags ----
pub const BUF_FLAG_ERROR: u32 = 0x0000_0040;
pub const BUF_FLAG_TIMESTAMP_MASK: u32 = 0x0000_e000;
pub const BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;
pub const BUF_FLAG_TSTAMP_SRC_MASK: u32 = 0x0007_0000;
pub const BUF_FLAG_TSTAMP_SRC_EOF: u32 = 0x0000_0000;
pub const BUF_FLAG_TSTAMP_SRC_SOE: u32 = 0x0001_0000;

// ---- controls ----
pub const CTRL_FLAG_DISABLED: u32 = 0x0001;
pub const CTRL_FLAG_READ_ONLY: u32 = 0x0004;
pub const CTRL_FLAG_NEXT_CTRL: u32 = 0x8000_0000;
pub const CTRL_FLAG_NEXT_COMPOUND: u32 = 0x4000_0000;
pub const CTRL_WHICH_CUR_VAL: u32 = 0;
pub const CTRL_TYPE_INTEGER: u32 = 1;
pub const CTRL_TYPE_BOOLEAN: u32 = 2;
pub const CTRL_TYPE_MENU: u32 = 3;
pub const CTRL_TYPE_BUTTON: u32 = 4;
pub const CTRL_TYPE_INTEGER64: u32 = 5;
pub const CTRL_TYPE_CTRL_CLASS: u32 = 6;
pub const CID_EXPOSURE: u32 = 0x0098_0911;
pub const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
pub const CID_HFLIP: u32 = 0x0098_0914;
pub const CID_VFLIP: u32 = 0x0098_0915;
/// The counter-clockwise turn that makes the sensor's pictures upright (the DT `rotation`).
pub const CID_CAMERA_SENSOR_ROTATION: u32 = 0x009a_0923;
pub const CID_FOCUS_ABSOLUTE: u32 = 0x009a_090a;
pub const CID_FOCUS_RELATIVE: u32 = 0x009a_090b;
pub const CID_FOCUS_AUTO: u32 = 0x009a_090c;
pub const CID_AUTO_FOCUS_START: u32 = 0x009a_091c;
pub const CID_AUTO_FOCUS_STOP: u32 = 0x009a_091d;
pub const CID_AUTO_FOCUS_STATUS: u32 = 0x009a_091e;
pub const CID_AUTO_FOCUS_RANGE: u32 = 0x009a_091f;
pub const CID_HBLANK: u32 = 0x009e_0902;
pub const CID_PIXEL_RATE: u32 = 0x009f_0902;

// ---- sub-devices ----
pub const SUBDEV_FORMAT_TRY: u32 = 0;
pub const SUBDEV_FORMAT_ACTIVE: u32 = 1;
pub const SEL_TGT_CROP: u32 = 0x0000;

// ---- media controller ----
pub const MEDIA_ENT_F_CAM_SENSOR: u32 = 0x0002_0001;
pub const MEDIA_ENT_F_LENS: u32 = 0x0002_0003;
pub const MEDIA_PAD_FL_SINK: u32 = 1 << 0;
pub const MEDIA_PAD_FL_SOURCE: u32 = 1 << 1;
pub const MEDIA_LNK_FL_ENABLED: u32 = 1 << 0;
pub const MEDIA_LNK_FL_IMMUTABLE: u32 = 1 << 1;
pub const MEDIA_LNK_FL_LINK_TYPE: u32 = 0xf << 28;
pub const MEDIA_LNK_FL_DATA_LINK: u32 = 0;
pub const MEDIA_LNK_FL_INTERFACE_LINK: u32 = 1 << 28;
pub const MEDIA_LNK_FL_ANCILLARY_LINK: u32 = 2 << 28;
pub const MEDIA_INTF_T_V4L_VIDEO: u32 = 0x0200;
pub const MEDIA_INTF_T_V4L_SUBDEV: u32 = 0x0203;

/// Media-bus codes (`MEDIA_BUS_FMT_*` of linux/media-bus-format.h) by name, the ones device
/// profiles may name.
pub const MBUS_CODES: [(&str, u32); 14] = [
    ("RGB888_1X24", 0x100a),
    ("UYVY8_2X8", 0x2006),
    ("YUYV8_2X8", 0x2008),
    ("YUYV8_1X16", 0x2011),
    ("SBGGR8_1X8", 0x3001),
    ("SGRBG8_1X8", 0x3002),
    ("SGBRG8_1X8", 0x3013),
    ("SRGGB8_1X8", 0x3014),
    ("SBGGR10_1X10", 0x3007),
    ("SGRBG10_1X10", 0x300a),
    ("SGBRG10_1X10", 0x300e),
    ("SRGGB10_1X10", 0x300f),
    ("SGBRG12_1X12", 0x3010),
    ("SRGGB12_1X12", 0x3012),
];

/// `struct v4l2_capability`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Capability {
    pub driver: [u8; 16],
    pub card: [u8; 32],
    pub bus_info: [u8; 32],
    pub version: u32,
    pub capabilities: u32,
    pub device_caps: u32,
    pub reserved: [u32; 3],
}

/// `struct v4l2_fmtdesc`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct FmtDesc {
    pub index: u32,
    pub type_: u32,
    pub flags: u32,
    pub description: [u8; 32],
    pub pixelformat: u32,
    pub mbus_code: u32,
    pub reserved: [u32; 3],
}

/// `struct v4l2_pix_format` (single-planar)
#[repr(C)]
#[derive(Clone, Copy)]
pub struct PixFormat {
    pub width: u32,
    pub height: u32,
    pub pixelformat: u32,
    pub field: u32,
    pub bytesperline: u32,
    pub sizeimage: u32,
    pub colorspace: u32,
    pub priv_: u32,
    pub flags: u32,
    pub ycbcr_enc: u32,
    pub quantization: u32,
    pub xfer_func: u32,
}

/// `struct v4l2_plane_pix_format` (packed in C: all its fields are naturally aligned anyway)
#[repr(C, packed)]
#[derive(Clone, Copy)]
pub struct PlanePixFormat {
    pub sizeimage: u32,
    pub bytesperline: u32,
    pub reserved: [u16; 6],
}

/// `struct v4l2_pix_format_mplane` (packed in C). Read its fields by value (`{ f.width }`).
#[repr(C, packed)]
#[derive(Clone, Copy)]
pub struct PixFormatMplane {
    pub width: u32,
    pub height: u32,
    pub pixelformat: u32,
    pub field: u32,
    pub colorspace: u32,
    pub plane_fmt: [PlanePixFormat; VIDEO_MAX_PLANES],
    pub num_planes: u8,
    pub flags: u8,
    pub ycbcr_enc: u8,
    pub quantization: u8,
    pub xfer_func: u8,
    pub reserved: [u8; 7],
}

/// The union in `struct v4l2_format`; `_align` gives it the pointer alignment that
/// `struct v4l2_window`'s pointers give it in C.
#[repr(C)]
#[derive(Clone, Copy)]
pub union FormatUnion {
    pub pix: PixFormat,
    pub pix_mp: PixFormatMplane,
    pub raw_data: [u8; 200],
    _align: [usize; 0],
}

/// `struct v4l2_format`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Format {
    pub type_: u32,
    pub fmt: FormatUnion,
}

/// `struct v4l2_fract`
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fract {
    pub numerator: u32,
    pub denominator: u32,
}

/// `struct v4l2_captureparm`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct CaptureParm {
    pub capability: u32,
    pub capturemode: u32,
    pub timeperframe: Fract,
    pub extendedmode: u32,
    pub readbuffers: u32,
    pub reserved: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union StreamParmUnion {
    pub capture: CaptureParm,
    pub raw_data: [u8; 200],
}

/// `struct v4l2_streamparm`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct StreamParm {
    pub type_: u32,
    pub parm: StreamParmUnion,
}

/// `struct v4l2_requestbuffers`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct RequestBuffers {
    pub count: u32,
    pub type_: u32,
    pub memory: u32,
    pub capabilities: u32,
    pub flags: u8,
    pub reserved: [u8; 3],
}

/// `struct timeval` on LP64 (`long` is 64 bits).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Timeval {
    pub tv_sec: i64,
    pub tv_usec: i64,
}

/// `struct v4l2_timecode`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Timecode {
    pub type_: u32,
    pub flags: u32,
    pub frames: u8,
    pub seconds: u8,
    pub minutes: u8,
    pub hours: u8,
    pub userbits: [u8; 4],
}

/// The `m` union of `struct v4l2_plane`.
#[repr(C)]
#[derive(Clone, Copy)]
pub union PlaneM {
    pub mem_offset: u32,
    pub userptr: usize,
    pub fd: i32,
}

/// `struct v4l2_plane`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Plane {
    pub bytesused: u32,
    pub length: u32,
    pub m: PlaneM,
    pub data_offset: u32,
    pub reserved: [u32; 11],
}

/// The `m` union of `struct v4l2_buffer`.
#[repr(C)]
#[derive(Clone, Copy)]
pub union BufferM {
    pub offset: u32,
    pub userptr: usize,
    pub planes: *mut Plane,
    pub fd: i32,
}

/// `struct v4l2_buffer`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Buffer {
    pub index: u32,
    pub type_: u32,
    pub bytesused: u32,
    pub flags: u32,
    pub field: u32,
    pub timestamp: Timeval,
    pub timecode: Timecode,
    pub sequence: u32,
    pub memory: u32,
    pub m: BufferM,
    pub length: u32,
    pub reserved2: u32,
    pub request_fd: i32,
}

/// `struct v4l2_query_ext_ctrl`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct QueryExtCtrl {
    pub id: u32,
    pub type_: u32,
    pub name: [c_char; 32],
    pub minimum: i64,
    pub maximum: i64,
    pub step: u64,
    pub default_value: i64,
    pub flags: u32,
    pub elem_size: u32,
    pub elems: u32,
    pub nr_of_dims: u32,
    pub dims: [u32; 4],
    pub reserved: [u32; 32],
}

/// The value union of `struct v4l2_ext_control` (only the integer members are used).
#[repr(C, packed)]
#[derive(Clone, Copy)]
pub union ExtControlValue {
    pub value: i32,
    pub value64: i64,
}

/// `struct v4l2_ext_control` (packed in C).
#[repr(C, packed)]
#[derive(Clone, Copy)]
pub struct ExtControl {
    pub id: u32,
    pub size: u32,
    pub reserved2: [u32; 1],
    pub value: ExtControlValue,
}

/// `struct v4l2_ext_controls`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct ExtControls {
    pub which: u32,
    pub count: u32,
    pub error_idx: u32,
    pub request_fd: i32,
    pub reserved: [u32; 1],
    pub controls: *mut ExtControl,
}

/// `struct v4l2_mbus_framefmt`
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MbusFramefmt {
    pub width: u32,
    pub height: u32,
    pub code: u32,
    pub field: u32,
    pub colorspace: u32,
    pub ycbcr_enc: u16,
    pub quantization: u16,
    pub xfer_func: u16,
    pub flags: u16,
    pub reserved: [u16; 10],
}

/// `struct v4l2_subdev_format` (6.1; later kernels name `reserved[0]` `stream`).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct SubdevFormat {
    pub which: u32,
    pub pad: u32,
    pub format: MbusFramefmt,
    pub reserved: [u32; 8],
}

/// `struct v4l2_subdev_mbus_code_enum` (6.1; later kernels name `reserved[0]` `stream`).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct SubdevMbusCodeEnum {
    pub pad: u32,
    pub index: u32,
    pub code: u32,
    pub which: u32,
    pub flags: u32,
    pub reserved: [u32; 7],
}

/// `struct v4l2_subdev_frame_size_enum` (6.1; later kernels name `reserved[0]` `stream`).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct SubdevFrameSizeEnum {
    pub index: u32,
    pub pad: u32,
    pub code: u32,
    pub min_width: u32,
    pub max_width: u32,
    pub min_height: u32,
    pub max_height: u32,
    pub which: u32,
    pub reserved: [u32; 8],
}

/// `struct v4l2_rect`
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Rect {
    pub left: i32,
    pub top: i32,
    pub width: u32,
    pub height: u32,
}

/// `struct v4l2_subdev_selection` (6.1; later kernels name `reserved[0]` `stream`).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct SubdevSelection {
    pub which: u32,
    pub pad: u32,
    pub target: u32,
    pub flags: u32,
    pub r: Rect,
    pub reserved: [u32; 8],
}

/// `struct media_device_info`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct MediaDeviceInfo {
    pub driver: [u8; 16],
    pub model: [u8; 32],
    pub serial: [u8; 40],
    pub bus_info: [u8; 32],
    pub media_version: u32,
    pub hw_revision: u32,
    pub driver_version: u32,
    pub reserved: [u32; 31],
}

/// `struct media_pad_desc`
#[repr(C)]
#[derive(Clone, Copy, Default)]
pub struct MediaPadDesc {
    pub entity: u32,
    pub index: u16,
    pub flags: u32,
    pub reserved: [u32; 2],
}

/// `struct media_link_desc`
#[repr(C)]
#[derive(Clone, Copy, Default)]
pub struct MediaLinkDesc {
    pub source: MediaPadDesc,
    pub sink: MediaPadDesc,
    pub flags: u32,
    pub reserved: [u32; 2],
}

/// `struct media_v2_topology` (packed in C; naturally aligned here, the same layout).
#[repr(C)]
#[derive(Clone, Copy, Default)]
pub struct MediaV2Topology {
    pub topology_version: u64,
    pub num_entities: u32,
    pub reserved1: u32,
    pub ptr_entities: u64,
    pub num_interfaces: u32,
    pub reserved2: u32,
    pub ptr_interfaces: u64,
    pub num_pads: u32,
    pub reserved3: u32,
    pub ptr_pads: u64,
    pub num_links: u32,
    pub reserved4: u32,
    pub ptr_links: u64,
}

/// `struct media_v2_entity` (packed in C; all `u32`, so the same layout).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct MediaV2Entity {
    pub id: u32,
    pub name: [u8; 64],
    pub function: u32,
    pub flags: u32,
    pub reserved: [u32; 5],
}

/// `struct media_v2_interface` with its union as `struct media_v2_intf_devnode` plus the rest.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct MediaV2Interface {
    pub id: u32,
    pub intf_type: u32,
    pub flags: u32,
    pub reserved: [u32; 9],
    pub devnode_major: u32,
    pub devnode_minor: u32,
    pub raw: [u32; 14],
}

/// `struct media_v2_pad`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct MediaV2Pad {
    pub id: u32,
    pub entity_id: u32,
    pub flags: u32,
    pub index: u32,
    pub reserved: [u32; 4],
}

/// `struct media_v2_link`
#[repr(C)]
#[derive(Clone, Copy)]
pub struct MediaV2Link {
    pub id: u32,
    pub source_id: u32,
    pub sink_id: u32,
    pub flags: u32,
    pub reserved: [u32; 6],
}

// ---- ioctl numbers ----
pub const VIDIOC_QUERYCAP: Opcode = opcode::read::<Capability>(b'V', 0);
pub const VIDIOC_ENUM_FMT: Opcode = opcode::read_write::<FmtDesc>(b'V', 2);
pub const VIDIOC_G_FMT: Opcode = opcode::read_write::<Format>(b'V', 4);
pub const VIDIOC_S_FMT: Opcode = opcode::read_write::<Format>(b'V', 5);
pub const VIDIOC_REQBUFS: Opcode = opcode::read_write::<RequestBuffers>(b'V', 8);
pub const VIDIOC_QUERYBUF: Opcode = opcode::read_write::<Buffer>(b'V', 9);
pub const VIDIOC_QBUF: Opcode = opcode::read_write::<Buffer>(b'V', 15);
pub const VIDIOC_DQBUF: Opcode = opcode::read_write::<Buffer>(b'V', 17);
pub const VIDIOC_STREAMON: Opcode = opcode::write::<i32>(b'V', 18);
pub const VIDIOC_STREAMOFF: Opcode = opcode::write::<i32>(b'V', 19);
pub const VIDIOC_G_PARM: Opcode = opcode::read_write::<StreamParm>(b'V', 21);
pub const VIDIOC_S_PARM: Opcode = opcode::read_write::<StreamParm>(b'V', 22);
pub const VIDIOC_G_EXT_CTRLS: Opcode = opcode::read_write::<ExtControls>(b'V', 71);
pub const VIDIOC_S_EXT_CTRLS: Opcode = opcode::read_write::<ExtControls>(b'V', 72);
pub const VIDIOC_QUERY_EXT_CTRL: Opcode = opcode::read_write::<QueryExtCtrl>(b'V', 103);
pub const VIDIOC_SUBDEV_ENUM_MBUS_CODE: Opcode = opcode::read_write::<SubdevMbusCodeEnum>(b'V', 2);
pub const VIDIOC_SUBDEV_ENUM_FRAME_SIZE: Opcode =
    opcode::read_write::<SubdevFrameSizeEnum>(b'V', 74);
pub const VIDIOC_SUBDEV_G_FMT: Opcode = opcode::read_write::<SubdevFormat>(b'V', 4);
pub const VIDIOC_SUBDEV_S_FMT: Opcode = opcode::read_write::<SubdevFormat>(b'V', 5);
pub const VIDIOC_SUBDEV_G_SELECTION: Opcode = opcode::read_write::<SubdevSelection>(b'V', 61);
pub const VIDIOC_SUBDEV_S_SELECTION: Opcode = opcode::read_write::<SubdevSelection>(b'V', 62);
pub const MEDIA_IOC_DEVICE_INFO: Opcode = opcode::read_write::<MediaDeviceInfo>(b'|', 0x00);
pub const MEDIA_IOC_SETUP_LINK: Opcode = opcode::read_write::<MediaLinkDesc>(b'|', 0x03);
pub const MEDIA_IOC_G_TOPOLOGY: Opcode = opcode::read_write::<MediaV2Topology>(b'|', 0x04);

/// A zeroed UAPI structure: every one of them is plain integers, arrays, unions of those and
/// null pointers, for which all-zero bytes are a valid value (and what the kernel expects in
/// the reserved fields).
pub fn zeroed<T: Zeroable>() -> T {
    // SAFETY: `Zeroable`'s contract is that all-zero bytes are a valid `T`.
    unsafe { std::mem::zeroed() }
}

/// The structures of this module, for which all-zero bytes are a valid value.
///
/// # Safety
///
/// An implementor must be valid when all of its bytes are zero: only integers, arrays and
/// unions of those, and raw pointers (null) — no references, `NonNull`, `bool`, `char`, enums
/// or other types with invalid bit patterns. [`zeroed`] relies on it.
pub unsafe trait Zeroable {}

/// `unsafe impl Zeroable` for each type named: only this module's UAPI structures.
macro_rules! zeroable {
    ($($t:ty),*) => {
        $(
            // SAFETY: each type named is a `#[repr(C)]` UAPI structure of this module made only
            // of integers, arrays and unions of those, and raw pointers, for which all-zero
            // bytes are valid.
            unsafe impl Zeroable for $t {}
        )*
    };
}
zeroable!(
    Capability,
    FmtDesc,
    PixFormat,
    PixFormatMplane,
    Format,
    StreamParm,
    RequestBuffers,
    Plane,
    Buffer,
    QueryExtCtrl,
    ExtControl,
    ExtControls,
    SubdevFormat,
    SubdevMbusCodeEnum,
    SubdevFrameSizeEnum,
    SubdevSelection,
    MediaDeviceInfo,
    MediaV2Topology,
    MediaV2Entity,
    MediaV2Interface,
    MediaV2Pad,
    MediaV2Link
);

/// A NUL-padded C string field as text.
pub fn c_str(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::fmt::Write as _;
    use std::mem::{offset_of, size_of};
    use std::process::Command;

    /// C assertions for every structure, ioctl number and constant above: `sizeof` and
    /// `offsetof` of the C types equal the Rust ones.
    fn assertions() -> String {
        let mut c = String::from(
            "#include <stddef.h>\n#include <sys/time.h>\n#include <linux/videodev2.h>\n\
             #include <linux/v4l2-subdev.h>\n#include <linux/media.h>\n\
             #include <linux/media-bus-format.h>\n",
        );
        let mut size = |c_type: &str, rust: usize, fields: &[(&str, usize)]| {
            let _ = writeln!(
                c,
                "_Static_assert(sizeof(struct {c_type}) == {rust}, \"sizeof {c_type}\");"
            );
            for (f, off) in fields {
                let _ = writeln!(
                    c,
                    "_Static_assert(offsetof(struct {c_type}, {f}) == {off}, \"{c_type}.{f}\");"
                );
            }
        };
        macro_rules! layout {
            ($c:literal, $t:ty $(, $cf:literal = $f:ident)*) => {
                size($c, size_of::<$t>(), &[$(($cf, offset_of!($t, $f))),*])
            };
        }
        layout!(
            "v4l2_capability",
            Capability,
            "card" = card,
            "capabilities" = capabilities,
            "device_caps" = device_caps
        );
        layout!(
            "v4l2_fmtdesc",
            FmtDesc,
            "description" = description,
            "pixelformat" = pixelformat
        );
        layout!(
            "v4l2_pix_format",
            PixFormat,
            "bytesperline" = bytesperline,
            "sizeimage" = sizeimage,
            "xfer_func" = xfer_func
        );
        layout!(
            "v4l2_plane_pix_format",
            PlanePixFormat,
            "bytesperline" = bytesperline
        );
        layout!(
            "v4l2_pix_format_mplane",
            PixFormatMplane,
            "plane_fmt" = plane_fmt,
            "num_planes" = num_planes,
            "xfer_func" = xfer_func
        );
        layout!("v4l2_format", Format, "fmt" = fmt);
        layout!(
            "v4l2_captureparm",
            CaptureParm,
            "timeperframe" = timeperframe,
            "readbuffers" = readbuffers
        );
        layout!("v4l2_streamparm", StreamParm, "parm" = parm);
        layout!(
            "v4l2_requestbuffers",
            RequestBuffers,
            "memory" = memory,
            "flags" = flags
        );
        layout!("v4l2_timecode", Timecode, "userbits" = userbits);
        layout!("v4l2_plane", Plane, "m" = m, "data_offset" = data_offset);
        layout!(
            "v4l2_buffer",
            Buffer,
            "flags" = flags,
            "timestamp" = timestamp,
            "timecode" = timecode,
            "sequence" = sequence,
            "memory" = memory,
            "m" = m,
            "length" = length,
            "request_fd" = request_fd
        );
        layout!(
            "v4l2_query_ext_ctrl",
            QueryExtCtrl,
            "name" = name,
            "minimum" = minimum,
            "step" = step,
            "default_value" = default_value,
            "flags" = flags,
            "dims" = dims
        );
        layout!("v4l2_ext_control", ExtControl, "value" = value);
        layout!(
            "v4l2_ext_controls",
            ExtControls,
            "count" = count,
            "request_fd" = request_fd,
            "controls" = controls
        );
        layout!(
            "v4l2_mbus_framefmt",
            MbusFramefmt,
            "colorspace" = colorspace,
            "ycbcr_enc" = ycbcr_enc,
            "flags" = flags
        );
        layout!(
            "v4l2_subdev_format",
            SubdevFormat,
            "pad" = pad,
            "format" = format
        );
        layout!(
            "v4l2_subdev_mbus_code_enum",
            SubdevMbusCodeEnum,
            "code" = code,
            "which" = which,
            "flags" = flags
        );
        layout!(
            "v4l2_subdev_frame_size_enum",
            SubdevFrameSizeEnum,
            "code" = code,
            "max_height" = max_height,
            "which" = which
        );
        layout!("v4l2_rect", Rect, "width" = width);
        layout!("v4l2_subdev_selection", SubdevSelection, "r" = r);
        layout!(
            "media_device_info",
            MediaDeviceInfo,
            "model" = model,
            "media_version" = media_version
        );
        layout!(
            "media_pad_desc",
            MediaPadDesc,
            "index" = index,
            "flags" = flags
        );
        layout!(
            "media_link_desc",
            MediaLinkDesc,
            "sink" = sink,
            "flags" = flags
        );
        layout!(
            "media_v2_topology",
            MediaV2Topology,
            "ptr_entities" = ptr_entities,
            "num_interfaces" = num_interfaces,
            "ptr_interfaces" = ptr_interfaces,
            "num_pads" = num_pads,
            "ptr_pads" = ptr_pads,
            "num_links" = num_links,
            "ptr_links" = ptr_links
        );
        layout!(
            "media_v2_entity",
            MediaV2Entity,
            "name" = name,
            "function" = function,
            "flags" = flags
        );
        layout!(
            "media_v2_interface",
            MediaV2Interface,
            "intf_type" = intf_type,
            "devnode.major" = devnode_major,
            "devnode.minor" = devnode_minor
        );
        layout!(
            "media_v2_pad",
            MediaV2Pad,
            "entity_id" = entity_id,
            "index" = index
        );
        layout!(
            "media_v2_link",
            MediaV2Link,
            "source_id" = source_id,
            "sink_id" = sink_id,
            "flags" = flags
        );

        let mut value = |name: &str, v: u64| {
            // Through unsigned int: the headers' flag macros are ints (0xf << 28 is negative).
            let _ = writeln!(
                c,
                "_Static_assert((unsigned int)({name}) == {v}U, \"{name}\");"
            );
        };
        macro_rules! values {
            ($($c:literal = $v:expr),* $(,)?) => { $(value($c, $v as u64);)* };
        }
        values!(
            "VIDEO_MAX_PLANES" = VIDEO_MAX_PLANES,
            "V4L2_CAP_VIDEO_CAPTURE" = CAP_VIDEO_CAPTURE,
            "V4L2_CAP_VIDEO_CAPTURE_MPLANE" = CAP_VIDEO_CAPTURE_MPLANE,
            "V4L2_CAP_STREAMING" = CAP_STREAMING,
            "V4L2_CAP_IO_MC" = CAP_IO_MC,
            "V4L2_CAP_DEVICE_CAPS" = CAP_DEVICE_CAPS,
            "V4L2_BUF_TYPE_VIDEO_CAPTURE" = BUF_TYPE_VIDEO_CAPTURE,
            "V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE" = BUF_TYPE_VIDEO_CAPTURE_MPLANE,
            "V4L2_MEMORY_MMAP" = MEMORY_MMAP,
            "V4L2_FIELD_ANY" = FIELD_ANY,
            "V4L2_FIELD_NONE" = FIELD_NONE,
            "V4L2_BUF_FLAG_ERROR" = BUF_FLAG_ERROR,
            "V4L2_BUF_FLAG_TIMESTAMP_MASK" = BUF_FLAG_TIMESTAMP_MASK,
            "V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC" = BUF_FLAG_TIMESTAMP_MONOTONIC,
            "V4L2_BUF_FLAG_TSTAMP_SRC_MASK" = BUF_FLAG_TSTAMP_SRC_MASK,
            "V4L2_BUF_FLAG_TSTAMP_SRC_EOF" = BUF_FLAG_TSTAMP_SRC_EOF,
            "V4L2_BUF_FLAG_TSTAMP_SRC_SOE" = BUF_FLAG_TSTAMP_SRC_SOE,
            "V4L2_CTRL_FLAG_DISABLED" = CTRL_FLAG_DISABLED,
            "V4L2_CTRL_FLAG_READ_ONLY" = CTRL_FLAG_READ_ONLY,
            "V4L2_CTRL_FLAG_NEXT_CTRL" = CTRL_FLAG_NEXT_CTRL,
            "V4L2_CTRL_FLAG_NEXT_COMPOUND" = CTRL_FLAG_NEXT_COMPOUND,
            "V4L2_CTRL_WHICH_CUR_VAL" = CTRL_WHICH_CUR_VAL,
            "V4L2_CTRL_TYPE_INTEGER" = CTRL_TYPE_INTEGER,
            "V4L2_CTRL_TYPE_BOOLEAN" = CTRL_TYPE_BOOLEAN,
            "V4L2_CTRL_TYPE_MENU" = CTRL_TYPE_MENU,
            "V4L2_CTRL_TYPE_BUTTON" = CTRL_TYPE_BUTTON,
            "V4L2_CTRL_TYPE_INTEGER64" = CTRL_TYPE_INTEGER64,
            "V4L2_CTRL_TYPE_CTRL_CLASS" = CTRL_TYPE_CTRL_CLASS,
            "V4L2_CID_EXPOSURE" = CID_EXPOSURE,
            "V4L2_CID_EXPOSURE_ABSOLUTE" = CID_EXPOSURE_ABSOLUTE,
            "V4L2_CID_FOCUS_ABSOLUTE" = CID_FOCUS_ABSOLUTE,
            "V4L2_CID_HFLIP" = CID_HFLIP,
            "V4L2_CID_VFLIP" = CID_VFLIP,
            "V4L2_CID_CAMERA_SENSOR_ROTATION" = CID_CAMERA_SENSOR_ROTATION,
            "V4L2_CID_FOCUS_RELATIVE" = CID_FOCUS_RELATIVE,
            "V4L2_CID_FOCUS_AUTO" = CID_FOCUS_AUTO,
            "V4L2_CID_AUTO_FOCUS_START" = CID_AUTO_FOCUS_START,
            "V4L2_CID_AUTO_FOCUS_STOP" = CID_AUTO_FOCUS_STOP,
            "V4L2_CID_AUTO_FOCUS_STATUS" = CID_AUTO_FOCUS_STATUS,
            "V4L2_CID_AUTO_FOCUS_RANGE" = CID_AUTO_FOCUS_RANGE,
            "V4L2_CID_HBLANK" = CID_HBLANK,
            "V4L2_CID_PIXEL_RATE" = CID_PIXEL_RATE,
            "V4L2_SUBDEV_FORMAT_TRY" = SUBDEV_FORMAT_TRY,
            "V4L2_SUBDEV_FORMAT_ACTIVE" = SUBDEV_FORMAT_ACTIVE,
            "V4L2_SEL_TGT_CROP" = SEL_TGT_CROP,
            "MEDIA_ENT_F_CAM_SENSOR" = MEDIA_ENT_F_CAM_SENSOR,
            "MEDIA_ENT_F_LENS" = MEDIA_ENT_F_LENS,
            "MEDIA_PAD_FL_SINK" = MEDIA_PAD_FL_SINK,
            "MEDIA_PAD_FL_SOURCE" = MEDIA_PAD_FL_SOURCE,
            "MEDIA_LNK_FL_ENABLED" = MEDIA_LNK_FL_ENABLED,
            "MEDIA_LNK_FL_IMMUTABLE" = MEDIA_LNK_FL_IMMUTABLE,
            "MEDIA_LNK_FL_LINK_TYPE" = MEDIA_LNK_FL_LINK_TYPE,
            "MEDIA_LNK_FL_DATA_LINK" = MEDIA_LNK_FL_DATA_LINK,
            "MEDIA_LNK_FL_INTERFACE_LINK" = MEDIA_LNK_FL_INTERFACE_LINK,
            "MEDIA_LNK_FL_ANCILLARY_LINK" = MEDIA_LNK_FL_ANCILLARY_LINK,
            "MEDIA_INTF_T_V4L_VIDEO" = MEDIA_INTF_T_V4L_VIDEO,
            "MEDIA_INTF_T_V4L_SUBDEV" = MEDIA_INTF_T_V4L_SUBDEV,
            "VIDIOC_QUERYCAP" = VIDIOC_QUERYCAP,
            "VIDIOC_ENUM_FMT" = VIDIOC_ENUM_FMT,
            "VIDIOC_G_FMT" = VIDIOC_G_FMT,
            "VIDIOC_S_FMT" = VIDIOC_S_FMT,
            "VIDIOC_REQBUFS" = VIDIOC_REQBUFS,
            "VIDIOC_QUERYBUF" = VIDIOC_QUERYBUF,
            "VIDIOC_QBUF" = VIDIOC_QBUF,
            "VIDIOC_DQBUF" = VIDIOC_DQBUF,
            "VIDIOC_STREAMON" = VIDIOC_STREAMON,
            "VIDIOC_STREAMOFF" = VIDIOC_STREAMOFF,
            "VIDIOC_G_PARM" = VIDIOC_G_PARM,
            "VIDIOC_S_PARM" = VIDIOC_S_PARM,
            "VIDIOC_G_EXT_CTRLS" = VIDIOC_G_EXT_CTRLS,
            "VIDIOC_S_EXT_CTRLS" = VIDIOC_S_EXT_CTRLS,
            "VIDIOC_QUERY_EXT_CTRL" = VIDIOC_QUERY_EXT_CTRL,
            "VIDIOC_SUBDEV_ENUM_MBUS_CODE" = VIDIOC_SUBDEV_ENUM_MBUS_CODE,
            "VIDIOC_SUBDEV_ENUM_FRAME_SIZE" = VIDIOC_SUBDEV_ENUM_FRAME_SIZE,
            "VIDIOC_SUBDEV_G_FMT" = VIDIOC_SUBDEV_G_FMT,
            "VIDIOC_SUBDEV_S_FMT" = VIDIOC_SUBDEV_S_FMT,
            "VIDIOC_SUBDEV_G_SELECTION" = VIDIOC_SUBDEV_G_SELECTION,
            "VIDIOC_SUBDEV_S_SELECTION" = VIDIOC_SUBDEV_S_SELECTION,
            "MEDIA_IOC_DEVICE_INFO" = MEDIA_IOC_DEVICE_INFO,
            "MEDIA_IOC_SETUP_LINK" = MEDIA_IOC_SETUP_LINK,
            "MEDIA_IOC_G_TOPOLOGY" = MEDIA_IOC_G_TOPOLOGY,
        );
        // The media-bus codes device profiles name.
        for (name, code) in MBUS_CODES {
            value(&format!("MEDIA_BUS_FMT_{name}"), code.into());
        }
        c
    }

    /// Compiles the assertions with `compiler` (no linking, no running: a cross compiler
    /// checks the target's layout without emulation). `Ok(false)` when it is not installed.
    /// Also the input layer's check (`backend::input::abi`).
    pub(crate) fn compile(compiler: &str, source: &std::path::Path) -> Result<bool, String> {
        let out = match Command::new(compiler)
            .args(["-std=gnu11", "-fsyntax-only", "-Werror"])
            .arg(source)
            .output()
        {
            Ok(out) => out,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
            Err(e) => return Err(format!("{compiler}: {e}")),
        };
        if out.status.success() {
            Ok(true)
        } else {
            Err(format!(
                "{compiler} says the Rust layouts differ from the kernel headers:\n{}",
                String::from_utf8_lossy(&out.stderr)
            ))
        }
    }

    /// On x86-64 with the host's `cc` (Debian's linux-libc-dev headers), and on arm64 with
    /// `aarch64-linux-gnu-gcc` (gcc-aarch64-linux-gnu, libc6-dev-arm64-cross) when it is
    /// installed; CI sets FOCUSD_REQUIRE_ARM64_HEADERS=1 so that arm64 cannot be skipped. The
    /// Rust values are the host's: both targets are LP64 with the same alignments, so the
    /// arm64 compile checks that the arm64 headers agree with them.
    #[test]
    fn layouts_match_the_kernel_headers() {
        let dir = tempfile::tempdir().expect("tempdir");
        let source = dir.path().join("layout.c");
        std::fs::write(&source, assertions()).expect("write");
        assert!(
            compile("cc", &source).expect("x86-64 headers"),
            "no C compiler `cc`: install gcc and linux-libc-dev"
        );
        let arm64 = compile("aarch64-linux-gnu-gcc", &source).expect("arm64 headers");
        if !arm64 {
            assert!(
                std::env::var_os("FOCUSD_REQUIRE_ARM64_HEADERS").is_none(),
                "aarch64-linux-gnu-gcc not found: apt-get install gcc-aarch64-linux-gnu \
                 libc6-dev-arm64-cross"
            );
            eprintln!("arm64 layout check skipped: aarch64-linux-gnu-gcc is not installed");
        }
    }

    #[test]
    fn a_wrong_layout_is_caught() {
        // The check itself can fail: a deliberately wrong size is refused.
        let dir = tempfile::tempdir().expect("tempdir");
        let source = dir.path().join("wrong.c");
        let wrong = assertions().replace(
            &format!("sizeof(struct v4l2_buffer) == {}", size_of::<Buffer>()),
            &format!("sizeof(struct v4l2_buffer) == {}", size_of::<Buffer>() + 8),
        );
        std::fs::write(&source, wrong).expect("write");
        let e = compile("cc", &source).expect_err("refused");
        assert!(e.contains("sizeof v4l2_buffer"), "{e}");
    }

    #[test]
    fn c_strings_stop_at_the_nul() {
        assert_eq!(c_str(b"vivid\0\0junk"), "vivid");
        assert_eq!(c_str(b"full"), "full");
    }
}
