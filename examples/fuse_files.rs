//! Fusing files with the library: load the frames, fuse them, save the picture.
//!
//! `cargo run --release --example fuse_files -- OUT FRAME...`, for example
//! `cargo run --release --example fuse_files -- fused.jpg sim-data/handheld/frame_*.jpg`.
//! The frames come in focus order, nearest first; the others are registered to the middle one.
//! `focusd fuse` does the same with every option.

use anyhow::{bail, Result};
use focusd::files::imageio::load_rgb8;
use focusd::files::outputs::save_image;

use focusd::stack::{fuse, middle_frame, FuseParams, NoProgress};
use std::path::PathBuf;

fn main() -> Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let Some((out, paths)) = args.split_first() else {
        bail!("usage: fuse_files OUT FRAME...");
    };
    let frames = paths
        .iter()
        .map(|p| load_rgb8(p))
        .collect::<Result<Vec<_>, _>>()?;
    let params = FuseParams {
        reference: middle_frame(frames.len()),
        ..FuseParams::default()
    };
    let fused = fuse(frames, &params, &NoProgress)?;
    save_image(&fused.image, out, 92)?;
    println!("{} frames fused into {}", paths.len(), out.display());
    Ok(())
}
