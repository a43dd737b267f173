//! The focus order read from occlusion edges (`stack::order`) through the whole fuse, on
//! simulated stacks of known order: a layered stack is found nearest first, the same frames
//! reversed farthest first, and stacks without depth steps decide nothing.

use focusd::sim::flats::{flats, FlatsParams};
use focusd::sim::{render, SimParams};
use focusd::stack::internal::gaussian_blur_channels;
use focusd::stack::{fuse, middle_frame, FuseParams, Image, NoProgress, Order, OrderEvidence};
use std::path::{Path, PathBuf};
use std::process::Command;

fn order_of(frames: Vec<Image<u8>>, align: bool) -> OrderEvidence {
    let mut params = FuseParams {
        reference: middle_frame(frames.len()),
        ..FuseParams::default()
    };
    if !align {
        params.align = None;
    }
    let e = fuse(frames, &params, &NoProgress).unwrap().order;
    eprintln!("{e}");
    e
}

/// Either way round, on a tripod stack mixed in linear light and on a hand-held one with
/// parallax, which the fuse aligns first (each frame's edges are then read where the warp put
/// them).
#[test]
fn layered_stacks_are_told_either_way_round() {
    for (handheld, seed) in [(false, 3), (true, 4)] {
        let s = render(&SimParams {
            width: 400,
            height: 300,
            seed,
            handheld,
            parallax_px: 3.0,
            linear_light: true,
            ..SimParams::default()
        });
        let n = s.frames.len();
        let e = order_of(s.frames.clone(), handheld);
        assert_eq!(e.order, Order::NearestFirst, "{e:?}");
        let r = order_of(s.frames.into_iter().rev().collect(), handheld);
        assert_eq!(r.order, Order::FarthestFirst, "{r:?}");
        assert_eq!(
            r.order.frame_at(0, n),
            n - 1,
            "the nearest is the last frame"
        );
    }
}

/// Flats (textured patches on a smooth field, no occlusion) and a single textured plane seen
/// at five focus settings have no depth steps to read.
#[test]
fn stacks_without_depth_steps_decide_nothing() {
    let e = order_of(
        flats(&FlatsParams {
            width: 320,
            height: 240,
            frames: 8,
            ..FlatsParams::default()
        }),
        false,
    );
    assert_eq!(e.order, Order::Unknown, "flats: {e:?}");

    let truth = render(&SimParams {
        width: 640,
        height: 480,
        ..SimParams::default()
    })
    .truth
    .convert::<f32>();
    let plane: Vec<Image<u8>> = (0..5)
        .map(|i: usize| gaussian_blur_channels(&truth, 2.0 * i.abs_diff(2) as f32).convert())
        .collect();
    let e = order_of(plane, false);
    assert_eq!(e.order, Order::Unknown, "single plane: {e:?}");
    assert_eq!(e.order.assumed(), Order::NearestFirst);
}

/// `focusd fuse` says in its log which order it found: the committed aligned stack (nearest
/// first) as given and reversed.
#[test]
fn the_fuse_log_names_the_order() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("sim-data/aligned");
    let frames: Vec<PathBuf> = (0..6)
        .map(|i| dir.join(format!("frame_{i:02}.jpg")))
        .collect();
    let out = tempfile::tempdir().unwrap();
    let log = |frames: &mut dyn Iterator<Item = &PathBuf>| {
        let o = Command::new(env!("CARGO_BIN_EXE_focusd"))
            .args(["fuse", "--no-align", "-o"])
            .arg(out.path().join("out.png"))
            .args(frames)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{err}");
        err
    };
    let order_line = |err: &str| {
        err.lines()
            .find(|l| l.starts_with("  order "))
            .unwrap_or_else(|| panic!("no order line in {err}"))
            .to_string()
    };
    let forward = order_line(&log(&mut frames.iter()));
    assert!(
        forward.starts_with("  order nearest focus first ("),
        "{forward}"
    );
    let reversed = order_line(&log(&mut frames.iter().rev()));
    assert!(
        reversed.starts_with("  order farthest focus first ("),
        "{reversed}"
    );
}
