//! `focusd fuse`: fuse a focus stack from image files into one all-in-focus image.

use super::progress::Bar;
use anyhow::{bail, Context, Result};
use focusd::develop::{stack::working_bytes, RawStack};
use focusd::files::dng;
use focusd::files::imageio::{self as io, Decoded, Header};
use focusd::files::outputs::Outputs;
use focusd::files::FileError;
use focusd::service::fuse_settings::FuseSettings;
use focusd::stack::{
    fuse, fuse_developing, memory_plan, mib, tenengrad, Alignment, Develop, FieldExtent,
    FrameTransform, FuseError, FuseParams, Image, Placement, RegisterError, Sample, StackShape,
    Transforms,
};
use img_parts::{jpeg::Jpeg, Bytes, ImageEXIF};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct FuseArgs {
    /// Output image; the format follows the extension (.jpg, .png, .tif).
    #[arg(short, long, value_name = "OUT")]
    pub output: PathBuf,
    /// Input frames, nearest focus first (JPEG, PNG or TIFF, 8 or 16 bit; or raw DNGs,
    /// developed as focusd develops its camera's raw frames).
    ///
    /// The fuse checks that order on the stack's occlusion edges: where a near object overlaps a
    /// far one, the frame focused on the near object shows their edge crisp, the frame focused
    /// behind it shows it blurred. Its `order` line says which order it found and on how many
    /// edge pixels; with fewer than 200 or no 2/3 majority of their contrast (a flat subject, a
    /// single plane) it says so and assumes nearest first. The spill removal takes near objects'
    /// defocus out of the farther frames in the order found; when the edges tell none it leaves
    /// the frames as they are (its `spill` line says so).
    #[arg(value_name = "FRAME")]
    pub frames: Vec<PathBuf>,
    /// Frame whose geometry the output takes (0-based; default: the middle frame).
    #[arg(long, value_name = "N")]
    pub reference: Option<usize>,
    /// Take the frames as already registered (by default each is aligned to the reference).
    #[arg(long)]
    pub no_align: bool,
    /// Write each frame's global affine (reference pixels to frame pixels) as JSON.
    #[arg(long, value_name = "FILE.json", conflicts_with = "no_align")]
    pub save_transforms: Option<PathBuf>,
    /// Write the label map: frame index scaled to 0..255 (0 = first frame), 8-bit gray.
    #[arg(long, value_name = "D.png")]
    pub depthmap: Option<PathBuf>,
    #[command(flatten)]
    pub settings: FuseSettings,
}

/// Checks every argument that can be checked before any pixel work.
fn check_args(a: &FuseArgs) -> Result<()> {
    if a.frames.is_empty() {
        bail!("no input frames given; usage: focusd fuse -o OUT FRAME...");
    }
    if a.frames.len() == 1 {
        bail!(
            "{}: a focus stack needs at least 2 frames, got 1",
            a.frames[0].display()
        );
    }
    if let Some(r) = a.reference {
        if r >= a.frames.len() {
            bail!(
                "--reference {r} is out of range: the stack has {} frames (0..={})",
                a.frames.len(),
                a.frames.len() - 1
            );
        }
    }
    io::format_for(&a.output)?;
    if a.save_transforms
        .as_ref()
        .is_some_and(|t| t.extension().is_none_or(|e| e != "json"))
    {
        bail!("--save-transforms must be a .json file");
    }
    if a.depthmap
        .as_ref()
        .is_some_and(|d| io::format_for(d).ok() != Some(image::ImageFormat::Png))
    {
        bail!("--depthmap must be a .png file");
    }
    Ok(())
}

