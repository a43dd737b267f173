//! glibc allocator settings and huge pages for a process whose working set is a few very large
//! buffers.

use std::alloc::{GlobalAlloc, Layout, System};

/// Serves every allocation of 1 MiB or more with its own mapping, unmapped when freed. glibc's
/// default raises that threshold to the size of the largest buffer freed so far, after which
/// frames and planes come from the heap, where a freed plane between two live ones cannot be
/// returned and the peak grows.
///
/// Keeps up to 4 MiB free at the top of each heap instead of glibc's 128 KiB: the stages free
/// and allocate planes under 1 MiB again and again, and a smaller threshold hands the pages
/// back only for the next allocation to fault them in again, zeroed, in the kernel's time.
pub fn tune() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes allocator parameters; called before any other thread.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
            libc::mallopt(libc::M_TRIM_THRESHOLD, 4 << 20);
        }
    }
}

/// Hands memory freed by the last stage back to the OS. glibc keeps what rayon's worker threads
/// free in their own arenas, so without this the resident memory stays well above the working
/// set. Costs a few milliseconds per stage. Every progress reporter (the CLI's bar, the
/// daemon's) calls it when a stage begins, so the engine stays free of allocator calls.
pub fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free heap pages; it is safe to call at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// The system allocator, with the whole huge pages inside every buffer of 2 MiB or more
/// ([`whole_pages`]) marked for transparent huge pages (`madvise(MADV_HUGEPAGE)`) before it
/// is first touched. Frames and planes are mapped afresh for each stage (see [`tune`]) and
/// would otherwise be faulted in 4 KiB at a time, a large share of a fuse's CPU spent in the
/// kernel; 2 MiB pages cut the faults several-fold, for the same peak memory.
///
/// Kernels that default to `madvise` for huge pages (Debian's) give them only when asked; where
/// there are none the call fails and nothing changes, and where memory is too fragmented for
/// one the kernel falls back to small pages. glibc can do the same
/// (`GLIBC_TUNABLES=glibc.malloc.hugetlb=1`), but only from the environment the process started
/// in; no allocator crate offers it for the system allocator.
pub struct HugePages;

/// A huge page on x86-64 and on arm64 with 4 KiB pages.
const HUGE_PAGE: usize = 2 << 20;

// SAFETY: every call is passed through to `System` unchanged; `advise` only adds a hint on
// memory `System` has just handed out.
unsafe impl GlobalAlloc for HugePages {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: our caller's guarantees for `layout` are `System`'s.
        let p = unsafe { System.alloc(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: our caller's guarantees for `layout` are `System`'s.
        let p = unsafe { System.alloc_zeroed(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System` through this allocator, with this `layout`.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: `ptr` came from `System` through this allocator, with this `layout`; our
        // caller's guarantees for `new_size` are `System`'s.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        advise(p, new_size);
        p
    }
}

/// Asks for huge pages over the whole huge pages inside `size` bytes at `p` ([`whole_pages`]).
fn advise(p: *mut u8, size: usize) {
    #[cfg(target_os = "linux")]
    if let Some(pages) = whole_pages(p as usize, size) {
        // SAFETY: the range lies inside the allocation just made; MADV_HUGEPAGE changes no
        // contents, and its failure (no huge pages in this kernel) is harmless.
        unsafe {
            libc::madvise(
                pages.start as *mut libc::c_void,
                pages.len(),
                libc::MADV_HUGEPAGE,
            );
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (p, size);
}

/// The whole huge pages inside `size` bytes from address `at`; `None` for a null buffer or one
/// that holds none (glibc's mappings start anywhere on a 4 KiB boundary). Buffers of one to
/// two huge pages are asked too: a 1.2 MP colour frame (3.7 MB) or a 3 MP frame's half-size
/// float plane (3.1 MB) most often holds one, half or more of its faults: asking from one
/// huge page up takes fewer faults and less system time, for the same peak memory.
fn whole_pages(at: usize, size: usize) -> Option<std::ops::Range<usize>> {
    if at == 0 || size < HUGE_PAGE {
        return None;
    }
    let start = at.next_multiple_of(HUGE_PAGE);
    let end = (at + size) / HUGE_PAGE * HUGE_PAGE;
    (start < end).then_some(start..end)
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    /// `AnonHugePages` of the mapping in `/proc/self/smaps` that holds `p`, in KiB.
    fn huge_kib_at(p: *const u8) -> Option<usize> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").ok()?;
        let addr = p as usize;
        let mut inside = false;
        for line in smaps.lines() {
            let first = line.split_whitespace().next().unwrap_or_default();
            if let Some((lo, hi)) = first.split_once('-') {
                if let (Ok(lo), Ok(hi)) =
                    (usize::from_str_radix(lo, 16), usize::from_str_radix(hi, 16))
                {
                    inside = (lo..hi).contains(&addr);
                    continue;
                }
            }
            if inside {
                if let Some(kib) = line.strip_prefix("AnonHugePages:") {
                    return kib.trim().trim_end_matches("kB").trim().parse().ok();
                }
            }
        }
        None
    }

    #[test]
    fn only_whole_huge_pages_of_big_buffers_are_advised() {
        const H: usize = HUGE_PAGE;
        assert_eq!(whole_pages(H + 16, 3 * H), Some(2 * H..4 * H));
        assert_eq!(whole_pages(2 * H, 2 * H), Some(2 * H..4 * H));
        assert_eq!(whole_pages(H + 16, 2 * H), Some(2 * H..3 * H));
        assert_eq!(
            whole_pages(H + 16, 2 * H - 1),
            Some(2 * H..3 * H),
            "one in under two"
        );
        assert_eq!(whole_pages(2 * H, H), Some(2 * H..3 * H), "exactly one");
        assert_eq!(whole_pages(H + 16, 3 * H / 2), None, "none inside");
        assert_eq!(whole_pages(16, H - 16), None, "smaller than one");
        assert_eq!(whole_pages(0, 8 * H), None, "null");
    }

    /// Where the kernel gives huge pages only when asked (`[madvise]`, Debian's default), a
    /// 16 MiB buffer from [`HugePages`] is backed by some once written; asked for nothing, it
    /// would have none. Elsewhere (`[always]`, `[never]`, no huge pages) there is nothing to
    /// tell apart.
    #[test]
    fn a_big_buffer_is_backed_by_huge_pages_when_the_kernel_waits_to_be_asked() {
        let mode = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled");
        // Under user-mode emulation (the arm64 tests in qemu) the advice never reaches the
        // kernel, whose architecture is then not this build's.
        let native = std::fs::read_to_string("/proc/sys/kernel/arch")
            .is_ok_and(|a| a.trim() == std::env::consts::ARCH);
        if !native || !mode.is_ok_and(|m| m.contains("[madvise]")) {
            return;
        }
        let layout = Layout::from_size_align(16 << 20, 64).unwrap();
        // SAFETY: a non-zero layout; the buffer is written within its size and freed once.
        unsafe {
            let p = HugePages.alloc(layout);
            assert!(!p.is_null());
            std::ptr::write_bytes(p, 1, layout.size());
            // The advice splits the mapping: its huge part starts at the first whole huge page.
            let huge = huge_kib_at(p.add(p.align_offset(HUGE_PAGE)));
            HugePages.dealloc(p, layout);
            assert!(
                huge.is_some_and(|kib| kib >= 2048),
                "AnonHugePages {huge:?} KiB"
            );
        }
    }
}
