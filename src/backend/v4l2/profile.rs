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
    /// The sensor's entity name; the lens is the lens entity linked to it. Like every entity
    /// name here it may leave out the I²C bus and address the kernel appends (`imx258` for
    /// `imx258 1-001a`), which depend on the board's wiring and probe order.
    pub sensor: String,
    /// The entity name of the video node to capture from.
    pub capture: String,
    /// The capture node's format.
    pub format: CaptureFormat,
    /// The sensor's black level (its pedestal) in the capture format's sample values
    /// (0..=255 for 8-bit Bayer), subtracted before white balance; 0 for formats an ISP has
    /// already processed.
    pub black_level: u32,
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

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureFormat {
    /// The fourcc (`RGGB`, `RGB3`, `NV12`, ...).
    pub fourcc: String,
    pub width: u32,
    pub height: u32,
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
    /// The media-bus code's name without `MEDIA_BUS_FMT_` (`SRGGB10_1X10`).
    pub code: String,
    pub width: u32,
    pub height: u32,
    /// The crop rectangle `[left, top, width, height]`, when the pad needs one.
    pub crop: Option<[u32; 4]>,
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
        for p in &self.pads {
            if mbus_code(&p.code).is_none() {
                let names: Vec<&str> = MBUS_CODES.iter().map(|(n, _)| *n).collect();
                return Err(format!(
                    "pad {}: unknown media-bus code {:?}; known: {}",
                    p.pad,
                    p.code,
                    names.join(", ")
                ));
            }
            if p.width == 0 || p.height == 0 {
                return Err(format!(
                    "pad {}: empty size {}x{}",
                    p.pad, p.width, p.height
                ));
            }
        }
        let format = super::format::PixelFormat::parse(&self.format.fourcc)
            .map_err(|e| format!("format.fourcc = {:?}: {e}", self.format.fourcc))?;
        if let Some(c) = self.compatible.iter().find(|c| c.trim().is_empty()) {
            return Err(format!(
                "compatible has an empty entry {c:?}: give device-tree compatibles such as \
                 \"pine64,pinephone-pro\" (see /proc/device-tree/compatible)"
            ));
        }
        // Half the range: a larger pedestal is a value in the wrong units (10-bit for 8-bit).
        let limit = format.raw_bits().map_or(0, |bits| 1u32 << (bits - 1));
        if self.black_level > 0 && self.black_level >= limit {
            return Err(match format.raw_bits() {
                Some(bits) => format!(
                    "black_level = {} is not below {limit}, half the range of the {bits}-bit \
                     format {}: give it in the capture format's sample values",
                    self.black_level, self.format.fourcc
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
        assert_eq!((pro.black_level, pro.lens), (16, LensSpec::Graph));
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
        let e = Profile::parse(&base.replace("SRGGB8_1X8", "SRGGB9_1X9"), "t").expect_err("code");
        assert!(
            e.contains("pad \"Sensor A\":0: unknown media-bus code \"SRGGB9_1X9\""),
            "{e}"
        );
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
        let raw = base.replace("fourcc = \"RGB3\"", "fourcc = \"RGGB\"");
        let p = Profile::parse(&raw.replace("black_level = 0", "black_level = 64"), "t")
            .expect("64 of 255");
        assert_eq!(p.black_level, 64);
        let e = Profile::parse(&raw.replace("black_level = 0", "black_level = 128"), "t")
            .expect_err("10-bit value for an 8-bit format");
        assert!(
            e.contains("black_level = 128 is not below 128, half the range of the 8-bit"),
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
