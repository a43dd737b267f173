//! Fake IIO sysfs trees, laid out as the kernel lays them out, for the IMU backend.

use focusd::backend::iio::IioConfig;
use std::fs;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

/// A temporary directory holding `sys/bus/iio/devices/` (with a trigger, as on a phone) and
/// `dev/`, where the devices' character files go.
pub struct Tree {
    pub dir: TempDir,
}

impl Tree {
    pub fn new() -> Tree {
        let t = Tree {
            dir: tempfile::tempdir().unwrap(),
        };
        fs::create_dir_all(t.dir.path().join("dev")).unwrap();
        fs::create_dir_all(t.sys().join("bus/iio/devices/trigger0")).unwrap();
        t
    }

    /// The sysfs root, what the config's `sysfs_root` names.
    pub fn sys(&self) -> PathBuf {
        self.dir.path().join("sys")
    }

    /// The directory of device `n`, created empty.
    pub fn device_dir(&self, n: u32) -> PathBuf {
        let d = self.sys().join(format!("bus/iio/devices/iio:device{n}"));
        fs::create_dir_all(&d).unwrap();
        d
    }

    /// Device `n` named `name`, with attribute files (paths relative to its directory).
    pub fn device(&self, n: u32, name: &str, files: &[(&str, &str)]) -> PathBuf {
        let d = self.device_dir(n);
        fs::write(d.join("name"), format!("{name}\n")).unwrap();
        for (rel, content) in files {
            write(&d.join(rel), content);
        }
        d
    }

    pub fn config(&self) -> IioConfig {
        IioConfig {
            sysfs_root: self.sys(),
            ..IioConfig::default()
        }
    }
}

/// Writes an attribute file as sysfs shows it (with a newline), creating its directory.
pub fn write(path: &Path, content: &str) {
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    fs::write(path, format!("{content}\n")).unwrap();
}
