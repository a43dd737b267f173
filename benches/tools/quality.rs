//! Quality figures of fused images: halos at depth steps and ghosts (used by
//! `benches/bench-quality`).
//!
//! `quality sim DIR IMAGE...`: DIR is a `focusd simulate` stack (frames, truth.png, depth.png,
//! steps.png, transforms.json, stack.json; motion_NN.png when it was written with `--motion`).
//! Prints the aligned depth oracle once (each pixel from the frame focused at its true depth,
//! sampled where that frame truly shows it: by `motion_NN.png`, else by the affine alone; its
//! gain from stack.json undone in the light the simulator applied it in) and the per-pixel best
//! frame (each pixel from whichever frame, so sampled, is nearest the truth: a bound on any
//! output that chooses among the frames), then
//! per image: PSNR overall, in the band within 3σ of a depth step (σ the largest defocus blur,
//! `max_sigma` in stack.json) and elsewhere, Tenengrad, and the ghost share
//! (`focusd::stack::internal::ghosts`).
//!
//! `quality ghosts IMAGE FRAME...`: only the ghost share of IMAGE against its raw input frames
//! (for real stacks, which have no truth).

use anyhow::{bail, Context, Result};
use focusd::files::imageio::{load, load_rgb8, Decoded};
use focusd::sim::render::Mixing;
use focusd::stack::internal::{best_frame_oracle, depth_oracle, ghosts, psnr_where, step_band};
use focusd::stack::{psnr, tenengrad, Image, Transforms};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

const USAGE: &str = "usage: quality sim DIR IMAGE... | quality ghosts IMAGE FRAME...";

fn load_gray(path: &Path) -> Result<Image<u8>> {
    match load(path)? {
        Decoded::U8(i) if i.channels() == 1 => Ok(i),
        _ => bail!("{}: expected 8-bit gray", path.display()),
    }
}

fn ghost_line(img: &Image<u8>, frames: &[Image<u8>]) -> String {
    let g = ghosts::check(img, frames);
    format!(
        "ghosts {:.1} % ({} of {} textured tiles)",
        100.0 * g.share(),
        g.ghosts(),
        g.textured()
    )
}

fn sim(dir: &Path, images: &[PathBuf]) -> Result<()> {
    let t: Transforms = serde_json::from_slice(
        &std::fs::read(dir.join("transforms.json")).context("transforms.json")?,
    )?;
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("stack.json")).context("stack.json")?)?;
    let sigma = meta["max_sigma"]
        .as_f64()
        .context("stack.json has no max_sigma: render it again with this focusd simulate")?;
    let frames = t
        .frames
        .iter()
        .map(|f| load_rgb8(&dir.join(&f.file)))
        .collect::<Result<Vec<_>, _>>()?;
    let n = frames.len();
    let truth = load_rgb8(&dir.join("truth.png"))?;
    let labels: Vec<u8> = load_gray(&dir.join("depth.png"))?
        .data()
        .iter()
        .map(|&v| (v as f32 * (n - 1) as f32 / 255.0).round() as u8)
        .collect();
    let band = step_band(&load_gray(&dir.join("steps.png"))?, 3.0 * sigma);
    let w = truth.width();
    let motion: Vec<Option<Image<u16>>> = (0..n)
        .map(|i| match load(&dir.join(format!("motion_{i:02}.png"))) {
            Ok(Decoded::U16(m)) => Some(m),
            _ => None,
        })
        .collect();
    // Each frame's gain (exposure × white balance), applied by the simulator in its mixing light.
    let gains: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let f = &meta["frames"][i];
            let g = f["gain"].as_f64().unwrap_or(1.0);
            std::array::from_fn(|c| (g * f["white_balance"][c].as_f64().unwrap_or(1.0)) as f32)
        })
        .collect();
    let light = if meta["params"]["linear_light"].as_bool().unwrap_or(false) {
        Mixing::Linear
    } else {
        Mixing::Display
    };
    let at = |k: usize, x: usize, y: usize| {
        let (mut u, mut v) = t.frames[k].ref_to_frame.apply(x as f64, y as f64);
        if let Some(m) = &motion[k] {
            u += (m.at(x, y, 0) as f64 - 32768.0) / 1024.0;
            v += (m.at(x, y, 1) as f64 - 32768.0) / 1024.0;
        }
        (u as f32, v as f32)
    };
    let undo = |k: usize, c: usize, v: f32| {
        255.0 * light.to_display(light.from_display(v / 255.0) / gains[k][c.min(2)])
    };
    let oracle = depth_oracle(&frames, &labels, at, undo);
    let best = best_frame_oracle(&frames, &truth, at, undo);
    let line = |name: &str, img: &Image<u8>, with_ghosts: bool| {
        let inb = psnr_where(img, &truth, |x, y| band[y * w + x]);
        let out = psnr_where(img, &truth, |x, y| !band[y * w + x]);
        println!(
            "{name}: psnr {:.2} dB, band {inb:.2} dB, elsewhere {out:.2} dB (gap {:.2}), \
             tenengrad {:.2}{}",
            psnr(img, &truth, 0),
            out - inb,
            tenengrad(img),
            if with_ghosts {
                format!(", {}", ghost_line(img, &frames))
            } else {
                String::new()
            }
        );
    };
    let in_band = band.iter().filter(|&&b| b).count();
    println!(
        "{}: {n} frames, band {:.1} % of the pixels (3 sigma = {:.1} px), oracle by {}",
        dir.display(),
        100.0 * in_band as f64 / band.len() as f64,
        3.0 * sigma,
        if motion.iter().all(Option::is_some) {
            "true per-pixel motion"
        } else {
            "affine only (no motion_NN.png)"
        }
    );
    line("aligned depth oracle", &oracle, false);
    line("per-pixel best frame (bound on any choice)", &best, false);
    for path in images {
        let img = load_rgb8(path)?;
        if !img.same_geometry(&truth) {
            bail!("{}: size differs from the truth's", path.display());
        }
        line(&path.display().to_string(), &img, true);
    }
    Ok(())
}

fn run() -> Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    match args.first().and_then(|a| a.to_str()) {
        Some("sim") if args.len() >= 3 => sim(&args[1], &args[2..]),
        Some("ghosts") if args.len() >= 3 => {
            let img = load_rgb8(&args[1])?;
            let frames = args[2..]
                .iter()
                .map(|p| load_rgb8(p))
                .collect::<Result<Vec<_>, _>>()?;
            println!("{}: {}", args[1].display(), ghost_line(&img, &frames));
            Ok(())
        }
        _ => bail!("{USAGE}"),
    }
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("quality: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
