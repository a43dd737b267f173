//! The `[camera]` table of the config.

use super::format::PixelFormat;
use super::lens::ControlSpec;
use crate::base::setting::{Bounds, Invalid};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[camera] profile = "none"`: no device profile, even where one would be chosen.
pub const NO_PROFILE: &str = "none";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct V4l2Config {
    /// The video node, e.g. `/dev/video1`. Phones have several (ISP paths, statistics,
    /// parameters), so naming one is the reliable way; unset: found by `card`.
    pub device: Option<PathBuf>,
    /// A device profile (`config/devices/`): a shipped one by name (`vimc`) or a `.toml` path.
    /// It sets the media pipeline up before streaming (links, pad formats) and gives the
    /// capture node, its format and size, and the lens through the media graph; `device`,
    /// `format`, `width` and `height` are then the profile's, and `lens` (when set) overrides
    /// the graph's. Unset: the shipped profile whose device-tree compatible this machine has
    /// (or, for profiles no device tree names, whose media model it has), else none. `"none"`:
    /// no media-controller set-up (USB cameras, vivid, a pipeline set up by hand).
    pub profile: Option<String>,
    /// Without `device`: the first capture node whose card or driver name (`query_caps`) or
    /// sysfs name contains this, case-insensitively; neither set: the first capture node.
    pub card: Option<String>,
    /// Frame width asked for; the driver may pick the nearest size it has, which is then used.
    pub width: u32,
    /// Frame height asked for, likewise.
    pub height: u32,
    /// Fourcc to insist on (`YUYV`, `NV12`, `RGGB`, ...); unset: the best one the device
    /// offers, in the order of [`PixelFormat::rank`].
    pub format: Option<String>,
    /// The lens: a sub-device path (`/dev/v4l-subdev3`) or a driver name (`dw9714`) matched
    /// against `<sysfs_root>/class/video4linux/v4l-subdev*/name`. Unset: the video node's own
    /// focus control, else the first sub-device named after a known lens driver, else the
    /// first sub-device with the control.
    pub lens: Option<String>,
    /// The control to sweep instead of V4L2_CID_FOCUS_ABSOLUTE: its name as the driver reports
    /// it (`Brightness`) or its id (`0x00980900`). Lets a sweep run against the vivid test
    /// driver, which has no focus control.
    pub focus_control: Option<String>,
    /// Wait after each lens move: the dw9714 jumps to the new position at once and rings for
    /// 10–20 ms.
    pub settle_ms: u64,
    /// The most frames dropped after a move for having started exposing before the lens
    /// settled; more means the timestamps or the exposure estimate are wrong, and the take
    /// fails. At least `buffers`: every queued buffer may hold a frame exposed before the move.
    pub drop_frames: u32,
    /// Buffers to stream with: more absorb scheduling hiccups, fewer keep stale frames short.
    pub buffers: u32,
    /// How long to wait for a frame before failing (a stalled sensor or ISP pipeline).
    pub frame_timeout_ms: u64,
    /// The sysfs mount; device nodes are in `/dev` for `/sys` and in `<root>/../dev` otherwise,
    /// so a test tree `T/sys` keeps them in `T/dev`.
    pub sysfs_root: PathBuf,
}

impl Default for V4l2Config {
    fn default() -> Self {
        Self {
            device: None,
            card: None,
            width: 1280,
            height: 720,
            format: None,
            lens: None,
            profile: None,
            focus_control: None,
            settle_ms: 20,
            drop_frames: 6,
            buffers: 4,
            frame_timeout_ms: 2000,
            sysfs_root: PathBuf::from("/sys"),
        }
    }
}

impl V4l2Config {
    pub fn validate(&self) -> Result<(), Invalid> {
        let range = |key, v: u64, lo, hi| Bounds::new(lo, hi).check(key, v);
        range("width", self.width.into(), 16, 16384)?;
        range("height", self.height.into(), 16, 16384)?;
        range("settle_ms", self.settle_ms, 0, 1000)?;
        range("buffers", self.buffers.into(), 2, 32)?;
        range("drop_frames", self.drop_frames.into(), 0, 64)?;
        // A minute without a frame is already a dead pipeline.
        range("frame_timeout_ms", self.frame_timeout_ms, 10, 60_000)?;
        if self.drop_frames < self.buffers {
            return Err(Invalid::new(
                "drop_frames",
                format!(
                    "drop_frames = {} is less than buffers = {}: each queued buffer may hold a \
                     frame exposed before the lens moved, so drop_frames must be at least buffers",
                    self.drop_frames, self.buffers
                ),
            ));
        }
        if let Some(f) = &self.format {
            PixelFormat::parse(f)
                .map_err(|e| Invalid::new("format", format!("format = {f:?}: {e}")))?;
        }
        ControlSpec::parse(self.focus_control.as_deref())
            .map_err(|e| Invalid::new("focus_control", format!("focus_control: {e}")))?;
        let empty = |key, v: Option<&str>| match v {
            Some("") => Err(Invalid::new(
                key,
                format!("{key} is empty: leave it out to pick automatically"),
            )),
            _ => Ok(()),
        };
        empty("device", self.device.as_ref().and_then(|p| p.to_str()))?;
        empty("card", self.card.as_deref())?;
        empty("lens", self.lens.as_deref())?;
        empty("profile", self.profile.as_deref())?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        assert_eq!(V4l2Config::default().validate(), Ok(()));
    }

    #[test]
    fn parses_a_table_and_fills_defaults() {
        let cfg: V4l2Config = toml::from_str(
            "device = \"/dev/video1\"\nlens = \"dw9714\"\nformat = \"NV12\"\nsettle_ms = 30\n",
        )
        .expect("parses");
        assert_eq!(cfg.device, Some(PathBuf::from("/dev/video1")));
        assert_eq!(cfg.lens.as_deref(), Some("dw9714"));
        assert_eq!(cfg.settle_ms, 30);
        assert_eq!(cfg.width, 1280);
        assert_eq!(cfg.validate(), Ok(()));
    }

    #[test]
    fn unknown_keys_are_refused() {
        let e = toml::from_str::<V4l2Config>("focus = 3\n").expect_err("refused");
        assert!(e.to_string().contains("unknown field"), "{e}");
    }

    #[test]
    fn out_of_range_values_name_the_key_and_range() {
        let bad = |f: fn(&mut V4l2Config)| {
            let mut cfg = V4l2Config::default();
            f(&mut cfg);
            cfg.validate().expect_err("refused").message
        };
        assert_eq!(bad(|c| c.width = 0), "width = 0 is out of range 16..=16384");
        assert_eq!(
            bad(|c| c.frame_timeout_ms = 3_000_000),
            "frame_timeout_ms = 3000000 is out of range 10..=60000"
        );
        assert_eq!(bad(|c| c.buffers = 1), "buffers = 1 is out of range 2..=32");
        assert!(bad(|c| c.drop_frames = 2).contains("at least buffers"));
        assert!(bad(|c| c.settle_ms = 5000).starts_with("settle_ms = 5000"));
    }

    #[test]
    fn format_focus_control_and_names_are_checked() {
        let mut cfg = V4l2Config {
            format: Some("XYZW".into()),
            ..V4l2Config::default()
        };
        let e = cfg.validate().expect_err("unknown fourcc").message;
        assert!(
            e.starts_with("format = \"XYZW\"") && e.contains("YUYV"),
            "{e}"
        );
        cfg.format = Some("yuyv".into());
        assert_eq!(cfg.validate(), Ok(()), "fourccs are case-insensitive");
        cfg.focus_control = Some("0xzz".into());
        assert!(cfg
            .validate()
            .expect_err("bad id")
            .message
            .starts_with("focus_control"));
        cfg.focus_control = Some("Brightness".into());
        assert_eq!(cfg.validate(), Ok(()));
        cfg.lens = Some(String::new());
        assert!(cfg
            .validate()
            .expect_err("empty")
            .message
            .starts_with("lens is empty"));
    }
}
