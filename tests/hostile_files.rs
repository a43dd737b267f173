//! Files that try to hang focusd, grow it without bound, clobber its inputs or read outside a
//! bundle: each is refused by name, quickly, in little memory (the child's peak resident set,
//! from its own rusage), with nothing left behind.

use std::io::Write;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// Peak memory any refused input may cost, and generously: the binary alone is ~10 MB.
const REFUSED_RSS_KIB: i64 = 100 << 10;

struct Run {
    status: ExitStatus,
    stderr: String,
    /// Peak resident set of the child, KiB.
    max_rss_kib: i64,
}

/// Runs focusd to its end (killing it after 60 s: a hang fails the test instead of blocking the
/// suite) and reads its own peak memory with wait4.
fn run(args: &[&std::ffi::OsStr]) -> Run {
    // Reaped by wait4 below (which reads its rusage), not by Child::wait.
    #[allow(clippy::zombie_processes)]
    let mut child = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut stderr, &mut s).unwrap();
        s
    });
    let pid = child.id() as libc::pid_t;
    let start = Instant::now();
    let (status, usage) = loop {
        let mut status = 0;
        // SAFETY: an all-zero rusage is valid; wait4 fills it for our own child.
        let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: pid is our child, not yet reaped (std's Child is never waited on).
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break (ExitStatus::from_raw(status), usage);
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "focusd {args:?} hangs"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    Run {
        status,
        stderr: reader.join().unwrap(),
        max_rss_kib: usage.ru_maxrss,
    }
}

fn os(s: &str) -> &std::ffi::OsStr {
    s.as_ref()
}

/// The run failed with one clear line that says `what`, in little memory, without a panic.
fn refused(r: &Run, what: &[&str]) {
    let err = &r.stderr;
    assert_eq!(r.status.code(), Some(1), "exit status; stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    for w in what {
        assert!(err.contains(w), "{w:?} not in: {err}");
    }
    assert!(
        r.max_rss_kib < REFUSED_RSS_KIB,
        "peak RSS {} KiB refusing it; stderr: {err}",
        r.max_rss_kib
    );
}

fn png(path: &Path, w: u32, h: u32, seed: u32) {
    image::RgbImage::from_fn(w, h, |x, y| {
        let v = ((x * 7 + y * 13 + seed * 31) % 256) as u8;
        image::Rgb([v, v / 2, 255 - v])
    })
    .save(path)
    .unwrap();
}

fn fifo(path: &Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn fuse(frames: &[PathBuf], out: &Path, extra: &[&str]) -> Run {
    let mut args: Vec<&std::ffi::OsStr> = vec![os("fuse"), os("--no-align")];
    args.extend(extra.iter().map(|s| os(s)));
    args.extend([os("-o"), out.as_os_str()]);
    args.extend(frames.iter().map(|f| f.as_os_str()));
    run(&args)
}

fn no_temp_files(dir: &Path) {
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "temporary files left: {left:?}");
}

#[test]
fn a_frame_that_is_not_a_regular_file_is_refused_by_its_kind() {
    let d = tempfile::tempdir().unwrap();
    let good = d.path().join("a.png");
    png(&good, 48, 32, 0);
    let pipe = d.path().join("pipe.png");
    fifo(&pipe);
    let zero = d.path().join("zero.png");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    let out = d.path().join("out.jpg");
    for (bad, kind) in [
        (&pipe, "FIFO"),
        (&zero, "character device"),
        (&d.path().to_path_buf(), "directory"),
    ] {
        let r = fuse(&[good.clone(), bad.clone()], &out, &[]);
        refused(
            &r,
            &[&bad.display().to_string(), kind, "not a regular file"],
        );
        assert!(!out.exists());
    }
    no_temp_files(d.path());
}

#[test]
fn a_config_that_is_a_fifo_a_device_or_too_long_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let pipe = d.path().join("focusd.toml");
    fifo(&pipe);
    let long = d.path().join("long.toml");
    let mut f = std::fs::File::create(&long).unwrap();
    for _ in 0..(1 << 20) / 16 + 1 {
        f.write_all(b"# a long config\n").unwrap();
    }
    for (file, what) in [
        (pipe.as_path(), "FIFO"),
        (Path::new("/dev/zero"), "character device"),
        (long.as_path(), "limit"),
    ] {
        let r = run(&[os("check-config"), file.as_os_str()]);
        refused(&r, &[&file.display().to_string(), what]);
    }
}

