//! Device profiles (`config/devices/*.toml`): what a phone's media-controller camera pipeline
//! needs before it streams (the links to enable, each pad's format and crop), which entity is
//! the sensor and which the capture node, the capture format, and where the lens is. One small
//! TOML file per device, like Megapixels' per-device configs; the fields are documented in
//! `config/devices/README.md`. Pure: parsing and checking only; `pipeline` applies them.

use crate::backend::videodev::abi::MBUS_CODES;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The profiles shipped inside the binary, by name.
pub const SHIPPED: [(&str, &str); 5] = [
    ("vimc", include_str!("../../../config/devices/vimc.toml")),
    (
        "pinephone",
        include_str!("../../../config/devices/pinephone.toml"),
    ),
    (
        "pinephone-pro",
        include_str!("../../../config/devices/pinephone-pro.toml"),
    ),
    (
        "librem5",
        include_str!("../../../config/devices/librem5.toml"),
    ),
    (
        "oneplus6",
        include_str!("../../../config/devices/oneplus6.toml"),
    ),
];

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    /// A short name for messages.
    pub name: String,
    /// The device-tree compatibles of the phones this profile is for (`pine64,pinephone-pro`):
    /// the first way a profile is chosen when the config names none.
    #[serde(default)]
    pub compatible: Vec<String>,
    /// The media device's model (MEDIA_IOC_DEVICE_INFO), which picks the media device (and a
    /// profile, when no device-tree compatible does).
    pub media_model: String,
    /// The sensor's entity name, or the names of the drivers that may drive it (`["s5k3l6xx",
    /// "s5k3l6"]`); the lens is the lens entity linked to it. Like every entity name here it
    /// may leave out the I²C bus and address the kernel appends (`imx258` for `imx258
    /// 1-001a`), which depend on the board's wiring and probe order.
    pub sensor: Names,
    /// The entity name of the video node to capture from.
    pub capture: String,
    /// The sensor's bit depth and the modes wanted, in order of preference.
    pub mode: ModeSpec,
    /// The capture node's format.
    pub format: CaptureFormat,
    /// The sensor's black level (its pedestal) in samples of `black_level_bits` bits,
    /// subtracted before white balance; 0 for formats an ISP has already processed.
    pub black_level: u32,
    /// The depth `black_level` is given at (the sensor's datasheet value, 64 at 10 bits, is 16
    /// at the 8 bits an ISP passes on); the capture's depth when absent.
    #[serde(default)]
    pub black_level_bits: Option<u32>,
    /// Camera RGB (black level removed, white balanced) to linear sRGB, row by row: each row
    /// sums to 1, so a white-balanced grey stays grey. The identity where none is known.
    pub colour_matrix: [[f32; 3]; 3],
    /// Where the lens is.
    pub lens: LensSpec,
    /// Data links to enable, in order.
    #[serde(default, rename = "link")]
    pub links: Vec<LinkSpec>,
    /// Pad formats to set, in order (upstream first: a driver propagates a sink pad's format to
    /// its source pads, which a later entry may then change).
    #[serde(default, rename = "pad")]
    pub pads: Vec<PadSpec>,
}

/// The sensor's depth and modes: the colour order is whatever the sensor reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeSpec {
    /// Bits a sample on the sensor's pad (8 or 10).
    pub bits: u32,
    /// Sensor modes `[width, height]`, the most wanted first; the first the sensor offers
    /// and the pipeline passes is taken.
    pub sizes: Vec<[u32; 2]>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureFormat {
    /// `BAYER8` or `BAYER10` (the sensor's order at that depth), or the fourcc of a format an
    /// ISP produced (`RGB3`, `NV12`, ...). The size is the negotiated one.
    pub fourcc: String,
}

/// One entity name, or several any of which may be the one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Names {
    One(String),
    Any(Vec<String>),
}

impl Names {
    pub fn all(&self) -> &[String] {
        match self {
            Names::One(n) => std::slice::from_ref(n),
            Names::Any(v) => v,
        }
    }
}

impl std::fmt::Display for Names {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let quoted: Vec<String> = self.all().iter().map(|n| format!("{n:?}")).collect();
        f.write_str(&quoted.join(" or "))
    }
}

/// The lens: through the media graph, or none (with the reason, said when a capture is asked).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "lowercase")]
pub enum LensSpec {
    /// The entity of function MEDIA_ENT_F_LENS with an ancillary link to the sensor; when the
    /// graph has none (older kernels), the sysfs lookup by driver name.
    Graph,
    /// No lens focusd can move.
    None { reason: String },
}

/// A pad: an entity's name and the pad's index.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PadRef(pub String, pub u16);

