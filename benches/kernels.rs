//! Pixel kernels on one 3 MP plane (2048x1536), the size of a phone frame, to track the costs
//! that dominate a fuse apart from the graph cut; warping one 3 MP colour frame; and developing
//! one 3 MP raw frame, which a phone pays for every plane before the fuse starts.

use criterion::{criterion_group, criterion_main, Criterion};
use focusd::develop::raw::{unpack, Packing};
use focusd::develop::{BayerOrder, Developer, Mosaic, IDENTITY};
use focusd::stack::internal::{
    collapse, focus_amplitude, gaussian_blur, laplacian_pyramid, levels_for, warp_frame_into,
    Plane, Warp,
};
use focusd::stack::{Affine, Exposure, FocusParams, Image, OffsetField};
use std::hint::black_box;

/// Deterministic texture with edges and noise, so no kernel sees a flat (cache-friendly) input.
fn plane(width: usize, height: usize) -> Plane {
    Plane::from_fn(width, height, 1, |x, y, _| {
        let h = (x as u32).wrapping_mul(0x9e37_79b9) ^ (y as u32).wrapping_mul(0x85eb_ca6b);
        let noise = (h >> 24) as f32 / 2550.0;
        let stripes = if (x / 7 + y / 5) % 2 == 0 { 0.3 } else { 0.7 };
        stripes + noise
    })
}

fn bench_kernels(c: &mut Criterion) {
    let (w, h) = (2048, 1536);
    let p = plane(w, h);
    let mut g = c.benchmark_group("kernels_3MP");
    g.sample_size(20);
    g.bench_function("gaussian_blur_sigma2", |b| {
        b.iter(|| gaussian_blur(black_box(&p), 2.0))
    });
    let fp = FocusParams::default();
    g.bench_function("focus_amplitude", |b| {
        b.iter(|| focus_amplitude(black_box(&p), &fp))
    });
    let levels = levels_for(w, h);
    g.bench_function("laplacian_pyramid", |b| {
        b.iter(|| laplacian_pyramid(black_box(&p), levels))
    });
    let pyr = laplacian_pyramid(&p, levels);
    g.bench_function("collapse", |b| b.iter(|| collapse(black_box(&pyr))));
    // A hand-held frame's warp: a small similarity plus a local offset field (one node every
    // 4 px, as local registration gives at its working level), bicubic, into reused buffers.
    let frame = Image::<u8>::from_fn(w, h, 3, |x, y, c| {
        (p.data()[y * w + x] * 255.0) as u8 ^ (c as u8 * 40)
    });
    let centre = (w as f64 / 2.0, h as f64 / 2.0);
    let affine = Affine::similarity(1.003, 0.004, centre, (3.3, -2.7));
    let (cols, rows) = (w / 4 + 1, h / 4 + 1);
    let offsets = (0..cols * rows)
        .map(|i| ((i % 97) as f32 * 0.03).sin())
        .map(|d| (d, -d))
        .collect();
    let field = Some(OffsetField {
        step: 4.0,
        cols,
        rows,
        offsets,
    });
    let warp = Warp { affine, field };
    let (mut out, mut scratch) = (frame.clone(), Vec::new());
    g.bench_function("warp_colour_field", |b| {
        b.iter(|| {
            let same = [Exposure::SAME; 3];
            warp_frame_into(
                black_box(&frame),
                &frame,
                &warp,
                &same,
                &mut out,
                &mut scratch,
            )
        })
    });
    // A MIPI RAW10 frame (the OnePlus 6's camss stores it packed) of the texture above: unpack,
    // black level, white balance, demosaic, colour matrix, sRGB to 8 bits.
    let codes: Vec<u16> = p.data().iter().map(|&v| (v * 1023.0) as u16).collect();
    let packed: Vec<u8> = codes
        .chunks_exact(4)
        .flat_map(|q| {
            let low = q
                .iter()
                .enumerate()
                .fold(0u8, |a, (i, &v)| a | ((v & 3) as u8) << (2 * i));
            q.iter()
                .map(|&v| (v >> 2) as u8)
                .chain([low])
                .collect::<Vec<u8>>()
        })
        .collect();
    let mut dev = Developer::new(64, IDENTITY);
    g.bench_function("develop_raw10", |b| {
        b.iter(|| {
            let samples = unpack(Packing::Mipi10, w, h, 0, black_box(&packed)).unwrap();
            let m = Mosaic::from_samples(&samples, w, h, BayerOrder::Rggb, 10, 64);
            dev.develop(m)
        })
    });
    g.finish();
}

criterion_group!(benches, bench_kernels);
criterion_main!(benches);
