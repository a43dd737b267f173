//! Formats through `focusd fuse`: EXIF of the reference frame in a JPEG output, 16-bit in and out.

use img_parts::{jpeg::Jpeg, Bytes, ImageEXIF};
use std::path::Path;
use std::process::Command;

mod common;
use common::stacks::exif_orientation;

fn fuse(args: &[&Path]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["fuse", "--no-align", "-o"])
        .args(args)
        .output()
        .unwrap()
}

/// A minimal little-endian TIFF/EXIF block with a Make tag and, if given, an Orientation.
fn exif_with(make: &str, orientation: Option<u16>) -> Vec<u8> {
    let entries = 1 + orientation.is_some() as u16;
    let data_at = 8 + 2 + 12 * entries as u32 + 4;
    let mut v = b"II\x2a\x00\x08\x00\x00\x00".to_vec();
    v.extend_from_slice(&entries.to_le_bytes());
    v.extend_from_slice(&0x010fu16.to_le_bytes());
    v.extend_from_slice(&2u16.to_le_bytes());
    v.extend_from_slice(&(make.len() as u32 + 1).to_le_bytes());
    v.extend_from_slice(&data_at.to_le_bytes());
    if let Some(o) = orientation {
        v.extend_from_slice(&0x0112u16.to_le_bytes());
        v.extend_from_slice(&3u16.to_le_bytes());
        v.extend_from_slice(&1u32.to_le_bytes());
        v.extend_from_slice(&(o as u32).to_le_bytes());
    }
    v.extend_from_slice(&0u32.to_le_bytes());
    v.extend_from_slice(make.as_bytes());
    v.push(0);
    v
}

fn exif_with_make(make: &str) -> Vec<u8> {
    exif_with(make, None)
}

fn jpeg_with_exif(img: &image::RgbImage, exif: Vec<u8>) -> Vec<u8> {
    let mut buf = std::io::Cursor::new(Vec::new());
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, 95)
        .encode_image(img)
        .unwrap();
    let mut jpeg = Jpeg::from_bytes(Bytes::from(buf.into_inner())).unwrap();
    jpeg.set_exif(Some(Bytes::from(exif)));
    jpeg.encoder().bytes().to_vec()
}

fn make_of(path: &Path) -> Option<String> {
    let file = std::fs::File::open(path).unwrap();
    let exif = exif::Reader::new()
        .read_from_container(&mut std::io::BufReader::new(file))
        .ok()?;
    let f = exif.get_field(exif::Tag::Make, exif::In::PRIMARY)?;
    Some(f.display_value().to_string().trim_matches('"').to_string())
}

