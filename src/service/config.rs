//! The configuration file (`config/focusd.toml`): one table per part, every key optional.
//! Unknown keys and bad values are refused with the file, the line and what is allowed.

use crate::backend::iio::IioConfig;
use crate::backend::v4l2::V4l2Config;
use crate::capture::sweep::SweepConfig;
use crate::stack::fuse::{FuseParams, Method};
use crate::stack::graphcut::GraphCutParams;
use crate::stack::memory::DEFAULT_BUDGET;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// How to fuse a captured stack (the `[fuse]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FuseConfig {
    /// `graphcut` (the paper's method) or `pyramid` (the enfuse-style baseline).
    pub method: FuseMethod,
    /// Seam weight against the focus cost, 0.01..=10.
    pub lambda: f32,
    /// JPEG quality of the output, 1..=100.
    pub quality: u8,
    /// Crop to the area every registered frame covers.
    pub crop: bool,
    /// Memory budget of a fuse in MiB, 64..=65536 (see `stack::memory`).
    pub memory_mb: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FuseMethod {
    Graphcut,
    Pyramid,
}

impl Default for FuseConfig {
    fn default() -> Self {
        Self {
            method: FuseMethod::Graphcut,
            lambda: GraphCutParams::default().lambda,
            quality: 92,
            crop: false,
            memory_mb: (DEFAULT_BUDGET >> 20) as u32,
        }
    }
}

impl FuseConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(0.01..=10.0).contains(&self.lambda) {
            return Err(format!(
                "lambda = {} is out of range 0.01..=10",
                self.lambda
            ));
        }
        if !(1..=100).contains(&self.quality) {
            return Err(format!(
                "quality = {} is out of range 1..=100",
                self.quality
            ));
        }
        if !(64..=65536).contains(&self.memory_mb) {
            return Err(format!(
                "memory_mb = {} is out of range 64..=65536",
                self.memory_mb
            ));
        }
        Ok(())
    }

    /// The engine's parameters for a stack of `frames` frames (reference: the middle one).
    pub fn params(&self, frames: usize) -> FuseParams {
        let mut p = FuseParams {
            method: match self.method {
                FuseMethod::Graphcut => Method::GraphCut,
                FuseMethod::Pyramid => Method::Pyramid,
            },
            reference: frames.saturating_sub(1) / 2,
            crop: self.crop,
            memory: (self.memory_mb as usize) << 20,
            ..FuseParams::default()
        };
        p.graphcut.lambda = self.lambda;
        p
    }
}

/// Where results go (the `[output]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// The only directory the daemon writes images to. Relative paths are relative to the
    /// working directory (systemd: the state directory).
    pub dir: PathBuf,
    /// `jpg`, `png` or `tif`.
    pub format: String,
    /// Also write the JSON report beside each image.
    pub report: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            dir: PathBuf::from("focusd"),
            format: "jpg".into(),
            report: true,
        }
    }
}

impl OutputConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !["jpg", "png", "tif"].contains(&self.format.as_str()) {
            return Err(format!(
                "format = {:?} is not one of \"jpg\", \"png\", \"tif\"",
                self.format
            ));
        }
        if self.dir.as_os_str().is_empty() {
            return Err("dir is empty: name the directory outputs go to".into());
        }
        Ok(())
    }
}

/// The whole file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub camera: V4l2Config,
    pub imu: IioConfig,
    /// Unset in the file: a replay sweeps its bundle's own planes and lens positions, a phone
    /// the defaults.
    pub sweep: Option<SweepConfig>,
    pub fuse: FuseConfig,
    pub output: OutputConfig,
}

/// A config file that cannot be used; the message is `FILE:LINE: problem`.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ConfigError(String);

impl Config {
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ConfigError(format!("{}: cannot read: {e}", path.display())))?;
        Config::parse(&text).map_err(|(line, why)| {
            ConfigError(match line {
                Some(l) => format!("{}:{l}: {why}", path.display()),
                None => format!("{}: {why}", path.display()),
            })
        })
    }

    /// Parses and checks a file's text; an error comes with its 1-based line when known.
    pub fn parse(text: &str) -> Result<Config, (Option<usize>, String)> {
        let config: Config = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            (line, e.message().trim().to_string())
        })?;
        config.validate(text)?;
        Ok(config)
    }

    fn validate(&self, text: &str) -> Result<(), (Option<usize>, String)> {
        let sweep = self.sweep.as_ref().map_or(Ok(()), |s| {
            // The lens range is the camera's, known only once it is open: checked then.
            s.validate((i32::MIN, i32::MAX))
        });
        for (table, result) in [
            ("camera", self.camera.validate()),
            ("imu", self.imu.validate()),
            ("sweep", sweep),
            ("fuse", self.fuse.validate()),
            ("output", self.output.validate()),
        ] {
            if let Err(why) = result {
                let key = why
                    .split([' ', ':', '='])
                    .next()
                    .unwrap_or_default()
                    .to_string();
                return Err((line_of(text, table, &key), format!("[{table}] {why}")));
            }
        }
        Ok(())
    }
}

