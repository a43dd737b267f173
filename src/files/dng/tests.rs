use super::*;
use crate::develop::raw::Packing;
use crate::develop::{RawFrame, IDENTITY};
use crate::files::orientation::Orientation;
use exif::{Context, In, Tag, Value};
use std::time::Duration;

/// A `width`×`height` frame of distinct samples at the packing's depth.
pub(super) fn frame(packing: Packing, order: BayerOrder, width: usize, height: usize) -> RawFrame {
    let max = (1u32 << packing.bits()) - 1;
    let samples: Vec<u16> = (0..width * height)
        .map(|i| ((i as u32 * 7919 + 13) % (max + 1)) as u16)
        .collect();
    let bytes = match packing {
        Packing::Bits8 => samples.iter().map(|&s| s as u8).collect(),
        _ => samples.iter().flat_map(|s| s.to_le_bytes()).collect(),
    };
    RawFrame {
        stride: packing.row_bytes(width),
        bytes,
        packing,
        width,
        height,
        order,
        black_level: max / 16,
        matrix: IDENTITY,
    }
}

pub(super) fn info() -> DngInfo {
    DngInfo {
        orientation: Orientation::clockwise(1),
        make: Some("Pine64".into()),
        model: "PinePhone Pro rear camera".into(),
        exposure: Some(Duration::from_micros(8_000)),
        taken: Some(1_796_083_199),
    }
}

fn field<'a>(e: &'a exif::Exif, number: u16, ifd: In) -> &'a exif::Field {
    e.get_field(Tag(Context::Tiff, number), ifd)
        .or_else(|| e.get_field(Tag(Context::Exif, number), ifd))
        .unwrap_or_else(|| panic!("tag {number} missing"))
}

fn uints(f: &exif::Field) -> Vec<u32> {
    (0..).map_while(|i| f.value.get_uint(i)).collect()
}

/// An independent TIFF reader (kamadak-exif) finds every tag written and the samples in the
/// strips.
#[test]
fn an_exif_reader_reads_the_tags_and_strips() {
    for (packing, bits) in [
        (Packing::Bits8, 8),
        (Packing::Le10, 10),
        (Packing::Le16, 16),
    ] {
        let f = frame(packing, BayerOrder::Gbrg, 6, 4);
        let dng = encode(&f, &info()).expect("encodes");
        let e = exif::Reader::new().read_raw(dng.clone()).expect("a TIFF");
        assert_eq!(uints(field(&e, 262, In::PRIMARY)), [32803]);
        assert_eq!(
            uints(field(&e, 274, In::PRIMARY)),
            [6],
            "one turn clockwise"
        );
        assert_eq!(uints(field(&e, 33421, In::PRIMARY)), [2, 2]);
        assert_eq!(uints(field(&e, 33422, In::PRIMARY)), [1, 2, 0, 1], "GBRG");
        assert_eq!(uints(field(&e, 50706, In::PRIMARY)), [1, 4, 0, 0]);
        assert_eq!(uints(field(&e, 50714, In::PRIMARY)), [f.black_level]);
        assert_eq!(uints(field(&e, 50717, In::PRIMARY)), [(1 << bits) - 1]);
        assert_eq!(
            uints(field(&e, 258, In::PRIMARY)),
            [if bits == 8 { 8 } else { 16 }]
        );
        assert_eq!(uints(field(&e, 50778, In::PRIMARY)), [21], "D65");
        let text = |n| field(&e, n, In::PRIMARY).display_value().to_string();
        assert_eq!(text(50708), "\"PinePhone Pro rear camera\"");
        assert_eq!(text(271), "\"Pine64\"");
        match &field(&e, 33434, In::PRIMARY).value {
            Value::Rational(r) => assert_eq!(r[0].to_f64(), 0.008),
            v => panic!("ExposureTime {v:?}"),
        }
        assert_eq!(text(36867), "2026-11-30 23:59:59");
        // The samples, strip by strip.
        let offsets = uints(field(&e, 273, In::PRIMARY));
        let counts = uints(field(&e, 279, In::PRIMARY));
        let data: Vec<u8> = offsets
            .iter()
            .zip(&counts)
            .flat_map(|(&o, &n)| dng[o as usize..][..n as usize].to_vec())
            .collect();
        let want = crate::develop::raw::unpack(packing, 6, 4, 0, &f.bytes).expect("unpacks");
        let got: Vec<u16> = if bits == 8 {
            data.iter().map(|&b| u16::from(b)).collect()
        } else {
            data.chunks(2)
                .map(|p| u16::from_le_bytes([p[0], p[1]]))
                .collect()
        };
        assert_eq!(got, want, "{bits} bits");
    }
}

/// With no colour data, ColorMatrix1 is XYZ to linear sRGB: raw tools render camera RGB as
/// sRGB, as focusd's development does. A profile's matrix survives the round trip.
#[test]
fn colour_matrices_say_camera_rgb_is_srgb_where_nothing_else_is_known() {
    let cm = color_matrix(IDENTITY).expect("invertible");
    let xyz_to_srgb = [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ];
    for (r, row) in xyz_to_srgb.iter().enumerate() {
        for (c, v) in row.iter().enumerate() {
            assert!((cm[(r, c)] - v).abs() < 1e-4, "{r},{c}: {}", cm[(r, c)]);
        }
    }
    let m = [[1.6, -0.4, -0.2], [-0.25, 1.5, -0.25], [0.0, -0.6, 1.6]];
    let back = development_matrix(color_matrix(m).expect("invertible")).expect("back");
    for (a, b) in back.iter().flatten().zip(m.iter().flatten()) {
        assert!((a - b).abs() < 1e-5, "{back:?}");
    }
    let singular = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
    assert!(encode(
        &RawFrame {
            matrix: singular,
            ..frame(Packing::Bits8, BayerOrder::Rggb, 4, 4)
        },
        &info()
    )
    .is_err());
}
