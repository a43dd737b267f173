//! Fusion of hand-held stacks (registration, exposure, coverage, crop) against ground truth.

use focusd::sim::{render, SimParams, SimStack};
use focusd::stack::internal::{warp_frame, Plane, Warp};
use focusd::stack::{fuse, psnr, Coverage, Exposure, FuseParams, Image, NoProgress, Placement};

/// A hand-held stack at the limits focusd is built for: shift up to 3% of the width, roll up to 1.5°,
/// breathing ±1%, gain ±5%, white balance ±3%, a pixel of parallax.
fn handheld(seed: u64) -> SimStack {
    render(&SimParams {
        width: 640,
        height: 480,
        planes: 6,
        seed,
        handheld: true,
        gain_jitter: 0.05,
        wb_jitter: 0.03,
        ..SimParams::default()
    })
}

/// Each frame warped with its true affine and exposure, each pixel copied from the frame focused
/// at its true depth.
fn oracle(s: &SimStack) -> Image<u8> {
    let r = &s.frames[s.reference];
    let mut out = r.clone();
    for (i, f) in s.frames.iter().enumerate() {
        let truth: Vec<Exposure> = s.info[i]
            .white_balance
            .iter()
            .map(|b| Exposure {
                gain: (b * s.info[i].gain) as f32,
                offset: 0.0,
            })
            .collect();
        let (warped, _) = warp_frame(f, r, &Warp::affine(s.ref_to_frame[i]), &truth);
        for (p, &d) in s.depth.data().iter().enumerate() {
            if d as usize == i {
                out.data_mut()[p * 3..p * 3 + 3].copy_from_slice(&warped.data()[p * 3..p * 3 + 3]);
            }
        }
    }
    out
}

fn params(s: &SimStack) -> FuseParams {
    FuseParams {
        reference: s.reference,
        ..FuseParams::default()
    }
}

#[test]
fn handheld_fusion_is_within_1_5_db_of_the_warped_oracle() {
    for seed in [21, 22] {
        let s = handheld(seed);
        let fused = fuse(s.frames.clone(), &params(&s), &NoProgress).unwrap();
        let got = psnr(&fused.image, &s.truth, 0);
        let best = psnr(&oracle(&s), &s.truth, 0);
        let unaligned = FuseParams {
            align: None,
            ..params(&s)
        };
        let raw = psnr(
            &fuse(s.frames.clone(), &unaligned, &NoProgress)
                .unwrap()
                .image,
            &s.truth,
            0,
        );
        eprintln!("seed {seed}: fused {got:.2} dB, oracle {best:.2} dB, unaligned {raw:.2} dB");
        assert!(
            got >= best - 1.5,
            "seed {seed}: {got:.2} dB, oracle {best:.2}"
        );
        // The registration is what makes the difference.
        assert!(
            got > raw + 3.0,
            "seed {seed}: {got:.2} dB vs {raw:.2} unaligned"
        );
        // Exposure and white balance are measured, per channel.
        let al = fused.alignment.unwrap();
        for (i, e) in al.exposure.iter().enumerate() {
            for (c, e) in e.iter().enumerate() {
                let truth = s.info[i].gain * s.info[i].white_balance[c];
                assert!(
                    (e.gain as f64 - truth).abs() < 0.01,
                    "frame {i} channel {c}: gain {} vs {truth:.4}",
                    e.gain
                );
            }
        }
    }
}

#[test]
fn no_pixel_comes_from_a_frame_that_does_not_cover_it() {
    let s = handheld(23);
    let fused = fuse(s.frames.clone(), &params(&s), &NoProgress).unwrap();
    let al = fused.alignment.unwrap();
    let w = s.truth.width();
    let uncovered = |c: &Coverage| (0..s.truth.height()).any(|y| c.spans[y] != (0, w as u32));
    // The stack's poses do leave parts of the reference uncovered by some frames.
    assert!(al.coverage.iter().any(uncovered));
    for (p, &l) in fused.labels.iter().enumerate() {
        assert!(
            al.coverage[l as usize].covers(p % w, p / w),
            "pixel {p} labelled {l}, which does not cover it"
        );
    }
    // No black border: the output's edge rows and columns are as bright as the truth's.
    let edge_mean = |img: &Image<u8>| {
        let (w, h) = (img.width(), img.height());
        let edge: Vec<f64> = (0..w)
            .flat_map(|x| [(x, 0), (x, h - 1)])
            .chain((0..h).flat_map(|y| [(0, y), (w - 1, y)]))
            .map(|(x, y)| img.at(x, y, 1) as f64)
            .collect();
        edge.iter().sum::<f64>() / edge.len() as f64
    };
    let (got, truth) = (edge_mean(&fused.image), edge_mean(&s.truth));
    assert!(
        (got - truth).abs() < 5.0,
        "edge mean {got:.1} vs {truth:.1}"
    );
}

#[test]
fn crop_keeps_the_area_every_frame_covers() {
    let s = handheld(21);
    let p = FuseParams {
        crop: true,
        ..params(&s)
    };
    let fused = fuse(s.frames.clone(), &p, &NoProgress).unwrap();
    let r = fused.crop.unwrap();
    let al = fused.alignment.unwrap();
    assert_eq!(
        (fused.image.width(), fused.image.height()),
        (r.width, r.height)
    );
    assert!(r.width < s.truth.width() && r.height < s.truth.height());
    // Every frame covers the whole rectangle...
    for c in &al.coverage {
        for y in r.y..r.y + r.height {
            assert!(c.covers(r.x, y) && c.covers(r.x + r.width - 1, y));
        }
    }
    // ...which is most of the frame for a 3% shift.
    assert!(r.width * r.height * 10 > s.truth.width() * s.truth.height() * 8);
}

#[test]
fn a_nearly_blank_frame_still_fuses() {
    let mut s = handheld(22);
    let blank = s.frames.len() - 2;
    let (w, h) = (s.truth.width(), s.truth.height());
    let noise = Plane::from_fn(w, h, 1, |x, y, _| {
        let v = (x as u32).wrapping_mul(2_654_435_761) ^ (y as u32).wrapping_mul(40_503);
        0.5 + 0.01 * ((v >> 24) as f32 / 255.0 - 0.5)
    });
    s.frames[blank] = Image::from_planes(&[noise.clone(), noise.clone(), noise]);
    let fused = fuse(s.frames.clone(), &params(&s), &NoProgress).unwrap();
    let al = fused.alignment.as_ref().unwrap();
    assert_eq!(
        al.registration.how[blank],
        Placement::Inherited { from: blank - 1 }
    );
    // The blank frame is left out of the fusion, so it costs nothing against leaving it out.
    let got = psnr(&fused.image, &s.truth, 0);
    let mut without = s.frames.clone();
    without.remove(blank);
    let left_out = psnr(
        &fuse(without, &params(&s), &NoProgress).unwrap().image,
        &s.truth,
        0,
    );
    eprintln!("blank frame: fused {got:.2} dB, without it {left_out:.2} dB");
    assert!(fused.labels.iter().all(|&l| l as usize != blank));
    assert!(
        got >= left_out - 0.3,
        "{got:.2} dB vs {left_out:.2} without"
    );
}
