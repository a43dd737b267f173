//! The graph-cut labelling alone on a stack that is hard for it: smooth regions plus noise where
//! many frames tie (`focusd::sim::flats`), 16 frames. The default candidates against exhaustive
//! expansion (every frame offered everywhere) in the same run.

use criterion::{criterion_group, criterion_main, Criterion};
use focusd::sim::flats::{flats, FlatsParams};
use focusd::stack::internal::label_stack;
use focusd::stack::{Coverage, GraphCutParams, NoProgress};
use std::hint::black_box;
use std::time::Duration;

fn bench_labelling(c: &mut Criterion) {
    let p = FlatsParams {
        width: 960,
        height: 720,
        frames: 16,
        ..FlatsParams::default()
    };
    let frames = flats(&p);
    let coverage = vec![Coverage::full(p.width, p.height); p.frames];
    let mut g = c.benchmark_group("labelling_flats_16x0.7MP");
    g.sample_size(10).measurement_time(Duration::from_secs(30));
    for (name, params) in [
        ("default", GraphCutParams::default()),
        ("exhaustive", GraphCutParams::exhaustive()),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                black_box(label_stack(
                    &frames,
                    &coverage,
                    0,
                    &params,
                    usize::MAX,
                    &NoProgress,
                ))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_labelling);
criterion_main!(benches);
