//! LibRaw's tools (Debian's `libraw-bin`), the independent reader of the DNGs focusd writes.

use std::path::Path;
use std::process::Command;

/// Whether LibRaw's tools are here; under CI they must be.
pub fn libraw() -> bool {
    let here = ["raw-identify", "unprocessed_raw", "dcraw_emu"]
        .iter()
        .all(|t| Command::new(t).output().is_ok());
    if !here {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "LibRaw's tools are needed (apt-get install libraw-bin)"
        );
        eprintln!("skipped: LibRaw's tools are not installed (apt-get install libraw-bin)");
    }
    here
}

/// Runs `tool` on `file`; its output, stdout then stderr. Fails the test if the tool does.
pub fn run(tool: &str, args: &[&str], file: &Path) -> String {
    let o = Command::new(tool)
        .args(args)
        .arg(file)
        .output()
        .expect(tool);
    let out = String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{tool} {args:?}: {out}");
    out
}

/// A 16-bit TIFF LibRaw wrote: width, height, channels and samples.
pub fn read_tiff(path: &Path) -> (usize, usize, usize, Vec<u16>) {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let (w, h) = (img.width() as usize, img.height() as usize);
    let c = usize::from(img.color().channel_count());
    let data = match img {
        image::DynamicImage::ImageLuma16(i) => i.into_raw(),
        image::DynamicImage::ImageRgb16(i) => i.into_raw(),
        other => panic!("{}: {:?}, not 16-bit", path.display(), other.color()),
    };
    (w, h, c, data)
}
