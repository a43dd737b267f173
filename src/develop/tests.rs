use super::demosaic::demosaic;
use super::linear::{bilinear, encoded, malvar};
use super::*;
use crate::sim::{self, SimParams};
use crate::stack::blur::gaussian_blur_channels;
use crate::stack::metrics::psnr;

/// All-in-focus truths from the simulator: textured surfaces, objects with sharp occluding
/// edges and a ruler, different for each seed.
fn truths() -> Vec<Image<u8>> {
    [3u64, 11, 29]
        .iter()
        .map(|&seed| sim::render(&SimParams::demosaic_scene(seed)).truth)
        .collect()
}

#[test]
fn samples_become_linear_light_above_the_black_level() {
    let m = Mosaic::from_samples(&[64, 1023, 544, 0], 2, 2, BayerOrder::Rggb, 10, 64);
    let want = [0.0, 1.0, 480.0 / 959.0, -64.0 / 959.0];
    for (got, want) in m.data.iter().zip(want) {
        assert!((got - want).abs() < 1e-6, "{:?}", m.data);
    }
}

#[test]
fn demosaic_beats_bilinear_by_6_db_and_malvar_by_2_5_db_on_simulated_scenes() {
    // The simulator's truths are sharper than a phone lens draws (12-15 % of their spectral
    // energy above 0.25 cycles/px, real frames at most 10.6 %), so also through a 0.5 px blur.
    for (i, truth) in truths().iter().enumerate() {
        for sigma in [0.0, 0.5] {
            let lin = gaussian_blur_channels(&decode(truth), sigma);
            let truth = encode(&lin);
            for order in [BayerOrder::Rggb, BayerOrder::Gbrg] {
                let m = Mosaic::sample(&lin, order);
                let db = |rgb: Image<f32>| psnr(&encode(&rgb), &truth, 2);
                let good = db(demosaic(&m));
                let mhc = db(encoded(&m, malvar));
                // What focusd did first: bilinear on the raw (linear) samples.
                let before = db(bilinear(&m));
                let same_domain = db(encoded(&m, bilinear));
                eprintln!(
                    "scene {i} blur {sigma} {order:?}: residual interpolation {good:.2} dB, \
                     Malvar-He-Cutler {mhc:.2} dB, bilinear {before:.2} dB (on encoded samples \
                     {same_domain:.2} dB)"
                );
                // Measured 7.6-9.0 dB above bilinear, 3.7-4.8 above Malvar-He-Cutler.
                assert!(
                    good >= before.max(same_domain) + 6.0 && good >= mhc + 2.5,
                    "scene {i} blur {sigma} {order:?}: {good:.2} dB against bilinear's \
                     {before:.2} and {same_domain:.2} dB, Malvar-He-Cutler's {mhc:.2} dB"
                );
            }
        }
    }
}

/// False colour on a neutral (grey) edge: the largest |R−G| or |B−G| in sRGB 8-bit units.
fn fringe(img: &Image<u8>) -> u8 {
    img.data()
        .chunks_exact(3)
        .map(|p| p[0].abs_diff(p[1]).max(p[2].abs_diff(p[1])))
        .max()
        .unwrap_or(0)
}

/// Zipper along a vertical edge: the largest difference between a pixel and the one below it
/// (each row of the image is the same).
fn zipper(img: &Image<u8>) -> u8 {
    let mut worst = 0;
    for y in 2..img.height() - 3 {
        for x in 0..img.width() {
            for c in 0..3 {
                worst = worst.max(img.at(x, y, c).abs_diff(img.at(x, y + 1, c)));
            }
        }
    }
    worst
}

