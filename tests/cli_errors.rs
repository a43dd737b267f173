//! Bad input to `focusd fuse`: a one-line error naming the file, a non-zero exit, no panic, and
//! no output file left behind.

use std::path::{Path, PathBuf};
use std::process::Command;

fn focusd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_focusd"))
}

fn write_png(path: &Path, w: u32, h: u32, seed: u32) {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        let v = ((x * 7 + y * 13 + seed * 31) % 256) as u8;
        image::Rgb([v, v / 2, 255 - v])
    });
    img.save(path).unwrap();
}

struct Case {
    dir: tempfile::TempDir,
}

impl Case {
    fn new() -> Self {
        Self {
            dir: tempfile::tempdir().unwrap(),
        }
    }
    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
    fn frames(&self, n: usize) -> Vec<PathBuf> {
        (0..n)
            .map(|i| {
                let p = self.path(&format!("f{i}.png"));
                write_png(&p, 48, 32, i as u32);
                p
            })
            .collect()
    }
    /// Runs fuse without alignment into `out`; asserts failure and returns stderr.
    fn fails(&self, frames: &[PathBuf], out: &Path) -> String {
        self.fails_with(&["--no-align"], frames, out)
    }
    /// Runs fuse with `args` into `out`; asserts a one-line failure, nothing left behind, and
    /// returns stderr.
    fn fails_with(&self, args: &[&str], frames: &[PathBuf], out: &Path) -> String {
        let o = focusd()
            .arg("fuse")
            .args(args)
            .arg("-o")
            .arg(out)
            .args(frames)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert_eq!(o.status.code(), Some(1), "exit status; stderr: {err}");
        assert!(!err.contains("panicked"), "panic: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
        assert!(err.starts_with("focusd: error: "), "{err}");
        assert!(!out.exists(), "output left behind");
        let leftovers: Vec<_> = std::fs::read_dir(self.dir.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
            .collect();
        assert!(leftovers.is_empty(), "temp files left: {leftovers:?}");
        err
    }
}

#[test]
fn missing_file_is_named() {
    let c = Case::new();
    let mut f = c.frames(2);
    f.push(c.path("nope.jpg"));
    let err = c.fails(&f, &c.path("out.jpg"));
    assert!(
        err.contains("nope.jpg") && err.contains("cannot open"),
        "{err}"
    );
}

#[test]
fn corrupt_and_truncated_images_are_named() {
    let c = Case::new();
    let f = c.frames(3);
    let garbage = c.path("garbage.jpg");
    std::fs::write(
        &garbage,
        b"\xff\xd8\xff\xe0 this is not really a jpeg at all",
    )
    .unwrap();
    let err = c.fails(&[f[0].clone(), garbage], &c.path("out.jpg"));
    assert!(
        err.contains("garbage.jpg") && err.contains("corrupt"),
        "{err}"
    );

    let bytes = std::fs::read(&f[1]).unwrap();
    let cut = c.path("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let err = c.fails(&[f[0].clone(), cut], &c.path("out.jpg"));
    assert!(
        err.contains("cut.png") && err.contains("corrupt or truncated"),
        "{err}"
    );

    // A JPEG cut short decodes without complaint (the rest comes out grey), so focusd checks
    // for its end-of-image marker; one whole JPEG with its EXIF thumbnail still loads.
    let jpeg = Path::new(env!("CARGO_MANIFEST_DIR")).join("sim-data/handheld/frame_03.jpg");
    let bytes = std::fs::read(&jpeg).unwrap();
    let cut = c.path("cut.jpg");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let err = c.fails(&[jpeg.clone(), cut], &c.path("out.jpg"));
    assert!(
        err.contains("cut.jpg") && err.contains("ends before its end-of-image marker"),
        "{err}"
    );

    let text = c.path("notes.txt");
    std::fs::write(&text, "hello").unwrap();
    let err = c.fails(&[f[0].clone(), text], &c.path("out.jpg"));
    assert!(
        err.contains("notes.txt") && err.contains("not a JPEG, PNG or TIFF"),
        "{err}"
    );
}

/// A BigTIFF (TIFF with 64-bit offsets, either byte order) is refused by that name, not as
/// "not an image".
#[test]
fn bigtiff_is_refused_by_name() {
    for (name, header) in [
        ("little.tif", *b"II\x2b\0\x08\0\0\0\x10\0\0\0\0\0\0\0"),
        ("big.tif", *b"MM\0\x2b\0\x08\0\0\0\0\0\0\0\0\0\x10"),
    ] {
        let c = Case::new();
        let mut f = c.frames(2);
        let big = c.path(name);
        std::fs::write(&big, header).unwrap();
        f.push(big);
        let err = c.fails(&f, &c.path("out.png"));
        assert!(
            err.contains(name) && err.contains("BigTIFF (64-bit offsets) is not supported"),
            "{err}"
        );
    }
}

#[test]
fn frames_of_different_sizes_are_named() {
    let c = Case::new();
    let mut f = c.frames(2);
    let odd = c.path("odd.png");
    write_png(&odd, 40, 32, 9);
    f.push(odd);
    let err = c.fails(&f, &c.path("out.png"));
    assert!(
        err.contains("odd.png") && err.contains("40x32") && err.contains("48x32"),
        "{err}"
    );
}

/// Frames that pass the 8x8 check but are too small for registration's pyramid are refused in
/// one line naming their size and the minimum, whichever side is short.
#[test]
fn frames_too_small_to_register_are_refused() {
    for (w, h) in [(320, 8), (320, 12), (320, 15), (12, 320), (15, 15)] {
        let c = Case::new();
        let f: Vec<PathBuf> = (0..3)
            .map(|i| {
                let p = c.path(&format!("f{i}.png"));
                write_png(&p, w, h, i);
                p
            })
            .collect();
        let err = c.fails_with(&[], &f, &c.path("out.jpg"));
        assert!(
            err.contains(&format!("{w}x{h}")) && err.contains("at least 16x16"),
            "{w}x{h}: {err}"
        );
    }
}

/// A grey frame in a colour stack, or a colour frame in a grey one, is refused by name rather
/// than gain-matched into a patchwork.
#[test]
fn grey_and_colour_frames_are_not_mixed() {
    let c = Case::new();
    let mut colour = c.frames(2);
    let grey = c.path("grey.png");
    image::GrayImage::from_fn(48, 32, |x, y| image::Luma([(x * 5 + y) as u8]))
        .save(&grey)
        .unwrap();
    colour.push(grey.clone());
    let err = c.fails_with(&[], &colour, &c.path("out.png"));
    assert!(
        err.contains("grey.png: frame is grey but")
            && err.contains("f0.png is colour")
            && err.contains("cannot mix grey and colour"),
        "{err}"
    );
    let mut greys = vec![grey.clone(), grey];
    greys.push(colour[1].clone());
    let err = c.fails_with(&[], &greys, &c.path("out.png"));
    assert!(
        err.contains("f1.png: frame is colour but") && err.contains("grey.png is grey"),
        "{err}"
    );
}

#[test]
fn one_frame_and_no_frames_are_refused() {
    let c = Case::new();
    let f = c.frames(1);
    let err = c.fails(&f, &c.path("out.jpg"));
    assert!(
        err.contains("f0.png") && err.contains("at least 2 frames"),
        "{err}"
    );
    let err = c.fails(&[], &c.path("out.jpg"));
    assert!(err.contains("no input frames"), "{err}");
}

#[test]
fn unwritable_output_is_refused_before_work() {
    let c = Case::new();
    let f = c.frames(2);
    let err = c.fails(&f, &c.path("missing-dir/out.jpg"));
    assert!(
        err.contains("missing-dir") && err.contains("does not exist"),
        "{err}"
    );
    // A parent that is a file: the write itself fails, and nothing is left behind.
    let file = c.path("plain");
    std::fs::write(&file, "x").unwrap();
    let err = c.fails(&f, &file.join("out.jpg"));
    assert!(err.contains("out.jpg"), "{err}");
    let err = c.fails(&f, &c.path("out.bmp"));
    assert!(
        err.contains("out.bmp") && err.contains(".jpg, .png or .tif"),
        "{err}"
    );
}

#[test]
fn reference_out_of_range_is_refused() {
    let c = Case::new();
    let f = c.frames(3);
    let o = focusd()
        .args(["fuse", "--no-align", "--reference", "3", "-o"])
        .arg(c.path("out.png"))
        .args(&f)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        err.contains("--reference 3") && err.contains("0..=2"),
        "{err}"
    );
}

#[test]
fn good_stack_writes_output_and_depthmap_of_reference_size() {
    let c = Case::new();
    let f = c.frames(3);
    let (out, dm) = (c.path("out.tif"), c.path("depth.png"));
    let o = focusd()
        .args(["fuse", "--no-align", "-o"])
        .arg(&out)
        .arg("--depthmap")
        .arg(&dm)
        .args(&f)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&out).unwrap();
    assert_eq!((img.width(), img.height()), (48, 32));
    let d = image::open(&dm).unwrap();
    assert_eq!(d.color(), image::ColorType::L8);
    assert_eq!((d.width(), d.height()), (48, 32));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("tenengrad") && err.contains("time"), "{err}");
}
