//! Lazy raw development against developing every frame in full, on real stacks mosaicked and
//! on a simulated raw stack: PSNR of both fused pictures, the pixels developed in full, and
//! the time of each way from raw frames to the fused picture.
//!
//! `lazy_develop [--real DIR]... [--sim WxH] [--planes N] [--runs N]`
//!
//! - Real stacks (every JPEG in each `--real` directory, decoded as linear light, cut to even
//!   sizes and mosaicked as `focusd simulate --bundle --raw` mosaics its frames: GRBG, 10 bit):
//!   no truth, so both fused pictures are compared with the original frames fused.
//! - A simulated hand-held stack (`--sim`, default 1024x768, `--planes` 10) mosaicked the same
//!   way: both against the truth.
//! - Where the two labellings differ (the lazy one is made on the cheap development): their
//!   share of the pixels, and a check that needs no truth, the mean squared luma gradient of
//!   both fused pictures there (a worse choice of frame is a blurrier one).
//! - Time: median of `--runs` (default 1) of each way, interleaved.

use anyhow::{bail, Context, Result};
use focusd::develop::{Developer, RawFrame, RawStack};
use focusd::files::imageio::load_rgb8;
use focusd::sim::bundle::raw_take;
use focusd::sim::{render, SimParams};
use focusd::stack::{fuse, fuse_developing, psnr, FuseParams, Fused, Image, NoProgress};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Developed in full, then fused; lazily: the fused pictures with their labels, the frames'
/// worth developed in full lazily, and the median times. White balance gains of 1: the frames' colours are the
/// pictures' (or the truth's) as mosaicked, so the comparisons see the development alone.
fn both(
    raws: &[RawFrame],
    params: &FuseParams,
    runs: usize,
) -> (Fused<u8>, Fused<u8>, f64, [Duration; 2]) {
    let mut times = [Vec::new(), Vec::new()];
    let (mut full, mut lazy, mut worth) = (None, None, 0.0);
    for _ in 0..runs {
        let t = Instant::now();
        let mut dev = Developer::new(raws[0].black_level, raws[0].matrix);
        dev.white_balance = Some([1.0; 3]);
        let frames: Vec<Image<u8>> = raws
            .iter()
            .map(|r| dev.develop(r.mosaic().expect("unpacks")))
            .collect();
        full = Some(fuse(frames, params, &NoProgress).expect("fuses"));
        times[0].push(t.elapsed());
        let t = Instant::now();
        let stack = RawStack::new(raws.to_vec()).expect("a stack");
        let f = fuse_developing(&stack, params, &NoProgress).expect("fuses");
        times[1].push(t.elapsed());
        worth = f.developed.expect("counted").frames();
        lazy = Some(f);
    }
    let median = |v: &mut Vec<Duration>| {
        v.sort();
        v[v.len() / 2]
    };
    let t = [median(&mut times[0]), median(&mut times[1])];
    (full.expect("a run"), lazy.expect("a run"), worth, t)
}

/// Where the labels of `a` and `b` differ: the share of the pixels, and the mean squared
/// central-difference gradient of each picture's luma there.
fn where_labels_differ(a: &Fused<u8>, b: &Fused<u8>) -> (f64, f64, f64) {
    let (w, h) = (a.image.width(), a.image.height());
    let luma = |img: &Image<u8>, x: usize, y: usize| -> f64 {
        (0..3).map(|c| f64::from(img.at(x, y, c))).sum::<f64>() / 3.0
    };
    let grad = |img: &Image<u8>, x: usize, y: usize| {
        let gx = luma(img, x + 1, y) - luma(img, x - 1, y);
        let gy = luma(img, x, y + 1) - luma(img, x, y - 1);
        gx * gx + gy * gy
    };
    let (mut n, mut ga, mut gb) = (0usize, 0.0, 0.0);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if a.labels[y * w + x] != b.labels[y * w + x] {
                n += 1;
                ga += grad(&a.image, x, y);
                gb += grad(&b.image, x, y);
            }
        }
    }
    let m = n.max(1) as f64;
    (n as f64 / (w * h) as f64, ga / m, gb / m)
}

fn even(img: Image<u8>) -> Image<u8> {
    let (w, h) = (img.width() & !1, img.height() & !1);
    Image::from_fn(w, h, 3, |x, y, c| img.at(x, y, c))
}

fn main() -> Result<()> {
    let (mut real, mut size, mut planes, mut runs) = (Vec::new(), (1024, 768), 10, 1);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--real" => real.push(PathBuf::from(value()?)),
            "--sim" => {
                let v = value()?;
                let (w, h) = v.split_once('x').context("--sim takes WxH")?;
                size = (w.parse()?, h.parse()?);
            }
            "--planes" => planes = value()?.parse()?,
            "--runs" => runs = value()?.parse()?,
            _ => bail!("unknown argument {a}"),
        }
    }
    println!("| stack | frames | all in full | lazily | lazy vs all | full frames' worth | labels differing | gradient there: all / lazily | time all | time lazy |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let row = |name: &str,
               n: usize,
               db: (f64, f64, f64),
               worth: f64,
               both: (&Fused<u8>, &Fused<u8>),
               t: [Duration; 2]| {
        let (share, ga, gb) = where_labels_differ(both.0, both.1);
        println!(
            "| {name} | {n} | {:.3} dB | {:.3} dB | {:.2} dB | {worth:.2} | {:.2} % | {ga:.0} / {gb:.0} | {:.2} s | {:.2} s |",
            db.0,
            db.1,
            db.2,
            100.0 * share,
            t[0].as_secs_f64(),
            t[1].as_secs_f64()
        );
    };
    for dir in &real {
        let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)?
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("jpg")))
            .collect();
        paths.sort();
        let pictures: Vec<Image<u8>> = paths
            .iter()
            .map(|p| load_rgb8(p).map(even))
            .collect::<Result<_, _>>()?;
        let params = FuseParams::default();
        let original = fuse(pictures.clone(), &params, &NoProgress)?.image;
        let raws: Vec<RawFrame> = pictures.iter().map(raw_take).collect();
        let (full, lazy, worth, t) = both(&raws, &params, runs);
        let db = (
            psnr(&full.image, &original, 8),
            psnr(&lazy.image, &original, 8),
            psnr(&lazy.image, &full.image, 8),
        );
        row(
            &dir.display().to_string(),
            raws.len(),
            db,
            worth,
            (&full, &lazy),
            t,
        );
    }
    let p = SimParams {
        width: size.0,
        height: size.1,
        planes,
        seed: 5,
        handheld: true,
        ..SimParams::default()
    };
    let s = render(&p);
    let raws: Vec<RawFrame> = s.frames.iter().map(raw_take).collect();
    let params = FuseParams {
        reference: p.reference(),
        ..FuseParams::default()
    };
    let (full, lazy, worth, t) = both(&raws, &params, runs);
    let db = (
        psnr(&full.image, &s.truth, 24),
        psnr(&lazy.image, &s.truth, 24),
        psnr(&lazy.image, &full.image, 8),
    );
    row(
        &format!("simulated {}x{}", size.0, size.1),
        planes,
        db,
        worth,
        (&full, &lazy),
        t,
    );
    Ok(())
}
