//! A frame file, as `fuse` gets it from anyone and a bundle from another machine: any bytes
//! either decode or give an error, and a decode never allocates much more than its header
//! declares (pixels, the conversions' copies and 16 MiB of ancillary data).
#![no_main]

use focusd::files::imageio::{load, probe};
use libfuzzer_sys::fuzz_target;

mod counting;

/// Headers above this are skipped: the fuzzer would spend its time filling huge buffers.
const MAX_FUZZ_PIXELS: usize = 1 << 22;

fuzz_target!(|data: &[u8]| {
    let dir = std::env::temp_dir().join(format!("focusd-fuzz-image-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("frame");
    if std::fs::write(&path, data).is_err() {
        return;
    }
    let Ok(h) = probe(&path) else {
        assert!(load(&path).is_err(), "probe refused what load took");
        return;
    };
    if h.width * h.height > MAX_FUZZ_PIXELS {
        return;
    }
    let before = counting::start();
    let decoded = load(&path);
    let peak = counting::peak_since(before);
    // The decoder's buffer at up to 4 channels of 16 bits, the converted copy and the frame,
    // the file for a JPEG (read into a growing buffer), and the ancillary allowance.
    let pixels = h.width * h.height;
    let bound = pixels * 8 * 3 + pixels * 16 + 2 * data.len() + (48 << 20);
    assert!(peak <= bound, "{peak} bytes for a {}x{} frame", h.width, h.height);
    if let Ok(d) = decoded {
        assert_eq!(d.dimensions(), (h.width, h.height));
    }
});
