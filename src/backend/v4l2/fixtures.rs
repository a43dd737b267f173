//! The phones' camera drivers as fixtures: media graphs and sub-devices that answer the
//! negotiation's calls ([`MediaOps`]) the way each phone's kernel drivers do, so the profile
//! choices and the failure messages are checked here without the phones. Every value cites the
//! driver or device tree it comes from.

use super::media_ops::MediaOps;
use super::pipeline::{apply_with, check_lens, Pipeline};
use super::profile::Profile;
use crate::backend::videodev::abi::{self, MbusFramefmt, Rect};
use crate::backend::videodev::media::{Entity, Info, Interface, Link, Pad, Topology};
use crate::backend::videodev::subdev::SizeRange;
use crate::develop::BayerOrder;
use std::collections::HashMap;
use std::io;
use std::path::{Path, PathBuf};

const SBGGR10: u32 = 0x3007;
const SGRBG10: u32 = 0x300a;
const SRGGB10: u32 = 0x300f;
const SGRBG8: u32 = 0x3002;

/// A sub-device's answers.
trait Driver {
    fn codes(&self, pad: u32) -> Vec<u32>;
    fn sizes(&self, pad: u32, code: u32) -> Vec<SizeRange>;
    fn format(&self, pad: u32) -> MbusFramefmt;
    /// What the driver makes of an S_FMT: the format it keeps.
    fn set_format(&mut self, pad: u32, f: MbusFramefmt) -> MbusFramefmt;
    fn set_crop(&mut self, _pad: u32, _r: Rect) -> io::Result<Rect> {
        Err(io::Error::from_raw_os_error(25)) // ENOTTY: no selection API
    }
    fn control(&self, _id: u32) -> Option<i64> {
        None
    }
}

/// The nearest of `modes` to the asked size, as v4l2_find_nearest_size picks (smallest sum of
/// the absolute differences).
fn nearest(modes: &[(u32, u32)], w: u32, h: u32) -> (u32, u32) {
    *modes
        .iter()
        .min_by_key(|(mw, mh)| mw.abs_diff(w) + mh.abs_diff(h))
        .expect("modes")
}

fn fmt(code: u32, (width, height): (u32, u32)) -> MbusFramefmt {
    MbusFramefmt {
        code,
        width,
        height,
        field: abi::FIELD_NONE,
        ..MbusFramefmt::default()
    }
}

/// A raw sensor with fixed modes and one code, which may follow its flips.
struct Sensor {
    /// The code for (vflip, hflip) = (0,0), (0,1), (1,0), (1,1); all four equal when the
    /// driver has no flips.
    codes: [u32; 4],
    flips: Option<(i64, i64)>,
    modes: Vec<(u32, u32)>,
    current: (u32, u32),
    /// V4L2_CID_CAMERA_SENSOR_ROTATION, made from the device tree's `rotation`.
    rotation: Option<i64>,
}

impl Sensor {
    fn code(&self) -> u32 {
        let (h, v) = self.flips.unwrap_or((0, 0));
        self.codes[((v != 0) as usize) << 1 | (h != 0) as usize]
    }
}

impl Driver for Sensor {
    fn codes(&self, _pad: u32) -> Vec<u32> {
        vec![self.code()]
    }
    fn sizes(&self, _pad: u32, code: u32) -> Vec<SizeRange> {
        if code == self.code() {
            self.modes.iter().map(|&m| (m, m)).collect()
        } else {
            Vec::new()
        }
    }
    fn format(&self, _pad: u32) -> MbusFramefmt {
        fmt(self.code(), self.current)
    }
    fn set_format(&mut self, _pad: u32, f: MbusFramefmt) -> MbusFramefmt {
        self.current = nearest(&self.modes, f.width, f.height);
        self.format(0)
    }
    fn control(&self, id: u32) -> Option<i64> {
        match id {
            abi::CID_HFLIP => self.flips.map(|f| f.0),
            abi::CID_VFLIP => self.flips.map(|f| f.1),
            abi::CID_CAMERA_SENSOR_ROTATION => self.rotation,
            _ => None,
        }
    }
}