/// The line of `key` (maybe dotted, `thresholds.gyro`) in `[table]`, written either under
/// its own header (`[sweep.thresholds]`) or dotted under the table's.
fn line_of(text: &str, table: &str, key: &str) -> Option<usize> {
    let (sub, leaf) = match key.rsplit_once('.') {
        Some((sub, leaf)) => (format!("{table}.{sub}"), leaf),
        None => (table.to_string(), key),
    };
    let mut current = String::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if let Some(h) = l.strip_prefix('[') {
            current = h.trim_end_matches(']').trim().to_string();
            continue;
        }
        let Some((k, _)) = l.split_once('=') else {
            continue;
        };
        let k = k.trim();
        if (current == sub && k == leaf) || (current == table && k == key) {
            return Some(i + 1);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> (Option<usize>, String) {
        Config::parse(text).unwrap_err()
    }

    #[test]
    fn the_shipped_config_is_valid_and_is_the_defaults_spelled_out() {
        let text = include_str!("../../config/focusd.toml");
        let c = Config::parse(text).unwrap();
        let spelled = Config {
            sweep: Some(SweepConfig::default()),
            ..Config::default()
        };
        assert_eq!(c.camera, spelled.camera);
        assert_eq!(c.imu, spelled.imu);
        assert_eq!(c.sweep, spelled.sweep);
        assert_eq!(c.fuse, spelled.fuse);
        assert_eq!(c.output.format, spelled.output.format);
    }

    #[test]
    fn bad_values_name_the_line_the_key_and_the_range() {
        let text = "# a comment\n[sweep]\nplanes = 1\n";
        assert_eq!(
            err(text),
            (
                Some(3),
                "[sweep] planes = 1 is out of range 2..=64".to_string()
            )
        );
        let text = "[sweep]\nplanes = 5\n\n[sweep.thresholds]\ngyro = -1.0\n";
        let (line, why) = err(text);
        assert_eq!(line, Some(5), "{why}");
        assert!(
            why.contains("thresholds.gyro = -1 must be a positive number"),
            "{why}"
        );
        let text = "[fuse]\nquality = 0\n";
        assert_eq!(err(text).0, Some(2));
        let text = "[camera]\nsettle_ms = 5000\n";
        let (line, why) = err(text);
        assert_eq!(
            (line, why.as_str()),
            (
                Some(2),
                "[camera] settle_ms = 5000 is out of range 0..=1000"
            )
        );
        let text = "[imu]\nsampling_hz = 0.5\n";
        assert!(err(text)
            .1
            .contains("sampling_hz = 0.5 is out of range 1..=8000"));
        let text = "[output]\nformat = \"gif\"\n";
        assert!(err(text).1.contains("format = \"gif\" is not one of"));
    }

    #[test]
    fn unknown_keys_and_wrong_types_name_the_line() {
        let (line, why) = err("[sweep]\nplanes = 4\nplains = 5\n");
        assert_eq!(line, Some(3), "{why}");
        assert!(why.contains("unknown field `plains`"), "{why}");
        let (line, why) = err("[camera]\n\nwidth = \"wide\"\n");
        assert_eq!(line, Some(3), "{why}");
        assert!(why.contains("invalid type"), "{why}");
        let (line, why) = err("[nonsense]\n");
        assert_eq!(line, Some(1), "{why}");
        let (line, _) = err("[sweep\nplanes = 4\n");
        assert_eq!(line, Some(1));
        let (_, why) = err("[sweep]\non_exhausted = \"retry\"\n");
        assert!(
            why.contains("fail") && why.contains("keep-least-shaken"),
            "{why}"
        );
    }

    proptest::proptest! {
        #[test]
        fn parser_never_panics(s in "(\\[[a-z.]{0,12}\\]\n|[a-z_]{1,10} = [-0-9a-z\".]{0,8}\n){0,6}") {
            let _ = Config::parse(&s);
        }
    }
}
