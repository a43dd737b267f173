//! Applying a device profile to the media controller before streaming: the media device by
//! model, the profile's links enabled, each pad's format (and crop) set and read back, the
//! capture node and the lens found through the graph. Every mismatch with the hardware is an
//! error naming the link or pad.

use super::lens::dev_dir;
use super::profile::{mbus_code, mbus_name, LensSpec, LinkSpec, PadRef, Profile};
use crate::backend::videodev::abi::{self, MbusFramefmt, Rect};
use crate::backend::videodev::media::{self, Topology};
use crate::backend::videodev::{subdev, Device};
use crate::capture::CaptureError;
use std::fs;
use std::path::{Path, PathBuf};

/// The nodes the profile's pipeline streams through, once set up.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pipeline {
    pub media: PathBuf,
    /// The capture video node.
    pub capture: PathBuf,
    /// The lens sub-device from the graph; `None`: the graph has no lens linked to the sensor.
    pub lens: Option<PathBuf>,
}

/// Sets the pipeline up as `profile` says. `sysfs_root` as in `[camera]` (device nodes beside
/// it). A profile whose lens is `none` fails here, before anything is touched, with its reason.
pub fn apply(profile: &Profile, sysfs_root: &Path) -> Result<Pipeline, CaptureError> {
    let label = format!("device profile {}", profile.name);
    let fail = |e: String| CaptureError::device(&label, e);
    if let LensSpec::None { reason } = &profile.lens {
        return Err(fail(format!(
            "this camera has no lens focusd can move: {reason}; a focus sweep is not possible \
             here (`focusd fuse` still fuses stacks taken elsewhere)"
        )));
    }
    let (media_path, dev, topo) = open_media(profile, sysfs_root).map_err(fail)?;
    for link in &profile.links {
        let (source, sink, flags) = data_link(&topo, link).map_err(fail)?;
        if flags & abi::MEDIA_LNK_FL_IMMUTABLE == 0 {
            for (other, other_sink) in rivals(&topo, source, sink) {
                media::setup_link(&dev, other, other_sink, false).map_err(|e| {
                    fail(format!(
                        "link {link}: cannot disable the link from {} into the same pad: {e}",
                        describe_pad(&topo, other)
                    ))
                })?;
            }
            media::setup_link(&dev, source, sink, true)
                .map_err(|e| fail(format!("link {link}: cannot enable it: {e}")))?;
        }
    }
    for p in &profile.pads {
        let entity = entity_id(&topo, &p.pad.0).map_err(|e| fail(format!("pad {}: {e}", p.pad)))?;
        let node =
            devnode(&topo, entity, sysfs_root).map_err(|e| fail(format!("pad {}: {e}", p.pad)))?;
        let sub = Device::open(&node)
            .map_err(|e| fail(format!("pad {}: {}: {e}", p.pad, node.display())))?;
        let want = MbusFramefmt {
            width: p.width,
            height: p.height,
            code: mbus_code(&p.code).unwrap_or_default(),
            field: abi::FIELD_NONE,
            ..MbusFramefmt::default()
        };
        let pad = u32::from(p.pad.1);
        let got = subdev::set_format(&sub, pad, want).map_err(|e| {
            fail(format!(
                "pad {}: cannot set {}: {e}",
                p.pad,
                describe(&want)
            ))
        })?;
        check_format(&p.pad, &want, &got).map_err(fail)?;
        if let Some([left, top, width, height]) = p.crop {
            let want = Rect {
                left: left as i32,
                top: top as i32,
                width,
                height,
            };
            let got = subdev::set_crop(&sub, pad, want)
                .map_err(|e| fail(format!("pad {}: cannot crop to {want:?}: {e}", p.pad)))?;
            if got != want {
                return Err(fail(format!(
                    "pad {}: asked to crop to {want:?}, the driver set {got:?}",
                    p.pad
                )));
            }
        }
    }
    let capture_id = entity_id(&topo, &profile.capture)
        .map_err(|e| fail(format!("capture {:?}: {e}", profile.capture)))?;
    let capture = devnode(&topo, capture_id, sysfs_root)
        .map_err(|e| fail(format!("capture {:?}: {e}", profile.capture)))?;
    let sensor = entity_id(&topo, &profile.sensor)
        .map_err(|e| fail(format!("sensor {:?}: {e}", profile.sensor)))?;
    let lens = match lens_of(&topo, sensor) {
        Some(id) => Some(devnode(&topo, id, sysfs_root).map_err(|e| fail(format!("lens: {e}")))?),
        None => None,
    };
    Ok(Pipeline {
        media: media_path,
        capture,
        lens,
    })
}