impl std::fmt::Display for PadRef {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "\"{}\":{}", self.0, self.1)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkSpec {
    pub source: PadRef,
    pub sink: PadRef,
}

impl std::fmt::Display for LinkSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} -> {}", self.source, self.sink)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PadSpec {
    pub pad: PadRef,
    /// `BAYER8` or `BAYER10` (the sensor's order at that depth), or a media-bus code's name
    /// without `MEDIA_BUS_FMT_` for what an ISP made (`RGB888_1X24`).
    pub code: String,
    /// The size; the negotiated one (the sensor's mode, or the crop upstream) when absent.
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// The crop, when the pad needs one.
    pub crop: Option<CropSpec>,
}

/// A pad's crop: a rectangle, or `"limit"`: the whole frame, unless the driver clamps it to
/// what it can process, which then is the size downstream (centred, on even offsets so the
/// Bayer order stays).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CropSpec {
    Rect([u32; 4]),
    Named(CropName),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CropName {
    Limit,
}

/// A pad code as a profile writes it: a depth-only Bayer code, or a known non-Bayer code. A
/// Bayer code with its colour order is refused: the order is the sensor's to report.
fn check_code(code: &str) -> Result<(), String> {
    if super::sensor::depth_token(code).is_some() {
        return Ok(());
    }
    match mbus_code(code) {
        Some(c) if super::sensor::bayer_of(c).is_some() => Err(format!(
            "{code:?} names a colour order; write BAYER{} and focusd takes the order the \
             sensor reports",
            super::sensor::bayer_of(c).map_or(0, |(_, b)| b)
        )),
        Some(_) => Ok(()),
        None => {
            let names: Vec<&str> = MBUS_CODES
                .iter()
                .map(|(n, _)| *n)
                .filter(|n| !n.starts_with('S'))
                .collect();
            Err(format!(
                "unknown media-bus code {code:?}; known: BAYER8, BAYER10, {}",
                names.join(", ")
            ))
        }
    }
}

/// A media-bus code by name.
pub fn mbus_code(name: &str) -> Option<u32> {
    MBUS_CODES.iter().find(|(n, _)| *n == name).map(|&(_, c)| c)
}

/// A media-bus code's name, or its hex value.
pub fn mbus_name(code: u32) -> String {
    MBUS_CODES
        .iter()
        .find(|&&(_, c)| c == code)
        .map_or_else(|| format!("0x{code:04x}"), |(n, _)| n.to_string())
}