/// The imx258 after 6.11: torvalds/linux drivers/media/i2c/imx258.c at 00c6649bafef, `codes[]`
/// (SRGGB10, SGRBG10, SGBRG10, SBGGR10 for no flip, hflip, vflip, both), imx258_get_format_code
/// (index vflip << 1 | hflip), HFLIP and VFLIP made with default 1 in imx258_init_controls,
/// supported_modes 4208x3120, 2104x1560, 1048x780, picked by v4l2_find_nearest_size in
/// imx258_set_pad_format; the rotation control from v4l2_ctrl_new_fwnode_properties and the
/// PinePhone Pro device tree's `rotation = <270>`.
fn imx258_after_6_11() -> Sensor {
    Sensor {
        codes: [SRGGB10, SGRBG10, 0x300e, SBGGR10],
        flips: Some((1, 1)),
        modes: vec![(4208, 3120), (2104, 1560), (1048, 780)],
        current: (4208, 3120),
        rotation: Some(270),
    }
}

/// The imx258 before 6.11 (and megi's tree): imx258_enum_mbus_code returned SGRBG10_1X10 only
/// (the hunk at imx258.c line 819 that commit 4c05213aeed7's series changed), no flip controls.
fn imx258_before_6_11() -> Sensor {
    Sensor {
        codes: [SGRBG10; 4],
        flips: None,
        ..imx258_after_6_11()
    }
}

/// Purism's s5k3l6xx: SGRBG8_1X8 only, at 1052x780, 2104x1560 and 4208x3120 (the hardware
/// notes' reading of its mode table); the mainline RFC `s5k3l6` driver is modelled the same.
fn s5k3l6xx() -> Sensor {
    Sensor {
        codes: [SGRBG8; 4],
        flips: None,
        modes: vec![(1052, 780), (2104, 1560), (4208, 3120)],
        current: (1052, 780),
        rotation: None,
    }
}

/// A bridge or ISP pad set: each pad keeps what it is given, bounded by `max` (and on sink
/// pad 0 by `crop_max` for the crop), widths aligned down at 8 bits to `align8`.
struct Bridge {
    pads: HashMap<u32, MbusFramefmt>,
    crops: HashMap<u32, Rect>,
    max: (u32, u32),
    crop_max: Option<(u32, u32)>,
    /// Width alignment at 8 bits (the imx7 CSI bridge's), 1 for none.
    align8: u32,
}

impl Bridge {
    fn new(max: (u32, u32)) -> Bridge {
        Bridge {
            pads: HashMap::new(),
            crops: HashMap::new(),
            max,
            crop_max: None,
            align8: 1,
        }
    }
}

impl Driver for Bridge {
    fn codes(&self, _pad: u32) -> Vec<u32> {
        Vec::new()
    }
    fn sizes(&self, _pad: u32, _code: u32) -> Vec<SizeRange> {
        vec![((32, 32), self.max)]
    }
    fn format(&self, pad: u32) -> MbusFramefmt {
        self.pads.get(&pad).copied().unwrap_or_default()
    }
    fn set_format(&mut self, pad: u32, f: MbusFramefmt) -> MbusFramefmt {
        let eight = crate::backend::v4l2::sensor::bayer_of(f.code).is_some_and(|(_, b)| b == 8);
        let align = if eight { self.align8 } else { 1 };
        // v4l_bound_align_image: clamp, then the nearest multiple of the alignment.
        let w = f.width.min(self.max.0);
        let w = (w + align / 2) / align * align;
        let got = MbusFramefmt {
            width: w,
            height: f.height.min(self.max.1),
            ..f
        };
        self.pads.insert(pad, got);
        got
    }
    fn set_crop(&mut self, pad: u32, r: Rect) -> io::Result<Rect> {
        let f = self.format(pad);
        let (mw, mh) = self.crop_max.unwrap_or((f.width, f.height));
        let width = r.width.min(mw).min(f.width) & !1;
        let height = r.height.min(mh).min(f.height);
        let got = Rect {
            left: (r.left & !1).min((f.width - width) as i32),
            top: r.top.min((f.height - height) as i32),
            width,
            height,
        };
        self.crops.insert(pad, got);
        Ok(got)
    }
}