/// The media device whose model is the profile's and whose graph holds its sensor (a phone may
/// have one media device per ISP or bridge, all with the same model), with its graph.
fn open_media(profile: &Profile, sysfs_root: &Path) -> Result<(PathBuf, Device, Topology), String> {
    let model = &profile.media_model;
    let dir = dev_dir(sysfs_root);
    let mut paths: Vec<PathBuf> = fs::read_dir(&dir)
        .map(|d| {
            d.flatten()
                .filter(|e| e.file_name().to_string_lossy().starts_with("media"))
                .map(|e| e.path())
                .collect()
        })
        .unwrap_or_default();
    paths.sort();
    let mut found = Vec::new();
    for path in paths {
        let info = Device::open(&path).and_then(|d| media::info(&d).map(|i| (d, i)));
        match info {
            Ok((dev, info)) if info.model == *model => match media::topology(&dev) {
                Ok(topo) => match entity_id(&topo, &profile.sensor) {
                    Ok(_) => return Ok((path, dev, topo)),
                    Err(e) => found.push(format!(
                        "{} ({model:?}, but sensor {:?}: {e})",
                        path.display(),
                        profile.sensor
                    )),
                },
                Err(e) => found.push(format!(
                    "{} ({model:?}, cannot read its graph: {e})",
                    path.display()
                )),
            },
            Ok((_, info)) => found.push(format!("{} ({:?})", path.display(), info.model)),
            Err(e) => found.push(format!("{}: {e}", path.display())),
        }
    }
    Err(format!(
        "no media device has the model {model:?} and the sensor {:?} (is the camera driver \
         loaded, is this the right profile?); found: {}",
        profile.sensor,
        if found.is_empty() {
            "none".to_string()
        } else {
            found.join(", ")
        }
    ))
}

/// Whether a graph entity's name is the one a profile gives: the same, or the same but for the
/// bus and address an I²C sub-device's name ends with (`imx258` for `imx258 1-001a`).
fn names_entity(profile_name: &str, entity_name: &str) -> bool {
    entity_name == profile_name
        || entity_name
            .strip_prefix(profile_name)
            .is_some_and(|rest| rest.starts_with(' '))
}

/// The entity a profile names: the one with that name, else the only one whose name is it
/// followed by a space and more (an I²C sub-device's bus and address).
fn entity_id(topo: &Topology, name: &str) -> Result<u32, String> {
    if let Some(e) = topo.entities.iter().find(|e| e.name == name) {
        return Ok(e.id);
    }
    let like: Vec<&media::Entity> = topo
        .entities
        .iter()
        .filter(|e| names_entity(name, &e.name))
        .collect();
    match like.as_slice() {
        [e] => Ok(e.id),
        [] => {
            let names: Vec<String> = topo
                .entities
                .iter()
                .map(|e| format!("{:?}", e.name))
                .collect();
            Err(format!(
                "no entity is named {name:?}; the graph has {}",
                names.join(", ")
            ))
        }
        many => {
            let names: Vec<String> = many.iter().map(|e| format!("{:?}", e.name)).collect();
            Err(format!(
                "{name:?} could be any of {}: give the whole name",
                names.join(", ")
            ))
        }
    }
}

/// The pad object id of `p`.
fn pad_id(topo: &Topology, p: &PadRef) -> Result<u32, String> {
    let entity = entity_id(topo, &p.0)?;
    topo.pads
        .iter()
        .find(|pad| pad.entity == entity && pad.index == u32::from(p.1))
        .map(|pad| pad.id)
        .ok_or_else(|| format!("{:?} has no pad {}", p.0, p.1))
}

/// The data link `link` names: its (entity, pad index) ends and its flags.
#[allow(clippy::type_complexity)]
fn data_link(topo: &Topology, link: &LinkSpec) -> Result<((u32, u16), (u32, u16), u32), String> {
    let source = pad_id(topo, &link.source).map_err(|e| format!("link {link}: {e}"))?;
    let sink = pad_id(topo, &link.sink).map_err(|e| format!("link {link}: {e}"))?;
    let l = topo
        .links
        .iter()
        .find(|l| {
            l.flags & abi::MEDIA_LNK_FL_LINK_TYPE == abi::MEDIA_LNK_FL_DATA_LINK
                && l.source == source
                && l.sink == sink
        })
        .ok_or_else(|| format!("link {link}: the graph has no such link"))?;
    let ends = |p: &PadRef| -> Result<(u32, u16), String> { Ok((entity_id(topo, &p.0)?, p.1)) };
    Ok((ends(&link.source)?, ends(&link.sink)?, l.flags))
}