#[test]
fn jpeg_output_keeps_the_reference_frames_exif() {
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<_> = (0..3u32)
        .map(|i| {
            let img = image::RgbImage::from_fn(64, 48, |x, y| {
                image::Rgb([((x * 9 + y * 5 + i * 40) % 256) as u8, (y * 4) as u8, 90])
            });
            let mut buf = std::io::Cursor::new(Vec::new());
            img.write_to(&mut buf, image::ImageFormat::Jpeg).unwrap();
            let mut jpeg = Jpeg::from_bytes(Bytes::from(buf.into_inner())).unwrap();
            jpeg.set_exif(Some(Bytes::from(exif_with_make(&format!("frame{i}")))));
            let p = dir.path().join(format!("f{i}.jpg"));
            std::fs::write(&p, jpeg.encoder().bytes()).unwrap();
            p
        })
        .collect();
    assert_eq!(make_of(&frames[2]).as_deref(), Some("frame2"));
    let out = dir.path().join("out.jpg");
    let mut args: Vec<&Path> = vec![&out, Path::new("--reference"), Path::new("2")];
    args.extend(frames.iter().map(|p| p.as_path()));
    let o = fuse(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(make_of(&out).as_deref(), Some("frame2"));
    // Default reference is the middle frame.
    let out = dir.path().join("mid.jpg");
    let mut args: Vec<&Path> = vec![&out];
    args.extend(frames.iter().map(|p| p.as_path()));
    assert!(fuse(&args).status.success());
    assert_eq!(make_of(&out).as_deref(), Some("frame1"));
}

#[test]
fn sixteen_bit_tiff_and_png_stay_sixteen_bit() {
    let dir = tempfile::tempdir().unwrap();
    let mut frames = Vec::new();
    for i in 0..2u32 {
        let img = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(40, 30, |x, y| {
            image::Rgb([
                (x * 1500 + i * 7) as u16,
                (y * 2000) as u16,
                30000 + i as u16,
            ])
        });
        let p = dir.path().join(format!("f{i}.tif"));
        img.save(&p).unwrap();
        frames.push(p);
    }
    // A mixed stack: an 8-bit PNG joins the 16-bit TIFFs.
    let eight = dir.path().join("e.png");
    image::RgbImage::from_fn(40, 30, |x, _| image::Rgb([(x * 6) as u8, 90, 200]))
        .save(&eight)
        .unwrap();
    frames.push(eight);
    for out in ["out.png", "out.tif"] {
        let out = dir.path().join(out);
        let mut args: Vec<&Path> = vec![&out];
        args.extend(frames.iter().map(|p| p.as_path()));
        let o = fuse(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let img = image::open(&out).unwrap();
        assert_eq!(img.color(), image::ColorType::Rgb16, "{}", out.display());
        assert_eq!((img.width(), img.height()), (40, 30));
    }
}

/// A portrait shot stored as landscape pixels with EXIF orientation 6 (turn 90° clockwise) is
/// fused upright, also beside a frame stored upright, and the output's EXIF (the reference's
/// Make kept) says upright.
#[test]
fn exif_orientation_is_applied_and_the_output_says_upright() {
    let dir = tempfile::tempdir().unwrap();
    let stored = image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, 90])
    });
    let frames: Vec<_> = (0..3)
        .map(|i| {
            let p = dir.path().join(format!("f{i}.jpg"));
            // Frame 0 stored upright, without an orientation.
            let bytes = if i == 0 {
                jpeg_with_exif(
                    &image::imageops::rotate90(&stored),
                    exif_with("frame0", None),
                )
            } else {
                jpeg_with_exif(&stored, exif_with(&format!("frame{i}"), Some(6)))
            };
            std::fs::write(&p, bytes).unwrap();
            p
        })
        .collect();
    assert_eq!(exif_orientation(&frames[1]), Some(6));
    let out = dir.path().join("out.jpg");
    let mut args: Vec<&Path> = vec![&out];
    args.extend(frames.iter().map(|p| p.as_path()));
    let o = fuse(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let fused = image::open(&out).unwrap().into_rgb8();
    assert_eq!(fused.dimensions(), (48, 64), "turned upright");
    let upright = image::imageops::rotate90(&stored);
    let diff: f64 = fused
        .as_raw()
        .iter()
        .zip(upright.as_raw())
        .map(|(a, b)| a.abs_diff(*b) as f64)
        .sum::<f64>()
        / fused.as_raw().len() as f64;
    assert!(
        diff < 4.0,
        "mean difference from the upright frame {diff:.2}"
    );
    assert_eq!(exif_orientation(&out), Some(1));
    assert_eq!(make_of(&out).as_deref(), Some("frame1"));
}

