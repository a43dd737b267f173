//! The fuse settings that `focusd fuse` and the config's `[fuse]` table share. Each is defined
//! once here — type, default, range, parsing, help text — and turned into the engine's
//! parameters once, so a new shared setting is added in one place and the two cannot drift.
//! Options that only make sense for files on the command line (`--reference`, `--no-align`,
//! `--depthmap`, `--save-transforms`) stay in `cli::fuse`.

use crate::base::setting::{Bounds, Invalid};
use crate::stack::graphcut::GraphCutParams;
use crate::stack::params::{middle_frame, FuseParams, Method, DEFAULT_BUDGET};
use serde::{Deserialize, Serialize};

const LAMBDA: Bounds<f32> = Bounds::new(0.01, 10.0);
pub const QUALITY: Bounds<u8> = Bounds::new(1, 100);
const MEMORY_MIB: Bounds<u32> = Bounds::new(64, 65536);

/// `[fuse]` in the config; flattened into `focusd fuse`'s options (flag names in brackets where
/// they differ from the key).
#[derive(clap::Args, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FuseSettings {
    #[arg(long, value_enum, default_value_t = FuseSettings::default().method)]
    pub method: FuseMethod,
    /// Seam weight λ against the focus cost, 0.01..=10; higher gives fewer, smoother seams.
    #[arg(long, default_value_t = FuseSettings::default().lambda, value_parser = LAMBDA.parser())]
    pub lambda: f32,
    /// JPEG quality, 1..=100.
    #[arg(long, default_value_t = FuseSettings::default().quality,
          value_parser = QUALITY.parser())]
    pub quality: u8,
    /// Crop the output to the largest rectangle every aligned frame covers (by default the
    /// output has the reference frame's full size, filled from the frames that cover it).
    #[arg(long, conflicts_with = "no_align")]
    pub crop: bool,
    /// Memory budget in MiB, 64..=65536 (`--memory`): a tighter one composes and labels in
    /// bands of rows and registers fewer frames at once (slower, same image). Below what the
    /// stack needs at least, `focusd fuse` refuses it before decoding a frame and names the
    /// budget it needs; a capture (whose frames come from the camera) fuses anyway in the
    /// smallest bands and warns.
    #[arg(long = "memory", value_name = "MIB", default_value_t = FuseSettings::default().memory_mb,
          value_parser = MEMORY_MIB.parser())]
    pub memory_mb: u32,
    /// Local registration (`--no-local-registration` turns it off): on top of each frame's
    /// global affine, a dense displacement field for near objects that move against the
    /// background by parallax in a hand-held sweep.
    #[arg(long = "no-local-registration", action = clap::ArgAction::SetFalse)]
    pub local_registration: bool,
    /// Halo removal (`--no-spill-removal` turns it off): where a near object meets the
    /// background, its defocused colour is taken out of the frames focused farther before
    /// they are composed, those frames do not give the near object's pixels their finest
    /// detail, the background seen through its defocused edge, and the label repairs run
    /// (graph cut only; off, it turns the label repairs off too).
    #[arg(long = "no-spill-removal", action = clap::ArgAction::SetFalse)]
    pub spill_removal: bool,
    /// Label repairs (`--no-label-repair` turns them off): where the labels gave a near object's
    /// edge a frame focused behind it, a plain near object takes the frame that shows its
    /// outline crisp, and the pixels next to a depth step whose colour is clearly the near
    /// object's take its frame. They run within the spill removal (graph cut only).
    #[arg(long = "no-label-repair", action = clap::ArgAction::SetFalse)]
    pub label_repair: bool,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FuseMethod {
    /// Graph-cut labelling with seam blending (the paper's method).
    Graphcut,
    /// Laplacian-pyramid max-contrast fusion (the enfuse-style baseline).
    Pyramid,
}

impl Default for FuseSettings {
    fn default() -> Self {
        Self {
            method: FuseMethod::Graphcut,
            lambda: GraphCutParams::default().lambda,
            quality: 92,
            crop: false,
            memory_mb: (DEFAULT_BUDGET >> 20) as u32,
            local_registration: true,
            spill_removal: true,
            label_repair: true,
        }
    }
}