/// The enabled, changeable data links into the pad `sink` from another source than `source`,
/// as (source, sink) ends: a sink pad takes one source at a time (a receiver shared by two
/// sensors, vimc's debayer fed by sensor A or B), and the kernel refuses a second enabled link
/// rather than switch, so they are disabled before the profile's link is enabled.
fn rivals(topo: &Topology, source: (u32, u16), sink: (u32, u16)) -> Vec<((u32, u16), (u32, u16))> {
    let ends = |pad: u32| {
        topo.pads
            .iter()
            .find(|p| p.id == pad)
            .and_then(|p| Some((p.entity, u16::try_from(p.index).ok()?)))
    };
    topo.links
        .iter()
        .filter(|l| l.flags & abi::MEDIA_LNK_FL_LINK_TYPE == abi::MEDIA_LNK_FL_DATA_LINK)
        .filter(|l| l.flags & abi::MEDIA_LNK_FL_ENABLED != 0)
        .filter(|l| l.flags & abi::MEDIA_LNK_FL_IMMUTABLE == 0)
        .filter_map(|l| Some((ends(l.source)?, ends(l.sink)?)))
        .filter(|&(s, k)| k == sink && s != source)
        .collect()
}

/// An (entity, pad) for a message: `"Sensor B":0`.
fn describe_pad(topo: &Topology, (entity, pad): (u32, u16)) -> String {
    let name = topo
        .entities
        .iter()
        .find(|e| e.id == entity)
        .map_or_else(|| format!("entity {entity}"), |e| e.name.clone());
    PadRef(name, pad).to_string()
}

/// The device node of an entity, through its interface link and sysfs's char-device table.
fn devnode(topo: &Topology, entity: u32, sysfs_root: &Path) -> Result<PathBuf, String> {
    let intf = topo
        .links
        .iter()
        .filter(|l| l.flags & abi::MEDIA_LNK_FL_LINK_TYPE == abi::MEDIA_LNK_FL_INTERFACE_LINK)
        .filter(|l| l.sink == entity)
        .find_map(|l| topo.interfaces.iter().find(|i| i.id == l.source))
        .ok_or_else(|| "it has no device node".to_string())?;
    let uevent = sysfs_root.join(format!("dev/char/{}:{}/uevent", intf.major, intf.minor));
    let text = fs::read_to_string(&uevent).map_err(|e| format!("{}: {e}", uevent.display()))?;
    let name = text
        .lines()
        .find_map(|l| l.strip_prefix("DEVNAME="))
        .ok_or_else(|| format!("{} has no DEVNAME", uevent.display()))?;
    Ok(dev_dir(sysfs_root).join(name))
}

/// The lens entity tied to `sensor` by an ancillary link (either direction).
fn lens_of(topo: &Topology, sensor: u32) -> Option<u32> {
    topo.links
        .iter()
        .filter(|l| l.flags & abi::MEDIA_LNK_FL_LINK_TYPE == abi::MEDIA_LNK_FL_ANCILLARY_LINK)
        .filter_map(|l| match (l.source, l.sink) {
            (s, other) | (other, s) if s == sensor => Some(other),
            _ => None,
        })
        .find(|&id| {
            topo.entities
                .iter()
                .any(|e| e.id == id && e.function == abi::MEDIA_ENT_F_LENS)
        })
}

fn describe(f: &MbusFramefmt) -> String {
    format!("{}/{}x{}", mbus_name(f.code), f.width, f.height)
}

