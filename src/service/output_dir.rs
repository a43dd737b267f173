//! The output directory: the only place the daemon writes images, under names it makes
//! itself from the capture time, so no caller can steer a write anywhere else. The writing
//! itself is `files::outputs`'s.

use super::config::OutputConfig;
use super::ServiceError;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// Creates the output directory if needed.
pub fn prepare(out: &OutputConfig) -> Result<(), ServiceError> {
    std::fs::create_dir_all(out.dir()).map_err(|error| ServiceError::OutputDir {
        dir: out.dir().display().to_string(),
        error,
    })
}

/// Creates the output directory if needed and makes its path absolute, so every path the
/// daemon reports (signals, `LastResult`, notifications, reports) opens from any directory.
pub fn settle(out: &mut OutputConfig) -> Result<(), ServiceError> {
    prepare(out)?;
    let dir = std::path::absolute(out.dir()).map_err(|error| ServiceError::OutputDir {
        dir: out.dir().display().to_string(),
        error,
    })?;
    out.dir = Some(dir);
    Ok(())
}

/// The image and report paths of a capture made now: `focus-YYYYMMDD-HHMMSS.jpg` in UTC, with
/// `-2`, `-3`, ... when that name is taken (by an image, a report or kept raw takes).
pub fn next_paths(out: &OutputConfig) -> Result<(PathBuf, PathBuf), ServiceError> {
    prepare(out)?;
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let stem = format!("focus-{}", utc_stamp(secs));
    for n in 1.. {
        let name = if n == 1 {
            stem.clone()
        } else {
            format!("{stem}-{n}")
        };
        let image = out.dir().join(format!("{name}.{}", out.format));
        let report = out.dir().join(format!("{name}.json"));
        if !image.exists() && !report.exists() && !raw_path(&image, 0).exists() {
            return Ok((image, report));
        }
    }
    unreachable!("an unbounded range ends only by returning")
}

/// Where a capture's raw take of `plane` is kept (`[output] keep_raw`): beside its picture,
/// named after it (`focus-….jpg` keeps `focus-…-raw-00.dng`, `focus-…-raw-01.dng`, …).
pub fn raw_path(output: &Path, plane: usize) -> PathBuf {
    let stem = output.file_stem().unwrap_or_default().to_string_lossy();
    output.with_file_name(format!("{stem}-raw-{plane:02}.dng"))
}

/// `YYYYMMDD-HHMMSS` of a Unix time, in UTC.
fn utc_stamp(secs: u64) -> String {
    let [year, month, day, hour, minute, second] = crate::base::civil::utc(secs);
    format!("{year:04}{month:02}{day:02}-{hour:02}{minute:02}{second:02}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_are_utc_calendar_times() {
        assert_eq!(utc_stamp(0), "19700101-000000");
        assert_eq!(utc_stamp(951_782_400), "20000229-000000");
        assert_eq!(utc_stamp(1_796_083_199), "20261130-235959");
        assert_eq!(utc_stamp(4_107_542_400), "21000301-000000");
    }

    /// A relative `dir` (here one climbing from the working directory into a temporary one)
    /// is made absolute, and so is every path made in it.
    #[test]
    fn a_relative_dir_is_settled_as_an_absolute_one() {
        let tmp = tempfile::tempdir().unwrap();
        let cwd = std::env::current_dir().unwrap();
        let up: std::path::PathBuf = cwd.components().skip(1).map(|_| "..").collect();
        let relative = up.join(tmp.path().strip_prefix("/").unwrap()).join("out");
        let mut out = OutputConfig {
            dir: Some(relative.clone()),
            ..OutputConfig::default()
        };
        settle(&mut out).unwrap();
        assert!(out.dir().is_absolute() && out.dir().is_dir(), "{out:?}");
        assert_eq!(out.dir(), cwd.join(&relative));
        let (image, report) = next_paths(&out).unwrap();
        assert!(image.is_absolute() && report.is_absolute());
    }

    #[test]
    fn names_never_collide_and_stay_in_the_directory() {
        let dir = tempfile::tempdir().unwrap();
        let out = OutputConfig {
            dir: Some(dir.path().join("new/sub")),
            ..OutputConfig::default()
        };
        let (a, r) = next_paths(&out).unwrap();
        assert!(out.dir().is_dir());
        assert_eq!(a.parent(), Some(out.dir()));
        assert_eq!(r.extension().unwrap(), "json");
        std::fs::write(&a, b"x").unwrap();
        let (b, _) = next_paths(&out).unwrap();
        assert_ne!(a, b);
        // Raw takes kept under a name whose picture is gone still hold the name.
        std::fs::remove_file(&a).unwrap();
        std::fs::write(raw_path(&a, 0), b"x").unwrap();
        assert_ne!(next_paths(&out).unwrap().0, a);
        std::fs::write(&a, b"x").unwrap();
        assert!(
            b.to_string_lossy().ends_with("-2.jpg")
                || !b
                    .to_string_lossy()
                    .contains(a.file_stem().unwrap().to_str().unwrap())
        );
        let blocked = OutputConfig {
            dir: Some(dir.path().join("new/sub").join(a.file_name().unwrap())),
            ..OutputConfig::default()
        };
        let e = format!("{:#}", next_paths(&blocked).unwrap_err());
        assert!(e.contains("cannot create it"), "{e}");
    }
}