#[test]
fn grey_edges_get_little_false_colour_and_no_zipper() {
    for width in [1.0f32, 3.0] {
        for slope in [0.0f32, 0.2, 1.0] {
            let m = Mosaic::sample(
                &sim::demosaic_scenes::grey_edge(slope, width),
                BayerOrder::Rggb,
            );
            let good = encode(&demosaic(&m));
            let base = encode(&bilinear(&m));
            let mhc = encode(&encoded(&m, malvar));
            let (fg, fm, fb) = (fringe(&good), fringe(&mhc), fringe(&base));
            eprintln!(
                "edge {width} px, slope {slope}: false colour {fg}, Malvar-He-Cutler {fm}, \
                 bilinear {fb}"
            );
            // At most half bilinear's everywhere; along edges near the sampling axes, which
            // are most of a picture's, at most half Malvar-He-Cutler's too (measured 0-9
            // against 7-26 in 8-bit units); on the 45° edges no more than Malvar-He-Cutler's
            // and a step (8-40 against 24-43).
            assert!(
                fg * 2 <= fb && (slope == 1.0 || fg * 2 <= fm) && fg <= fm + 2,
                "width {width} slope {slope}: false colour {fg}, Malvar-He-Cutler {fm}, \
                 bilinear {fb}"
            );
            if slope == 0.0 {
                let (zg, zm, zb) = (zipper(&good), zipper(&mhc), zipper(&base));
                eprintln!("edge {width} px: zipper {zg}, Malvar-He-Cutler {zm}, bilinear {zb}");
                // Measured 0-1 against 7-18 and 18-45: two steps of 8 bits at most.
                assert!(
                    zg <= 2 && zg < zm,
                    "width {width}: zipper {zg}, Malvar-He-Cutler {zm}, bilinear {zb}"
                );
            }
        }
    }
}

#[test]
fn white_balance_is_measured_once_and_locked() {
    // A grey scene under a warm light: red 1.6x, blue 0.6x green.
    let light = [1.6f32, 1.0, 0.6];
    let scene = |level: f32| {
        Image::from_fn(32, 32, 3, move |x, y, c| {
            let grey = level * (0.3 + 0.4 * (((x / 8 + y / 8) % 2) as f32));
            grey * light[c] * 0.5
        })
    };
    let first = Mosaic::sample(&scene(1.0), BayerOrder::Bggr);
    let gains = grey_world(&[&first]);
    for c in 0..3 {
        assert!((gains[c] * light[c] - 1.0).abs() < 1e-3, "gains {gains:?}");
    }
    let mut dev = Developer::new(0, IDENTITY);
    let a = dev.develop_linear(first);
    assert_eq!(dev.white_balance, Some(gains));
    // Grey again: the channels' means agree, inside the blocks (at their edges the demosaic's
    // own errors, which are not symmetric in linear light, would mix in).
    let inside = |i: &usize| (2..6).contains(&(i % 32 % 8)) && (2..6).contains(&(i / 32 % 8));
    let mean = |c: usize| {
        let v: Vec<f32> = (0..1024)
            .filter(inside)
            .map(|i| a.data()[i * 3 + c])
            .collect();
        v.iter().sum::<f32>() / v.len() as f32
    };
    assert!((mean(0) / mean(1) - 1.0).abs() < 0.01 && (mean(2) / mean(1) - 1.0).abs() < 0.01);
    // A later frame of a bluish subject keeps the first frame's gains: no flicker.
    let bluish = Image::from_fn(32, 32, 3, |_, _, c| [0.1f32, 0.2, 0.5][c]);
    let b = dev.develop_linear(Mosaic::sample(&bluish, BayerOrder::Bggr));
    assert_eq!(dev.white_balance, Some(gains));
    let want = [0.1 * gains[0], 0.2, 0.5 * gains[2]];
    for (c, want) in want.into_iter().enumerate() {
        let got = b.at(16, 16, c);
        assert!(
            (got - want).abs() < 1e-4,
            "channel {c}: {got}, expected {want}"
        );
    }
    // Over several frames the estimate is the frames' pooled means.
    let two = grey_world(&[
        &Mosaic::sample(&scene(1.0), BayerOrder::Bggr),
        &Mosaic::sample(&bluish, BayerOrder::Bggr),
    ]);
    assert!(
        two[2] < gains[2] && two[0] > gains[0],
        "{two:?} vs {gains:?}"
    );
}