impl FuseSettings {
    /// The command line's parser refuses the same values as it parses them.
    pub fn validate(&self) -> Result<(), Invalid> {
        LAMBDA.check("lambda", self.lambda)?;
        QUALITY.check("quality", self.quality)?;
        MEMORY_MIB.check("memory_mb", self.memory_mb)
    }

    /// The engine's parameters for a stack of `frames` frames, registered to the middle one.
    pub fn params(&self, frames: usize) -> FuseParams {
        let mut p = FuseParams {
            method: match self.method {
                FuseMethod::Graphcut => Method::GraphCut,
                FuseMethod::Pyramid => Method::Pyramid,
            },
            reference: middle_frame(frames),
            crop: self.crop,
            memory: (self.memory_mb as usize) << 20,
            spill: self.spill_removal,
            label_repair: self.label_repair,
            ..FuseParams::default()
        };
        p.graphcut.lambda = self.lambda;
        if let Some(a) = &mut p.align {
            a.local = self.local_registration;
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    /// The settings alone, as `focusd fuse` takes them.
    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        settings: FuseSettings,
        #[arg(long)]
        no_align: bool,
    }

    fn cli(args: &[&str]) -> Result<FuseSettings, clap::Error> {
        let argv = std::iter::once("fuse").chain(args.iter().copied());
        Cli::try_parse_from(argv).map(|c| c.settings)
    }

    #[test]
    fn the_command_line_and_the_file_have_the_same_defaults_and_ranges() {
        assert_eq!(cli(&[]).unwrap(), FuseSettings::default());
        let file = |t: &str| toml::from_str::<FuseSettings>(t).unwrap();
        assert_eq!(file(""), FuseSettings::default());
        let both = cli(&[
            "--method",
            "pyramid",
            "--lambda",
            "2.5",
            "--quality",
            "80",
            "--crop",
            "--memory",
            "100",
            "--no-local-registration",
            "--no-spill-removal",
            "--no-label-repair",
        ])
        .unwrap();
        let text =
            "method = \"pyramid\"\nlambda = 2.5\nquality = 80\ncrop = true\nmemory_mb = 100\n\
                    local_registration = false\nspill_removal = false\nlabel_repair = false";
        assert_eq!(both, file(text));
        for (flag, key, bad) in [
            ("--lambda", "lambda", "10.5"),
            ("--lambda", "lambda", "0.001"),
            ("--quality", "quality", "0"),
            ("--memory", "memory_mb", "63"),
            ("--memory", "memory_mb", "65537"),
        ] {
            let err = cli(&[flag, bad]).unwrap_err().to_string();
            assert!(err.contains(&format!("{bad} is out of range")), "{err}");
            let refused = file(&format!("{key} = {bad}")).validate().unwrap_err();
            assert_eq!(refused.key, key);
            assert!(refused.message.contains(&format!("{bad} is out of range")));
        }
    }

    #[test]
    fn params_take_the_middle_frame_and_the_budget_in_bytes() {
        let p = FuseSettings {
            method: FuseMethod::Pyramid,
            lambda: 1.5,
            memory_mb: 100,
            ..FuseSettings::default()
        }
        .params(6);
        assert_eq!(
            (p.reference, p.memory, p.method),
            (2, 100 << 20, Method::Pyramid)
        );
        assert_eq!(p.graphcut.lambda, 1.5);
        assert!(p.align.as_ref().is_some_and(|a| a.local));
        let off = FuseSettings {
            local_registration: false,
            ..FuseSettings::default()
        };
        assert!(off.params(6).align.is_some_and(|a| !a.local));
        assert!(FuseSettings::default().params(6).spill);
        let kept = FuseSettings {
            spill_removal: false,
            ..FuseSettings::default()
        };
        assert!(!kept.params(6).spill);
        assert!(FuseSettings::default().params(6).label_repair);
        let unrepaired = FuseSettings {
            label_repair: false,
            ..FuseSettings::default()
        };
        assert!(!unrepaired.params(6).label_repair);
    }
}
