//! `focusd simulate`: renders a synthetic focus stack with ground truth into a directory.
//!
//! Files: `frame_NN.jpg` (frame i focused at plane i, 0 = nearest), `truth.png` (all-in-focus, in
//! the reference frame's geometry), `depth.png` (8-bit gray, plane i written as
//! round(i·255/(planes−1)), as `focusd fuse --depthmap` writes it), `transforms.json` (true
//! reference→frame affines) and `stack.json` (parameters and per-frame focus, gain and pose).

use anyhow::{bail, Context, Result};
use focusd::backend::replay::BundleWriter;
use focusd::files::dng::{self, DngInfo};
use focusd::files::imageio::encode;
use focusd::files::imageio::load_rgb8;
use focusd::files::outputs::{save_image, write_atomic};
use focusd::sim::bundle::{self, Shake};
use focusd::sim::texture::Photo;
use focusd::sim::{self, FrameInfo, SceneKind, SimParams};
use focusd::stack::{FrameTransform, Image, Transforms};
use serde::Serialize;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Render a synthetic focus stack with ground truth (frames, truth, depth, transforms).
#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Output directory (created if missing; existing files of the same names are replaced).
    #[arg(short = 'o', long = "output", value_name = "DIR")]
    pub output: PathBuf,
    /// Frame width in pixels (16..=8192).
    #[arg(long, default_value_t = 640)]
    pub width: usize,
    /// Frame height in pixels (16..=8192).
    #[arg(long, default_value_t = 480)]
    pub height: usize,
    /// Number of focus planes = frames (2..=64).
    #[arg(long, default_value_t = 6)]
    pub planes: usize,
    /// Random seed: the same arguments always give the same stack.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulate a hand-held sweep (shift, roll, breathing, parallax); default is an aligned stack.
    #[arg(long)]
    pub handheld: bool,
    /// Max hand-held translation as a fraction of the width (0..=0.2).
    #[arg(long, default_value_t = 0.03, value_name = "FRACTION")]
    pub max_shift: f64,
    /// Max hand-held roll in degrees (0..=10).
    #[arg(long = "max-rotation", default_value_t = 1.5, value_name = "DEGREES")]
    pub max_rotation: f64,
    /// Total magnification change across the sweep, hand-held only (0..=0.2).
    #[arg(long, default_value_t = 0.02)]
    pub breathing: f64,
    /// Per-frame gain jitter: gains uniform in 1±this (0..=0.5; reference keeps 1).
    #[arg(long, default_value_t = 0.0)]
    pub gain_jitter: f64,
    /// Per-frame, per-channel white-balance jitter: channel gains uniform in 1±this (0..=0.5).
    #[arg(long, default_value_t = 0.0)]
    pub wb_jitter: f64,
    /// Sensor read-noise sigma in 8-bit units, plus shot noise (0..=50).
    #[arg(long, default_value_t = 1.5, value_name = "SIGMA")]
    pub noise: f64,
    /// Extra shift of the nearest layers against the background at full shift, px (0..=8).
    #[arg(long, default_value_t = 1.0, value_name = "PX")]
    pub parallax: f64,
    /// Defocus sigma of a layer one plane from focus, px (0.3..=max-blur).
    #[arg(long, default_value_t = 2.0, value_name = "PX")]
    pub blur_per_plane: f64,
    /// Cap on the defocus sigma, px (0.5..=30).
    #[arg(long, default_value_t = 9.0, value_name = "PX")]
    pub max_blur: f64,
    /// Focus distance of the nearest plane, diopters (0.1..=1000).
    #[arg(long, default_value_t = 20.0)]
    pub near_diopters: f64,
    /// Focus distance of the farthest plane, diopters (0..near).
    #[arg(long, default_value_t = 5.0)]
    pub far_diopters: f64,
    /// Also write a replay bundle (bundle.toml, imu.csv): the frames as the takes of a focus
    /// sweep, with an IMU trace of hand tremor (see sim-data/README.md).
    #[arg(long)]
    pub bundle: bool,
    /// With --bundle: shake plane P's first N takes, then take it once more steadily;
    /// `P:N:stuck` leaves out the steady take, so the reshoots run out. Repeatable.
    #[arg(long, value_name = "P:N[:stuck]", requires = "bundle")]
    pub shake: Vec<String>,
    /// With --bundle: write the takes as raw DNGs (10-bit GRBG mosaics over a black level of
    /// 64), which a replay develops as the camera's raw frames.
    #[arg(long, requires = "bundle")]
    pub raw: bool,
    /// JPEG quality of the frames (1..=100).
    #[arg(long, default_value_t = 92)]
    pub quality: u32,
    /// Mix layers and blur in linear light, encoding sRGB only at the end, as a camera does.
    #[arg(long)]
    pub linear_light: bool,
    /// What the scene shows: layers (objects over a table-top, depth steps everywhere), tilted or
    /// curved (one surface, smooth depth, no occlusion), dark-on-light or light-on-dark (a few
    /// near objects over a tilted ground).
    #[arg(long, default_value = "layers", value_name = "KIND",
          value_parser = clap::builder::PossibleValuesParser::new(SceneKind::ALL.map(|k| k.1)))]
    pub scene: String,
    /// A photograph (JPEG, PNG or TIFF) to paint the scene with, mirrored to cover it: the
    /// surface of tilted and curved, the ground of dark-on-light, the objects of light-on-dark.
    #[arg(long, value_name = "FILE")]
    pub photo: Option<PathBuf>,
    /// Total magnification change across the sweep of a stack that is not hand-held (a tripod
    /// stack whose lens breathes), e.g. 0.006 (0..=0.2).
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    pub tripod_breathing: f64,
    /// Also write each frame's true per-pixel motion (`motion_NN.png`, see sim-data/README.md),
    /// what an aligned depth oracle needs on a stack with parallax.
    #[arg(long)]
    pub motion: bool,
}

