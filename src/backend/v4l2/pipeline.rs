//! Applying a device profile to the media controller before streaming: the media device by
//! model, the profile's links enabled, each pad's format (and crop) set and read back, the
//! capture node and the lens found through the graph. Every mismatch with the hardware is an
//! error naming the link or pad.

use super::format::PixelFormat;
use super::media_ops::{Kernel, MediaOps};
use super::profile::{
    mbus_code, mbus_name, CropName, CropSpec, LensSpec, LinkSpec, PadRef, PadSpec, Profile,
};
use super::sensor;
use crate::backend::videodev::abi::{self, MbusFramefmt, Rect};
use crate::backend::videodev::media::{self, Topology};
use crate::capture::CaptureError;
use crate::develop::BayerOrder;
use std::path::{Path, PathBuf};

/// The nodes the profile's pipeline streams through, once set up, and what was chosen.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pipeline {
    pub media: PathBuf,
    /// The capture video node.
    pub capture: PathBuf,
    /// The lens sub-device from the graph; `None`: the graph has no lens linked to the sensor.
    pub lens: Option<PathBuf>,
    /// The sensor's entity name in the graph.
    pub sensor: String,
    /// The colour order the sensor reports (after its flips).
    pub order: BayerOrder,
    /// The capture node's format and size.
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    /// `V4L2_CID_CAMERA_SENSOR_ROTATION` on the sensor, where it has it.
    pub rotation: Option<i64>,
    /// What was chosen and why, a line each, for the log.
    pub notes: Vec<String>,
}

/// Sets the pipeline up as `profile` says. `sysfs_root` as in `[camera]` (device nodes beside
/// it). A profile whose lens is `none` fails here, before anything is touched, with its reason.
pub fn apply(profile: &Profile, sysfs_root: &Path) -> Result<Pipeline, CaptureError> {
    apply_with(&mut Kernel::new(sysfs_root), profile)
}