/// A baseline JPEG with four components (Adobe CMYK, stored inverted as Photoshop writes it) of
/// flat 8×8 blocks: each block is its DC coefficient alone, so no DCT is needed to write it.
fn cmyk_jpeg(bw: usize, bh: usize, color: impl Fn(usize, usize) -> [u8; 4]) -> Vec<u8> {
    let (w, h) = ((bw * 8) as u16, (bh * 8) as u16);
    let mut v = vec![0xFF, 0xD8];
    let segment = |v: &mut Vec<u8>, marker: u8, body: &[u8]| {
        v.extend_from_slice(&[0xFF, marker]);
        v.extend_from_slice(&(body.len() as u16 + 2).to_be_bytes());
        v.extend_from_slice(body);
    };
    segment(&mut v, 0xEE, b"Adobe\x00\x64\x00\x00\x00\x00\x00");
    segment(&mut v, 0xDB, &[[0u8].as_slice(), &[1u8; 64]].concat());
    let mut sof = vec![8];
    sof.extend_from_slice(&h.to_be_bytes());
    sof.extend_from_slice(&w.to_be_bytes());
    sof.push(4);
    for id in 1..=4 {
        sof.extend_from_slice(&[id, 0x11, 0]);
    }
    segment(&mut v, 0xC0, &sof);
    // The standard luminance DC table; an AC table with the end-of-block code alone ("0").
    let dc_bits = [0u8, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0];
    let dc_vals: Vec<u8> = (0..12).collect();
    segment(&mut v, 0xC4, &[&[0x00][..], &dc_bits, &dc_vals].concat());
    let mut ac_bits = [0u8; 16];
    ac_bits[0] = 1;
    segment(&mut v, 0xC4, &[&[0x10][..], &ac_bits, &[0x00]].concat());
    segment(&mut v, 0xDA, &[4, 1, 0, 2, 0, 3, 0, 4, 0, 0, 63, 0]);
    // Canonical codes of the DC table: (code, length) per category.
    let mut codes = Vec::new();
    let mut code = 0u32;
    for (len, &n) in dc_bits.iter().enumerate() {
        for _ in 0..n {
            codes.push((code, len as u32 + 1));
            code += 1;
        }
        code <<= 1;
    }
    let (mut acc, mut nbits, mut data) = (0u64, 0u32, Vec::new());
    let mut put = |bits: u32, len: u32, data: &mut Vec<u8>| {
        acc = (acc << len) | bits as u64;
        nbits += len;
        while nbits >= 8 {
            let byte = (acc >> (nbits - 8)) as u8;
            data.push(byte);
            if byte == 0xFF {
                data.push(0);
            }
            nbits -= 8;
        }
    };
    let mut pred = [0i32; 4];
    for by in 0..bh {
        for bx in 0..bw {
            let c = color(bx, by);
            for k in 0..4 {
                let dc = 8 * (c[k] as i32 - 128);
                let diff = dc - pred[k];
                pred[k] = dc;
                let cat = 32 - diff.unsigned_abs().leading_zeros();
                let (code, len) = codes[cat as usize];
                put(code, len, &mut data);
                if cat > 0 {
                    let bits = if diff < 0 {
                        diff + (1 << cat) - 1
                    } else {
                        diff
                    };
                    put(bits as u32, cat, &mut data);
                }
                put(0, 1, &mut data);
            }
        }
    }
    put(0x7F, 7, &mut data);
    v.extend_from_slice(&data[..]);
    v.extend_from_slice(&[0xFF, 0xD9]);
    v
}

/// CMYK JPEGs (print workflows, some scanners) become RGB: R = C·K/255 of the stored,
/// inverted inks, and a stack of them fuses.
#[test]
fn cmyk_jpeg_is_read_as_rgb_and_fuses() {
    let dir = tempfile::tempdir().unwrap();
    let ink = |bx: usize, by: usize, i: usize| -> [u8; 4] {
        [
            (40 + bx * 30) as u8,
            (200 - by * 40) as u8,
            (90 + i * 20) as u8,
            230,
        ]
    };
    let frames: Vec<_> = (0..3)
        .map(|i| {
            let p = dir.path().join(format!("c{i}.jpg"));
            std::fs::write(&p, cmyk_jpeg(6, 4, |bx, by| ink(bx, by, i))).unwrap();
            p
        })
        .collect();
    let img = match focusd::files::imageio::load(&frames[0]).unwrap() {
        focusd::files::imageio::Decoded::U8(i) => i,
        focusd::files::imageio::Decoded::U16(_) => panic!("8-bit expected"),
    };
    assert_eq!((img.width(), img.height(), img.channels()), (48, 32, 3));
    for (bx, by) in [(0, 0), (5, 0), (2, 3)] {
        let c = ink(bx, by, 0);
        let (x, y) = (bx * 8 + 4, by * 8 + 4);
        for ch in 0..3 {
            let want = c[ch] as f32 * c[3] as f32 / 255.0;
            let got = img.at(x, y, ch) as f32;
            assert!(
                (got - want).abs() <= 2.0,
                "block ({bx},{by}) channel {ch}: {got} vs {want}"
            );
        }
    }
    let out = dir.path().join("out.png");
    let mut args: Vec<&Path> = vec![&out];
    args.extend(frames.iter().map(|p| p.as_path()));
    let o = fuse(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(image::open(&out).unwrap().color(), image::ColorType::Rgb8);
}
