//! The configuration file (`config/focusd.toml`): one table per part, every key optional.
//! Unknown keys and bad values are refused with the file, the line and what is allowed.

use super::fuse_settings::FuseSettings;
use crate::backend::iio::IioConfig;
use crate::backend::input::TriggerConfig;
use crate::backend::v4l2::V4l2Config;
use crate::base::setting::{Bounds, Invalid};
use crate::capture::sweep::SweepConfig;
use serde::{Deserialize, Serialize};
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};

/// Where results go (the `[output]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// The only directory the daemon writes images to. Relative paths are relative to the
    /// working directory (systemd: the state directory); the daemon makes them absolute when
    /// it loads the config (`output_dir::settle`). Unset: the session service writes to
    /// `focusd` in the user's Pictures folder (`service::pictures`), the system service to
    /// `focusd` in its working directory ([`SYSTEM_OUTPUT_DIR`]).
    pub dir: Option<PathBuf>,
    /// `jpg`, `png` or `tif`.
    pub format: String,
    /// Also write the JSON report beside each image.
    pub report: bool,
    /// Also keep a capture's raw takes, as DNGs beside its image (`focus-…-raw-00.dng`, …),
    /// for raw tools; a camera that delivers developed frames has none to keep.
    pub keep_raw: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            dir: None,
            format: "jpg".into(),
            report: true,
            keep_raw: false,
        }
    }
}

impl OutputConfig {
    pub fn validate(&self) -> Result<(), Invalid> {
        if !["jpg", "png", "tif"].contains(&self.format.as_str()) {
            return Err(Invalid::new(
                "format",
                format!(
                    "format = {:?} is not one of \"jpg\", \"png\", \"tif\"",
                    self.format
                ),
            ));
        }
        if self.dir.as_ref().is_some_and(|d| d.as_os_str().is_empty()) {
            return Err(Invalid::new(
                "dir",
                "dir is empty: name the directory outputs go to, or leave it out",
            ));
        }
        if self
            .dir
            .as_ref()
            .is_some_and(|d| d.as_os_str().as_bytes().contains(&0))
        {
            return Err(Invalid::new(
                "dir",
                "dir contains a NUL byte, which no path can hold",
            ));
        }
        Ok(())
    }

    /// The output directory: `dir`, or the system service's default.
    pub fn dir(&self) -> &Path {
        self.dir.as_deref().unwrap_or(Path::new(SYSTEM_OUTPUT_DIR))
    }
}

/// The system service's output directory when `[output] dir` is unset, relative to its working
/// directory (the unit's state directory, `/var/lib/focusd`).
pub const SYSTEM_OUTPUT_DIR: &str = "focusd";

/// How the daemon watches its jobs (the `[service]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    /// Seconds a job may go without progress (or run on after a cancel) before the daemon
    /// reports it as stalled and exits for systemd to restart it. Below the unit's
    /// `WatchdogSec=30s`, so focusd reports the stall before systemd kills it.
    pub stall_timeout_s: u64,
    /// Seconds the live preview runs after a client's last `StartPreview`, so one that
    /// forgets to stop it does not keep the camera open.
    pub preview_timeout_s: u64,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        Self {
            stall_timeout_s: 20,
            preview_timeout_s: 120,
        }
    }
}

impl ServiceConfig {
    pub fn validate(&self) -> Result<(), Invalid> {
        Bounds::new(1, 3600).check("stall_timeout_s", self.stall_timeout_s)?;
        Bounds::new(1, 3600).check("preview_timeout_s", self.preview_timeout_s)
    }

    pub fn preview_timeout(&self) -> std::time::Duration {
        std::time::Duration::from_secs(self.preview_timeout_s)
    }

