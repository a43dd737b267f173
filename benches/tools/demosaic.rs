//! Where the demosaic's error is, and what it costs, in one run, so that two builds can be
//! compared back to back.
//!
//! `demosaic [--real DIR]... [--no-fuse] [--tune] [--runs N] [--crops DIR]`
//!
//! Each figure for three methods: the residual interpolation (the product's full development),
//! its cheap one on encoded samples (Malvar–He–Cutler with a directional green) and Ratio
//! Corrected Demosaicing, on encoded samples and on linear ones (`rcd.rs` beside this file).
//!
//! - Simulator frames (the unit tests' three truths, 240×180, RGGB and GBRG), sharp and through
//!   a 0.5 px lens blur: PSNR over all channels, per channel, and on edges (pixels whose truth
//!   has a luma gradient above 16 in 8-bit units) against the flat rest.
//! - Real frames (every JPEG in each `--real` directory, taken as linear truth once decoded),
//!   mosaicked RGGB: the same figures.
//! - The fused gap (unless `--no-fuse`): simulated stacks of seeds 5 and 17 (5 planes, 256×192,
//!   linear light, as in `tests/develop.rs`), fused from developed mosaics and from the RGB
//!   frames, sharp and blurred; PSNR against the truth and the gap.
//! - False colour and zipper on grey edges, as in the unit tests.
//! - Time per 3 MP frame (2048×1536 of a simulated scene): median of `--runs` (default 5) on all
//!   cores and on one. `--tune` applies the product's allocator setting (`malloc::tune`) first.
//! - With `--crops DIR`: for the first real frame of each directory, the 64×64 block of most
//!   edge, truth and each method three to a row, 4× enlarged, as a PNG.

use anyhow::{bail, Context, Result};
use focusd::develop::demosaic::demosaic;
use focusd::develop::linear::cheap_over;
use focusd::develop::{decode, encode, srgb_tabulated, BayerOrder, Developer, Mosaic, IDENTITY};
use focusd::files::imageio::load_rgb8;
use focusd::sim::demosaic_scenes::grey_edge;
use focusd::sim::{render, SimParams};
use focusd::stack::internal::gaussian_blur_channels;
use focusd::stack::Rect;
use focusd::stack::{fuse, psnr, FuseParams, Image, NoProgress};
use rcd::rcd;
use std::path::PathBuf;
use std::time::Instant;

mod rcd;

fn db(se: f64, n: usize) -> f64 {
    if se == 0.0 {
        return 120.0;
    }
    10.0 * (255.0f64 * 255.0 * n as f64 / se).log10()
}

/// Squared errors by channel, split by edge and flat pixels, leaving out `margin` px.
#[derive(Default, Clone, Copy)]
struct Errors {
    se: [[f64; 3]; 2],
    n: [usize; 2],
}

impl Errors {
    fn of(out: &Image<u8>, truth: &Image<u8>, margin: usize) -> Errors {
        let (w, h) = (truth.width(), truth.height());
        let luma = |x: usize, y: usize| {
            0.299 * f32::from(truth.at(x, y, 0))
                + 0.587 * f32::from(truth.at(x, y, 1))
                + 0.114 * f32::from(truth.at(x, y, 2))
        };
        let mut e = Errors::default();
        for y in margin.max(1)..h - margin.max(1) {
            for x in margin.max(1)..w - margin.max(1) {
                let gx = luma(x + 1, y) - luma(x - 1, y);
                let gy = luma(x, y + 1) - luma(x, y - 1);
                let edge = usize::from((gx * gx + gy * gy).sqrt() / 2.0 > 16.0);
                e.n[edge] += 1;
                for c in 0..3 {
                    let d = f64::from(out.at(x, y, c)) - f64::from(truth.at(x, y, c));
                    e.se[edge][c] += d * d;
                }
            }
        }
        e
    }

    fn add(&mut self, o: &Errors) {
        for k in 0..2 {
            self.n[k] += o.n[k];
            for c in 0..3 {
                self.se[k][c] += o.se[k][c];
            }
        }
    }

