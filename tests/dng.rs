//! The DNGs focusd writes, read by an independent reader: LibRaw's tools (Debian's
//! `libraw-bin`) find exactly the samples, CFA pattern, black and white levels and orientation
//! written, and LibRaw's linear half-size development of a grey patch, in camera RGB, is
//! neutral. Without the tools the tests fail under CI and are skipped elsewhere, saying why.

mod common;

use common::libraw::{libraw, read_tiff, run};
use focusd::develop::raw::{self, Packing};
use focusd::develop::{BayerOrder, RawFrame, IDENTITY};
use focusd::files::dng::{encode, DngInfo};
use focusd::files::orientation::Orientation;
use std::path::Path;
use std::process::Command;

const W: usize = 64;
const H: usize = 48;

/// A frame of varied samples over the whole range of the packing's depth.
fn frame(packing: Packing, order: BayerOrder) -> RawFrame {
    let max = (1u32 << packing.bits()) - 1;
    let samples: Vec<u16> = (0..W * H)
        .map(|i| (((i as u64 * 2_654_435_761) >> 7) % (u64::from(max) + 1)) as u16)
        .collect();
    raw_frame(packing, order, &samples)
}

fn raw_frame(packing: Packing, order: BayerOrder, samples: &[u16]) -> RawFrame {
    RawFrame {
        stride: packing.row_bytes(W),
        bytes: raw::pack(packing, W, samples),
        packing,
        width: W,
        height: H,
        order,
        black_level: ((1u32 << packing.bits()) - 1) / 16,
        matrix: IDENTITY,
        white_balance: None,
    }
}

fn write(dir: &Path, name: &str, f: &RawFrame, turns: u8) -> std::path::PathBuf {
    let info = DngInfo {
        orientation: Orientation::clockwise(turns),
        make: Some("focusd".into()),
        model: "test sensor".into(),
        ..DngInfo::default()
    };
    let path = dir.join(name);
    std::fs::write(&path, encode(f, &info).expect("encodes")).expect("writes");
    path
}

#[test]
fn libraw_reads_the_samples_pattern_and_levels_written() {
    if !libraw() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let orders = [
        (BayerOrder::Rggb, "RGGB"),
        (BayerOrder::Bggr, "BGGR"),
        (BayerOrder::Grbg, "GRBG"),
        (BayerOrder::Gbrg, "GBRG"),
    ];
    for packing in [Packing::Bits8, Packing::Le10, Packing::Le16] {
        for (i, (order, pattern)) in orders.into_iter().enumerate() {
            let f = frame(packing, order);
            let name = format!("{}-{pattern}.dng", packing.bits());
            let path = write(dir.path(), &name, &f, i as u8);
            let id = run("raw-identify", &["-v"], &path);
            let line = |key: &str| {
                id.lines()
                    .find_map(|l| l.trim().strip_prefix(key))
                    .unwrap_or_else(|| panic!("no {key:?} in {id}"))
                    .trim()
                    .to_string()
            };
            assert!(line("Filter pattern:").starts_with(pattern), "{name}: {id}");
            assert_eq!(line("black:"), f.black_level.to_string(), "{name}: {id}");
            // LibRaw's flip codes: 0 upright, 6 a quarter clockwise, 3 a half, 5 counter-clockwise.
            assert_eq!(line("Image flip:"), ["0", "6", "3", "5"][i], "{name}: {id}");
            // The samples, as LibRaw unpacks them (no black subtracted, no scaling).
            run("unprocessed_raw", &["-T"], &path);
            let (w, h, c, data) = read_tiff(&path.with_extension("dng.tiff"));
            assert_eq!((w, h, c), (W, H, 1), "{name}");
            let want = focusd::develop::raw::unpack(packing, W, H, 0, &f.bytes).unwrap();
            assert_eq!(data, want, "{name}");
        }
    }
}

/// LibRaw's linear half-size development in camera RGB (`dcraw_emu -h -4 -T -o 0`) of a
/// frame whose middle is a grey patch (every sample 2/5 of the way from the black level to the
/// white level): neutral within 2 %, at 2/5 of full scale within 2 % (so LibRaw scales by the
/// white level written; raw-identify does not print it), and turned as the Orientation says.
#[test]
fn libraw_develops_a_grey_patch_neutral_and_upright() {
    if !libraw() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for (packing, order, turns) in [
        (Packing::Bits8, BayerOrder::Grbg, 0),
        (Packing::Le10, BayerOrder::Bggr, 1),
        (Packing::Le16, BayerOrder::Rggb, 3),
    ] {
        let f = frame(packing, order);
        let max = (1u32 << packing.bits()) - 1;
        let grey = (f.black_level + (max - f.black_level) * 2 / 5) as u16;
        let mut samples = focusd::develop::raw::unpack(packing, W, H, 0, &f.bytes).unwrap();
        for y in H / 4..3 * H / 4 {
            for x in W / 4..3 * W / 4 {
                samples[y * W + x] = grey;
            }
        }
        let f = raw_frame(packing, order, &samples);
        let path = write(
            dir.path(),
            &format!("grey-{}.dng", packing.bits()),
            &f,
            turns,
        );
        run("dcraw_emu", &["-h", "-4", "-T", "-o", "0"], &path);
        let (w, h, c, data) = read_tiff(&path.with_extension("dng.tiff"));
        let (ew, eh) = if turns % 2 == 1 {
            (H / 2, W / 2)
        } else {
            (W / 2, H / 2)
        };
        assert_eq!((w, h, c), (ew, eh, 3), "{packing:?} turned {turns}");
        // The patch's middle half, away from its edges.
        let mut sum = [0f64; 3];
        let mut n = 0.0;
        for y in 3 * h / 8..5 * h / 8 {
            for x in 3 * w / 8..5 * w / 8 {
                for (ch, s) in sum.iter_mut().enumerate() {
                    *s += f64::from(data[(y * w + x) * 3 + ch]);
                }
                n += 1.0;
            }
        }
        let mean = sum.map(|s| s / n);
        let g = mean[1];
        // The grey is 2/5 of the way from the black level to the white level written: LibRaw
        // scales by the same levels.
        assert!(
            (g / (0.4 * 65535.0) - 1.0).abs() < 0.02,
            "{packing:?}: {mean:?}"
        );
        for m in mean {
            assert!(
                (m / g - 1.0).abs() < 0.02,
                "{packing:?}: not neutral: {mean:?}"
            );
        }
    }
}

