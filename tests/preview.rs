//! The live preview on a private bus, replaying the committed bundles: frames arrive and are
//! the bundle's reference frame, the shared memory cannot be resized or written by a client,
//! a capture pauses the preview and it comes back, a client that never reads costs nothing,
//! and the preview stops (freeing its memory) when the last client leaves or it times out.

mod common;

use common::daemon::{connect, outcome, runtime, subscribe, Bus, Daemon};
use common::stacks::{bundle_dir, load};
use focusd::service::preview::ring::{RingReader, State};
use std::os::fd::{AsFd, OwnedFd};
use std::time::{Duration, Instant};

/// Waits until `what` holds, for at most 20 s.
async fn until(what: &str, mut f: impl FnMut() -> bool) {
    let t = Instant::now();
    while !f() {
        assert!(t.elapsed() < Duration::from_secs(20), "never: {what}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

fn memfd_maps(pid: u32) -> usize {
    std::fs::read_to_string(format!("/proc/{pid}/maps"))
        .unwrap()
        .lines()
        .filter(|l| l.contains("focusd-preview"))
        .count()
}

/// The daemon's resident memory, KiB.
fn rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

#[test]
fn frames_arrive_as_the_reference_frame_in_memory_a_client_cannot_resize_or_write() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("calm"), false);
    // Six planes: the reference is the middle plane, 2, whose take is frame_02.jpg.
    let reference = load(&bundle_dir("calm").join("frame_02.jpg"));
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        assert_eq!(
            memfd_maps(d.child.id()),
            0,
            "preview memory before any client"
        );
        let fd: OwnedFd = proxy.start_preview().await.unwrap().into();
        let ring = RingReader::new(&fd).unwrap();
        until("ten frames", || ring.sequence() >= 10).await;
        assert_eq!(ring.state(), Some(State::Running));
        let f = ring.latest().unwrap();
        assert_eq!((f.width, f.height, f.stride), (480, 360, 1440));
        assert!(
            f.pixels == reference.data(),
            "the frame is not frame_02.jpg"
        );
        assert_eq!(memfd_maps(d.child.id()), 1);

        // Sealed: no resize, no writes through a new mapping or write(2), no seal removal.
        let seals = rustix::fs::fcntl_get_seals(&fd).unwrap();
        use rustix::fs::SealFlags;
        let want = SealFlags::SHRINK | SealFlags::GROW | SealFlags::FUTURE_WRITE | SealFlags::SEAL;
        assert!(seals.contains(want), "{seals:?}");
        let size = rustix::fs::fstat(&fd).unwrap().st_size as u64;
        for to in [0, size / 2, size * 2] {
            let e = rustix::fs::ftruncate(&fd, to).unwrap_err();
            assert_eq!(e, rustix::io::Errno::PERM, "ftruncate to {to}");
        }
        let e = rustix::io::write(&fd, b"x").unwrap_err();
        assert_eq!(e, rustix::io::Errno::PERM);
        // SAFETY: a new mapping the kernel must refuse; nothing is mapped when it does.
        let mapped = unsafe {
            rustix::mm::mmap(
                std::ptr::null_mut(),
                4096,
                rustix::mm::ProtFlags::READ | rustix::mm::ProtFlags::WRITE,
                rustix::mm::MapFlags::SHARED,
                fd.as_fd(),
                0,
            )
        };
        assert_eq!(mapped.unwrap_err(), rustix::io::Errno::PERM);
        let e = rustix::fs::fcntl_add_seals(&fd, SealFlags::WRITE).unwrap_err();
        assert_eq!(e, rustix::io::Errno::PERM);
        // Still the same frames.
        let before = ring.sequence();
        until("more frames", || ring.sequence() > before + 3).await;
        assert!(ring.latest().unwrap().pixels == reference.data());
    });
}

#[test]
fn a_capture_pauses_the_preview_and_it_comes_back() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("shaken"), true);
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let fd: OwnedFd = proxy.start_preview().await.unwrap().into();
        let ring = RingReader::new(&fd).unwrap();
        until("frames", || ring.sequence() >= 3).await;
        let (finished, failed) = subscribe(&proxy).await;
        let job = proxy.capture().await.unwrap();
        until("paused", || ring.state() == Some(State::Paused)).await;
        let paused_at = ring.sequence();
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(ring.sequence(), paused_at, "frames while a capture ran");
        assert_eq!(ring.state(), Some(State::Paused));
        assert_ne!(proxy.state().await.unwrap(), "idle");
        outcome(&job, finished, failed).await.unwrap();
        until("running again", || ring.state() == Some(State::Running)).await;
        until("new frames", || ring.sequence() > paused_at + 3).await;
    });
    assert!(d.log().contains("preview: client added"), "{}", d.log());
}