/// [`apply`] through `ops`: the sensor's Bayer code at the profile's depth and the first of
/// the profile's modes that every pad passes (a pad's size limit moves on to the next mode, a
/// crop limit crops), then the capture node and the lens.
pub fn apply_with(ops: &mut dyn MediaOps, profile: &Profile) -> Result<Pipeline, CaptureError> {
    let label = format!("device profile {}", profile.name);
    let fail = |e: String| CaptureError::device(&label, e);
    if let LensSpec::None { reason } = &profile.lens {
        return Err(fail(format!(
            "this camera has no lens focusd can move: {reason}; a focus sweep is not possible \
             here (`focusd fuse` still fuses stacks taken elsewhere)"
        )));
    }
    let (media_path, topo) = open_media(ops, profile).map_err(fail)?;
    for link in &profile.links {
        let (source, sink, flags) = data_link(&topo, link).map_err(fail)?;
        if flags & abi::MEDIA_LNK_FL_IMMUTABLE == 0 {
            for (other, other_sink) in rivals(&topo, source, sink) {
                ops.setup_link(&media_path, other, other_sink, false)
                    .map_err(|e| {
                        fail(format!(
                            "link {link}: cannot disable the link from {} into the same pad: {e}",
                            describe_pad(&topo, other)
                        ))
                    })?;
            }
            ops.setup_link(&media_path, source, sink, true)
                .map_err(|e| fail(format!("link {link}: cannot enable it: {e}")))?;
        }
    }
    let (sensor_id, sensor_name) = sensor_entity(&topo, profile).map_err(fail)?;
    let sensor_node =
        devnode(ops, &topo, sensor_id).map_err(|e| fail(format!("sensor {sensor_name:?}: {e}")))?;
    let at_sensor = |e: String| fail(format!("sensor {sensor_name:?}: {e}"));
    let offered = ops
        .codes(&sensor_node, 0)
        .map_err(|e| at_sensor(format!("cannot list its media-bus codes: {e}")))?;
    let current = ops.format(&sensor_node, 0).ok().map(|f| f.code);
    let code = sensor::choose_code(&offered, current, profile.mode.bits).map_err(at_sensor)?;
    let order = sensor::bayer_of(code).map_or(BayerOrder::Rggb, |(o, _)| o);
    let mut notes = vec![format!(
        "sensor {sensor_name:?} reports {}{}",
        mbus_name(code),
        flips(ops, &sensor_node)
    )];
    let rotation = ops
        .control(&sensor_node, abi::CID_CAMERA_SENSOR_ROTATION)
        .ok()
        .flatten();
    if let Some(r) = rotation {
        notes.push(format!("sensor rotation {r}"));
    }
    let sizes = ops
        .sizes(&sensor_node, 0, code)
        .map_err(|e| at_sensor(format!("cannot list its frame sizes: {e}")))?;
    let modes = sensor::offered_modes(&profile.mode.sizes, &sizes).map_err(at_sensor)?;
    let sensor_pad = PadRef(sensor_name.clone(), 0);
    let mut refused = Vec::new();
    let mut chosen = None;
    for mode in modes {
        match try_mode(ops, &topo, profile, (&sensor_pad, &sensor_node), code, mode) {
            Ok((size, mut said)) => {
                notes.push(format!("mode {}x{}", mode[0], mode[1]));
                notes.append(&mut said);
                chosen = Some(size);
                break;
            }
            Err(Refused::Mode(why)) => refused.push(format!("{}x{}: {why}", mode[0], mode[1])),
            Err(Refused::Pipeline(e)) => return Err(fail(e)),
        }
    }
    if !refused.is_empty() {
        notes.push(format!(
            "modes the pipeline refused: {}",
            refused.join("; ")
        ));
    }
    let Some([width, height]) = chosen else {
        return Err(fail(format!(
            "no sensor mode passes the pipeline: {}",
            refused.join("; ")
        )));
    };
    let format = match profile.capture_bits().map_err(fail)? {
        Some(bits) => sensor::capture_format(order, bits),
        None => PixelFormat::parse(&profile.format.fourcc)
            .map_err(|e| fail(format!("format.fourcc: {e}")))?,
    };
    let capture_id = entity_id(&topo, &profile.capture)
        .map_err(|e| fail(format!("capture {:?}: {e}", profile.capture)))?;
    let capture = devnode(ops, &topo, capture_id)
        .map_err(|e| fail(format!("capture {:?}: {e}", profile.capture)))?;
    let lens = match lens_of(&topo, sensor_id) {
        Some(id) => Some(devnode(ops, &topo, id).map_err(|e| fail(format!("lens: {e}")))?),
        None => None,
    };
    Ok(Pipeline {
        media: media_path,
        capture,
        lens,
        sensor: sensor_name,
        order,
        format,
        width,
        height,
        rotation,
        notes,
    })
}

/// Where the graph ties no lens to the sensor, none is configured and no sub-device is named
/// after a lens driver, the capture cannot move a lens: the error, said before any sweep,
/// names the missing `lens-focus` link, the device-tree fix and `[camera] lens`.
pub fn check_lens(p: &Pipeline, configured: Option<&str>, named: &[PathBuf]) -> Result<(), String> {
    if p.lens.is_some() || configured.is_some() || !named.is_empty() {
        return Ok(());
    }
    Err(format!(
        "the media graph links no lens to the sensor {:?}: the device tree gives the sensor no \
         `lens-focus` property, so the kernel makes no ancillary link and no lens sub-device. \
         Fix the device tree: add `lens-focus = <&lens>;` to the sensor's node, pointing to its \
         lens actuator (on the Librem 5, the dongwoon,dw9714 at i2c4 0x0c in \
         imx8mq-librem5.dtsi). On a kernel that has the lens sub-device but not the link, set \
         [camera] lens to its node (/dev/v4l-subdevN) or name",
        p.sensor
    ))
}

/// Why a mode was not taken: the pipeline cannot pass its size (try the next), or the
/// hardware does not match the profile at all.
enum Refused {
    Mode(String),
    Pipeline(String),
}