/// `fuse` takes a stack of DNGs: a simulated stack's frames mosaicked (10-bit, black level 64,
/// stored turned a quarter with Orientation 8 to undo it) fuse upright and as close to the
/// truth as the same frames developed by the library's stack developer and fused as pictures; a
/// stack mixing DNGs and pictures, and a compressed DNG, are refused naming the problem.
#[test]
fn fuse_develops_a_dng_stack() {
    use focusd::develop::{decode, Mosaic, StackDeveloper};
    let focusd = || Command::new(env!("CARGO_BIN_EXE_focusd"));
    let d = tempfile::tempdir().unwrap();
    let stack = d.path().join("stack");
    let st = focusd()
        .args([
            "simulate", "--width", "320", "--height", "240", "--planes", "4", "-o",
        ])
        .arg(&stack)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let load = |p: &Path| match focusd::files::imageio::load(p).expect("loads") {
        focusd::files::imageio::Decoded::U8(i) => i,
        _ => panic!("8-bit"),
    };
    let pictures: Vec<_> = (0..4)
        .map(|i| stack.join(format!("frame_{i:02}.jpg")))
        .collect();
    let mut dngs = Vec::new();
    let mut developed = Vec::new();
    let mut developer = StackDeveloper::default();
    for (i, p) in pictures.iter().enumerate() {
        // Stored a quarter turn clockwise; Orientation 8 (a quarter counter-clockwise) undoes it.
        let upright = load(p);
        let stored = Orientation::clockwise(1).turn(&decode(&upright));
        let m = Mosaic::sample(&stored, BayerOrder::Gbrg);
        let samples: Vec<u16> = m
            .data
            .iter()
            .map(|&v| (v.clamp(0.0, 1.0) * 959.0).round() as u16 + 64)
            .collect();
        let f = RawFrame {
            stride: Packing::Le10.row_bytes(m.width),
            bytes: raw::pack(Packing::Le10, m.width, &samples),
            packing: Packing::Le10,
            width: m.width,
            height: m.height,
            order: BayerOrder::Gbrg,
            black_level: 64,
            matrix: IDENTITY,
            white_balance: None,
        };
        let info = DngInfo {
            orientation: Orientation::clockwise(3),
            model: "simulated".into(),
            ..DngInfo::default()
        };
        let path = d.path().join(format!("frame_{i:02}.DNG"));
        std::fs::write(&path, encode(&f, &info).unwrap()).unwrap();
        dngs.push(path);
        let picture = Orientation::clockwise(3).turn(&developer.develop(&f).unwrap());
        let path = d.path().join(format!("developed_{i:02}.png"));
        focusd::files::outputs::save_image(&picture, &path, 95).unwrap();
        developed.push(path);
    }
    let fuse = |frames: &[std::path::PathBuf], out: &Path| {
        focusd()
            .arg("fuse")
            .arg("-o")
            .arg(out)
            .args(frames)
            .output()
            .unwrap()
    };
    let (from_dng, from_png) = (d.path().join("dng.png"), d.path().join("png.png"));
    for (frames, out) in [(&dngs, &from_dng), (&developed, &from_png)] {
        let o = fuse(frames, out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let (a, b) = (load(&from_dng), load(&from_png));
    assert_eq!((a.width(), a.height()), (320, 240), "upright");
    // The DNGs are developed lazily (in full only where the output keeps a frame), the
    // pictures were developed in full: against the truth, as good.
    let truth = load(&stack.join("truth.png"));
    let (lazy, full) = (
        focusd::stack::psnr(&a, &truth, 8),
        focusd::stack::psnr(&b, &truth, 8),
    );
    let p = focusd::stack::psnr(&a, &b, 0);
    eprintln!("from DNGs {lazy:.2} dB, from developed frames {full:.2} dB, {p:.1} dB apart");
    assert!(
        lazy > full - 0.1 && p > 30.0,
        "the DNG stack fused otherwise than its developed frames: {lazy:.2} against {full:.2} dB \
         from the truth, {p:.1} dB apart"
    );

    let mixed = [dngs[0].clone(), pictures[1].clone()];
    let o = fuse(&mixed, &d.path().join("mixed.png"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("cannot mix raw and developed"),
        "{err}"
    );
    // A DNG whose Compression says lossless JPEG.
    let mut bytes = std::fs::read(&dngs[1]).unwrap();
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes([bytes[ifd], bytes[ifd + 1]]) as usize;
    let e = (0..n)
        .map(|i| ifd + 2 + 12 * i)
        .find(|&e| bytes[e..e + 2] == [3, 1])
        .unwrap();
    bytes[e + 8..e + 10].copy_from_slice(&7u16.to_le_bytes());
    std::fs::write(&dngs[1], bytes).unwrap();
    let o = fuse(&dngs, &d.path().join("bad.png"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("Compression = 7 (lossless JPEG)"),
        "{err}"
    );
}