/// A media graph and its sub-devices, answering as the kernel does.
struct Fake {
    model: String,
    topo: Topology,
    nodes: HashMap<(u32, u32), PathBuf>,
    drivers: HashMap<PathBuf, Box<dyn Driver>>,
}

impl Fake {
    fn new(model: &str) -> Fake {
        Fake {
            model: model.into(),
            topo: Topology::default(),
            nodes: HashMap::new(),
            drivers: HashMap::new(),
        }
    }

    fn next_id(&self) -> u32 {
        (self.topo.entities.len()
            + self.topo.pads.len()
            + self.topo.links.len()
            + self.topo.interfaces.len()) as u32
            + 1
    }

    /// An entity with `pads` (true: source), a device node, and its driver.
    fn entity(
        &mut self,
        name: &str,
        function: u32,
        pads: &[bool],
        driver: Option<Box<dyn Driver>>,
    ) -> &mut Fake {
        let id = self.next_id();
        self.topo.entities.push(Entity {
            id,
            name: name.into(),
            function,
        });
        for (index, &source) in pads.iter().enumerate() {
            let pid = self.next_id();
            self.topo.pads.push(Pad {
                id: pid,
                entity: id,
                index: index as u32,
                flags: if source {
                    abi::MEDIA_PAD_FL_SOURCE
                } else {
                    abi::MEDIA_PAD_FL_SINK
                },
            });
        }
        let iid = self.next_id();
        let minor = self.topo.interfaces.len() as u32;
        self.topo.interfaces.push(Interface {
            id: iid,
            kind: abi::MEDIA_INTF_T_V4L_SUBDEV,
            major: 81,
            minor,
        });
        let lid = self.next_id();
        self.topo.links.push(Link {
            id: lid,
            source: iid,
            sink: id,
            flags: abi::MEDIA_LNK_FL_INTERFACE_LINK,
        });
        let path = PathBuf::from(format!("/dev/node{minor}"));
        self.nodes.insert((81, minor), path.clone());
        if let Some(d) = driver {
            self.drivers.insert(path, d);
        }
        self
    }

    fn id(&self, name: &str) -> u32 {
        self.topo
            .entities
            .iter()
            .find(|e| e.name == name)
            .expect("entity")
            .id
    }

    fn pad(&self, name: &str, index: u32) -> u32 {
        let e = self.id(name);
        self.topo
            .pads
            .iter()
            .find(|p| p.entity == e && p.index == index)
            .expect("pad")
            .id
    }

    fn link(&mut self, a: &str, ai: u32, b: &str, bi: u32) -> &mut Fake {
        let (source, sink, id) = (self.pad(a, ai), self.pad(b, bi), self.next_id());
        self.topo.links.push(Link {
            id,
            source,
            sink,
            flags: abi::MEDIA_LNK_FL_ENABLED,
        });
        self
    }

    /// The ancillary link a `lens-focus` property makes from the sensor to its lens.
    fn lens_focus(&mut self, sensor: &str, lens: &str) -> &mut Fake {
        let (source, sink, id) = (self.id(sensor), self.id(lens), self.next_id());
        self.topo.links.push(Link {
            id,
            source,
            sink,
            flags: abi::MEDIA_LNK_FL_ANCILLARY_LINK
                | abi::MEDIA_LNK_FL_ENABLED
                | abi::MEDIA_LNK_FL_IMMUTABLE,
        });
        self
    }

    fn driver(&mut self, node: &Path) -> io::Result<&mut Box<dyn Driver>> {
        self.drivers
            .get_mut(node)
            .ok_or_else(|| io::Error::from_raw_os_error(25))
    }

    /// The active format of an entity's pad.
    fn format_of(&mut self, name: &str, pad: u32) -> MbusFramefmt {
        let node = self.node_of(name);
        self.driver(&node).expect("driver").format(pad)
    }