pub fn run(a: &FuseArgs) -> Result<()> {
    check_args(a)?;
    let outputs: Vec<&Path> = std::iter::once(&a.output)
        .chain(&a.depthmap)
        .chain(&a.save_transforms)
        .map(PathBuf::as_path)
        .collect();
    let inputs: Vec<&Path> = a.frames.iter().map(PathBuf::as_path).collect();
    let outs = Outputs::check(&outputs, &inputs)?;
    check_memory(a)?;
    let t0 = Instant::now();
    if a.frames.iter().any(|p| dng::is_dng(p)) {
        let stack = raw_stack(&a.frames)?;
        return run_typed(a, Input::Raw(Box::new(stack)), t0.elapsed(), outs);
    }
    let decoded: Vec<Decoded> = a
        .frames
        .par_iter()
        .map(|p| io::load(p))
        .collect::<Result<_, FileError>>()?;
    let load_time = t0.elapsed();
    let sixteen = decoded.iter().any(|d| matches!(d, Decoded::U16(_)));
    if sixteen {
        let frames = decoded.into_iter().map(to_u16).collect();
        run_typed(a, Input::Pictures(frames), load_time, outs)
    } else {
        let frames = decoded
            .into_iter()
            .map(|d| match d {
                Decoded::U8(i) => i,
                Decoded::U16(_) => unreachable!("checked above"),
            })
            .collect();
        run_typed(a, Input::Pictures(frames), load_time, outs)
    }
}

/// A stack's frames: pictures, or raw frames the fuse develops, cheaply in whole and in full
/// where the output keeps them.
enum Input<T> {
    Pictures(Vec<Image<T>>),
    Raw(Box<dyn Develop<T>>),
}

/// DNG frames, each turned upright, to be developed as the camera's raw takes are (one white
/// balance for the stack: the first frame's AsShotNeutral, or grey-world measured on it where
/// it has none). A stack is all DNG or none.
fn raw_stack(paths: &[PathBuf]) -> Result<RawStack> {
    if let Some(p) = paths.iter().find(|p| !dng::is_dng(p)) {
        bail!(
            "{}: not a DNG, but {} is; a stack cannot mix raw and developed frames",
            p.display(),
            paths
                .iter()
                .find(|p| dng::is_dng(p))
                .expect("one is")
                .display()
        );
    }
    let read: Vec<dng::DngFrame> = paths
        .par_iter()
        .map(|p| dng::load(p))
        .collect::<Result<_, FileError>>()?;
    let frames = read
        .into_iter()
        .zip(paths)
        .map(|(d, p)| {
            d.raw
                .upright(d.orientation)
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
        })
        .collect::<Result<_>>()?;
    RawStack::new(frames).map_err(anyhow::Error::msg)
}

/// Reads every frame's header and refuses, before any frame is decoded, frames of different
/// sizes, a stack that mixes grey and colour frames (one kind would be gain-matched to the
/// other, a patchwork), and a stack that does not fit the memory budget even in its leanest
/// plan, naming the `--memory` it needs. (The daemon's frames come from its own camera: it fuses and warns.)
fn check_memory(a: &FuseArgs) -> Result<()> {
    let headers: Vec<Header> = a
        .frames
        .iter()
        .map(|p| {
            if dng::is_dng(p) {
                dng::probe(p)
            } else {
                io::probe(p)
            }
        })
        .collect::<Result<_, FileError>>()?;
    let (w, h) = (headers[0].width, headers[0].height);
    for (d, p) in headers.iter().zip(&a.frames).skip(1) {
        if (d.width, d.height) != (w, h) {
            bail!(
                "{}: frame is {}x{} but {} is {w}x{h}; all frames must have the same size",
                p.display(),
                d.width,
                d.height,
                a.frames[0].display()
            );
        }
    }
    let model = |channels| if channels == 1 { "grey" } else { "colour" };
    if let Some((d, p)) = headers
        .iter()
        .zip(&a.frames)
        .find(|(d, _)| d.channels != headers[0].channels)
    {
        bail!(
            "{}: frame is {} but {} is {}; a stack cannot mix grey and colour frames",
            p.display(),
            model(d.channels),
            a.frames[0].display(),
            model(headers[0].channels)
        );
    }
    // Raw frames are held as 16-bit samples at most until the compose.
    let raw = dng::is_dng(&a.frames[0]);
    let stack = StackShape {
        frames: headers.len(),
        width: w,
        height: h,
        channels: headers[0].channels,
        sample_bytes: headers.iter().map(|d| d.sample_bytes).max().unwrap_or(1),
        held: if raw { headers.len() * w * h * 2 } else { 0 },
        developing: if raw { working_bytes(w, h) } else { 0 },
    };
    let plan = memory_plan(&stack, &params(a, headers.len()));
    if !plan.fits() {
        bail!(
            "{} frames of {w}x{h} need about {} MiB even in the smallest bands, over the {} MiB \
             budget: give --memory {} or more, or fuse fewer or smaller frames",
            stack.frames,
            mib(plan.floor),
            mib(plan.budget),
            mib(plan.floor).max(64)
        );
    }
    Ok(())
}