impl SimulateArgs {
    pub fn params(&self) -> SimParams {
        SimParams {
            width: self.width,
            height: self.height,
            planes: self.planes,
            seed: self.seed,
            handheld: self.handheld,
            max_shift: self.max_shift,
            max_rotation_deg: self.max_rotation,
            breathing: self.breathing,
            gain_jitter: self.gain_jitter,
            wb_jitter: self.wb_jitter,
            noise_sigma: self.noise,
            parallax_px: self.parallax,
            blur_per_plane: self.blur_per_plane,
            max_blur: self.max_blur,
            near_diopters: self.near_diopters,
            far_diopters: self.far_diopters,
            linear_light: self.linear_light,
            scene: SceneKind::ALL
                .iter()
                .find(|k| k.1 == self.scene)
                .map_or(SceneKind::Layers, |k| k.0),
            tripod_breathing: self.tripod_breathing,
        }
    }

    /// The `--shake` plan, checked against the plane count.
    pub fn shakes(&self) -> Result<Vec<Shake>> {
        self.shake
            .iter()
            .map(|s| {
                let bad = || anyhow::anyhow!("--shake {s:?}: expected P:N or P:N:stuck, e.g. 2:2");
                let f: Vec<&str> = s.split(':').collect();
                let (plane, takes) = match f[..] {
                    [p, n] | [p, n, "stuck"] => (
                        p.parse::<usize>().map_err(|_| bad())?,
                        n.parse::<usize>().map_err(|_| bad())?,
                    ),
                    _ => return Err(bad()),
                };
                if plane >= self.planes || !(1..=20).contains(&takes) {
                    bail!(
                        "--shake {s:?}: plane must be below --planes {} and takes in 1..=20",
                        self.planes
                    );
                }
                Ok(Shake {
                    plane,
                    takes,
                    recovers: f.len() == 2,
                })
            })
            .collect()
    }

