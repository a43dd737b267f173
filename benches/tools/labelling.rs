//! Measures the labelling: its time and its labels' energy with the default candidates against
//! exhaustive expansion (every frame offered everywhere), on the same stack in the same run.
//!
//! `labelling compare [--runs N] [--no-align] [FRAME...]`: fuses the frames (or, given none, a
//! generated flats stack of 8 frames of 1152×864) once per setting and run, and prints the median
//! labelling and whole-fuse times and the energy of each setting's labels, computed by
//! `focusd::stack::internal::labelling_energy` on the aligned frames, with their ratio. The
//! spill removal is off: it moves labels afterwards on colour evidence the energy does not hold.
//!
//! `labelling flats DIR [--frames N] [--width W] [--height H] [--seed S] [--noise SIGMA]
//! [--patches N]`: writes a flats stack (`focusd::sim::flats`: smooth regions plus noise where
//! many frames tie; two textured patches a frame unless `--patches` says how many) as
//! DIR/frame_NN.png. `compare` takes the same options for the stack it generates.

use anyhow::{bail, Context, Result};
use focusd::files::imageio::load_rgb8;
use focusd::files::outputs::save_image as save;
use focusd::sim::flats::{flats, FlatsParams};
use focusd::stack::internal::{labelling_energy, warp_onto_reference};
use focusd::stack::{
    fuse, middle_frame, Coverage, FuseParams, Fused, GraphCutParams, Image, NoProgress, Stage,
};
use std::path::PathBuf;
use std::time::Instant;

const USAGE: &str = "usage: labelling compare [--runs N] [--no-align] [FRAME...] | \
                     labelling flats DIR [--frames N] [--width W] [--height H] [--seed S] \
                     [--noise SIGMA] [--patches N]";

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let command = args.next().context(USAGE)?;
    let mut numbers = Vec::new();
    let (mut paths, mut no_align) = (Vec::new(), false);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" | "--frames" | "--width" | "--height" | "--seed" | "--noise" | "--patches" => {
                let v = args.next().context(USAGE)?;
                numbers.push((a, v.parse::<f64>().context(USAGE)?));
            }
            "--no-align" => no_align = true,
            s if s.starts_with("--") => bail!("unknown option {s}\n{USAGE}"),
            _ => paths.push(PathBuf::from(a)),
        }
    }
    let given = |name: &str| {
        numbers
            .iter()
            .rev()
            .find(|(n, _)| n == name)
            .map(|&(_, v)| v)
    };
    let number = |name: &str, default: f64| given(name).unwrap_or(default);
    let generated = |frames| FlatsParams {
        width: number("--width", 1152.0) as usize,
        height: number("--height", 864.0) as usize,
        frames: number("--frames", frames) as usize,
        seed: number("--seed", 1.0) as u64,
        noise_sigma: number("--noise", FlatsParams::default().noise_sigma.into()) as f32,
        patches: given("--patches").map(|v| v as usize),
        ..FlatsParams::default()
    };
    match command.as_str() {
        "flats" => {
            let [dir] = &paths[..] else { bail!(USAGE) };
            std::fs::create_dir_all(dir)?;
            for (i, f) in flats(&generated(8.0)).iter().enumerate() {
                save(f, &dir.join(format!("frame_{i:02}.png")), 95)?;
            }
            Ok(())
        }
        "compare" => {
            let frames = if paths.is_empty() {
                flats(&generated(8.0))
            } else {
                paths
                    .iter()
                    .map(|p| load_rgb8(p).with_context(|| p.display().to_string()))
                    .collect::<Result<_>>()?
            };
            compare(frames, (number("--runs", 3.0) as usize).max(1), !no_align)
        }
        _ => bail!(USAGE),
    }
}

fn compare(frames: Vec<Image<u8>>, runs: usize, align: bool) -> Result<()> {
    let (n, w, h) = (frames.len(), frames[0].width(), frames[0].height());
    println!("{n} frames of {w}x{h}, {runs} runs each, align {align}");
    println!(
        "{:<12} {:>10} {:>10} {:>16}",
        "candidates", "labels s", "fuse s", "energy"
    );
    let mut energies = Vec::new();
    for graphcut in [GraphCutParams::default(), GraphCutParams::exhaustive()] {
        let candidates = graphcut.candidates;
        let params = FuseParams {
            graphcut,
            align: if align {
                Some(Default::default())
            } else {
                None
            },
            reference: middle_frame(n),
            spill: false,
            ..FuseParams::default()
        };
        let (mut labels_s, mut fuse_s, mut last) = (Vec::new(), Vec::new(), None);
        for _ in 0..runs {
            let t = Instant::now();
            let fused = fuse(frames.clone(), &params, &NoProgress)?;
            fuse_s.push(t.elapsed().as_secs_f64());
            let stage = fused.timings.iter().find(|(s, _)| *s == Stage::Labels);
            labels_s.push(stage.map_or(0.0, |(_, d)| d.as_secs_f64()));
            last = Some(fused);
        }
        let fused = last.expect("at least one run");
        let (aligned, coverage) = aligned(&frames, &fused, params.reference);
        let e = labelling_energy(
            &aligned,
            &coverage,
            &fused.labels,
            params.reference as u8,
            &params.graphcut,
        );
        let name = match candidates {
            usize::MAX => "exhaustive".to_string(),
            k => k.to_string(),
        };
        println!(
            "{name:<12} {:>10.3} {:>10.3} {e:>16}",
            median(labels_s),
            median(fuse_s)
        );
        energies.push(e);
    }
    println!(
        "energy ratio {:.4}",
        energies[0] as f64 / energies[1] as f64
    );
    Ok(())
}

/// The frames as the fuse labelled them: warped onto the reference by the fuse's own step.
fn aligned(
    frames: &[Image<u8>],
    fused: &Fused<u8>,
    reference: usize,
) -> (Vec<Image<u8>>, Vec<Coverage>) {
    let mut frames = frames.to_vec();
    let Some(a) = &fused.alignment else {
        let (w, h) = (frames[0].width(), frames[0].height());
        let n = frames.len();
        return (frames, vec![Coverage::full(w, h); n]);
    };
    let coverage = warp_onto_reference(
        &mut frames,
        &a.registration,
        &a.exposure,
        reference,
        &NoProgress,
    );
    (frames, coverage)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