/// A pad format the driver changed means the hardware cannot do what the profile says.
fn check_format(pad: &PadRef, want: &MbusFramefmt, got: &MbusFramefmt) -> Result<(), String> {
    if (got.code, got.width, got.height) == (want.code, want.width, want.height) {
        Ok(())
    } else {
        Err(format!(
            "pad {pad}: asked for {}, the driver set {}: the profile does not match this hardware",
            describe(want),
            describe(got)
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::videodev::media::{Entity, Interface, Link, Pad};

    /// vimc's sensor, debayer and lens, as G_TOPOLOGY gives them.
    fn graph() -> Topology {
        let e = |id, name: &str, function| Entity {
            id,
            name: name.into(),
            function,
        };
        let pad = |id, entity, index, flags| Pad {
            id,
            entity,
            index,
            flags,
        };
        let link = |id, source, sink, flags| Link {
            id,
            source,
            sink,
            flags,
        };
        Topology {
            version: 1,
            entities: vec![
                e(1, "Sensor A", abi::MEDIA_ENT_F_CAM_SENSOR),
                e(5, "Debayer A", 0x4003),
                e(28, "Lens A", abi::MEDIA_ENT_F_LENS),
            ],
            interfaces: vec![Interface {
                id: 40,
                kind: abi::MEDIA_INTF_T_V4L_SUBDEV,
                major: 81,
                minor: 6,
            }],
            pads: vec![
                pad(2, 1, 0, abi::MEDIA_PAD_FL_SOURCE),
                pad(6, 5, 0, abi::MEDIA_PAD_FL_SINK),
                pad(7, 5, 1, abi::MEDIA_PAD_FL_SOURCE),
            ],
            links: vec![
                link(
                    50,
                    2,
                    6,
                    abi::MEDIA_LNK_FL_ENABLED | abi::MEDIA_LNK_FL_IMMUTABLE,
                ),
                link(51, 40, 28, abi::MEDIA_LNK_FL_INTERFACE_LINK),
                link(52, 1, 28, abi::MEDIA_LNK_FL_ANCILLARY_LINK | 3),
            ],
        }
    }

    fn spec(a: &str, ai: u16, b: &str, bi: u16) -> LinkSpec {
        LinkSpec {
            source: PadRef(a.into(), ai),
            sink: PadRef(b.into(), bi),
        }
    }

    #[test]
    fn links_resolve_by_entity_name_and_pad() {
        let t = graph();
        let (s, k, flags) = data_link(&t, &spec("Sensor A", 0, "Debayer A", 0)).expect("found");
        assert_eq!((s, k), ((1, 0), (5, 0)));
        assert_ne!(flags & abi::MEDIA_LNK_FL_IMMUTABLE, 0);
        let e = data_link(&t, &spec("Sensor A", 0, "Debayer A", 1)).expect_err("no such link");
        assert_eq!(
            e,
            "link \"Sensor A\":0 -> \"Debayer A\":1: the graph has no such link"
        );
        let e = data_link(&t, &spec("Sensor Z", 0, "Debayer A", 0)).expect_err("no entity");
        assert!(
            e.starts_with(
                "link \"Sensor Z\":0 -> \"Debayer A\":0: no entity is named \"Sensor Z\""
            ) && e.contains("\"Lens A\""),
            "{e}"
        );
        let e = data_link(&t, &spec("Sensor A", 3, "Debayer A", 0)).expect_err("no pad");
        assert!(e.ends_with("\"Sensor A\" has no pad 3"), "{e}");
    }

    #[test]
    fn entities_are_named_with_or_without_their_bus_and_address() {
        let mut t = graph();
        t.entities[0].name = "imx258 1-001a".into();
        assert_eq!(entity_id(&t, "imx258 1-001a"), Ok(1));
        assert_eq!(entity_id(&t, "imx258"), Ok(1));
        // A prefix counts only when a space follows it in the entity's name.
        assert!(entity_id(&t, "imx25").is_err());
        assert_eq!(entity_id(&t, "Lens A"), Ok(28));
        assert_eq!(entity_id(&t, "Lens"), Ok(28));
        t.entities[1].name = "imx258 2-0010".into();
        let e = entity_id(&t, "imx258").expect_err("ambiguous");
        assert_eq!(
            e,
            "\"imx258\" could be any of \"imx258 1-001a\", \"imx258 2-0010\": give the whole name"
        );
        assert_eq!(entity_id(&t, "imx258 2-0010"), Ok(5));
    }

    #[test]
    fn other_enabled_links_into_the_sink_pad_are_the_ones_to_disable() {
        // vimc's debayer sink fed by Sensor A (immutable here) and Sensor B (enabled): enabling
        // B's link must not disturb anything else; enabling a third source must drop B's.
        let mut t = graph();
        for (id, name) in [(60, "Sensor B"), (70, "Sensor C")] {
            t.entities.push(Entity {
                id,
                name: name.into(),
                function: abi::MEDIA_ENT_F_CAM_SENSOR,
            });
            t.pads.push(Pad {
                id: id + 1,
                entity: id,
                index: 0,
                flags: abi::MEDIA_PAD_FL_SOURCE,
            });
        }
        t.links[0].flags = abi::MEDIA_LNK_FL_ENABLED;
        let link = |id, source, flags| Link {
            id,
            source,
            sink: 6,
            flags,
        };
        t.links.push(link(62, 61, 0));
        t.links.push(link(72, 71, abi::MEDIA_LNK_FL_ENABLED));
        // Enabling A: C's enabled link goes, B's (disabled) stays as it is.
        assert_eq!(rivals(&t, (1, 0), (5, 0)), vec![((70, 0), (5, 0))]);
        // Enabling B: both A's and C's go.
        assert_eq!(
            rivals(&t, (60, 0), (5, 0)),
            vec![((1, 0), (5, 0)), ((70, 0), (5, 0))]
        );
        assert_eq!(describe_pad(&t, (70, 0)), "\"Sensor C\":0");
        // An immutable link is the hardware's and is never touched; another pad's links neither.
        t.links[0].flags |= abi::MEDIA_LNK_FL_IMMUTABLE;
        assert_eq!(rivals(&t, (70, 0), (5, 0)), vec![]);
        assert_eq!(rivals(&t, (60, 0), (5, 1)), vec![]);
    }

    #[test]
    fn the_lens_is_the_lens_entity_linked_to_the_sensor() {
        let t = graph();
        assert_eq!(lens_of(&t, 1), Some(28));
        // Not linked to the debayer; a link to a non-lens entity does not count.
        assert_eq!(lens_of(&t, 5), None);
        let mut t2 = t.clone();
        t2.entities[2].function = abi::MEDIA_ENT_F_CAM_SENSOR;
        assert_eq!(lens_of(&t2, 1), None);
    }

    #[test]
    fn device_nodes_come_from_the_interface_and_sysfs() {
        let dir = tempfile::tempdir().expect("tempdir");
        let root = dir.path().join("sys");
        let char_dir = root.join("dev/char/81:6");
        fs::create_dir_all(&char_dir).expect("mkdir");
        fs::write(
            char_dir.join("uevent"),
            "MAJOR=81\nMINOR=6\nDEVNAME=v4l-subdev6\n",
        )
        .expect("w");
        let t = graph();
        assert_eq!(
            devnode(&t, 28, &root),
            Ok(dir.path().join("dev/v4l-subdev6"))
        );
        assert_eq!(devnode(&t, 1, &root), Err("it has no device node".into()));
    }

    #[test]
    fn a_changed_pad_format_names_the_pad() {
        let want = MbusFramefmt {
            code: 0x3014,
            width: 640,
            height: 480,
            ..MbusFramefmt::default()
        };
        let pad = PadRef("Scaler".into(), 1);
        assert_eq!(check_format(&pad, &want, &want), Ok(()));
        let got = MbusFramefmt {
            code: 0x100a,
            ..want
        };
        assert_eq!(
            check_format(&pad, &want, &got),
            Err(
                "pad \"Scaler\":1: asked for SRGGB8_1X8/640x480, the driver set \
                 RGB888_1X24/640x480: the profile does not match this hardware"
                    .into()
            )
        );
    }

    #[test]
    fn a_profile_without_a_lens_fails_before_touching_anything() {
        let mut p = Profile::load("vimc").expect("vimc");
        p.lens = LensSpec::None {
            reason: "the ov5640 has only its firmware autofocus".into(),
        };
        let e = apply(&p, Path::new("/nonexistent/sys")).expect_err("no lens");
        let msg = e.to_string();
        assert!(
            msg.contains("ov5640 has only its firmware autofocus")
                && msg.contains("a focus sweep is not possible"),
            "{msg}"
        );
    }

    #[test]
    fn no_media_device_lists_what_was_found() {
        let dir = tempfile::tempdir().expect("tempdir");
        let vimc = Profile::load("vimc").expect("vimc");
        let e = open_media(&vimc, &dir.path().join("sys")).expect_err("none");
        assert!(
            e.contains("no media device has the model \"VIMC MDEV\" and the sensor \"Sensor A\"")
                && e.ends_with("none"),
            "{e}"
        );
    }
}