/// The engine's parameters: the shared settings with this command's own flags.
fn params(a: &FuseArgs, frames: usize) -> FuseParams {
    let mut params = a.settings.params(frames);
    if let Some(r) = a.reference {
        params.reference = r;
    }
    if a.no_align {
        params.align = None;
    }
    params
}

fn to_u16(d: Decoded) -> Image<u16> {
    match d {
        Decoded::U8(i) => i.convert(),
        Decoded::U16(i) => i,
    }
}

fn run_typed<T: Sample>(
    a: &FuseArgs,
    input: Input<T>,
    load_time: std::time::Duration,
    mut outs: Outputs,
) -> Result<()> {
    let n = a.frames.len();
    let params = params(a, n);
    let reference = params.reference;
    let bar = Bar::stderr();
    let (sharp, fused): (Vec<f64>, _) = match input {
        Input::Pictures(frames) => (
            frames.par_iter().map(tenengrad).collect(),
            fuse(frames, &params, &bar),
        ),
        Input::Raw(stack) => (Vec::new(), fuse_developing(stack.as_ref(), &params, &bar)),
    };
    let fused = fused.map_err(|e| name_frame(e, &a.frames));
    bar.finish();
    let fused = fused?;
    // The frames' size: the output's, unless cropped to what every aligned frame covers.
    let (w, h) = match &fused.alignment {
        Some(al) => (al.coverage[0].width, al.coverage[0].spans.len()),
        None => (fused.image.width(), fused.image.height()),
    };
    if let Some(al) = &fused.alignment {
        report_alignment(al, &a.frames);
    }
    if let Some(s) = &fused.spill {
        if let Some(r) = &s.repaired {
            eprintln!("  repair {r}");
        }
        eprintln!("  spill  {s}");
    }

    let t = Instant::now();
    let mut bytes = io::encode(&fused.image, io::format_for(&a.output)?, a.settings.quality)?;
    if io::format_for(&a.output)? == image::ImageFormat::Jpeg {
        bytes = with_exif_of(&a.frames[reference], bytes)?;
    }
    if let Some(d) = &a.depthmap {
        let scale = 255.0 / (n - 1) as f32;
        let depth = Image::from_vec(
            fused.image.width(),
            fused.image.height(),
            1,
            fused
                .labels
                .iter()
                .map(|&l| (l as f32 * scale).round() as u8)
                .collect(),
        );
        outs.write(d, &io::encode(&depth, image::ImageFormat::Png, 100)?)?;
    }
    if let (Some(path), Some(al)) = (&a.save_transforms, &fused.alignment) {
        let t = Transforms {
            reference,
            size: [w, h],
            frames: a
                .frames
                .iter()
                .zip(&al.registration.ref_to_frame)
                .zip(&al.registration.field)
                .map(|((p, &ref_to_frame), field)| FrameTransform {
                    file: p.display().to_string(),
                    ref_to_frame,
                    local_field: field.as_ref().map(FieldExtent::of),
                })
                .collect(),
        };
        let json = serde_json::to_vec_pretty(&t).context("encoding the transforms")?;
        outs.write(path, &json)?;
    }
    outs.write(&a.output, &bytes)?;
    outs.commit()?;
    let save_time = t.elapsed();

    eprintln!("focusd: fused {n} frames of {w}x{h} (reference {reference})");
    if let Some(r) = fused.crop {
        eprintln!(
            "  crop  {}x{} at ({}, {}): the area every frame covers",
            r.width, r.height, r.x, r.y
        );
    }
    eprintln!("  order {}", fused.order);
    if let Some(d) = &fused.developed {
        eprintln!("  develop {d}");
    }
    let (fits, plan) = (fused.memory.fits(), fused.memory.to_string());
    let raise = "raise --memory or fuse fewer or smaller frames";
    eprintln!("  {}", memory_line(fits, &plan, raise));
    eprintln!("  time  load {:>8.1} ms", load_time.as_secs_f64() * 1e3);
    for (stage, d) in &fused.timings {
        eprintln!("  time  {stage:<5}{:>8.1} ms", d.as_secs_f64() * 1e3);
    }
    eprintln!("  time  save {:>8.1} ms", save_time.as_secs_f64() * 1e3);
    for (i, (s, p)) in sharp.iter().zip(&a.frames).enumerate() {
        eprintln!("  tenengrad  frame {i:>3} {s:>8.3}  {}", p.display());
    }
    eprintln!(
        "  tenengrad  output    {:>8.3}  {}",
        tenengrad(&fused.image),
        a.output.display()
    );
    Ok(())
}

