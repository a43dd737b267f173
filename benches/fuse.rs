//! Fusion speed on synthetic stacks: graph-cut against the pyramid baseline in the same run, and
//! the whole hand-held pipeline (registration, warping, graph cut) on a hand-held stack.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use focusd::sim::{render, SimParams};
use focusd::stack::{fuse, FuseParams, Image, Method, NoProgress};
use std::time::Duration;

fn stack(width: usize, height: usize, planes: usize, handheld: bool) -> Vec<Image<u8>> {
    render(&SimParams {
        width,
        height,
        planes,
        seed: 7,
        handheld,
        gain_jitter: if handheld { 0.05 } else { 0.0 },
        ..SimParams::default()
    })
    .frames
}

fn bench_fuse(c: &mut Criterion) {
    for (name, w, h, n) in [("6x1MP", 1152, 864, 6), ("10x3MP", 2048, 1536, 10)] {
        let aligned = stack(w, h, n, false);
        let handheld = stack(w, h, n, true);
        let mut g = c.benchmark_group(format!("fuse_{name}"));
        g.sample_size(10).measurement_time(Duration::from_secs(20));
        let runs = [
            ("graphcut", Method::GraphCut, false),
            ("pyramid", Method::Pyramid, false),
            ("graphcut_handheld", Method::GraphCut, true),
        ];
        for (label, method, align) in runs {
            let params = FuseParams {
                method,
                align: align.then(Default::default),
                reference: (n - 1) / 2,
                ..FuseParams::default()
            };
            let frames = if align { &handheld } else { &aligned };
            g.bench_function(label, |b| {
                b.iter_batched(
                    || frames.clone(),
                    |f| fuse(f, &params, &NoProgress).unwrap(),
                    BatchSize::LargeInput,
                )
            });
        }
        g.finish();
    }
}

criterion_group!(benches, bench_fuse);
criterion_main!(benches);