    /// Checks every argument; errors are one line naming the value and the allowed range.
    pub fn validate(&self) -> Result<SimParams> {
        if !(1..=100).contains(&self.quality) {
            bail!("--quality {} is out of range 1..=100", self.quality);
        }
        if self.photo.is_some() && self.scene == "layers" {
            bail!("--photo needs a --scene other than layers (tilted, curved, dark-on-light, light-on-dark)");
        }
        let p = self.params();
        if let Err(e) = p.validate() {
            // Name the command-line flag rather than the struct field.
            let (field, rest) = e.split_once(' ').unwrap_or((&e, ""));
            let flag = match field {
                "max_rotation_deg" => "max-rotation".to_string(),
                "noise_sigma" => "noise".to_string(),
                "parallax_px" => "parallax".to_string(),
                "stack" => bail!("{e}"),
                f => f.replace('_', "-"),
            };
            bail!("--{flag} {rest}");
        }
        Ok(p)
    }
}

/// One line of `stack.json`'s frame list.
#[derive(Serialize)]
struct FrameEntry<'a> {
    file: &'a str,
    /// Focus plane index (0 = nearest) = frame index.
    plane: usize,
    /// Focus distance in metres (1 / diopters).
    focus_distance_m: f64,
    #[serde(flatten)]
    info: &'a FrameInfo,
}

#[derive(Serialize)]
struct StackJson<'a> {
    generator: String,
    /// Command line that regenerates this directory exactly.
    command: String,
    seed: u64,
    params: &'a SimParams,
    jpeg_quality: u32,
    reference: usize,
    size: [usize; 2],
    truth: &'static str,
    depth: &'static str,
    depth_encoding: &'static str,
    steps: &'static str,
    /// The largest defocus sigma of any layer in any frame, px.
    max_sigma: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    motion: Option<&'static str>,
    transforms: &'static str,
    frames: Vec<FrameEntry<'a>>,
}

/// The exact command line for `p` (every parameter explicit) writing into `dir`.
pub fn command_line(p: &SimParams, quality: u32, dir: &Path) -> String {
    let mut s = format!(
        "focusd simulate -o {} --width {} --height {} --planes {} --seed {}",
        dir.display(),
        p.width,
        p.height,
        p.planes,
        p.seed
    );
    if p.handheld {
        s += &format!(
            " --handheld --max-shift {} --max-rotation {} --breathing {} --parallax {}",
            p.max_shift, p.max_rotation_deg, p.breathing, p.parallax_px
        );
    }
    s += &format!(
        " --gain-jitter {} --wb-jitter {} --noise {} --blur-per-plane {} --max-blur {} \
         --near-diopters {} --far-diopters {} --quality {quality}",
        p.gain_jitter,
        p.wb_jitter,
        p.noise_sigma,
        p.blur_per_plane,
        p.max_blur,
        p.near_diopters,
        p.far_diopters
    );
    if p.linear_light {
        s += " --linear-light";
    }
    if p.scene != SceneKind::Layers {
        let name = SceneKind::ALL
            .iter()
            .find(|k| k.0 == p.scene)
            .map_or("", |k| k.1);
        s += &format!(" --scene {name}");
    }
    if p.tripod_breathing > 0.0 {
        s += &format!(" --tripod-breathing {}", p.tripod_breathing);
    }
    s
}

/// The photograph `--photo` names, as the simulator's display values.
fn load_photo(path: &Path) -> Result<Photo> {
    let img = load_rgb8(path).with_context(|| format!("--photo {}", path.display()))?;
    Ok(Photo::from_rgb8(&img))
}

pub fn frame_name(i: usize) -> String {
    format!("frame_{i:02}.jpg")
}

pub fn motion_name(i: usize) -> String {
    format!("motion_{i:02}.png")
}

/// How `motion_NN.png` holds the motion (also written into stack.json).
const MOTION_ENCODING: &str = "motion_NN.png: 16-bit RGB; frame NN shows reference pixel (x, y) at \
     ref_to_frame(x, y) + (dx, dy) frame px, dx = (R - 32768) / 1024, dy = (G - 32768) / 1024, B = 0";

/// One motion component (frame px, |d| < 32) as `MOTION_ENCODING` stores it.
fn motion_code(d: f64) -> u16 {
    (d * 1024.0 + 32768.0).round().clamp(0.0, 65535.0) as u16
}