/// The memory plan in one line, or the warning that the budget is below what the stack needs
/// with `raise`, how to raise it.
pub fn memory_line(within_budget: bool, plan: &str, raise: &str) -> String {
    if within_budget {
        format!("memory  {plan}")
    } else {
        format!("warning: {plan}; {raise}")
    }
}

/// Names the input file of a frame the registration could not place.
fn name_frame(e: FuseError, files: &[PathBuf]) -> anyhow::Error {
    match &e {
        FuseError::Register(RegisterError::Unmatched { frame, .. }) => {
            anyhow::anyhow!("{}: {e}", files[*frame].display())
        }
        _ => e.into(),
    }
}

/// One stderr line per frame: how it was registered and its exposure against the reference.
fn report_alignment(al: &Alignment, files: &[PathBuf]) {
    let reg = &al.registration;
    for (i, file) in files.iter().enumerate() {
        let how = match reg.how[i] {
            Placement::Reference => "reference".to_string(),
            Placement::Direct => format!(
                "matched  {:>4} inliers, rms {:.2} px, ncc {:.3}",
                reg.inliers[i], reg.residual_px[i], reg.correlation[i]
            ),
            Placement::Chained { via } => format!(
                "chained via frame {via}: {} inliers, rms {:.2} px, ncc {:.3}",
                reg.inliers[i], reg.residual_px[i], reg.correlation[i]
            ),
            Placement::Inherited { from } => {
                format!("too little texture to match: takes frame {from}'s pose, left out")
            }
        };
        let gains: Vec<String> = al.exposure[i]
            .iter()
            .map(|e| format!("{:.3}", e.gain))
            .collect();
        let local = match &reg.field[i] {
            Some(f) => format!(
                "local motion {:.1} px (99 %), {:.1} px (median)",
                f.reach(0.99),
                f.reach(0.5)
            ),
            None => "no local motion".to_string(),
        };
        eprintln!(
            "  align  frame {i:>3} {how}; {local}; gain {}  {}",
            gains.join("/"),
            file.display()
        );
    }
}

/// Copies the reference frame's EXIF block into an encoded JPEG (a no-op when it has none).
fn with_exif_of(reference: &Path, jpeg: Vec<u8>) -> Result<Vec<u8>> {
    let src = std::fs::read(reference)
        .with_context(|| format!("{}: cannot read", reference.display()))?;
    let exif = match Jpeg::from_bytes(Bytes::from(src)) {
        Ok(j) => j.exif(),
        Err(_) => None,
    };
    let Some(exif) = exif else {
        return Ok(jpeg);
    };
    // The frames were turned upright when loaded, so the output is too.
    let mut exif = exif.to_vec();
    io::exif_upright(&mut exif);
    let mut out = Jpeg::from_bytes(Bytes::from(jpeg)).context("re-reading the encoded output")?;
    out.set_exif(Some(Bytes::from(exif)));
    Ok(out.encoder().bytes().to_vec())
}