    pub fn stall_timeout(&self) -> std::time::Duration {
        std::time::Duration::from_secs(self.stall_timeout_s)
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
    pub fuse: FuseSettings,
    pub output: OutputConfig,
    pub service: ServiceConfig,
    pub trigger: TriggerConfig,
}

/// A config file that cannot be used; the message is `FILE:LINE: problem`.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ConfigError(String);

impl Config {
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text =
            crate::files::bounded_read::read_to_string(path, crate::files::bounded_read::TEXT_CAP)
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
            ("service", self.service.validate()),
            ("trigger", self.trigger.validate()),
        ] {
            if let Err(e) = result {
                return Err((line_of(text, table, e.key), format!("[{table}] {e}")));
            }
        }
        Ok(())
    }
}

/// The 1-based line where `key` (maybe dotted, `thresholds.gyro`) of `[table]` is set, however
/// the file spells it (under `[sweep.thresholds]`, dotted under `[sweep]`, inline), from the
/// spans of the parsed document.
fn line_of(text: &str, table: &str, key: &str) -> Option<usize> {
    use toml::de::{DeTable, DeValue};
    let doc = DeTable::parse(text).ok()?;
    let mut t = doc.get_ref();
    let mut span = None;
    for part in std::iter::once(table).chain(key.split('.')) {
        let (k, v) = t.get_key_value(part)?;
        span = Some(k.span());
        match v.get_ref() {
            DeValue::Table(inner) => t = inner,
            _ => break,
        }
    }
    span.map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
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
        assert_eq!(c.output.keep_raw, spelled.output.keep_raw);
        assert_eq!(c.service, spelled.service);
        assert_eq!(c.trigger, spelled.trigger);
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
            why.contains("thresholds.gyro = -1 is out of range 0.000000001..=10"),
            "{why}"
        );
        let text = "[fuse]\nquality = 0\n";
        assert_eq!(err(text).0, Some(2));
        // A still window whose nanoseconds would overflow, one that could never be still, and a
        // timeout shorter than the window.
        let text = "[sweep]\nstill_ms = 10000000000000\n";
        assert_eq!(
            err(text),
            (
                Some(2),
                "[sweep] still_ms = 10000000000000 is out of range 20..=10000".to_string()
            )
        );
        assert!(err("[sweep]\nstill_ms = 0\n").1.contains("still_ms = 0"));
        let (line, why) = err("[sweep]\nstill_ms = 500\nstill_timeout_ms = 400\n");
        assert_eq!(line, Some(3), "{why}");
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
        let (line, why) = err("[output]\nkeep_raw = \"yes\"\n");
        assert_eq!(line, Some(2), "{why}");
        assert!(why.contains("expected a boolean"), "{why}");
        assert!(
            Config::parse("[output]\nkeep_raw = true\n")
                .unwrap()
                .output
                .keep_raw
        );
        let text = "[service]\nstall_timeout_s = 0\n";
        assert_eq!(
            err(text),
            (
                Some(2),
                "[service] stall_timeout_s = 0 is out of range 1..=3600".to_string()
            )
        );
        let text = "[trigger]\nkeys = [\"KEY_VOLUMEUP\"]\nlong_press_ms = 50\n";
        assert_eq!(
            err(text),
            (
                Some(3),
                "[trigger] long_press_ms = 50 is out of range 100..=10000".to_string()
            )
        );
        let (line, why) = err("[trigger]\nkeys = [\"KEY_CAMERA_FOCUS\"]\n");
        assert_eq!(line, Some(2), "{why}");
        assert!(why.starts_with("[trigger] keys: KEY_CAMERA_FOCUS is the camera key's half-press"));
        let (line, why) = err("\n[trigger]\nkeys = [\"KEY_CAMERA\", \"camera\"]\n");
        assert_eq!(line, Some(3), "{why}");
        assert!(
            why.contains("\"camera\" is not a key focusd knows"),
            "{why}"
        );
        assert!(err("[trigger]\ndevice = \"\"\n")
            .1
            .contains("device is empty"));
        let c = Config::parse("[trigger]\nkeys = []\ndevice = \"gpio-keys\"\n").unwrap();
        assert!(c.trigger.keys.is_empty());
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