pub fn run(args: &SimulateArgs) -> Result<()> {
    let p = args.validate()?;
    let shakes = args.shakes()?;
    let dir = &args.output;
    fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create directory", dir.display()))?;
    let photo = args.photo.as_deref().map(load_photo).transpose()?;
    let scene = sim::scene::Scene::generate_with(&p, photo.map(Arc::new));
    let rendered = sim::render::render_scene(&p, &scene);
    let stack = &rendered.stack;
    let quality = args.quality as u8;
    let names: Vec<String> = (0..p.planes).map(frame_name).collect();
    for (frame, name) in stack.frames.iter().zip(&names) {
        save_image(frame, &dir.join(name), quality)?;
    }
    save_image(&stack.truth, &dir.join("truth.png"), quality)?;
    let scale = 255.0 / (p.planes - 1) as f32;
    let depth_png = Image::<u8>::from_vec(
        p.width,
        p.height,
        1,
        stack
            .depth
            .data()
            .iter()
            .map(|&i| (i as f32 * scale).round() as u8)
            .collect(),
    );
    save_image(&depth_png, &dir.join("depth.png"), quality)?;
    save_image(&stack.steps, &dir.join("steps.png"), quality)?;
    if args.motion {
        for i in 0..p.planes {
            let a = stack.ref_to_frame[i];
            let pos = sim::render::true_positions(&p, &scene, &rendered, i);
            let img = Image::<u16>::from_fn(p.width, p.height, 3, |x, y, c| {
                let (u, v) = pos[y * p.width + x];
                let (au, av) = a.apply(x as f64, y as f64);
                match c {
                    0 => motion_code(u - au),
                    1 => motion_code(v - av),
                    _ => 0,
                }
            });
            save_image(&img, &dir.join(motion_name(i)), quality)?;
        }
    }

    let transforms = Transforms {
        reference: stack.reference,
        size: [p.width, p.height],
        frames: names
            .iter()
            .zip(&stack.ref_to_frame)
            .map(|(name, a)| FrameTransform {
                file: name.clone(),
                ref_to_frame: *a,
                local_field: None,
            })
            .collect(),
    };
    write_atomic(
        &dir.join("transforms.json"),
        &serde_json::to_vec_pretty(&transforms)?,
    )?;

    let meta = StackJson {
        generator: format!("focusd simulate {}", env!("CARGO_PKG_VERSION")),
        command: command_line(&p, args.quality, dir)
            + if args.bundle { " --bundle" } else { "" }
            + if args.raw { " --raw" } else { "" }
            + &args
                .shake
                .iter()
                .map(|s| format!(" --shake {s}"))
                .collect::<String>()
            + &args
                .photo
                .as_ref()
                .map(|f| format!(" --photo {}", f.display()))
                .unwrap_or_default(),
        seed: p.seed,
        params: &p,
        jpeg_quality: args.quality,
        reference: stack.reference,
        size: [p.width, p.height],
        truth: "truth.png",
        depth: "depth.png",
        depth_encoding: "gray = round(plane * 255 / (planes - 1)); plane 0 = nearest focus",
        steps: "steps.png",
        max_sigma: stack.max_sigma,
        motion: args.motion.then_some(MOTION_ENCODING),
        transforms: "transforms.json",
        frames: names
            .iter()
            .zip(&stack.info)
            .enumerate()
            .map(|(i, (name, info))| FrameEntry {
                file: name,
                plane: i,
                focus_distance_m: 1.0 / info.focus_diopters,
                info,
            })
            .collect(),
    };
    let mut json = serde_json::to_vec_pretty(&meta)?;
    json.push(b'\n');
    write_atomic(&dir.join("stack.json"), &json)?;

    if args.bundle {
        write_bundle(&p, stack, &names, &shakes, dir, quality, args.raw)?;
    }

    let mut stale: Vec<String> = fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter_map(|e| e.file_name().into_string().ok())
                .filter(|f| f.starts_with("frame_") && f.ends_with(".jpg") && !names.contains(f))
                .collect()
        })
        .unwrap_or_default();
    if !stale.is_empty() {
        stale.sort();
        let more = stale.len().saturating_sub(3);
        stale.truncate(3);
        eprintln!(
            "focusd: warning: {}: {} frame file(s) from an earlier run left in place ({}{}); \
             remove them before fusing this directory",
            dir.display(),
            stale.len() + more,
            stale.join(", "),
            if more > 0 {
                format!(", and {more} more")
            } else {
                String::new()
            }
        );
    }
    println!(
        "wrote {} frames ({}x{}, {}) with truth, depth and transforms to {}",
        p.planes,
        p.width,
        p.height,
        if p.handheld { "hand-held" } else { "aligned" },
        dir.display()
    );
    Ok(())
}

