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
    RawFrame {
        stride: packing.row_bytes(width),
        bytes: crate::develop::raw::pack(packing, width, &samples),
        packing,
        width,
        height,
        order,
        black_level: max / 16,
        matrix: IDENTITY,
        white_balance: None,
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

fn field(e: &exif::Exif, number: u16, ifd: In) -> &exif::Field {
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

#[test]
fn what_focusd_writes_reads_back_exactly() {
    let orders = [
        BayerOrder::Rggb,
        BayerOrder::Bggr,
        BayerOrder::Grbg,
        BayerOrder::Gbrg,
    ];
    for (i, order) in orders.into_iter().enumerate() {
        for packing in [Packing::Bits8, Packing::Le10, Packing::Le16] {
            // Half the frames say their white balance, the others leave it to grey-world.
            let f = RawFrame {
                matrix: [[1.6, -0.4, -0.2], [-0.25, 1.5, -0.25], [0.0, -0.6, 1.6]],
                white_balance: (i % 2 == 0).then_some([2.0, 1.0, 1.25]),
                ..frame(packing, order, 10, 6)
            };
            let info = DngInfo {
                orientation: Orientation::clockwise(i as u8),
                ..info()
            };
            let back = read::decode(&encode(&f, &info).expect("encodes")).expect("decodes");
            assert_eq!(back.orientation, info.orientation);
            assert_eq!(
                RawFrame {
                    matrix: f.matrix,
                    white_balance: f.white_balance,
                    ..back.raw.clone()
                },
                f
            );
            let gains = back.raw.white_balance.expect("AsShotNeutral read");
            let expected = f
                .white_balance
                .unwrap_or_else(|| crate::develop::grey_world(&[&f.mosaic().expect("unpacks")]));
            for (a, b) in gains.iter().zip(expected) {
                assert!((a - b).abs() < 1e-5, "{gains:?} against {expected:?}");
            }
            for (a, b) in back
                .raw
                .matrix
                .iter()
                .flatten()
                .zip(f.matrix.iter().flatten())
            {
                assert!((a - b).abs() < 1e-5, "{:?}", back.raw.matrix);
            }
        }
    }
}

/// Sets the inline value of `tag` in IFD0 of a little-endian DNG focusd wrote.
fn patch(dng: &mut [u8], tag: u16, value: &[u8]) {
    let ifd = u32::from_le_bytes(dng[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes([dng[ifd], dng[ifd + 1]]) as usize;
    let e = (0..n)
        .map(|i| ifd + 2 + 12 * i)
        .find(|&e| u16::from_le_bytes([dng[e], dng[e + 1]]) == tag)
        .expect("tag present");
    dng[e + 8..e + 12].fill(0);
    dng[e + 8..][..value.len()].copy_from_slice(value);
}

#[test]
fn unsupported_dngs_are_refused_naming_the_tag_and_value() {
    let good = encode(&frame(Packing::Le16, BayerOrder::Rggb, 8, 8), &info()).expect("encodes");
    let refused = |tag, value: &[u8]| {
        let mut d = good.clone();
        patch(&mut d, tag, value);
        read::decode(&d).expect_err("refused")
    };
    let e = refused(259, &7u16.to_le_bytes());
    assert!(
        e.starts_with("Compression = 7 (lossless JPEG): focusd reads uncompressed"),
        "{e}"
    );
    let e = refused(262, &34892u16.to_le_bytes());
    assert!(
        e.starts_with("PhotometricInterpretation = 34892 (LinearRaw"),
        "{e}"
    );
    let e = refused(33422, &[0, 0, 1, 2]);
    assert!(
        e.starts_with("CFAPattern = [0, 0, 1, 2]: not a Bayer pattern"),
        "{e}"
    );
    let e = refused(33421, &[3, 0, 3, 0]);
    assert!(e.starts_with("CFARepeatPatternDim = [3, 3]"), "{e}");
    let e = refused(274, &2u16.to_le_bytes());
    assert!(
        e.starts_with("Orientation = 2: focusd reads unmirrored"),
        "{e}"
    );
    // AsShotNeutral with a zero for red (its three rationals lie outside the entry).
    let mut zero = good.clone();
    let ifd = u32::from_le_bytes(zero[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes([zero[ifd], zero[ifd + 1]]) as usize;
    let e = (0..n)
        .map(|i| ifd + 2 + 12 * i)
        .find(|&e| u16::from_le_bytes([zero[e], zero[e + 1]]) == 50728)
        .expect("AsShotNeutral written");
    let at = u32::from_le_bytes(zero[e + 8..e + 12].try_into().unwrap()) as usize;
    zero[at..at + 4].fill(0);
    let e = read::decode(&zero).expect_err("zero neutral");
    assert!(
        e.starts_with("AsShotNeutral = [0.0, ") && e.contains("three positive values"),
        "{e}"
    );
    // Not a DNG at all, a TIFF without DNGVersion, and a truncated file.
    assert!(read::decode(b"GIF89a")
        .expect_err("gif")
        .contains("no TIFF header"));
    let mut plain = good.clone();
    let ifd = u32::from_le_bytes(plain[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes([plain[ifd], plain[ifd + 1]]) as usize;
    for i in 0..n {
        let e = ifd + 2 + 12 * i;
        if u16::from_le_bytes([plain[e], plain[e + 1]]) == 50706 {
            plain[e..e + 2].copy_from_slice(&50000u16.to_le_bytes());
        }
    }
    let e = read::decode(&plain).expect_err("plain TIFF");
    assert!(e.contains("no DNGVersion"), "{e}");
    for cut in [4, 20, good.len() / 2] {
        assert!(read::decode(&good[..cut]).is_err(), "cut at {cut}");
    }
}

/// A minimal TIFF in either byte order: the pixel data at offset 8, then IFD0 with `entries`
/// (tag, type, values), values longer than four bytes after it.
fn tiff(big_endian: bool, entries: &[(u16, u16, Vec<u32>)], data: &[u8]) -> Vec<u8> {
    // The low `n` bytes of `v` in the file's order.
    let word = |v: u32, n: usize| -> Vec<u8> {
        if big_endian {
            v.to_be_bytes()[4 - n..].to_vec()
        } else {
            v.to_le_bytes()[..n].to_vec()
        }
    };
    let mut out = if big_endian { b"MM\0\x2a" } else { b"II\x2a\0" }.to_vec();
    let ifd = 8 + data.len() + data.len() % 2;
    out.extend(word(ifd as u32, 4));
    out.extend(data);
    out.resize(ifd, 0);
    let mut extra = Vec::new();
    let extra_at = ifd + 2 + 12 * entries.len() + 4;
    out.extend(word(entries.len() as u32, 2));
    for (tag, typ, values) in entries {
        let size = match typ {
            1 => 1,
            3 => 2,
            _ => 4,
        };
        let bytes: Vec<u8> = values.iter().flat_map(|&v| word(v, size)).collect();
        out.extend(word(u32::from(*tag), 2));
        out.extend(word(u32::from(*typ), 2));
        out.extend(word(values.len() as u32, 4));
        if bytes.len() <= 4 {
            let mut field = bytes.clone();
            field.resize(4, 0);
            out.extend(field);
        } else {
            out.extend(word((extra_at + extra.len()) as u32, 4));
            extra.extend(bytes);
        }
    }
    out.extend([0; 4]);
    out.extend(extra);
    out
}

/// Tags of a 4×4 CFA DNG with `bits` a sample, BGGR, black 64, white `white`.
fn cfa_tags(bits: u32, white: u32) -> Vec<(u16, u16, Vec<u32>)> {
    vec![
        (256, 4, vec![4]),
        (257, 4, vec![4]),
        (258, 3, vec![bits]),
        (259, 3, vec![1]),
        (262, 3, vec![32803]),
        (277, 3, vec![1]),
        (33421, 3, vec![2, 2]),
        (33422, 1, vec![2, 1, 1, 0]),
        (50706, 1, vec![1, 4, 0, 0]),
        (50714, 4, vec![64]),
        (50717, 4, vec![white]),
    ]
}

/// 12-bit samples packed from the high bit in big-endian strips, and 16-bit ones in 2×2
/// tiles, as other cameras' DNGs hold them: rescaled to 16 bits with the levels kept.
#[test]
fn packed_strips_and_tiles_from_other_writers() {
    let samples: Vec<u16> = (0..16).map(|i| 64 + i * 250).collect();
    let mut packed = Vec::new();
    for p in samples.chunks(2) {
        packed.extend([
            (p[0] >> 4) as u8,
            ((p[0] & 15) << 4 | p[1] >> 8) as u8,
            p[1] as u8,
        ]);
    }
    let mut tags = cfa_tags(12, 4095);
    tags.extend([
        (273, 4, vec![8, 20]),
        (278, 3, vec![2]),
        (279, 4, vec![12, 12]),
    ]);
    tags.sort_by_key(|t| t.0);
    let d = read::decode(&tiff(true, &tags, &packed)).expect("12-bit strips");
    assert_eq!(
        (d.raw.packing, d.raw.order),
        (Packing::Le16, BayerOrder::Bggr)
    );
    let scale: f64 = 65535.0 / 4095.0;
    assert_eq!(d.raw.black_level, (64.0 * scale).round() as u32);
    let got = crate::develop::raw::unpack(Packing::Le16, 4, 4, 0, &d.raw.bytes).expect("16");
    for (g, s) in got.iter().zip(&samples) {
        let want = (f64::from(*s) - 64.0) / (4095.0 - 64.0) * (65535.0 - 1024.0) + 1024.0;
        assert!((f64::from(*g) - want).abs() <= 0.5 + 1e-9, "{g} vs {want}");
    }

    // 2×2 tiles of 16-bit samples, tile by tile.
    let words: Vec<u16> = (0..16).map(|i| 1000 + i * 3).collect();
    let mut tiled = Vec::new();
    for ty in 0..2 {
        for tx in 0..2 {
            for y in 0..2 {
                for x in 0..2 {
                    tiled.extend(words[(ty * 2 + y) * 4 + tx * 2 + x].to_be_bytes());
                }
            }
        }
    }
    let mut tags = cfa_tags(16, 65535);
    tags.extend([
        (322, 3, vec![2]),
        (323, 3, vec![2]),
        (324, 4, vec![8, 16, 24, 32]),
        (325, 4, vec![8; 4]),
    ]);
    tags.sort_by_key(|t| t.0);
    let d = read::decode(&tiff(true, &tags, &tiled)).expect("tiles");
    assert_eq!((d.raw.packing, d.raw.black_level), (Packing::Le16, 64));
    let got = crate::develop::raw::unpack(Packing::Le16, 4, 4, 0, &d.raw.bytes).expect("16");
    assert_eq!(got, words);
    // A tile past the end of the file.
    let mut tags2 = tags.clone();
    tags2.iter_mut().find(|t| t.0 == 324).unwrap().2 = vec![8, 16, 24, 9000];
    let e = read::decode(&tiff(true, &tags2, &tiled)).expect_err("outside");
    assert!(e.contains("tile 3"), "{e}");
    // A header claiming far more pixels than the file holds is refused before allocating.
    let mut huge = tags.clone();
    huge.iter_mut().find(|t| t.0 == 256).unwrap().2 = vec![10_000];
    huge.iter_mut().find(|t| t.0 == 257).unwrap().2 = vec![10_000];
    let e = read::decode(&tiff(true, &huge, &tiled)).expect_err("huge");
    assert!(e.starts_with("truncated: a 10000x10000 mosaic"), "{e}");
}

/// 16-bit samples in tiles that overhang the image, little-endian (kept as the file's bytes)
/// and big-endian (unpacked and packed again): the same frame either way, at both white levels
/// a camera's packing has.
#[test]
fn little_endian_words_are_read_as_big_endian_ones() {
    // 3×3 tiles over 4×4 samples: the right and bottom tiles hold one column or row each.
    let words: Vec<u16> = (0..16).map(|i| 70 + i * 61).collect();
    let (tile, across) = (3, 2);
    let at = |t: usize, x: usize, y: usize| {
        let (x, y) = ((t % across) * tile + x, (t / across) * tile + y);
        (x < 4 && y < 4).then(|| words[y * 4 + x])
    };
    let tiles = |big: bool| -> Vec<u8> {
        (0..across * across)
            .flat_map(|t| (0..tile * tile).map(move |i| at(t, i % tile, i / tile).unwrap_or(0)))
            .flat_map(|v| {
                if big {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                }
            })
            .collect()
    };
    for white in [1023, 65535] {
        let read = |big: bool| {
            let mut tags = cfa_tags(16, white);
            tags.extend([
                (322, 3, vec![tile as u32]),
                (323, 3, vec![tile as u32]),
                (324, 4, vec![8, 26, 44, 62]),
                (325, 4, vec![18; 4]),
            ]);
            tags.sort_by_key(|t| t.0);
            read::decode(&tiff(big, &tags, &tiles(big))).expect("tiles")
        };
        let (le, be) = (read(false), read(true));
        assert_eq!(le, be, "white {white}");
        let packing = if white == 1023 {
            Packing::Le10
        } else {
            Packing::Le16
        };
        assert_eq!(le.raw.packing, packing);
        let got = crate::develop::raw::unpack(packing, 4, 4, 0, &le.raw.bytes).expect("unpacks");
        assert_eq!(got, words, "white {white}");
    }
}