    fn node_of(&self, name: &str) -> PathBuf {
        let id = self.id(name);
        let intf = self
            .topo
            .links
            .iter()
            .find(|l| l.sink == id && l.flags == abi::MEDIA_LNK_FL_INTERFACE_LINK)
            .expect("interface")
            .source;
        let i = self
            .topo
            .interfaces
            .iter()
            .find(|i| i.id == intf)
            .expect("i");
        self.nodes[&(i.major, i.minor)].clone()
    }
}

impl MediaOps for Fake {
    fn media_nodes(&mut self) -> Vec<PathBuf> {
        vec![PathBuf::from("/dev/media0")]
    }
    fn info(&mut self, _media: &Path) -> io::Result<Info> {
        Ok(Info {
            driver: String::new(),
            model: self.model.clone(),
            bus_info: String::new(),
        })
    }
    fn topology(&mut self, _media: &Path) -> io::Result<Topology> {
        Ok(self.topo.clone())
    }
    fn setup_link(&mut self, _: &Path, _: (u32, u16), _: (u32, u16), _: bool) -> io::Result<()> {
        Ok(())
    }
    fn devnode(&mut self, major: u32, minor: u32) -> Result<PathBuf, String> {
        self.nodes
            .get(&(major, minor))
            .cloned()
            .ok_or_else(|| format!("no node {major}:{minor}"))
    }
    fn codes(&mut self, node: &Path, pad: u32) -> io::Result<Vec<u32>> {
        Ok(self.driver(node)?.codes(pad))
    }
    fn sizes(&mut self, node: &Path, pad: u32, code: u32) -> io::Result<Vec<SizeRange>> {
        Ok(self.driver(node)?.sizes(pad, code))
    }
    fn format(&mut self, node: &Path, pad: u32) -> io::Result<MbusFramefmt> {
        Ok(self.driver(node)?.format(pad))
    }
    fn set_format(&mut self, node: &Path, pad: u32, f: MbusFramefmt) -> io::Result<MbusFramefmt> {
        Ok(self.driver(node)?.set_format(pad, f))
    }
    fn set_crop(&mut self, node: &Path, pad: u32, r: Rect) -> io::Result<Rect> {
        self.driver(node)?.set_crop(pad, r)
    }
    fn control(&mut self, node: &Path, id: u32) -> io::Result<Option<i64>> {
        Ok(self.driver(node)?.control(id))
    }
}

/// The PinePhone Pro's rear pipeline (rkisp1 entity names from rkisp1-common.h and the
/// profile), with `isp` as the ISP sub-device.
fn pinephone_pro(sensor: Sensor, isp: Bridge, lens: bool) -> Fake {
    let mut f = Fake::new("rkisp1");
    let sensor_fn = abi::MEDIA_ENT_F_CAM_SENSOR;
    f.entity("imx258 1-001a", sensor_fn, &[true], Some(Box::new(sensor)))
        .entity(
            "rkisp1_csi",
            0x4004,
            &[false, true],
            Some(Box::new(Bridge::new((65535, 65535)))),
        )
        .entity(
            "rkisp1_isp",
            0x4003,
            &[false, false, true, true],
            Some(Box::new(isp)),
        )
        .entity(
            "rkisp1_resizer_mainpath",
            0x4005,
            &[false, true],
            Some(Box::new(Bridge::new((4416, 3312)))),
        )
        .entity("rkisp1_mainpath", 0x10001, &[false], None)
        .link("imx258 1-001a", 0, "rkisp1_csi", 0)
        .link("rkisp1_csi", 1, "rkisp1_isp", 0)
        .link("rkisp1_isp", 2, "rkisp1_resizer_mainpath", 0)
        .link("rkisp1_resizer_mainpath", 1, "rkisp1_mainpath", 0);
    if lens {
        f.entity("dw9714 1-000c", abi::MEDIA_ENT_F_LENS, &[], None)
            .lens_focus("imx258 1-001a", "dw9714 1-000c");
    }
    f
}

