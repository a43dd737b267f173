//! Formats through `focusd fuse`: EXIF of the reference frame in a JPEG output, 16-bit in and out.

use img_parts::{jpeg::Jpeg, Bytes, ImageEXIF};
use std::path::Path;
use std::process::Command;

fn fuse(args: &[&Path]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(["fuse", "--no-align", "-o"])
        .args(args)
        .output()
        .unwrap()
}

/// A minimal little-endian TIFF/EXIF block with one Make tag.
fn exif_with_make(make: &str) -> Vec<u8> {
    let mut v = b"II\x2a\x00\x08\x00\x00\x00".to_vec();
    v.extend_from_slice(&1u16.to_le_bytes());
    v.extend_from_slice(&0x010fu16.to_le_bytes());
    v.extend_from_slice(&2u16.to_le_bytes());
    v.extend_from_slice(&(make.len() as u32 + 1).to_le_bytes());
    v.extend_from_slice(&26u32.to_le_bytes());
    v.extend_from_slice(&0u32.to_le_bytes());
    v.extend_from_slice(make.as_bytes());
    v.push(0);
    v
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
    // A mixed stack: an 8-bit gray PNG joins the 16-bit colour TIFFs.
    let gray = dir.path().join("g.png");
    image::GrayImage::from_fn(40, 30, |x, _| image::Luma([(x * 6) as u8]))
        .save(&gray)
        .unwrap();
    frames.push(gray);
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
