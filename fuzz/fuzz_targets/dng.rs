//! A DNG frame, as `fuse` gets it from anyone: any bytes either decode to a raw frame or give
//! an error, and a decode never allocates more than a small multiple of the file's size (the
//! pixel data must be in the file before it is unpacked).
#![no_main]

use focusd::files::dng::decode;
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

fuzz_target!(|data: &[u8]| {
    let before = LIVE.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let decoded = decode(data);
    let peak = PEAK.load(Ordering::Relaxed) - before;
    // Two directories' entries, the samples and the frame's bytes (each at most twice the
    // file, a growing vector twice that), and a little for messages.
    let bound = 24 * data.len() + (1 << 20);
    assert!(peak <= bound, "{peak} bytes for a {}-byte file", data.len());
    if let Ok(d) = decoded {
        assert!(d.raw.width >= 2 && d.raw.height >= 2);
        assert!(d.raw.mosaic().is_ok());
    }
});