impl Profile {
    /// Parses and checks a profile's text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Profile, String> {
        let p: Profile =
            toml::from_str(text).map_err(|e| format!("device profile {origin}: {e}"))?;
        p.check()
            .map_err(|e| format!("device profile {origin}: {e}"))?;
        Ok(p)
    }

    /// The capture format's Bayer depth (`BAYER8`: 8); `None` for a format an ISP made. A
    /// fourcc with a colour order is refused, as in pad codes.
    pub fn capture_bits(&self) -> Result<Option<u32>, String> {
        let fourcc = &self.format.fourcc;
        if let Some(bits) = super::sensor::depth_token(fourcc) {
            return Ok(Some(bits));
        }
        let format = super::format::PixelFormat::parse(fourcc)
            .map_err(|e| format!("format.fourcc = {fourcc:?}: {e}"))?;
        match format.raw_bits() {
            Some(bits) => Err(format!(
                "format.fourcc = {fourcc:?} names a colour order; write BAYER{bits} and focusd \
                 takes the order the sensor reports"
            )),
            None => Ok(None),
        }
    }

    /// The black level in samples of `bits` bits.
    pub fn black_level_at(&self, bits: u32) -> u32 {
        let given = self.black_level_bits.unwrap_or(bits);
        if given >= bits {
            self.black_level >> (given - bits)
        } else {
            self.black_level << (bits - given)
        }
    }

    /// A shipped profile by name, or a file by path (anything with a `/` or ending `.toml`).
    pub fn load(spec: &str) -> Result<Profile, String> {
        if spec.contains('/') || spec.ends_with(".toml") {
            let text = crate::files::bounded_read::read_to_string(
                Path::new(spec),
                crate::files::bounded_read::TEXT_CAP,
            )
            .map_err(|e| format!("device profile {spec}: {e}"))?;
            return Profile::parse(&text, spec);
        }
        let (_, text) = SHIPPED.iter().find(|(n, _)| *n == spec).ok_or_else(|| {
            let names: Vec<&str> = SHIPPED.iter().map(|(n, _)| *n).collect();
            format!(
                "no shipped device profile {spec:?}; shipped: {} (or give a path to a .toml file)",
                names.join(", ")
            )
        })?;
        Profile::parse(text, spec)
    }

    fn check(&self) -> Result<(), String> {
        if self.sensor.all().is_empty() || self.sensor.all().iter().any(|n| n.trim().is_empty()) {
            return Err(format!(
                "sensor = {}: give the sensor's entity name",
                self.sensor
            ));
        }
        if !super::sensor::DEPTHS.contains(&self.mode.bits) {
            return Err(format!(
                "[mode] bits = {}: give 8 or 10, the depth on the sensor's pad",
                self.mode.bits
            ));
        }
        if self.mode.sizes.is_empty() || self.mode.sizes.iter().any(|&[w, h]| w == 0 || h == 0) {
            return Err(format!(
                "[mode] sizes = {:?}: give the sensor modes wanted, such as [[4208, 3120]]",
                self.mode.sizes
            ));
        }
        for p in &self.pads {
            check_code(&p.code).map_err(|e| format!("pad {}: {e}", p.pad))?;
            if p.width == Some(0) || p.height == Some(0) {
                return Err(format!(
                    "pad {}: empty size {:?}x{:?}",
                    p.pad, p.width, p.height
                ));
            }
        }
        let bits = self.capture_bits()?;
        if let Some(c) = self.compatible.iter().find(|c| c.trim().is_empty()) {
            return Err(format!(
                "compatible has an empty entry {c:?}: give device-tree compatibles such as \
                 \"pine64,pinephone-pro\" (see /proc/device-tree/compatible)"
            ));
        }
        // Half the range: a larger pedestal is a value in the wrong units (10-bit for 8-bit).
        let given_at = self.black_level_bits.or(bits);
        let limit = given_at.map_or(0, |bits| 1u32 << (bits - 1));
        if self.black_level > 0 && self.black_level >= limit {
            return Err(match given_at {
                Some(b) => format!(
                    "black_level = {} is not below {limit}, half the range of {b}-bit samples: \
                     give it at the depth black_level_bits says (the capture's when absent)",
                    self.black_level
                ),
                None => format!(
                    "black_level = {}: format {} is not raw Bayer, its black level is the \
                     ISP's; give 0",
                    self.black_level, self.format.fourcc
                ),
            });
        }
        for (i, row) in self.colour_matrix.iter().enumerate() {
            let sum: f32 = row.iter().sum();
            if row.iter().any(|v| !v.is_finite()) || (sum - 1.0).abs() > 0.02 || row[i] <= 0.0 {
                return Err(format!(
                    "colour_matrix row {} = {row:?} sums to {sum}: each row must sum to 1 with \
                     a positive diagonal (camera RGB to linear sRGB, white kept white; a DNG \
                     ColorMatrix maps the other way and does not fit here)",
                    i + 1
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_profiles_parse() {
        for (name, text) in SHIPPED {
            let p = Profile::parse(text, name).expect("parses");
            assert_eq!(p.name, name);
            // Every file says where its facts come from and what is unknown.
            assert!(text.contains("Verified"), "{name} says what was verified");
            let phone = name != "vimc";
            assert_eq!(!p.compatible.is_empty(), phone, "{name}: compatibles");
        }
        // Each phone's device-tree compatibles are its own.
        let mut all: Vec<String> = SHIPPED
            .iter()
            .flat_map(|(n, t)| Profile::parse(t, n).expect("parses").compatible)
            .collect();
        let count = all.len();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), count, "a compatible in two profiles");
        let pro = Profile::load("pinephone-pro").expect("pro");
        assert_eq!((pro.black_level, pro.lens), (64, LensSpec::Graph));
        assert_eq!(pro.mode.sizes[0], [4208, 3120]);
        let l5 = Profile::load("librem5").expect("librem5");
        assert_eq!(l5.sensor.all(), ["s5k3l6xx", "s5k3l6"]);
        assert_eq!(l5.mode.sizes, vec![[4208, 3120], [2104, 1560]]);
        // No shipped profile names a colour order: the sensor reports it.
        for (name, text) in SHIPPED {
            for order in ["RGGB", "GRBG", "GBRG", "BGGR", "BA81"] {
                let named = text
                    .lines()
                    .filter(|l| !l.starts_with('#'))
                    .any(|l| l.contains(order));
                assert!(!named, "{name} names {order}");
            }
        }
        assert!(matches!(
            Profile::load("oneplus6").expect("op6").lens,
            LensSpec::None { .. }
        ));
        let vimc = Profile::load("vimc").expect("vimc");
        assert_eq!(vimc.media_model, "VIMC MDEV");
        assert_eq!(vimc.lens, LensSpec::Graph);
        assert_eq!(vimc.links[0].to_string(), "\"Debayer A\":1 -> \"Scaler\":0");
    }

    #[test]
    fn bad_profiles_name_the_problem() {
        let e = Profile::load("pinephone-x").expect_err("unknown");
        assert!(e.contains("shipped: vimc, pinephone"), "{e}");
        let base = SHIPPED[0].1;
        let e = Profile::parse(&base.replace("BAYER8", "SRGGB9_1X9"), "t").expect_err("code");
        assert!(
            e.contains("pad \"Debayer A\":0: unknown media-bus code \"SRGGB9_1X9\"; known: BAYER8"),
            "{e}"
        );
        let e = Profile::parse(&base.replace("BAYER8", "SRGGB8_1X8"), "t").expect_err("order");
        assert!(
            e.contains("\"SRGGB8_1X8\" names a colour order; write BAYER8"),
            "{e}"
        );
        let e = Profile::parse(&base.replace("bits = 8", "bits = 12"), "t").expect_err("bits");
        assert!(e.contains("[mode] bits = 12: give 8 or 10"), "{e}");
        let e = Profile::parse(&base.replace("sizes = [[640, 480]]", "sizes = []"), "t")
            .expect_err("sizes");
        assert!(e.contains("[mode] sizes = []"), "{e}");
        let e = Profile::parse(&base.replace("fourcc = \"RGB3\"", "fourcc = \"XX\""), "t")
            .expect_err("fourcc");
        assert!(e.contains("format.fourcc = \"XX\""), "{e}");
        let e = Profile::parse("name = 1", "t").expect_err("toml");
        assert!(e.starts_with("device profile t: "), "{e}");
        let none = base.replace(
            "kind = \"graph\"",
            "kind = \"none\"\nreason = \"firmware autofocus only\"",
        );
        let p = Profile::parse(&none, "t").expect("lens none");
        assert_eq!(
            p.lens,
            LensSpec::None {
                reason: "firmware autofocus only".into()
            }
        );
    }

    #[test]
    fn black_level_matrix_and_compatibles_are_checked() {
        let base = SHIPPED[0].1;
        let raw = base.replace("fourcc = \"RGB3\"", "fourcc = \"BAYER8\"");
        let p = Profile::parse(&raw.replace("black_level = 0", "black_level = 64"), "t")
            .expect("64 of 255");
        assert_eq!((p.black_level, p.black_level_at(8)), (64, 64));
        let e = Profile::parse(&raw.replace("black_level = 0", "black_level = 128"), "t")
            .expect_err("10-bit value for an 8-bit format");
        assert!(
            e.contains("black_level = 128 is not below 128, half the range of 8-bit samples"),
            "{e}"
        );
        // Given at 10 bits, the same pedestal passes and scales to the capture's depth.
        let ten = raw.replace(
            "black_level = 0",
            "black_level = 128\nblack_level_bits = 10",
        );
        let p = Profile::parse(&ten, "t").expect("128 of 1023");
        assert_eq!((p.black_level_at(8), p.black_level_at(10)), (32, 128));
        let e = Profile::parse(
            &raw.replace("fourcc = \"BAYER8\"", "fourcc = \"GRBG\""),
            "t",
        )
        .expect_err("capture order");
        assert!(
            e.contains("format.fourcc = \"GRBG\" names a colour order; write BAYER8"),
            "{e}"
        );
        let e = Profile::parse(&base.replace("black_level = 0", "black_level = 3"), "t")
            .expect_err("not raw");
        assert!(e.contains("format RGB3 is not raw Bayer"), "{e}");
        // A DNG ColorMatrix (XYZ to camera) pasted in: its rows do not sum to 1.
        let dng = "[[1.384, -0.3203, -0.0124], [-0.2728, 1.049, 0.1556], [-0.0506, 0.2577, 0.805]]";
        let identity = "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]";
        let e = Profile::parse(&base.replace(identity, dng), "t").expect_err("dng matrix");
        assert!(
            e.contains("colour_matrix row 1 = [1.384, -0.3203, -0.0124] sums to 1.05"),
            "{e}"
        );
        let e = Profile::parse(
            &base.replace("compatible = []", "compatible = [\" \"]"),
            "t",
        )
        .expect_err("empty compatible");
        assert!(e.contains("compatible has an empty entry"), "{e}");
        let e = Profile::parse(&base.replace("black_level = 0\n", ""), "t").expect_err("missing");
        assert!(e.contains("black_level"), "{e}");
    }

    #[test]
    fn mbus_names_round_trip() {
        for (n, c) in MBUS_CODES {
            assert_eq!(mbus_code(n), Some(c));
            assert_eq!(mbus_name(c), n);
        }
        assert_eq!(mbus_name(0x9999), "0x9999");
    }
}