/// The frames as the takes of a sweep: a steady take is its frame file, a shaken take a
/// smeared copy of it; with `raw`, each take is the DNG of its picture mosaicked.
fn write_bundle(
    p: &SimParams,
    stack: &sim::SimStack,
    names: &[String],
    shakes: &[Shake],
    dir: &Path,
    quality: u8,
    raw: bool,
) -> Result<()> {
    let (takes, imu) = bundle::plan(p.planes, shakes, p.seed);
    let mut w = BundleWriter::create(dir, bundle::LENS_RANGE)?;
    let dng_info = DngInfo {
        model: "focusd simulate".into(),
        ..DngInfo::default()
    };
    for t in &takes {
        let frame = &stack.frames[t.plane];
        let smeared = t.shaken.then(|| bundle::smear(frame, SHAKE_SMEAR_PX));
        if raw {
            let bytes = dng::encode(
                &bundle::raw_take(smeared.as_ref().unwrap_or(frame)),
                &dng_info,
            )?;
            w.add_take(t.plane, t.lens, t.exposure, "dng", &bytes)
        } else if let Some(smeared) = smeared {
            let bytes = encode(&smeared, image::ImageFormat::Jpeg, quality)?;
            w.add_take(t.plane, t.lens, t.exposure, "jpg", &bytes)
        } else {
            w.add_existing(t.plane, t.lens, t.exposure, &names[t.plane])
        }
        .with_context(|| format!("{}: cannot write the bundle", dir.display()))?;
    }
    w.finish(&imu)
        .with_context(|| format!("{}: cannot write the bundle", dir.display()))
}

