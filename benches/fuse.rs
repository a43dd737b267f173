//! Fusion speed on synthetic stacks: graph-cut against the pyramid baseline in the same run.

use criterion::{criterion_group, criterion_main, Criterion};
use focusd::sim::{render, SimParams};
use focusd::stack::fuse::{fuse, FuseParams, Method};
use focusd::stack::NoProgress;
use std::time::Duration;

fn stack(width: usize, height: usize, planes: usize) -> Vec<focusd::stack::image::Image<u8>> {
    render(&SimParams {
        width,
        height,
        planes,
        seed: 7,
        ..SimParams::default()
    })
    .frames
}

fn bench_fuse(c: &mut Criterion) {
    for (name, w, h, n) in [("6x1MP", 1152, 864, 6), ("10x3MP", 2048, 1536, 10)] {
        let frames = stack(w, h, n);
        let mut g = c.benchmark_group(format!("fuse_{name}"));
        g.sample_size(10).measurement_time(Duration::from_secs(20));
        for (label, method) in [("graphcut", Method::GraphCut), ("pyramid", Method::Pyramid)] {
            let params = FuseParams {
                method,
                ..FuseParams::default()
            };
            g.bench_function(label, |b| {
                b.iter(|| fuse(&frames, &params, &NoProgress).unwrap())
            });
        }
        g.finish();
    }
}

criterion_group!(benches, bench_fuse);
criterion_main!(benches);