/// Sets the sensor to `mode` and every profile pad after it; the size that reaches the
/// capture node, and what was cropped.
fn try_mode(
    ops: &mut dyn MediaOps,
    topo: &Topology,
    profile: &Profile,
    (sensor_pad, sensor_node): (&PadRef, &Path),
    code: u32,
    mode: [u32; 2],
) -> Result<([u32; 2], Vec<String>), Refused> {
    let order = sensor::bayer_of(code).map_or(BayerOrder::Rggb, |(o, _)| o);
    let want = framefmt(code, mode);
    let got = ops.set_format(sensor_node, 0, want).map_err(|e| {
        Refused::Pipeline(format!(
            "pad {sensor_pad}: cannot set {}: {e}",
            describe(&want)
        ))
    })?;
    check_pad(sensor_pad, &want, &got)?;
    let mut size = mode;
    let mut notes = Vec::new();
    for p in &profile.pads {
        let at = |e: String| Refused::Pipeline(format!("pad {}: {e}", p.pad));
        let entity = entity_id(topo, &p.pad.0).map_err(at)?;
        let node = devnode(ops, topo, entity).map_err(at)?;
        let code = pad_code(p, order).map_err(at)?;
        let want = framefmt(
            code,
            [p.width.unwrap_or(size[0]), p.height.unwrap_or(size[1])],
        );
        let pad = u32::from(p.pad.1);
        let got = ops
            .set_format(&node, pad, want)
            .map_err(|e| at(format!("cannot set {}: {e}", describe(&want))))?;
        check_pad(&p.pad, &want, &got)?;
        size = [want.width, want.height];
        let Some(crop) = &p.crop else { continue };
        let full = Rect {
            left: 0,
            top: 0,
            width: size[0],
            height: size[1],
        };
        let asked = match crop {
            CropSpec::Rect([left, top, width, height]) => Rect {
                left: *left as i32,
                top: *top as i32,
                width: *width,
                height: *height,
            },
            CropSpec::Named(CropName::Limit) => full,
        };
        let got = ops
            .set_crop(&node, pad, asked)
            .map_err(|e| at(format!("cannot crop to {asked:?}: {e}")))?;
        let got = match crop {
            CropSpec::Named(CropName::Limit) if got != asked => {
                // The driver's processing limit: the same size, centred on even offsets.
                let centred = Rect {
                    left: (((size[0] - got.width.min(size[0])) / 2) & !1) as i32,
                    top: (((size[1] - got.height.min(size[1])) / 2) & !1) as i32,
                    ..got
                };
                let again = ops
                    .set_crop(&node, pad, centred)
                    .map_err(|e| at(format!("cannot crop to {centred:?}: {e}")))?;
                notes.push(format!(
                    "pad {} crops {}x{} to {}x{} at ({}, {}), its limit",
                    p.pad, size[0], size[1], again.width, again.height, again.left, again.top
                ));
                (again == centred).then_some(again).ok_or_else(|| {
                    at(format!(
                        "asked to crop to {centred:?}, the driver set {again:?}"
                    ))
                })?
            }
            _ if got != asked => {
                return Err(at(format!(
                    "asked to crop to {asked:?}, the driver set {got:?}"
                )))
            }
            _ => got,
        };
        size = [got.width, got.height];
    }
    Ok((size, notes))
}

/// A pad's code: the sensor's order at the token's depth, or the named code.
fn pad_code(p: &PadSpec, order: BayerOrder) -> Result<u32, String> {
    match sensor::depth_token(&p.code) {
        Some(bits) => sensor::bayer_code(order, bits)
            .ok_or_else(|| format!("no {bits}-bit code for {order:?}")),
        None => mbus_code(&p.code).ok_or_else(|| format!("unknown code {:?}", p.code)),
    }
}

fn framefmt(code: u32, [width, height]: [u32; 2]) -> MbusFramefmt {
    MbusFramefmt {
        width,
        height,
        code,
        field: abi::FIELD_NONE,
        ..MbusFramefmt::default()
    }
}

