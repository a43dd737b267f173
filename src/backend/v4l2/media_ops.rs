//! The device calls a media-controller pipeline is negotiated with, behind a trait: the kernel
//! answers them on a phone ([`Kernel`]); tests answer them as each phone's drivers do, so the
//! negotiation code that runs on the phone is the code the tests run.

use super::lens::dev_dir;
use crate::backend::videodev::abi::{MbusFramefmt, Rect};
use crate::backend::videodev::media::{self, Info, Topology};
use crate::backend::videodev::subdev::{self, SizeRange};
use crate::backend::videodev::Device;
use std::collections::HashMap;
use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// Media devices and sub-devices by path.
pub trait MediaOps {
    /// The media device nodes (`/dev/mediaN`), in name order.
    fn media_nodes(&mut self) -> Vec<PathBuf>;
    fn info(&mut self, media: &Path) -> io::Result<Info>;
    fn topology(&mut self, media: &Path) -> io::Result<Topology>;
    fn setup_link(
        &mut self,
        media: &Path,
        source: (u32, u16),
        sink: (u32, u16),
        enabled: bool,
    ) -> io::Result<()>;
    /// The node of the character device `major:minor`.
    fn devnode(&mut self, major: u32, minor: u32) -> Result<PathBuf, String>;
    /// VIDIOC_SUBDEV_ENUM_MBUS_CODE over all indices.
    fn codes(&mut self, node: &Path, pad: u32) -> io::Result<Vec<u32>>;
    /// VIDIOC_SUBDEV_ENUM_FRAME_SIZE over all indices.
    fn sizes(&mut self, node: &Path, pad: u32, code: u32) -> io::Result<Vec<SizeRange>>;
    fn format(&mut self, node: &Path, pad: u32) -> io::Result<MbusFramefmt>;
    fn set_format(&mut self, node: &Path, pad: u32, f: MbusFramefmt) -> io::Result<MbusFramefmt>;
    fn set_crop(&mut self, node: &Path, pad: u32, r: Rect) -> io::Result<Rect>;
    /// A control's value; `None` when the device has no such control.
    fn control(&mut self, node: &Path, id: u32) -> io::Result<Option<i64>>;
}

/// The kernel's answers: device nodes opened once each and kept while negotiating.
pub struct Kernel {
    sysfs_root: PathBuf,
    open: HashMap<PathBuf, Device>,
}

impl Kernel {
    /// `sysfs_root` as in `[camera]` (device nodes beside it).
    pub fn new(sysfs_root: &Path) -> Kernel {
        Kernel {
            sysfs_root: sysfs_root.to_path_buf(),
            open: HashMap::new(),
        }
    }

    fn dev(&mut self, node: &Path) -> io::Result<&Device> {
        if !self.open.contains_key(node) {
            let d = Device::open(node)?;
            self.open.insert(node.to_path_buf(), d);
        }
        Ok(&self.open[node])
    }
}

impl MediaOps for Kernel {
    fn media_nodes(&mut self) -> Vec<PathBuf> {
        let mut paths: Vec<PathBuf> = fs::read_dir(dev_dir(&self.sysfs_root))
            .map(|d| {
                d.flatten()
                    .filter(|e| e.file_name().to_string_lossy().starts_with("media"))
                    .map(|e| e.path())
                    .collect()
            })
            .unwrap_or_default();
        paths.sort();
        paths
    }

    fn info(&mut self, media: &Path) -> io::Result<Info> {
        media::info(self.dev(media)?)
    }

    fn topology(&mut self, media: &Path) -> io::Result<Topology> {
        media::topology(self.dev(media)?)
    }

    fn setup_link(
        &mut self,
        media: &Path,
        source: (u32, u16),
        sink: (u32, u16),
        enabled: bool,
    ) -> io::Result<()> {
        media::setup_link(self.dev(media)?, source, sink, enabled)
    }

    fn devnode(&mut self, major: u32, minor: u32) -> Result<PathBuf, String> {
        let uevent = self
            .sysfs_root
            .join(format!("dev/char/{major}:{minor}/uevent"));
        let text = fs::read_to_string(&uevent).map_err(|e| format!("{}: {e}", uevent.display()))?;
        let name = text
            .lines()
            .find_map(|l| l.strip_prefix("DEVNAME="))
            .ok_or_else(|| format!("{} has no DEVNAME", uevent.display()))?;
        Ok(dev_dir(&self.sysfs_root).join(name))
    }

    fn codes(&mut self, node: &Path, pad: u32) -> io::Result<Vec<u32>> {
        subdev::codes(self.dev(node)?, pad)
    }

    fn sizes(&mut self, node: &Path, pad: u32, code: u32) -> io::Result<Vec<SizeRange>> {
        subdev::sizes(self.dev(node)?, pad, code)
    }

    fn format(&mut self, node: &Path, pad: u32) -> io::Result<MbusFramefmt> {
        subdev::format(self.dev(node)?, pad)
    }

    fn set_format(&mut self, node: &Path, pad: u32, f: MbusFramefmt) -> io::Result<MbusFramefmt> {
        subdev::set_format(self.dev(node)?, pad, f)
    }

    fn set_crop(&mut self, node: &Path, pad: u32, r: Rect) -> io::Result<Rect> {
        subdev::set_crop(self.dev(node)?, pad, r)
    }

    fn control(&mut self, node: &Path, id: u32) -> io::Result<Option<i64>> {
        let dev = self.dev(node)?;
        if !dev.controls()?.iter().any(|c| c.id == id) {
            return Ok(None);
        }
        dev.control(id).map(Some)
    }
}