/// rkisp1's ISP as in torvalds/linux rkisp1-common.h at 0753874617de: RKISP1_ISP_MAX_WIDTH
/// x HEIGHT 4032x3024 bounds the sink format.
fn rkisp1_isp_4032() -> Bridge {
    Bridge::new((4032, 3024))
}

/// rkisp1's ISP with the "Increase ISP input resolution limit" patch: the sink format up to
/// 4416x3312 (RKISP1_ISP_MAX_WIDTH/HEIGHT there), its crop clamped to 4032x3024
/// (RKISP1_ISP_MAX_WIDTH_CROP/HEIGHT_CROP in rkisp1_isp_set_sink_crop).
fn rkisp1_isp_cropping() -> Bridge {
    Bridge {
        crop_max: Some((4032, 3024)),
        ..Bridge::new((4416, 3312))
    }
}

/// The Librem 5's rear pipeline: sensor -> imx8mq-mipi-csi2 -> csi (imx7-media-csi) -> "csi
/// capture"; the bridge aligns widths to 8 at 8 bits; the dw9714 at i2c4 0x0c has a node only
/// when a `lens-focus` links it (imx8mq-librem5.dtsi has none).
fn librem5(sensor_name: &str, bridge_max: (u32, u32), lens: bool) -> Fake {
    let mut f = Fake::new("imx-media");
    f.entity(
        sensor_name,
        abi::MEDIA_ENT_F_CAM_SENSOR,
        &[true],
        Some(Box::new(s5k3l6xx())),
    )
    .entity(
        "imx8mq-mipi-csi2 30a70000.csi",
        0x4004,
        &[false, true],
        Some(Box::new(Bridge::new((16384, 16384)))),
    )
    .entity(
        "csi",
        0x4004,
        &[false, true],
        Some(Box::new(Bridge {
            align8: 8,
            ..Bridge::new(bridge_max)
        })),
    )
    .entity("csi capture", 0x10001, &[false], None)
    .link(sensor_name, 0, "imx8mq-mipi-csi2 30a70000.csi", 0)
    .link("imx8mq-mipi-csi2 30a70000.csi", 1, "csi", 0)
    .link("csi", 1, "csi capture", 0);
    if lens {
        f.entity("dw9714 3-000c", abi::MEDIA_ENT_F_LENS, &[], None)
            .lens_focus(sensor_name, "dw9714 3-000c");
    }
    f
}

fn negotiate(f: &mut Fake, profile: &str) -> Result<Pipeline, String> {
    let p = Profile::load(profile).expect("profile");
    apply_with(f, &p).map_err(|e| e.to_string())
}

#[test]
fn pinephone_pro_after_6_11_follows_the_flipped_order() {
    let mut f = pinephone_pro(imx258_after_6_11(), rkisp1_isp_cropping(), true);
    let p = negotiate(&mut f, "pinephone-pro").expect("negotiates");
    assert_eq!(p.order, BayerOrder::Bggr);
    assert_eq!(p.format.fourcc(), *b"BA81");
    // The full mode, cropped centred to the ISP's processing limit.
    assert_eq!((p.width, p.height), (4032, 3024));
    assert_eq!(f.format_of("imx258 1-001a", 0).code, SBGGR10);
    assert_eq!(
        (
            f.format_of("rkisp1_isp", 0).code,
            f.format_of("rkisp1_isp", 2).code
        ),
        (SBGGR10, 0x3001)
    );
    assert!(
        p.notes.iter().any(
            |n| n == "pad \"rkisp1_isp\":0 crops 4208x3120 to 4032x3024 at (88, 48), its limit"
        ),
        "{:?}",
        p.notes
    );
    assert_eq!(
        p.notes[0],
        "sensor \"imx258 1-001a\" reports SBGGR10_1X10 (hflip 1, vflip 1)"
    );
    assert_eq!(p.lens, Some(PathBuf::from("/dev/node5")));
    assert_eq!(p.rotation, Some(270));
    let profile = Profile::load("pinephone-pro").expect("pro");
    assert_eq!(
        (profile.black_level_at(8), profile.black_level_at(10)),
        (16, 64)
    );
}