/// A pad whose format came back with another code does not match the profile; one that came
/// back smaller cannot pass this mode.
fn check_pad(pad: &PadRef, want: &MbusFramefmt, got: &MbusFramefmt) -> Result<(), Refused> {
    match check_format(pad, want, got) {
        Ok(()) => Ok(()),
        Err(e) if got.code == want.code => Err(Refused::Mode(e)),
        Err(e) => Err(Refused::Pipeline(e)),
    }
}

/// The sensor's flips, where it has the controls, for the log: the imx258 ties its order to
/// them.
fn flips(ops: &mut dyn MediaOps, node: &Path) -> String {
    let h = ops.control(node, abi::CID_HFLIP).ok().flatten();
    let v = ops.control(node, abi::CID_VFLIP).ok().flatten();
    match (h, v) {
        (None, None) => String::new(),
        (h, v) => {
            let say = |c: Option<i64>| c.map_or("none".to_string(), |v| v.to_string());
            format!(" (hflip {}, vflip {})", say(h), say(v))
        }
    }
}

/// The sensor's entity: the first of the profile's names the graph has, and its name there.
fn sensor_entity(topo: &Topology, profile: &Profile) -> Result<(u32, String), String> {
    let mut errors = Vec::new();
    for name in profile.sensor.all() {
        match entity_id(topo, name) {
            Ok(id) => {
                let full = topo
                    .entities
                    .iter()
                    .find(|e| e.id == id)
                    .map_or_else(|| name.clone(), |e| e.name.clone());
                return Ok((id, full));
            }
            Err(e) => errors.push(e),
        }
    }
    Err(format!("sensor {}: {}", profile.sensor, errors.join("; ")))
}

/// The media device whose model is the profile's and whose graph holds its sensor (a phone may
/// have one media device per ISP or bridge, all with the same model), with its graph.
fn open_media(ops: &mut dyn MediaOps, profile: &Profile) -> Result<(PathBuf, Topology), String> {
    let model = &profile.media_model;
    let mut found = Vec::new();
    for path in ops.media_nodes() {
        match ops.info(&path) {
            Ok(info) if info.model == *model => match ops.topology(&path) {
                Ok(topo) => match sensor_entity(&topo, profile) {
                    Ok(_) => return Ok((path, topo)),
                    Err(e) => found.push(format!("{} ({model:?}, but {e})", path.display())),
                },
                Err(e) => found.push(format!(
                    "{} ({model:?}, cannot read its graph: {e})",
                    path.display()
                )),
            },
            Ok(info) => found.push(format!("{} ({:?})", path.display(), info.model)),
            Err(e) => found.push(format!("{}: {e}", path.display())),
        }
    }
    Err(format!(
        "no media device has the model {model:?} and the sensor {} (is the camera driver \
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

/// The device node of an entity, through its interface link.
fn devnode(ops: &mut dyn MediaOps, topo: &Topology, entity: u32) -> Result<PathBuf, String> {
    let intf = topo
        .links
        .iter()
        .filter(|l| l.flags & abi::MEDIA_LNK_FL_LINK_TYPE == abi::MEDIA_LNK_FL_INTERFACE_LINK)
        .filter(|l| l.sink == entity)
        .find_map(|l| topo.interfaces.iter().find(|i| i.id == l.source))
        .ok_or_else(|| "it has no device node".to_string())?;
    ops.devnode(intf.major, intf.minor)
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
        std::fs::create_dir_all(&char_dir).expect("mkdir");
        std::fs::write(
            char_dir.join("uevent"),
            "MAJOR=81\nMINOR=6\nDEVNAME=v4l-subdev6\n",
        )
        .expect("w");
        let t = graph();
        let mut kernel = Kernel::new(&root);
        assert_eq!(
            devnode(&mut kernel, &t, 28),
            Ok(dir.path().join("dev/v4l-subdev6"))
        );
        assert_eq!(
            devnode(&mut kernel, &t, 1),
            Err("it has no device node".into())
        );
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
        let mut kernel = Kernel::new(&dir.path().join("sys"));
        let e = open_media(&mut kernel, &vimc).expect_err("none");
        assert!(
            e.contains("no media device has the model \"VIMC MDEV\" and the sensor \"Sensor A\"")
                && e.ends_with("none"),
            "{e}"
        );
    }
}
