//! Registration speed on a hand-held 10 × 3 MP stack (2048x1536, a phone sweep), whose budget is
//! 1 s on 2 cores; with and without local registration (on by default).

use criterion::{criterion_group, criterion_main, Criterion};
use focusd::sim::{render, SimParams};
use focusd::stack::internal::{register, Plane};
use focusd::stack::RegisterParams;
use std::hint::black_box;
use std::time::Duration;

fn bench_register(c: &mut Criterion) {
    let s = render(&SimParams {
        width: 2048,
        height: 1536,
        planes: 10,
        handheld: true,
        gain_jitter: 0.05,
        ..SimParams::default()
    });
    let lumas: Vec<Plane> = s.frames.iter().map(|f| f.luma()).collect();
    let mut g = c.benchmark_group("register_10x3MP");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    for (label, local) in [("affine", false), ("with_local", true)] {
        let p = RegisterParams {
            local,
            ..RegisterParams::default()
        };
        g.bench_function(label, |b| {
            b.iter(|| register(black_box(&lumas), s.reference, &p).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench_register);
criterion_main!(benches);