    fn line(&self) -> String {
        let n = self.n[0] + self.n[1];
        let all: f64 = self.se.iter().flatten().sum();
        let ch = |c: usize| db(self.se[0][c] + self.se[1][c], n);
        let part = |k: usize| db(self.se[k].iter().sum(), 3 * self.n[k]);
        format!(
            "{:.2} dB (R {:.2} G {:.2} B {:.2}; edges {:.2} on {:.0} %, flat {:.2})",
            db(all, 3 * n),
            ch(0),
            ch(1),
            ch(2),
            part(1),
            100.0 * self.n[1] as f64 / n.max(1) as f64,
            part(0)
        )
    }
}

/// A demosaic from a mosaic in linear light to linear RGB.
type Method = fn(&Mosaic) -> Image<f32>;

/// The demosaics compared.
const METHODS: [(&str, Method); 4] = [
    ("RI", demosaic),
    ("cheap", cheap_encoded),
    ("RCD", |m| rcd(m, true)),
    ("RCD linear", |m| rcd(m, false)),
];

/// The cheap development on encoded samples, as a stack's development runs it.
fn cheap_encoded(m: &Mosaic) -> Image<f32> {
    let curves = srgb_tabulated();
    let (w, h) = (m.width, m.height);
    let mut out = vec![0.0f32; w * h * 3];
    let fill = |y: usize, x0: usize, row: &mut [f32]| {
        for (v, s) in row.iter_mut().zip(&m.data[y * w + x0..]) {
            *v = curves.encode.at(*s);
        }
    };
    let pixels = |rgb: [&[f32]; 3], out: &mut [f32]| {
        for (k, px) in out.chunks_exact_mut(3).enumerate() {
            for (o, c) in px.iter_mut().zip(rgb) {
                *o = curves.decode.at(c[k]);
            }
        }
    };
    let all = Rect {
        x: 0,
        y: 0,
        width: w,
        height: h,
    };
    cheap_over((w, h), m.order, all, &fill, &pixels, &mut out);
    Image::from_vec(w, h, 3, out)
}

fn simulated() {
    for sigma in [0.0f32, 0.5] {
        let mut total = [Errors::default(); METHODS.len()];
        for seed in [3u64, 11, 29] {
            let truth = render(&SimParams::demosaic_scene(seed)).truth;
            let lin = gaussian_blur_channels(&decode(&truth), sigma);
            let truth = encode(&lin);
            for order in [BayerOrder::Rggb, BayerOrder::Gbrg] {
                let m = Mosaic::sample(&lin, order);
                for ((name, f), t) in METHODS.iter().zip(&mut total) {
                    let e = Errors::of(&encode(&f(&m)), &truth, 2);
                    t.add(&e);
                    println!(
                        "sim seed {seed} blur {sigma} {order:?} {name}: {}",
                        e.line()
                    );
                }
            }
        }
        for ((name, _), t) in METHODS.iter().zip(&total) {
            println!("sim blur {sigma} pooled {name}: {}", t.line());
        }
    }
}