/// A copy of the shipped hand-held bundle, to spoil.
fn bundle() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("sim-data/bundles/shaken");
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), d.path().join(e.file_name())).unwrap();
    }
    d
}

fn capture(bundle: &Path) -> Run {
    let out = bundle.join("out.jpg");
    run(&[
        os("capture"),
        os("--replay"),
        bundle.as_os_str(),
        os("-o"),
        out.as_os_str(),
    ])
}

#[test]
fn a_bundle_whose_manifest_or_trace_hangs_or_never_ends_is_refused() {
    for (file, kind) in [("imu.csv", "FIFO"), ("bundle.toml", "FIFO")] {
        let b = bundle();
        std::fs::remove_file(b.path().join(file)).unwrap();
        fifo(&b.path().join(file));
        refused(&capture(b.path()), &[file, kind]);
    }
    // /dev/zero is outside the bundle: refused before it is opened.
    let b = bundle();
    std::fs::remove_file(b.path().join("imu.csv")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", b.path().join("imu.csv")).unwrap();
    refused(&capture(b.path()), &["imu.csv", "outside the bundle"]);
    // A manifest with a million takes is refused by its size before it is parsed.
    let b = bundle();
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(b.path().join("bundle.toml"))
        .unwrap();
    for i in 0..1_000_000 {
        writeln!(f, "[[takes]]\nplane = {i}").unwrap();
    }
    refused(&capture(b.path()), &["bundle.toml", "limit"]);
}

#[test]
fn a_bundle_file_linked_from_outside_is_not_read_nor_echoed() {
    let secret_dir = tempfile::tempdir().unwrap();
    let secret = secret_dir.path().join("secret.jpg");
    std::fs::write(&secret, "TOP-SECRET-CONTENTS").unwrap();
    // The image itself a link out of the bundle.
    let b = bundle();
    std::fs::remove_file(b.path().join("frame_02.jpg")).unwrap();
    std::os::unix::fs::symlink(&secret, b.path().join("frame_02.jpg")).unwrap();
    let r = capture(b.path());
    refused(&r, &["frame_02.jpg", "outside the bundle"]);
    assert!(!r.stderr.contains("TOP-SECRET"), "{}", r.stderr);
    // The image under a directory that is a link out of the bundle.
    let b = bundle();
    std::fs::copy(
        b.path().join("frame_03.jpg"),
        secret_dir.path().join("frame_03.jpg"),
    )
    .unwrap();
    std::os::unix::fs::symlink(secret_dir.path(), b.path().join("sub")).unwrap();
    let toml = std::fs::read_to_string(b.path().join("bundle.toml")).unwrap();
    std::fs::write(
        b.path().join("bundle.toml"),
        toml.replace("\"frame_03.jpg\"", "\"sub/frame_03.jpg\""),
    )
    .unwrap();
    refused(
        &capture(b.path()),
        &["sub/frame_03.jpg", "outside the bundle"],
    );
    // A link that stays inside the bundle is fine.
    let b = bundle();
    std::fs::rename(b.path().join("frame_04.jpg"), b.path().join("real_04.jpg")).unwrap();
    std::os::unix::fs::symlink("real_04.jpg", b.path().join("frame_04.jpg")).unwrap();
    let r = capture(b.path());
    assert!(r.status.success(), "{}", r.stderr);
}

/// A small JPEG of a 320x240 gradient.
fn jpeg(path: &Path) {
    image::RgbImage::from_fn(320, 240, |x, y| image::Rgb([x as u8, y as u8, 128]))
        .save(path)
        .unwrap();
}

#[test]
fn trailing_bytes_after_a_jpeg_are_never_read() {
    let d = tempfile::tempdir().unwrap();
    let frames: Vec<PathBuf> = (0..2).map(|i| d.path().join(format!("{i}.jpg"))).collect();
    for f in &frames {
        jpeg(f);
    }
    // 900 MB of (sparse) zeros after the end-of-image marker.
    std::fs::OpenOptions::new()
        .write(true)
        .open(&frames[1])
        .unwrap()
        .set_len(900 << 20)
        .unwrap();
    let out = d.path().join("out.png");
    let r = fuse(&frames, &out, &[]);
    assert!(r.status.success(), "{}", r.stderr);
    assert!(r.max_rss_kib < REFUSED_RSS_KIB, "{} KiB", r.max_rss_kib);
    // Without its end marker, the data after the scan is read only up to what a JPEG of that
    // size could hold.
    let data = std::fs::read(&frames[0]).unwrap();
    let cut = data.len() - 2;
    let mut f = std::fs::File::create(&frames[0]).unwrap();
    f.write_all(&data[..cut]).unwrap();
    f.set_len(900 << 20).unwrap();
    refused(&fuse(&frames, &out, &[]), &["0.jpg", "end-of-image"]);
}

/// A PNG chunk: length, type, data, CRC.
fn chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut c = (data.len() as u32).to_be_bytes().to_vec();
    c.extend_from_slice(kind);
    c.extend_from_slice(data);
    let mut crc = 0xFFFF_FFFFu32;
    for &b in kind.iter().chain(data) {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    c.extend_from_slice(&(!crc).to_be_bytes());
    c
}

/// A zlib stream (stored blocks) inflating to `n` zero bytes, compressed with repeated
/// references: a deflate bomb without a compression crate. Uses fixed-Huffman blocks of
/// one literal then back-references of length 258 at distance 1.
fn zlib_zeros(n: usize) -> Vec<u8> {
    struct Bits {
        out: Vec<u8>,
        acc: u32,
        n: u32,
    }
    impl Bits {
        fn put(&mut self, v: u32, len: u32) {
            self.acc |= v << self.n;
            self.n += len;
            while self.n >= 8 {
                self.out.push(self.acc as u8);
                self.acc >>= 8;
                self.n -= 8;
            }
        }
        /// Huffman codes go most significant bit first.
        fn code(&mut self, v: u32, len: u32) {
            let r = (0..len).fold(0, |r, i| r | ((v >> i) & 1) << (len - 1 - i));
            self.put(r, len);
        }
    }
    let mut b = Bits {
        out: vec![0x78, 0x01],
        acc: 0,
        n: 0,
    };
    b.put(1, 1); // final block
    b.put(1, 2); // fixed Huffman
    b.code(0x30, 8); // literal 0
    let mut left = n - 1;
    while left >= 258 {
        b.code(0b1100_0101, 8); // length code 285: 258
        b.code(0, 5); // distance code 0: 1
        left -= 258;
    }
    for _ in 0..left {
        b.code(0x30, 8);
    }
    b.code(0, 7); // end of block
    if b.n > 0 {
        b.out.push(b.acc as u8);
    }
    // Adler-32 of n zeros: a = 1, b = n mod 65521.
    let adler = ((n % 65521) as u32) << 16 | 1;
    b.out.extend_from_slice(&adler.to_be_bytes());
    b.out
}

#[test]
fn images_whose_headers_promise_too_much_cost_little_memory() {
    let d = tempfile::tempdir().unwrap();
    let good = d.path().join("good.png");
    png(&good, 320, 240, 0);
    // An ICC profile that inflates to 500 MB.
    let bytes = std::fs::read(&good).unwrap();
    let ihdr_end = 8 + 8 + 13 + 4;
    let mut iccp = b"bomb\0\0".to_vec();
    iccp.extend(zlib_zeros(500 << 20));
    let mut bomb = bytes[..ihdr_end].to_vec();
    bomb.extend(chunk(b"iCCP", &iccp));
    bomb.extend_from_slice(&bytes[ihdr_end..]);
    let icc = d.path().join("icc.png");
    std::fs::write(&icc, bomb).unwrap();
    let out = d.path().join("out.jpg");
    // The decoder gives up on the profile within its 16 MiB for ancillary data and reads the
    // pixels: the frame fuses, in little memory.
    let r = fuse(&[good.clone(), icc.clone()], &out, &[]);
    assert!(r.status.success(), "{}", r.stderr);
    assert!(r.max_rss_kib < REFUSED_RSS_KIB, "{} KiB", r.max_rss_kib);
    std::fs::remove_file(&out).unwrap();
    // Two tiny PNGs that declare 144 MP each: refused from their headers, naming the budget
    // they need.
    let big: Vec<PathBuf> = (0..2)
        .map(|i| d.path().join(format!("big{i}.png")))
        .collect();
    for f in &big {
        let mut ihdr = 12_000u32.to_be_bytes().to_vec();
        ihdr.extend(12_000u32.to_be_bytes());
        ihdr.extend([8, 2, 0, 0, 0]);
        let mut p = b"\x89PNG\r\n\x1a\n".to_vec();
        p.extend(chunk(b"IHDR", &ihdr));
        p.extend(chunk(b"IDAT", &zlib_zeros(1000)));
        p.extend(chunk(b"IEND", &[]));
        std::fs::write(f, p).unwrap();
    }
    refused(
        &fuse(&big, &out, &["--memory", "64"]),
        &["--memory", "12000x12000"],
    );
    assert!(!out.exists());
    no_temp_files(d.path());
}

#[test]
fn float_and_multipage_tiffs_are_refused_by_name() {
    use tiff::encoder::{colortype, TiffEncoder};
    let d = tempfile::tempdir().unwrap();
    let good = d.path().join("good.tif");
    png(&d.path().join("g.png"), 64, 48, 0);
    image::open(d.path().join("g.png"))
        .unwrap()
        .save(&good)
        .unwrap();
    let float = d.path().join("float.tif");
    let mut e = TiffEncoder::new(std::fs::File::create(&float).unwrap()).unwrap();
    let data: Vec<f32> = (0..64 * 48 * 3).map(|i| (i % 7) as f32 * 0.4).collect();
    e.write_image::<colortype::RGB32Float>(64, 48, &data)
        .unwrap();
    let pages = d.path().join("pages.tif");
    let mut e = TiffEncoder::new(std::fs::File::create(&pages).unwrap()).unwrap();
    e.write_image::<colortype::RGB8>(8, 6, &[0u8; 8 * 6 * 3])
        .unwrap();
    e.write_image::<colortype::RGB8>(64, 48, &[9u8; 64 * 48 * 3])
        .unwrap();
    let out = d.path().join("out.tif");
    refused(
        &fuse(&[good.clone(), float], &out, &[]),
        &["float.tif", "floating point"],
    );
    refused(
        &fuse(&[good, pages], &out, &[]),
        &["pages.tif", "multipage"],
    );
}

#[test]
fn outputs_never_clobber_inputs_and_land_all_or_nothing() {
    let d = tempfile::tempdir().unwrap();
    let frames: Vec<PathBuf> = (0..3).map(|i| d.path().join(format!("f{i}.png"))).collect();
    for (i, f) in frames.iter().enumerate() {
        png(f, 48, 32, i as u32);
    }
    let before = std::fs::read(&frames[1]).unwrap();
    let out = d.path().join("out.png");
    // -o naming an input, and --depthmap naming one through a link and another spelling.
    let link = d.path().join("link.png");
    std::os::unix::fs::symlink(&frames[1], &link).unwrap();
    let odd = d.path().join(".").join("f1.png");
    refused(&fuse(&frames, &frames[1], &[]), &["f1.png", "is the input"]);
    for depth in [&link, &odd] {
        let r = fuse(&frames, &out, &["--depthmap", depth.to_str().unwrap()]);
        refused(&r, &["is the input"]);
        assert!(!out.exists(), "the image landed without its depth map");
    }
    assert_eq!(std::fs::read(&frames[1]).unwrap(), before);
    // A depth map that cannot be written: checked before the work, nothing lands.
    let r = fuse(&frames, &out, &["--depthmap", "/nonexistent-dir/d.png"]);
    refused(&r, &["/nonexistent-dir", "does not exist"]);
    assert!(!out.exists());
    no_temp_files(d.path());
    // A legal 246-byte name: its temporary name must fit in 255 bytes too.
    let long = d.path().join(format!("{}.png", "x".repeat(242)));
    let r = fuse(&frames, &long, &[]);
    assert!(r.status.success(), "{}", r.stderr);
    assert!(long.exists());
    no_temp_files(d.path());
}

#[test]
fn an_error_about_a_huge_name_is_cut_to_a_sane_length() {
    let b = bundle();
    let name = "n".repeat(500_000);
    let toml = std::fs::read_to_string(b.path().join("bundle.toml")).unwrap();
    std::fs::write(
        b.path().join("bundle.toml"),
        toml.replacen("\"frame_00.jpg\"", &format!("\"{name}.jpg\""), 1),
    )
    .unwrap();
    let r = capture(b.path());
    refused(&r, &["take 0 of plane 0", "more bytes cut"]);
    assert!(r.stderr.len() < 5000, "{} bytes", r.stderr.len());
}