#[test]
fn pinephone_pro_where_the_isp_sink_is_limited_takes_the_next_mode() {
    let mut f = pinephone_pro(imx258_after_6_11(), rkisp1_isp_4032(), true);
    let p = negotiate(&mut f, "pinephone-pro").expect("negotiates");
    assert_eq!((p.width, p.height), (2104, 1560));
    assert_eq!(f.format_of("imx258 1-001a", 0).width, 2104);
    let refused = p.notes.last().expect("notes");
    assert_eq!(
        refused,
        "modes the pipeline refused: 4208x3120: pad \"rkisp1_isp\":0: asked for \
         SBGGR10_1X10/4208x3120, the driver set SBGGR10_1X10/4032x3024: the profile does not \
         match this hardware"
    );
}

#[test]
fn pinephone_pro_before_6_11_reports_grbg() {
    let mut f = pinephone_pro(imx258_before_6_11(), rkisp1_isp_cropping(), true);
    let p = negotiate(&mut f, "pinephone-pro").expect("negotiates");
    assert_eq!(p.order, BayerOrder::Grbg);
    assert_eq!(p.format.fourcc(), *b"GRBG");
    assert_eq!(p.notes[0], "sensor \"imx258 1-001a\" reports SGRBG10_1X10");
    // No shipped profile names a colour order any more: the old RGGB is refused.
    let old = crate::backend::v4l2::profile::SHIPPED[2]
        .1
        .replace("code = \"BAYER10\"\ncrop", "code = \"SRGGB10_1X10\"\ncrop");
    let e = Profile::parse(&old, "old").expect_err("order named");
    assert!(
        e.contains("\"SRGGB10_1X10\" names a colour order; write BAYER10"),
        "{e}"
    );
}

#[test]
fn a_pad_that_changes_the_code_names_the_pad_and_both_formats() {
    // An ISP that forces RGGB on its sink would make wrong colours: it is an error.
    struct Forcing(Bridge);
    impl Driver for Forcing {
        fn codes(&self, pad: u32) -> Vec<u32> {
            self.0.codes(pad)
        }
        fn sizes(&self, pad: u32, code: u32) -> Vec<SizeRange> {
            self.0.sizes(pad, code)
        }
        fn format(&self, pad: u32) -> MbusFramefmt {
            self.0.format(pad)
        }
        fn set_format(&mut self, pad: u32, f: MbusFramefmt) -> MbusFramefmt {
            self.0.set_format(pad, MbusFramefmt { code: SRGGB10, ..f })
        }
    }
    let mut f = pinephone_pro(imx258_after_6_11(), rkisp1_isp_cropping(), true);
    let csi = f.node_of("rkisp1_csi");
    f.drivers
        .insert(csi, Box::new(Forcing(Bridge::new((65535, 65535)))));
    let e = negotiate(&mut f, "pinephone-pro").expect_err("forced order");
    assert_eq!(
        e,
        "device profile pinephone-pro: pad \"rkisp1_csi\":0: asked for SBGGR10_1X10/4208x3120, \
         the driver set SRGGB10_1X10/4208x3120: the profile does not match this hardware"
    );
}

#[test]
fn librem5_takes_the_full_mode_where_the_bridge_takes_it() {
    for name in ["s5k3l6xx 3-002d", "s5k3l6 3-002d"] {
        let mut f = librem5(name, (8192, 8192), true);
        let p = negotiate(&mut f, "librem5").expect("negotiates");
        assert_eq!((p.width, p.height, p.order), (4208, 3120, BayerOrder::Grbg));
        assert_eq!(p.format.fourcc(), *b"GRBG");
        assert_eq!(p.sensor, name);
        assert!(p.lens.is_some());
    }
}