#[test]
fn a_client_that_never_reads_costs_nothing() {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &bundle_dir("calm"), false);
    let pid = d.child.id();
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let fd: OwnedFd = proxy.start_preview().await.unwrap().into();
        let ring = RingReader::new(&fd).unwrap();
        // Every slot written once, so the ring's pages count from here on.
        until("a lap of the ring", || ring.sequence() >= 6).await;
        let (seq, rss) = (ring.sequence(), rss_kib(pid));
        tokio::time::sleep(Duration::from_secs(4)).await;
        let (seq2, rss2) = (ring.sequence(), rss_kib(pid));
        // ~60 frames of 506 KiB went by unread: one kept per frame would be ~30 MiB.
        assert!(seq2 >= seq + 30, "{seq} -> {seq2} frames");
        assert!(rss2 < rss + 2048, "resident {rss} KiB -> {rss2} KiB");
    });
}

#[test]
fn the_preview_stops_with_its_last_client_and_when_it_times_out() {
    let bus = Bus::start();
    let d = Daemon::start_full(
        &bus,
        Some(&bundle_dir("calm")),
        false,
        &[],
        "[service]\npreview_timeout_s = 2\n",
        &[],
    );
    let pid = d.child.id();
    runtime().block_on(async {
        // Two clients: the first leaving the bus leaves the preview running for the second.
        let (first_conn, first) = connect(&bus).await;
        let (_conn, second) = connect(&bus).await;
        let fd: OwnedFd = first.start_preview().await.unwrap().into();
        let ring = RingReader::new(&fd).unwrap();
        let _also: OwnedFd = second.start_preview().await.unwrap().into();
        drop(first);
        drop(first_conn);
        until("the first client gone", || d.log().contains("left the bus")).await;
        let now = ring.sequence();
        until("frames for the second", || ring.sequence() > now + 3).await;
        // The second stops it: no more frames, no memory, no open source.
        second.stop_preview().await.unwrap();
        until("stopped", || ring.state() == Some(State::Stopped)).await;
        until("memory freed", || memfd_maps(pid) == 0).await;
        assert!(
            d.log()
                .contains("preview stopped: its last client stopped it"),
            "{}",
            d.log()
        );
        let e = second.stop_preview().await.unwrap_err();
        assert!(e.to_string().contains("no preview to stop"), "{e}");

        // A client that leaves without a word stops it as well.
        let (conn, third) = connect(&bus).await;
        let fd: OwnedFd = third.start_preview().await.unwrap().into();
        let ring = RingReader::new(&fd).unwrap();
        until("frames", || ring.sequence() > 0).await;
        drop(third);
        drop(conn);
        until("stopped", || ring.state() == Some(State::Stopped)).await;
        until("memory freed", || memfd_maps(pid) == 0).await;

        // One that stays but does not renew it: stopped after preview_timeout_s.
        let fd: OwnedFd = second.start_preview().await.unwrap().into();
        let ring = RingReader::new(&fd).unwrap();
        let t = Instant::now();
        until("timed out", || ring.state() == Some(State::Stopped)).await;
        assert!(t.elapsed() >= Duration::from_secs(1), "{:?}", t.elapsed());
        until("memory freed", || memfd_maps(pid) == 0).await;
        assert!(d.log().contains("no client renewed it"), "{}", d.log());
    });
}

#[test]
fn a_preview_that_cannot_open_says_why_in_its_memory_and_a_new_start_tries_again() {
    // The calm bundle with its reference frame replaced by a FIFO, which the preview refuses
    // on its own thread; StartPreview answers with the memory at once.
    let bundle = tempfile::tempdir().unwrap();
    for f in std::fs::read_dir(bundle_dir("calm")).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, bundle.path().join(f.file_name().unwrap())).unwrap();
    }
    let reference = bundle.path().join("frame_02.jpg");
    let jpeg = std::fs::read(&reference).unwrap();
    std::fs::remove_file(&reference).unwrap();
    rustix::fs::mknodat(
        rustix::fs::CWD,
        &reference,
        rustix::fs::FileType::Fifo,
        rustix::fs::Mode::from_raw_mode(0o600),
        0,
    )
    .unwrap();
    let bus = Bus::start();
    let _d = Daemon::start(&bus, bundle.path(), false);
    runtime().block_on(async {
        let (_conn, proxy) = connect(&bus).await;
        let fd: OwnedFd = proxy.start_preview().await.unwrap().into();
        let ring = RingReader::new(&fd).unwrap();
        until("failed", || ring.state() == Some(State::Failed)).await;
        let why = ring.error().unwrap();
        assert!(
            why.contains("frame_02.jpg") && why.contains("not a regular file"),
            "{why}"
        );
        assert_eq!(ring.sequence(), 0);
        // The frame back in place: the next StartPreview opens a new memory with frames.
        std::fs::remove_file(&reference).unwrap();
        std::fs::write(&reference, &jpeg).unwrap();
        let fd: OwnedFd = proxy.start_preview().await.unwrap().into();
        let again = RingReader::new(&fd).unwrap();
        until("frames", || again.sequence() >= 1).await;
        assert_eq!(again.state(), Some(State::Running));
        assert_eq!(ring.state(), Some(State::Failed));
    });
}