/// Length of a shaken take's smear, pixels.
const SHAKE_SMEAR_PX: usize = 9;

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use focusd::files::imageio::{load, Decoded};

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: SimulateArgs,
    }

    fn parse(extra: &[&str]) -> SimulateArgs {
        let mut argv = vec!["simulate", "-o", "out"];
        argv.extend_from_slice(extra);
        Cli::try_parse_from(argv).unwrap().args
    }

    #[test]
    fn defaults_match_library_defaults() {
        let a = parse(&[]);
        assert_eq!(a.params(), SimParams::default());
        assert_eq!(a.quality, 92);
        let a = parse(&[
            "--handheld",
            "--planes",
            "8",
            "--seed",
            "2",
            "--max-rotation",
            "1",
        ]);
        let p = a.validate().unwrap();
        assert!(p.handheld && p.planes == 8 && p.seed == 2 && p.max_rotation_deg == 1.0);
    }

    #[test]
    fn bad_values_give_one_line_errors_with_range() {
        let err = |extra: &[&str]| parse(extra).validate().unwrap_err().to_string();
        assert_eq!(err(&["--planes", "1"]), "--planes 1 is out of range 2..=64");
        assert_eq!(
            err(&["--width", "8"]),
            "--width 8 is out of range 16..=8192"
        );
        assert_eq!(
            err(&["--quality", "0"]),
            "--quality 0 is out of range 1..=100"
        );
        assert_eq!(err(&["--noise=-1"]), "--noise -1 is out of range 0..=50");
        assert_eq!(
            err(&["--max-rotation", "20"]),
            "--max-rotation 20 is out of range 0..=10"
        );
        assert_eq!(
            err(&["--parallax", "9"]),
            "--parallax 9 is out of range 0..=8"
        );
        assert!(err(&["--width", "8192", "--height", "8192"]).starts_with("stack 8192x8192x6"));
        assert!(!err(&["--blur-per-plane", "12"]).contains('\n'));
    }

    #[test]
    fn writes_a_complete_stack() {
        let dir = std::env::temp_dir().join(format!("focusd-simulate-test-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let mut args = parse(&[
            "--width",
            "64",
            "--height",
            "48",
            "--planes",
            "4",
            "--handheld",
            "--parallax",
            "6",
            "--linear-light",
            "--motion",
        ]);
        args.output = dir.join("nested");
        run(&args).unwrap();
        let out = &args.output;
        for i in 0..4 {
            match load(&out.join(frame_name(i))).unwrap() {
                Decoded::U8(f) => assert_eq!((f.width(), f.height(), f.channels()), (64, 48, 3)),
                Decoded::U16(_) => panic!("frames are 8-bit"),
            }
        }
        let Decoded::U8(depth) = load(&out.join("depth.png")).unwrap() else {
            panic!("depth is 8-bit")
        };
        assert_eq!(depth.channels(), 1);
        assert!(depth.data().iter().all(|v| [0, 85, 170, 255].contains(v)));
        let Decoded::U8(truth) = load(&out.join("truth.png")).unwrap() else {
            panic!("truth is 8-bit")
        };
        assert_eq!((truth.width(), truth.channels()), (64, 3));
        let Decoded::U8(steps) = load(&out.join("steps.png")).unwrap() else {
            panic!("steps are 8-bit")
        };
        assert!(steps.data().contains(&255) && steps.data().contains(&0));
        // The written motion is the simulator's: the reference does not move, the others move
        // by their affine plus up to the frame's parallax on near layers.
        let p = args.params();
        let scene = sim::scene::Scene::generate(&p);
        let r = sim::render::render_scene(&p, &scene);
        for i in 0..4 {
            let Decoded::U16(m) = load(&out.join(motion_name(i))).unwrap() else {
                panic!("motion is 16-bit")
            };
            let pos = sim::render::true_positions(&p, &scene, &r, i);
            let a = r.stack.ref_to_frame[i];
            let mut most = 0.0f64;
            for (k, &(u, v)) in pos.iter().enumerate() {
                let (x, y) = ((k % 64) as f64, (k / 64) as f64);
                let (au, av) = a.apply(x, y);
                let dx = (m.data()[3 * k] as f64 - 32768.0) / 1024.0;
                let dy = (m.data()[3 * k + 1] as f64 - 32768.0) / 1024.0;
                assert!((au + dx - u).abs() < 1e-3 && (av + dy - v).abs() < 1e-3);
                most = most.max(dx.hypot(dy));
            }
            assert_eq!(most == 0.0, i == 1, "frame {i}: largest motion {most}");
        }
        let t: Transforms =
            serde_json::from_slice(&fs::read(out.join("transforms.json")).unwrap()).unwrap();
        assert_eq!((t.reference, t.size, t.frames.len()), (1, [64, 48], 4));
        assert_eq!(t.frames[2].file, "frame_02.jpg");
        assert_eq!(t.frames[1].ref_to_frame, focusd::stack::Affine::IDENTITY);
        let s: serde_json::Value =
            serde_json::from_slice(&fs::read(out.join("stack.json")).unwrap()).unwrap();
        assert_eq!(s["seed"], 1);
        assert_eq!(s["params"]["planes"], 4);
        assert_eq!(s["frames"][0]["focus_diopters"], 20.0);
        assert_eq!(s["frames"][1]["gain"], 1.0);
        assert_eq!(s["params"]["linear_light"], true);
        assert_eq!(s["max_sigma"], 6.0);
        assert!(s["command"].as_str().unwrap().ends_with(
            "--parallax 6 --gain-jitter 0 --wb-jitter 0 --noise 1.5 --blur-per-plane 2 \
                 --max-blur 9 --near-diopters 20 --far-diopters 5 --quality 92 --linear-light"
        ));
        // No temporary files are left behind.
        assert!(fs::read_dir(out).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".tmp")));
        fs::remove_dir_all(&dir).unwrap();
    }
}