#[test]
fn clipped_highlights_do_not_count_for_white_balance() {
    let mut rgb = Image::from_fn(16, 16, 3, |_, _, c| [0.4f32, 0.2, 0.1][c]);
    for x in 0..16 {
        for y in 0..8 {
            for c in 0..3 {
                rgb.data_mut()[(y * 16 + x) * 3 + c] = 1.0;
            }
        }
    }
    let gains = grey_world(&[&Mosaic::sample(&rgb, BayerOrder::Rggb)]);
    assert!(
        (gains[0] - 0.5).abs() < 1e-4 && (gains[2] - 2.0).abs() < 1e-4,
        "{gains:?}"
    );
}

#[test]
fn the_colour_matrix_and_srgb_curve_are_applied() {
    let grey = Image::from_fn(8, 8, 3, |_, _, _| 0.2f32);
    // Rows summing to 1 keep a balanced grey grey; a swap matrix moves colour.
    let mut dev = Developer::new(0, [[1.5, -0.3, -0.2], [-0.2, 1.4, -0.2], [0.0, -0.5, 1.5]]);
    let out = dev.develop_linear(Mosaic::sample(&grey, BayerOrder::Grbg));
    assert!(out.data().iter().all(|v| (v - 0.2).abs() < 1e-5));
    let colour = Image::from_fn(8, 8, 3, |_, _, c| [0.5f32, 0.25, 0.125][c]);
    let mut dev = Developer {
        black_level: 0,
        matrix: [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]],
        white_balance: Some([1.0; 3]),
    };
    let out = dev.develop(Mosaic::sample(&colour, BayerOrder::Grbg));
    let enc = |v: f32| (srgb_encode(v) * 255.0 + 0.5) as u8;
    assert_eq!(
        [out.at(4, 4, 0), out.at(4, 4, 1), out.at(4, 4, 2)],
        [enc(0.125), enc(0.25), enc(0.5)]
    );
    assert_eq!((enc(0.0), enc(1.0), enc(2.0), enc(-1.0)), (0, 255, 255, 0));
    // 18% grey is sRGB 118.
    assert_eq!(enc(0.18), 118);
}

#[test]
fn the_half_size_development_has_the_full_ones_colours() {
    // A smooth, strongly coloured scene through a non-trivial matrix: the half-size picture
    // must match the full development averaged over cells, white balance and matrix included,
    // whichever of the two develops first.
    let k = [[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.0, -0.5, 1.5]];
    let truth = Image::from_fn(64, 48, 3, |x, y, c| {
        let v = [0.2 + 0.004 * x as f32, 0.5, 0.15 + 0.006 * y as f32][c];
        v * [1.3, 1.0, 0.6][c]
    });
    let m = Mosaic::sample(&truth, BayerOrder::Grbg);
    let mut full_first = Developer::new(0, k);
    let full = full_first.develop_linear(m.clone());
    let half = full_first.develop_half_linear(&m);
    let mut half_first = Developer::new(0, k);
    let half_alone = half_first.develop_half_linear(&m);
    assert_eq!(full_first.white_balance, half_first.white_balance);
    assert_eq!(half.data(), half_alone.data());
    let mut worst = 0.0f32;
    for y in 2..half.height() - 2 {
        for x in 2..half.width() - 2 {
            for c in 0..3 {
                let cell: f32 = [(0, 0), (0, 1), (1, 0), (1, 1)]
                    .iter()
                    .map(|(dx, dy)| full.at(2 * x + dx, 2 * y + dy, c))
                    .sum::<f32>()
                    / 4.0;
                worst = worst.max((half.at(x, y, c) - cell).abs());
            }
        }
    }
    // A gradient's colours are sampled half a pixel off the cell's centre: 0.006 at most.
    assert!(worst < 0.01, "largest difference {worst}");
}
