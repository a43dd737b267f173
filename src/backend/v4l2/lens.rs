//! Finding the device nodes in sysfs and the lens's control among a device's controls: pure
//! functions over sysfs trees and control lists, so they are tested without a camera.

use crate::capture::CaptureError;
use std::fs;
use std::path::{Path, PathBuf};

pub use crate::backend::videodev::abi::CID_FOCUS_ABSOLUTE;
use crate::backend::videodev::abi::{
    CID_AUTO_FOCUS_RANGE, CID_AUTO_FOCUS_START, CID_AUTO_FOCUS_STATUS, CID_AUTO_FOCUS_STOP,
    CID_FOCUS_AUTO, CID_FOCUS_RELATIVE,
};

/// The autofocus controls: a camera with only these (the original PinePhone's ov5640 with its
/// autofocus firmware) cannot be swept.
const AUTOFOCUS_CIDS: [u32; 6] = [
    CID_FOCUS_RELATIVE,
    CID_FOCUS_AUTO,
    CID_AUTO_FOCUS_START,
    CID_AUTO_FOCUS_STOP,
    CID_AUTO_FOCUS_STATUS,
    CID_AUTO_FOCUS_RANGE,
];

/// Voice-coil lens drivers in the kernel, by the name their sub-device gets.
pub const LENS_DRIVERS: [&str; 9] = [
    "dw9714", "dw9719", "dw9768", "dw9807", "ad5820", "ak7375", "lc898217", "ak7345", "ak7371",
];

/// One `video*` or `v4l-subdev*` node under `<root>/class/video4linux`.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    /// Its character device.
    pub dev: PathBuf,
    /// Its sysfs `name`: the card of a video node, `driver bus-address` of an I²C sub-device.
    pub name: String,
}

impl Node {
    pub fn label(&self) -> String {
        format!("{} ({})", self.dev.display(), self.name)
    }
}

/// Where `root`'s device nodes are: `/dev` for `/sys`, else `<root>/../dev`, so a test tree
/// `T/sys` keeps them in `T/dev` (as the IIO backend does).
pub fn dev_dir(root: &Path) -> PathBuf {
    root.parent().unwrap_or(Path::new("/")).join("dev")
}

/// The nodes named `<prefix>N`, by N. No video4linux class (no V4L2 driver loaded) is an empty
/// list, which the callers turn into their own message.
pub fn list_nodes(root: &Path, prefix: &str) -> Vec<Node> {
    let Ok(entries) = fs::read_dir(root.join("class/video4linux")) else {
        return Vec::new();
    };
    let mut found: Vec<(u32, Node)> = entries
        .flatten()
        .filter_map(|e| {
            let file_name = e.file_name();
            let n = file_name.to_str()?.strip_prefix(prefix)?.parse().ok()?;
            let name = fs::read_to_string(e.path().join("name")).unwrap_or_default();
            let dev = dev_dir(root).join(&file_name);
            Some((
                n,
                Node {
                    dev,
                    name: name.trim().to_string(),
                },
            ))
        })
        .collect();
    found.sort_by_key(|(n, _)| *n);
    found.into_iter().map(|(_, d)| d).collect()
}

/// The nodes for a message: `a (name), b (name)`, or `none`.
pub fn describe(nodes: &[Node]) -> String {
    if nodes.is_empty() {
        return "none".to_string();
    }
    let labels: Vec<String> = nodes.iter().map(Node::label).collect();
    labels.join(", ")
}

/// The sub-devices to look for the lens control on, in order: the one the config names (a
/// path, or a name matched against the sysfs names), else those named after a known lens
/// driver, then the rest.
pub fn lens_candidates(root: &Path, spec: Option<&str>) -> Result<Vec<PathBuf>, CaptureError> {
    let subdevs = list_nodes(root, "v4l-subdev");
    match spec {
        Some(s) if s.contains('/') => Ok(vec![PathBuf::from(s)]),
        Some(s) => {
            let want = s.to_ascii_lowercase();
            subdevs
                .iter()
                .find(|d| d.name.to_ascii_lowercase().contains(&want))
                .map(|d| vec![d.dev.clone()])
                .ok_or_else(|| {
                    CaptureError::device(
                        root.join("class/video4linux").display().to_string(),
                        format!(
                            "no V4L2 sub-device is named like {s:?} (set [camera] lens); \
                             sub-devices found: {}",
                            describe(&subdevs)
                        ),
                    )
                })
        }
        None => {
            let lenses = named_lenses(root);
            Ok(lenses
                .iter()
                .cloned()
                .chain(
                    subdevs
                        .into_iter()
                        .map(|d| d.dev)
                        .filter(|d| !lenses.contains(d)),
                )
                .collect())
        }
    }
}