#[test]
fn librem5_falls_back_to_2104_where_the_bridge_is_narrower() {
    let mut f = librem5("s5k3l6xx 3-002d", (4096, 4096), true);
    let p = negotiate(&mut f, "librem5").expect("negotiates");
    assert_eq!((p.width, p.height), (2104, 1560));
    // 1052 is not a multiple of 8: the bridge makes it 1056, so that mode is never used.
    let mut bridge = Bridge {
        align8: 8,
        ..Bridge::new((8192, 8192))
    };
    assert_eq!(bridge.set_format(0, fmt(SGRBG8, (1052, 780))).width, 1056);
}

#[test]
fn librem5_on_mainline_has_no_lens_and_says_how_to_link_it() {
    let mut f = librem5("s5k3l6 3-002d", (8192, 8192), false);
    let p = negotiate(&mut f, "librem5").expect("negotiates");
    assert_eq!(p.lens, None);
    let e = check_lens(&p, None, &[]).expect_err("no lens");
    assert!(
        e.starts_with("the media graph links no lens to the sensor \"s5k3l6 3-002d\"")
            && e.contains("no `lens-focus` property")
            && e.contains("add `lens-focus = <&lens>;` to the sensor's node")
            && e.contains("dongwoon,dw9714 at i2c4 0x0c in imx8mq-librem5.dtsi")
            && e.contains("set [camera] lens"),
        "{e}"
    );
    // A configured lens, or a sub-device named after a lens driver, is used instead.
    assert_eq!(check_lens(&p, Some("/dev/v4l-subdev7"), &[]), Ok(()));
    assert_eq!(
        check_lens(&p, None, &[PathBuf::from("/dev/v4l-subdev7")]),
        Ok(())
    );
    // Linked (Purism's device tree), there is nothing to say.
    let mut f = librem5("s5k3l6xx 3-002d", (8192, 8192), true);
    let linked = negotiate(&mut f, "librem5").expect("negotiates");
    assert_eq!(check_lens(&linked, None, &[]), Ok(()));
}

#[test]
fn a_sensor_with_every_order_keeps_the_one_it_was_set_to() {
    // vimc's sensor lists every code (vimc-sensor.c's vimc_sensor_enum_mbus_code over
    // vimc_pix_map_list); set to GBRG at run time, GBRG reaches the debayer.
    struct Vimc(MbusFramefmt);
    impl Driver for Vimc {
        fn codes(&self, _: u32) -> Vec<u32> {
            vec![0x100a, 0x3001, 0x3013, 0x3002, 0x3014]
        }
        fn sizes(&self, _: u32, _: u32) -> Vec<SizeRange> {
            // VIMC_FRAME_MIN/MAX_WIDTH/HEIGHT in vimc-common.h.
            vec![((16, 16), (4096, 2160))]
        }
        fn format(&self, _: u32) -> MbusFramefmt {
            self.0
        }
        fn set_format(&mut self, _: u32, f: MbusFramefmt) -> MbusFramefmt {
            self.0 = f;
            f
        }
    }
    let mut f = Fake::new("VIMC MDEV");
    f.entity(
        "Sensor A",
        abi::MEDIA_ENT_F_CAM_SENSOR,
        &[true],
        Some(Box::new(Vimc(fmt(0x3013, (640, 480))))),
    )
    .entity(
        "Debayer A",
        0x4003,
        &[false, true],
        Some(Box::new(Bridge::new((4096, 2160)))),
    )
    .entity(
        "Scaler",
        0x4005,
        &[false, true],
        Some(Box::new(Bridge::new((4096, 2160)))),
    )
    .entity("RGB/YUV Capture", 0x10001, &[false], None)
    .link("Sensor A", 0, "Debayer A", 0)
    .link("Debayer A", 1, "Scaler", 0)
    .link("Scaler", 1, "RGB/YUV Capture", 0)
    .entity("Lens A", abi::MEDIA_ENT_F_LENS, &[], None)
    .lens_focus("Sensor A", "Lens A");
    let p = Profile::load("vimc").expect("vimc");
    let got = apply_with(&mut f, &p).expect("negotiates");
    assert_eq!(got.order, BayerOrder::Gbrg);
    assert_eq!(f.format_of("Debayer A", 0).code, 0x3013);
    assert_eq!(got.format.fourcc(), *b"RGB3");
}
