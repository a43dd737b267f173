//! Raw stacks developed lazily: cheaply in whole for registration, labels, spill and the
//! coarse blending, in full only where the output keeps a frame's finest levels. Against
//! developing every frame in full: the fused picture within 0.1 dB of it against the truth on
//! simulated stacks, sharp and through a lens blur, for at most two frames' worth of full
//! development on a 10-frame stack. (The real stacks' figures: `benches/tools/lazy_develop.rs`.)

use focusd::develop::raw::Packing;
use focusd::develop::{decode, encode, BayerOrder, Developer, Mosaic, RawFrame, RawLayout};
use focusd::develop::{RawStack, IDENTITY};
use focusd::sim::{render, SimParams};
use focusd::stack::internal::gaussian_blur_channels;
use focusd::stack::{fuse, fuse_developing, psnr, FuseParams, Image, NoProgress};

/// A linear-light frame as a sensor records it: a 16-bit mosaic, black level 0.
fn raw(rgb: &Image<f32>, order: BayerOrder) -> RawFrame {
    let m = Mosaic::sample(rgb, order);
    let bytes: Vec<u8> = m
        .data
        .iter()
        .flat_map(|&v| ((v.clamp(0.0, 1.0) * 65535.0).round() as u16).to_le_bytes())
        .collect();
    let layout = RawLayout {
        packing: Packing::Le16,
        width: m.width,
        height: m.height,
        stride: 0,
        order,
        black_level: 0,
        matrix: IDENTITY,
    };
    RawFrame {
        // Camera RGB is the scene's linear sRGB.
        white_balance: Some([1.0; 3]),
        ..RawFrame::copy(&bytes, layout).expect("a whole frame")
    }
}

/// Fuses `frames` developed in full and lazily; returns the two fused pictures and the pixels
/// the lazy development developed in full. White balance locked at 1 (the simulator has no
/// colour cast, and the real frames are developed already).
fn both_ways(frames: &[RawFrame], params: &FuseParams) -> (Image<u8>, Image<u8>, usize) {
    let mut dev = Developer::new(0, IDENTITY);
    dev.white_balance = Some([1.0; 3]);
    let full: Vec<Image<u8>> = frames
        .iter()
        .map(|f| dev.develop(f.mosaic().expect("unpacks")))
        .collect();
    let full = fuse(full, params, &NoProgress).expect("fuses");
    let stack = RawStack::new(frames.to_vec()).expect("a stack");
    let lazy = fuse_developing(&stack, params, &NoProgress).expect("fuses");
    let developed = lazy.developed.expect("counted").pixels;
    (full.image, lazy.image, developed)
}

#[test]
fn lazy_development_of_simulated_stacks_is_within_0_1_db_of_developing_all() {
    for (seed, handheld) in [(5u64, true)] {
        let p = SimParams {
            width: 1024,
            height: 768,
            planes: 10,
            seed,
            handheld,
            linear_light: true,
            ..SimParams::default()
        };
        let s = render(&p);
        for sigma in [0.0, 0.5] {
            let linear = |f: &Image<u8>| gaussian_blur_channels(&decode(f), sigma);
            let frames: Vec<RawFrame> = s
                .frames
                .iter()
                .map(|f| raw(&linear(f), BayerOrder::Grbg))
                .collect();
            let truth = encode(&linear(&s.truth));
            let params = FuseParams {
                reference: p.reference(),
                ..FuseParams::default()
            };
            let (full, lazy, developed) = both_ways(&frames, &params);
            let (full_db, lazy_db) = (psnr(&full, &truth, 24), psnr(&lazy, &truth, 24));
            let worth = developed as f64 / (p.width * p.height) as f64;
            eprintln!(
                "seed {seed} hand-held {handheld} blur {sigma}: all developed {full_db:.3} dB, \
                 lazily {lazy_db:.3} dB, {worth:.2} frames' worth developed in full, {:.2} dB \
                 between the two",
                psnr(&full, &lazy, 8)
            );
            assert!(
                lazy_db >= full_db - 0.1,
                "seed {seed} blur {sigma}: lazily {lazy_db:.3} dB, all {full_db:.3} dB"
            );
            assert!(
                worth <= 2.0,
                "seed {seed}: {worth:.2} frames developed in full"
            );
            assert!(
                worth > 0.5,
                "seed {seed}: only {worth:.2} frames developed in full"
            );
        }
    }
}