/// The sub-devices named after a known lens driver (`dw9714 3-000c`), in sysfs order.
pub fn named_lenses(root: &Path) -> Vec<PathBuf> {
    list_nodes(root, "v4l-subdev")
        .into_iter()
        .filter(|d| {
            let name = d.name.to_ascii_lowercase();
            LENS_DRIVERS.iter().any(|l| name.starts_with(l))
        })
        .map(|d| d.dev)
        .collect()
}

/// What a control is, for picking one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ControlKind {
    /// Integer or 64-bit integer: settable to a position.
    Integer,
    Other,
}

/// A control as `VIDIOC_QUERY_EXT_CTRL` describes it.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlInfo {
    pub id: u32,
    pub name: String,
    pub min: i64,
    pub max: i64,
    pub step: u64,
    pub default: i64,
    pub kind: ControlKind,
    /// Not disabled, read-only or inactive.
    pub writable: bool,
}

/// Which control moves the lens.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ControlSpec {
    Focus,
    Id(u32),
    Name(String),
}

impl ControlSpec {
    /// The config's `focus_control`: unset is the absolute focus control, `0x…` an id, anything
    /// else a name.
    pub fn parse(s: Option<&str>) -> Result<ControlSpec, String> {
        match s {
            None => Ok(ControlSpec::Focus),
            Some("") => Err("is empty: leave it out to drive the focus control".to_string()),
            Some(s) => match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
                Some(hex) => u32::from_str_radix(hex, 16)
                    .map(ControlSpec::Id)
                    .map_err(|_| format!("{s:?} is not a hexadecimal control id")),
                None => Ok(ControlSpec::Name(s.to_string())),
            },
        }
    }

    pub fn describe(&self) -> String {
        match self {
            ControlSpec::Focus => "Focus, Absolute (V4L2_CID_FOCUS_ABSOLUTE)".to_string(),
            ControlSpec::Id(id) => format!("control 0x{id:08x}"),
            ControlSpec::Name(n) => format!("control {n:?}"),
        }
    }
}

/// Whether a sweep could drive `c`: an integer with a range, writable.
fn drivable(c: &ControlInfo) -> bool {
    c.kind == ControlKind::Integer && c.writable && c.min < c.max
}

/// The control `spec` asks for, if `controls` has it in a form a sweep can drive: an integer
/// with a range, writable. Names match case-insensitively.
pub fn pick<'a>(controls: &'a [ControlInfo], spec: &ControlSpec) -> Option<&'a ControlInfo> {
    controls
        .iter()
        .filter(|c| drivable(c))
        .find(|c| match spec {
            ControlSpec::Focus => c.id == CID_FOCUS_ABSOLUTE,
            ControlSpec::Id(id) => c.id == *id,
            ControlSpec::Name(n) => c.name.eq_ignore_ascii_case(n),
        })
}

/// A device's controls, or why they could not be read.
pub type ControlList = Result<Vec<ControlInfo>, String>;

