//! PSNR against a ground-truth image, and Tenengrad sharpness, of fused images (used by
//! `benches/compare-enfuse`, and handy on any `focusd simulate` stack).
//!
//! `psnr [--margin N] TRUTH IMAGE [IMAGE...]`
//!
//! Every file is decoded as 8-bit RGB (JPEG, PNG or TIFF; an alpha channel is dropped, 16-bit
//! is scaled down). Prints one line for the truth, then one per image:
//!
//! ```text
//! sim-data/aligned/truth.png: tenengrad 21.37
//! fused.png: psnr 30.96 dB, max diff 187, tenengrad 20.85
//! ```
//!
//! PSNR is over all pixels and channels on the 8-bit scale (`focusd::stack::psnr`),
//! leaving out `N` pixels along each edge (default 0, as in the README's quality tables); max
//! diff is the largest difference of one channel of one pixel over the same pixels (the arm64
//! check in `tests/arm64/run` compares two builds' pictures with it).
//! Tenengrad is the mean Sobel gradient magnitude of luma in 8-bit units
//! (`focusd::stack::tenengrad`). An image that cannot be read or whose size differs
//! from the truth's is reported on stderr and skipped; the exit status is then 1.

use anyhow::{bail, Context, Result};
use focusd::files::imageio::load_rgb8;
use focusd::stack::{psnr, tenengrad};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

const USAGE: &str = "usage: psnr [--margin N] TRUTH IMAGE [IMAGE...]";

struct Args {
    margin: usize,
    truth: PathBuf,
    images: Vec<PathBuf>,
}

fn parse_args() -> Result<Args> {
    let mut margin = 0usize;
    let mut paths = Vec::new();
    let mut args = std::env::args_os().skip(1);
    while let Some(arg) = args.next() {
        match arg.to_str() {
            Some("-h" | "--help") => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            Some("--margin") => {
                let v = args.next().context("--margin needs a value")?;
                margin = v
                    .to_str()
                    .and_then(|s| s.parse().ok())
                    .with_context(|| format!("--margin {v:?}: not a pixel count"))?;
            }
            Some(s) if s.starts_with("--margin=") => {
                let v = s.strip_prefix("--margin=").unwrap_or_default();
                margin = v
                    .parse()
                    .with_context(|| format!("{s}: not a pixel count"))?;
            }
            Some(s) if s.starts_with('-') && s.len() > 1 => bail!("unknown option {s}"),
            _ => paths.push(PathBuf::from(arg)),
        }
    }
    if paths.len() < 2 {
        bail!("need a truth image and at least one image");
    }
    let truth = paths.remove(0);
    Ok(Args {
        margin,
        truth,
        images: paths,
    })
}

fn measure(truth: &focusd::stack::Image<u8>, path: &Path, margin: usize) -> Result<()> {
    let img = load_rgb8(path)?;
    if (img.width(), img.height()) != (truth.width(), truth.height()) {
        bail!(
            "{}: {}x{} does not match the truth's size {}x{}",
            path.display(),
            img.width(),
            img.height(),
            truth.width(),
            truth.height()
        );
    }
    if 2 * margin >= img.width().min(img.height()) {
        bail!(
            "{}: a margin of {margin} px leaves no pixels of {}x{}",
            path.display(),
            img.width(),
            img.height()
        );
    }
    let (w, ch) = (img.width(), img.channels());
    let max_diff = (margin..img.height() - margin)
        .flat_map(|y| (margin * ch..(w - margin) * ch).map(move |i| y * w * ch + i))
        .map(|i| img.data()[i].abs_diff(truth.data()[i]))
        .max()
        .unwrap_or(0);
    println!(
        "{}: psnr {:.2} dB, max diff {max_diff}, tenengrad {:.2}",
        path.display(),
        psnr(&img, truth, margin),
        tenengrad(&img)
    );
    Ok(())
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("psnr: error: {e:#}\n{USAGE}");
            return ExitCode::FAILURE;
        }
    };
    let truth = match load_rgb8(&args.truth) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("psnr: error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    println!(
        "{}: tenengrad {:.2}",
        args.truth.display(),
        tenengrad(&truth)
    );
    let mut failed = false;
    for path in &args.images {
        if let Err(e) = measure(&truth, path, args.margin) {
            eprintln!("psnr: error: {e:#}");
            failed = true;
        }
    }
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
