//! A frame file, as `fuse` gets it from anyone and a bundle from another machine: any bytes
//! either decode or give an error, and a decode never allocates much more than its header
//! declares (pixels, the conversions' copies and 16 MiB of ancillary data).
#![no_main]

use focusd::files::imageio::{load, probe};
use libfuzzer_sys::fuzz_target;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Counts the bytes live on the heap and their peak since the last reset.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator; the counters do not change what it returns.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
        PEAK.fetch_max(live, Ordering::Relaxed);
        // SAFETY: the caller's layout, passed on.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: `ptr` came from `alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

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
    let before = LIVE.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let decoded = load(&path);
    let peak = PEAK.load(Ordering::Relaxed) - before;
    // The decoder's buffer at up to 4 channels of 16 bits, the converted copy and the frame,
    // the file for a JPEG (read into a growing buffer), and the ancillary allowance.
    let pixels = h.width * h.height;
    let bound = pixels * 8 * 3 + pixels * 16 + 2 * data.len() + (48 << 20);
    assert!(peak <= bound, "{peak} bytes for a {}x{} frame", h.width, h.height);
    if let Ok(d) = decoded {
        assert_eq!(d.dimensions(), (h.width, h.height));
    }
});