/// Why none of the devices searched for the lens control (label and controls, the video node
/// first) has it, for an error: the autofocus controls a device has instead (the original
/// PinePhone's ov5640 case), or the controls `focus_control` could name instead. Only those
/// are listed: a driver's list also holds control-class headers, buttons, menus, arrays and
/// read-only controls (vivid has some seventy), which would bury the message.
pub fn missing_detail(searched: &[(String, ControlList)]) -> String {
    let parts: Vec<String> = searched
        .iter()
        .enumerate()
        .map(|(i, (label, controls))| {
            let who = if i == 0 { "it" } else { label.as_str() };
            let controls = match controls {
                Ok(c) => c,
                Err(e) => return format!("{who} could not be read: {e}"),
            };
            let auto: Vec<&str> = controls
                .iter()
                .filter(|c| AUTOFOCUS_CIDS.contains(&c.id))
                .map(|c| c.name.as_str())
                .collect();
            if !auto.is_empty() {
                format!("{who} has only {}, i.e. autofocus", auto.join(" / "))
            } else if controls.is_empty() {
                format!("{who} has no controls")
            } else {
                let names: Vec<String> = controls
                    .iter()
                    .filter(|c| drivable(c))
                    .map(|c| format!("{} (0x{:08x})", c.name, c.id))
                    .collect();
                if names.is_empty() {
                    format!(
                        "{who} has no writable integer control at all ({} others)",
                        controls.len()
                    )
                } else {
                    format!("{who} has {}", names.join(", "))
                }
            }
        })
        .collect();
    if parts.is_empty() {
        String::new()
    } else {
        format!(": {}", parts.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctrl(id: u32, name: &str, min: i64, max: i64) -> ControlInfo {
        ControlInfo {
            id,
            name: name.to_string(),
            min,
            max,
            step: 1,
            default: 0,
            kind: ControlKind::Integer,
            writable: true,
        }
    }

    fn tree(nodes: &[(&str, &str)]) -> tempfile::TempDir {
        let t = tempfile::tempdir().expect("tempdir");
        for (node, name) in nodes {
            let dir = t.path().join("sys/class/video4linux").join(node);
            fs::create_dir_all(&dir).expect("mkdir");
            fs::write(dir.join("name"), format!("{name}\n")).expect("write");
        }
        t
    }

    #[test]
    fn dev_dir_is_next_to_the_root() {
        assert_eq!(dev_dir(Path::new("/sys")), PathBuf::from("/dev"));
        assert_eq!(
            dev_dir(Path::new("/tmp/t/sys")),
            PathBuf::from("/tmp/t/dev")
        );
    }

    #[test]
    fn lists_nodes_by_number() {
        let t = tree(&[
            ("video10", "rkisp1_selfpath"),
            ("video2", "rkisp1_mainpath"),
            ("v4l-subdev0", "rkisp1_isp"),
        ]);
        let root = t.path().join("sys");
        let videos = list_nodes(&root, "video");
        assert_eq!(
            videos,
            vec![
                Node {
                    dev: t.path().join("dev/video2"),
                    name: "rkisp1_mainpath".into()
                },
                Node {
                    dev: t.path().join("dev/video10"),
                    name: "rkisp1_selfpath".into()
                },
            ]
        );
        assert_eq!(list_nodes(&root, "v4l-subdev").len(), 1);
        assert!(describe(&videos).contains("video2 (rkisp1_mainpath), "));
        assert_eq!(list_nodes(&t.path().join("nothing"), "video"), vec![]);
        assert_eq!(describe(&[]), "none");
    }

    #[test]
    fn known_lens_drivers_come_first() {
        let t = tree(&[
            ("v4l-subdev0", "rkisp1_isp"),
            ("v4l-subdev1", "imx258 1-001a"),
            ("v4l-subdev2", "dw9714 1-000c"),
        ]);
        let root = t.path().join("sys");
        let dev = |n: &str| t.path().join("dev").join(n);
        assert_eq!(
            lens_candidates(&root, None).expect("lists"),
            vec![dev("v4l-subdev2"), dev("v4l-subdev0"), dev("v4l-subdev1")]
        );
        assert_eq!(
            lens_candidates(&root, Some("DW9714")).expect("by name"),
            vec![dev("v4l-subdev2")]
        );
        assert_eq!(
            lens_candidates(&root, Some("/dev/v4l-subdev7")).expect("by path"),
            vec![PathBuf::from("/dev/v4l-subdev7")]
        );
        let e = lens_candidates(&root, Some("ak7375")).expect_err("absent");
        let msg = e.to_string();
        assert!(
            msg.contains("named like \"ak7375\"") && msg.contains("v4l-subdev2 (dw9714 1-000c)"),
            "{msg}"
        );
    }

    #[test]
    fn control_specs_parse() {
        assert_eq!(ControlSpec::parse(None), Ok(ControlSpec::Focus));
        assert_eq!(
            ControlSpec::parse(Some("0x0098090b")),
            Ok(ControlSpec::Id(0x0098_090b))
        );
        assert_eq!(
            ControlSpec::parse(Some("Brightness")),
            Ok(ControlSpec::Name("Brightness".into()))
        );
        assert!(ControlSpec::parse(Some("0x")).is_err());
        assert!(ControlSpec::parse(Some("")).is_err());
    }

    #[test]
    fn picks_the_focus_or_the_named_control() {
        let controls = vec![
            ctrl(0x0098_0900, "Brightness", 0, 255),
            ctrl(CID_FOCUS_ABSOLUTE, "Focus, Absolute", 0, 1023),
        ];
        let id = |spec| pick(&controls, &spec).map(|c| c.id);
        assert_eq!(id(ControlSpec::Focus), Some(CID_FOCUS_ABSOLUTE));
        assert_eq!(
            id(ControlSpec::Name("brightness".into())),
            Some(0x0098_0900)
        );
        assert_eq!(id(ControlSpec::Id(0x0098_0900)), Some(0x0098_0900));
        assert_eq!(id(ControlSpec::Name("Contrast".into())), None);
    }

    #[test]
    fn unusable_controls_are_not_picked() {
        let mut read_only = ctrl(CID_FOCUS_ABSOLUTE, "Focus, Absolute", 0, 1023);
        read_only.writable = false;
        let mut menu = ctrl(CID_FOCUS_ABSOLUTE, "Focus, Absolute", 0, 3);
        menu.kind = ControlKind::Other;
        let fixed = ctrl(CID_FOCUS_ABSOLUTE, "Focus, Absolute", 5, 5);
        for c in [read_only, menu, fixed] {
            assert_eq!(pick(&[c], &ControlSpec::Focus), None);
        }
    }

    #[test]
    fn ov5640_autofocus_only_is_explained() {
        let node = vec![
            ctrl(0x0098_0900, "Brightness", 0, 255),
            ctrl(0x009a_090c, "Focus, Automatic Continuous", 0, 1),
            ctrl(0x009a_091c, "Auto Focus, Start", 0, 0),
        ];
        let detail = missing_detail(&[
            ("/dev/video0".into(), Ok(node)),
            ("/dev/v4l-subdev0 (ov5640 1-004c)".into(), Ok(vec![])),
            (
                "/dev/v4l-subdev1 (csi)".into(),
                Err("permission denied".into()),
            ),
        ]);
        assert_eq!(
            detail,
            ": it has only Focus, Automatic Continuous / Auto Focus, Start, i.e. autofocus; \
             /dev/v4l-subdev0 (ov5640 1-004c) has no controls; /dev/v4l-subdev1 (csi) could \
             not be read: permission denied"
        );
        let e = CaptureError::NoFocusControl {
            device: "/dev/video0".into(),
            detail,
        };
        assert!(e.to_string().starts_with(
            "/dev/video0 has no absolute focus control (V4L2_CID_FOCUS_ABSOLUTE): it has only"
        ));
    }

    #[test]
    fn other_controls_are_listed_with_ids() {
        let plain = missing_detail(&[(
            "/dev/video0".into(),
            Ok(vec![ctrl(0x0098_0900, "Brightness", 0, 255)]),
        )]);
        assert_eq!(plain, ": it has Brightness (0x00980900)");
        assert_eq!(missing_detail(&[]), "");
    }

    #[test]
    fn only_controls_a_sweep_could_drive_are_listed() {
        // As vivid lists them: a class header, a button, a read-only integer, a fixed one.
        let mut class = ctrl(0x0098_0001, "User Controls", 0, 0);
        class.kind = ControlKind::Other;
        let mut button = ctrl(0x0098_f900, "Button", 0, 0);
        button.kind = ControlKind::Other;
        let mut read_only = ctrl(0x0098_f90c, "Read-Only Integer 32 Bits", 0, 255);
        read_only.writable = false;
        let fixed = ctrl(0x0098_f90f, "Fixed", 3, 3);
        let brightness = ctrl(0x0098_0900, "Brightness", 0, 255);
        let all = vec![class, button, read_only, brightness, fixed];
        assert_eq!(
            missing_detail(&[("/dev/video0".into(), Ok(all.clone()))]),
            ": it has Brightness (0x00980900)"
        );
        assert_eq!(
            missing_detail(&[("/dev/video0".into(), Ok(all[..3].to_vec()))]),
            ": it has no writable integer control at all (3 others)"
        );
    }
}
