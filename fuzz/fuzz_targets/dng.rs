//! A DNG frame, as `fuse` gets it from anyone: any bytes either decode to a raw frame or give
//! an error, and a decode never allocates more than a small multiple of the file's size (the
//! pixel data must be in the file before it is unpacked).
#![no_main]

use focusd::files::dng::decode;
use libfuzzer_sys::fuzz_target;

mod counting;

fuzz_target!(|data: &[u8]| {
    let before = counting::start();
    let decoded = decode(data);
    let peak = counting::peak_since(before);
    // Two directories' entries, the samples and the frame's bytes (each at most twice the
    // file, a growing vector twice that), and a little for messages.
    let bound = 24 * data.len() + (1 << 20);
    assert!(peak <= bound, "{peak} bytes for a {}-byte file", data.len());
    if let Ok(d) = decoded {
        assert!(d.raw.width >= 2 && d.raw.height >= 2);
        assert!(d.raw.mosaic().is_ok());
    }
});