fn real(dirs: &[PathBuf]) -> Result<()> {
    for dir in dirs {
        let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
            .with_context(|| format!("reading {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
            .collect();
        paths.sort();
        let mut total = [Errors::default(); METHODS.len()];
        for p in &paths {
            let truth = load_rgb8(p)?;
            let m = Mosaic::sample(&decode(&truth), BayerOrder::Rggb);
            for ((name, f), t) in METHODS.iter().zip(&mut total) {
                let e = Errors::of(&encode(&f(&m)), &truth, 4);
                t.add(&e);
                println!("real {} {name}: {}", p.display(), e.line());
            }
        }
        for ((name, _), t) in METHODS.iter().zip(&total) {
            println!("real {} pooled {name}: {}", dir.display(), t.line());
        }
    }
    Ok(())
}

fn fused() {
    for seed in [5u64, 17] {
        for sigma in [0.0f32, 0.5] {
            let s = render(&SimParams::raw_stack(seed));
            let lin = |f: &Image<u8>| gaussian_blur_channels(&decode(f), sigma);
            let frames: Vec<Image<f32>> = s.frames.iter().map(lin).collect();
            let truth = encode(&lin(&s.truth));
            let mut dev = Developer {
                black_level: 0,
                matrix: IDENTITY,
                white_balance: Some([1.0; 3]),
            };
            let dev_frames: Vec<Image<u8>> = frames
                .iter()
                .map(|f| dev.develop(Mosaic::sample(f, BayerOrder::Rggb)))
                .collect();
            let mut frame_e = Errors::default();
            for (d, f) in dev_frames.iter().zip(&frames) {
                frame_e.add(&Errors::of(d, &encode(f), 4));
            }
            let params = FuseParams {
                align: None,
                ..FuseParams::default()
            };
            let rgb_frames: Vec<Image<u8>> = frames.iter().map(encode).collect();
            let from_mosaics = fuse(dev_frames.clone(), &params, &NoProgress).expect("fuses");
            let rgb = fuse(rgb_frames.clone(), &params, &NoProgress).expect("fuses");
            // Where the gap comes from: each pixel taken whole from the frame a labelling chose,
            // the developed frames by their own labels and by the RGB frames', the RGB frames by
            // theirs.
            let pick = |frames: &[Image<u8>], labels: &[u8]| {
                Image::from_fn(truth.width(), truth.height(), 3, |x, y, c| {
                    frames[labels[y * truth.width() + x] as usize].at(x, y, c)
                })
            };
            let picked = [
                pick(&dev_frames, &from_mosaics.labels),
                pick(&dev_frames, &rgb.labels),
                pick(&rgb_frames, &rgb.labels),
            ]
            .map(|p| psnr(&p, &truth, 4));
            println!(
                "picked seed {seed} blur {sigma}: developed frames by their labels {:.2} dB, by \
                 the RGB frames' {:.2} dB, RGB frames {:.2} dB",
                picked[0], picked[1], picked[2]
            );
            let (m, r) = (
                psnr(&from_mosaics.image, &truth, 4),
                psnr(&rgb.image, &truth, 4),
            );
            println!(
                "fused seed {seed} blur {sigma}: mosaics {m:.2} dB, RGB {r:.2} dB, {:.2} dB short; \
                 frames' demosaic {}",
                r - m,
                frame_e.line()
            );
        }
    }
}

fn edges() {
    for (name, f) in METHODS {
        edges_of(name, f);
    }
}

fn edges_of(name: &str, f: Method) {
    for width in [1.0f32, 3.0] {
        for slope in [0.0f32, 0.2, 1.0] {
            let out = encode(&f(&Mosaic::sample(
                &grey_edge(slope, width),
                BayerOrder::Rggb,
            )));
            let fringe = out
                .data()
                .chunks_exact(3)
                .map(|p| p[0].abs_diff(p[1]).max(p[2].abs_diff(p[1])))
                .max()
                .unwrap_or(0);
            let mut zipper = 0;
            for y in 2..out.height() - 3 {
                for x in 0..out.width() {
                    for c in 0..3 {
                        zipper = zipper.max(out.at(x, y, c).abs_diff(out.at(x, y + 1, c)));
                    }
                }
            }
            let z = if slope == 0.0 {
                format!(", zipper {zipper}")
            } else {
                String::new()
            };
            println!("{name} edge {width} px slope {slope}: false colour {fringe}{z}");
        }
    }
}

fn timing(runs: usize) {
    let scene = render(&SimParams {
        width: 1024,
        height: 768,
        planes: 2,
        seed: 7,
        noise_sigma: 0.0,
        ..SimParams::default()
    })
    .truth;
    // Tiled 2×2 to 2048×1536.
    let lin = decode(&scene);
    let big = Image::from_fn(2048, 1536, 3, |x, y, c| lin.at(x % 1024, y % 768, c));
    let m = Mosaic::sample(&big, BayerOrder::Rggb);
    // Wall time, and the process's CPU time: on a machine shared with other work the CPU time
    // of the single-threaded run is the steadier figure.
    let cpu = || {
        let mut t = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes only the timespec it is given.
        unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
        t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
    };
    let median = |f: &dyn Fn()| {
        let t: Vec<(f64, f64)> = (0..runs)
            .map(|_| {
                let (t0, c0) = (Instant::now(), cpu());
                f();
                (t0.elapsed().as_secs_f64(), cpu() - c0)
            })
            .collect();
        let mid = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        (
            mid(t.iter().map(|p| p.0).collect()),
            mid(t.iter().map(|p| p.1).collect()),
        )
    };
    let one_pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    for (name, f) in METHODS {
        let (all, _) = median(&|| drop(f(&m)));
        let (one, one_cpu) = median(&|| one_pool.install(|| drop(f(&m))));
        println!(
            "{name} time per 3 MP frame: {all:.3} s on {} threads, {one:.3} s on one ({one_cpu:.3} \
             s CPU)",
            rayon::current_num_threads()
        );
    }
}

/// For the first real frame of each of `dirs`, the 64×64 block (on an 8 px grid) with the most
/// edge pixels, truth then each method three to a row, enlarged 4×, into `out/<dir name>.png`.
fn crops(dirs: &[PathBuf], out: &std::path::Path) -> Result<()> {
    const SIDE: usize = 64;
    const ZOOM: usize = 4;
    std::fs::create_dir_all(out)?;
    for dir in dirs {
        let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
            .collect();
        paths.sort();
        let Some(first) = paths.first() else {
            continue;
        };
        let truth = load_rgb8(first)?;
        let (w, h) = (truth.width(), truth.height());
        let luma = truth.luma();
        let edge = |x: usize, y: usize| {
            let gx = luma.at(x + 1, y, 0) - luma.at(x - 1, y, 0);
            let gy = luma.at(x, y + 1, 0) - luma.at(x, y - 1, 0);
            (gx * gx + gy * gy).sqrt() / 2.0 > 16.0 / 255.0
        };
        // Edge pixels per 8×8 cell, then per block of 8×8 cells.
        let (cw, ch) = (w / 8 - 1, h / 8 - 1);
        let mut cells = vec![0usize; cw * ch];
        for y in 8..ch * 8 {
            for x in 8..cw * 8 {
                cells[y / 8 * cw + x / 8] += usize::from(edge(x, y));
            }
        }
        let cells_per = SIDE / 8;
        let mut best = (0, 8, 8);
        for by in 1..ch.saturating_sub(cells_per) {
            for bx in 1..cw.saturating_sub(cells_per) {
                let n: usize = (by..by + cells_per)
                    .map(|j| cells[j * cw + bx..][..cells_per].iter().sum::<usize>())
                    .sum();
                best = best.max((n, 8 * bx, 8 * by));
            }
        }
        let (_, bx, by) = best;
        let m = Mosaic::sample(&decode(&truth), BayerOrder::Rggb);
        let mut shown = vec![truth.clone()];
        shown.extend(METHODS.iter().map(|(_, f)| encode(&f(&m))));
        // Three to a row, the last row's gaps black.
        let side = SIDE * ZOOM;
        let rows = shown.len().div_ceil(3);
        let sheet = Image::from_fn(3 * side, rows * side, 3, |x, y, c| {
            shown
                .get(y / side * 3 + x / side)
                .map_or(0, |s| s.at(bx + x % side / ZOOM, by + y % side / ZOOM, c))
        });
        let name = dir
            .file_name()
            .map_or("frame".into(), |n| n.to_string_lossy());
        let path = out.join(format!("{name}.png"));
        let bytes = focusd::files::imageio::encode(&sheet, image::ImageFormat::Png, 100)?;
        std::fs::write(&path, bytes)?;
        println!(
            "crop of {} at ({bx}, {by}): {}",
            first.display(),
            path.display()
        );
    }
    Ok(())
}

fn main() -> Result<()> {
    let mut real_dirs = Vec::new();
    let (mut fuse_too, mut runs) = (true, 5usize);
    let mut crop_dir = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--real" => real_dirs.push(PathBuf::from(args.next().context("--real DIR")?)),
            "--no-fuse" => fuse_too = false,
            "--tune" => focusd::base::malloc::tune(),
            "--runs" => runs = args.next().context("--runs N")?.parse()?,
            "--crops" => crop_dir = Some(PathBuf::from(args.next().context("--crops DIR")?)),
            _ => bail!(
                "usage: demosaic [--real DIR]... [--no-fuse] [--tune] [--runs N] [--crops DIR]"
            ),
        }
    }
    if let Some(dir) = &crop_dir {
        crops(&real_dirs, dir)?;
    }
    simulated();
    real(&real_dirs)?;
    if fuse_too {
        fused();
    }
    edges();
    timing(runs.max(1));
    Ok(())
}
