//! Grid max-flow on segmentation-like problems, the shape of one graph-cut fusion move.
//!
//! `solve` times `maxflow()` alone on a freshly loaded graph; `build_and_solve` times reset, loading
//! precomputed capacities and solving with a reused solver, which is what each expansion move pays.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use focusd::stack::internal::GridMaxflow;

/// Capacities of a two-label segmentation of a noisy image, computed once so the benchmark does
/// not time `exp`.
struct Problem {
    width: usize,
    height: usize,
    /// `(source, sink)` per node.
    terminals: Vec<(i32, i32)>,
    /// Symmetric weight of the edge to the right / down neighbour (0 past the border).
    right: Vec<i32>,
    down: Vec<i32>,
}

impl Problem {
    /// Two smooth-edged regions of grey 90 and 160 plus roughly Gaussian noise (sigma ~45, so ~22%
    /// of pixels are on the wrong side of the midpoint), with squared-distance unaries and
    /// contrast-sensitive Potts weights strong enough to clean that up: a typical graph-cut
    /// segmentation.
    fn new(width: usize, height: usize, seed: u64) -> Self {
        const NOISE: i32 = 45;
        const LAMBDA: f64 = 2000.0;
        let mut state = seed;
        let mut uniform = |max: i32| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % (max as u64 + 1)) as i32
        };
        let image: Vec<i32> = (0..width * height)
            .map(|p| {
                let (x, y) = ((p % width) as f64, (p / width) as f64);
                let dark =
                    (x * 0.021).sin() + (y * 0.017).cos() + (0.013 * (x + 0.5 * y)).sin() > 0.3;
                let noise: i32 = (0..3).map(|_| uniform(2 * NOISE) - NOISE).sum();
                let base = if dark { 90 } else { 160 };
                base + noise
            })
            .collect();
        let beta = 1.0 / (4.0 * f64::from(NOISE * NOISE));
        let weight = |a: i32, b: i32| {
            let d = f64::from(a - b);
            (LAMBDA * (-beta * d * d).exp()) as i32
        };
        let mut pb = Problem {
            width,
            height,
            terminals: Vec::with_capacity(width * height),
            right: vec![0; width * height],
            down: vec![0; width * height],
        };
        for (p, &v) in image.iter().enumerate() {
            pb.terminals
                .push(((v - 90).pow(2) / 8, (v - 160).pow(2) / 8));
            if p % width + 1 < width {
                pb.right[p] = weight(v, image[p + 1]);
            }
            if p + width < width * height {
                pb.down[p] = weight(v, image[p + width]);
            }
        }
        pb
    }

    fn load(&self, g: &mut GridMaxflow) {
        g.reset(self.width, self.height);
        for (p, &(source, sink)) in self.terminals.iter().enumerate() {
            g.add_tweights(p, source, sink);
            if p % self.width + 1 < self.width {
                g.add_right(p, self.right[p], self.right[p]);
            }
            if p + self.width < self.width * self.height {
                g.add_down(p, self.down[p], self.down[p]);
            }
        }
    }
}

fn bench_maxflow(c: &mut Criterion) {
    let mut group = c.benchmark_group("maxflow");
    // A 1 MP solve takes ~0.1 s, so keep the sample count low and give it time.
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(10));
    for (width, height) in [(1000, 1000), (256, 256)] {
        let pb = Problem::new(width, height, 0x2545_f491_4f6c_dd1d);
        let size = format!("{width}x{height}");
        group.bench_function(format!("solve/{size}"), |b| {
            b.iter_batched_ref(
                || {
                    let mut g = GridMaxflow::new();
                    pb.load(&mut g);
                    g
                },
                |g| black_box(g.maxflow()),
                BatchSize::PerIteration,
            )
        });
        let mut g = GridMaxflow::new();
        group.bench_function(format!("build_and_solve/{size}"), |b| {
            b.iter(|| {
                pb.load(&mut g);
                black_box(g.maxflow())
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_maxflow);
criterion_main!(benches);
