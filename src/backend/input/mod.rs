//! The trigger keys through evdev (`/dev/input/eventN`): the `[trigger]` table, and
//! [`EvdevKeys`], the capture side's [`Keys`] on a phone.
//!
//! The devices are the one the config names (by path or by name), or every device that
//! reports one of the keys (its EVIOCGBIT key bitmap). They are looked for again whenever
//! /dev/input changes (inotify: udev's netlink events do not reach the system unit's private
//! network namespace), so a keyboard plugged in later, or a device that comes back, is used.
//! A device that cannot be opened, or goes away, is a log line, never an error: the daemon
//! serves D-Bus captures without keys.

pub mod abi;
pub mod device;
pub mod keys;

use crate::base::setting::{Bounds, Invalid};
use crate::capture::trigger::{KeyId, Keys, Seen};
use crate::capture::Nanos;
use device::{InputDevice, KeyRead};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, VecDeque};
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};

/// The `[trigger]` table of the config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TriggerConfig {
    /// evdev key names; empty: no key triggers (D-Bus only).
    pub keys: Vec<String>,
    /// An input device path (`/dev/input/event3`, a `/dev/input/by-path/...` link) or its name
    /// (`gpio-keys`); unset: every device that reports one of `keys`.
    pub device: Option<String>,
    /// A key held this long cancels the running job; a shorter press starts one.
    pub long_press_ms: u64,
}

impl Default for TriggerConfig {
    fn default() -> Self {
        Self {
            keys: vec!["KEY_CAMERA".into()],
            device: None,
            long_press_ms: 800,
        }
    }
}

impl TriggerConfig {
    pub fn validate(&self) -> Result<(), Invalid> {
        for k in &self.keys {
            keys::code(k).map_err(|why| Invalid::new("keys", format!("keys: {why}")))?;
        }
        if self.device.as_ref().is_some_and(|d| d.is_empty()) {
            return Err(Invalid::new(
                "device",
                "device is empty: name the input device, or leave it out for every device with \
                 the keys",
            ));
        }
        Bounds::new(100, 10_000).check("long_press_ms", self.long_press_ms)
    }

    /// The key codes (the config was validated).
    pub fn codes(&self) -> Vec<u16> {
        self.keys
            .iter()
            .filter_map(|k| keys::code(k).ok())
            .collect()
    }

    pub fn long_press(&self) -> Nanos {
        self.long_press_ms as Nanos * 1_000_000
    }
}

const DEV_INPUT: &str = "/dev/input";

/// The trigger keys on every matching evdev device, re-found when /dev/input changes.
pub struct EvdevKeys {
    config: TriggerConfig,
    codes: Vec<u16>,
    dir: PathBuf,
    /// Watches `dir`; `None` when inotify could not be set up (then no hot-plug).
    inotify: Option<OwnedFd>,
    /// The devices in use, by the id their keys carry.
    devices: BTreeMap<u64, InputDevice>,
    next_id: u64,
    pending: VecDeque<Seen>,
    /// The last scan's summary, logged only when it changes.
    said: String,
}

impl EvdevKeys {
    /// Looks for the devices now; never fails (see the module doc).
    pub fn open(config: &TriggerConfig) -> EvdevKeys {
        Self::open_in(config, Path::new(DEV_INPUT))
    }

    fn open_in(config: &TriggerConfig, dir: &Path) -> EvdevKeys {
        use rustix::fs::inotify;
        let inotify = inotify::init(inotify::CreateFlags::CLOEXEC | inotify::CreateFlags::NONBLOCK)
            .and_then(|fd| {
                let flags = inotify::WatchFlags::CREATE
                    | inotify::WatchFlags::DELETE
                    | inotify::WatchFlags::ATTRIB
                    | inotify::WatchFlags::MOVED_TO;
                inotify::add_watch(&fd, dir, flags).map(|_| fd)
            })
            .map_err(|e| {
                tracing::warn!(
                    "trigger keys: cannot watch {} ({e}): input devices that appear later are \
                     not used until the service restarts",
                    dir.display()
                )
            })
            .ok();
        let mut keys = EvdevKeys {
            codes: config.codes(),
            config: config.clone(),
            dir: dir.to_path_buf(),
            inotify,
            devices: BTreeMap::new(),
            next_id: 0,
            pending: VecDeque::new(),
            said: String::new(),
        };
        keys.scan();
        keys
    }

    fn key_names(&self) -> String {
        self.config.keys.join(", ")
    }

    /// Opens every device not yet in use that the config wants, and logs what changed.
    fn scan(&mut self) {
        let in_use: Vec<PathBuf> = self.devices.values().map(|d| d.path.clone()).collect();
        let mut refused = Vec::new();
        let paths: Vec<PathBuf> = match &self.config.device {
            Some(d) if d.starts_with('/') => vec![PathBuf::from(d)],
            _ => match std::fs::read_dir(&self.dir) {
                Ok(entries) => {
                    let mut p: Vec<PathBuf> = entries
                        .flatten()
                        .map(|e| e.path())
                        .filter(|p| {
                            p.file_name()
                                .is_some_and(|n| n.to_string_lossy().starts_with("event"))
                        })
                        .collect();
                    p.sort();
                    p
                }
                Err(e) => {
                    refused.push(format!("{}: {e}", self.dir.display()));
                    Vec::new()
                }
            },
        };
        for path in paths {
            if in_use.contains(&path) {
                continue;
            }
            let dev = match InputDevice::open(&path) {
                Ok(d) => d,
                Err(e)
                    if e.kind() == std::io::ErrorKind::NotFound && self.config.device.is_none() =>
                {
                    continue
                }
                Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => {
                    refused.push(format!(
                        "{}: {e} (systemd/70-focusd.rules gives key devices to group focusd)",
                        path.display()
                    ));
                    continue;
                }
                Err(e) => {
                    refused.push(format!("{}: {e}", path.display()));
                    continue;
                }
            };
            if let Some(name) = self.config.device.as_ref().filter(|d| !d.starts_with('/')) {
                if dev.name != *name {
                    continue;
                }
            }
            let has: Vec<u16> = match self
                .codes
                .iter()
                .map(|&c| dev.has_key(c).map(|h| (c, h)))
                .collect::<Result<Vec<_>, _>>()
            {
                Ok(h) => h.into_iter().filter(|(_, h)| *h).map(|(c, _)| c).collect(),
                Err(e) => {
                    refused.push(format!("{}: cannot read its keys: {e}", path.display()));
                    continue;
                }
            };
            if has.is_empty() {
                if self.config.device.is_some() {
                    refused.push(format!(
                        "{} ({}) reports none of {}",
                        path.display(),
                        dev.name,
                        self.key_names()
                    ));
                }
                continue;
            }
            let names: Vec<String> = has.iter().map(|&c| keys::name(c)).collect();
            tracing::info!(
                "trigger keys: {} on {} ({})",
                names.join(", "),
                path.display(),
                dev.name
            );
            self.devices.insert(self.next_id, dev);
            self.next_id += 1;
        }
        let summary = if self.devices.is_empty() {
            let which = match &self.config.device {
                Some(d) => format!("input device {d} is not in use"),
                None => format!("no input device reports {}", self.key_names()),
            };
            let refused = if refused.is_empty() {
                String::new()
            } else {
                format!("; cannot use {}", refused.join("; "))
            };
            format!(
                "trigger keys: {which}{refused}; captures come only over D-Bus until one appears"
            )
        } else if refused.is_empty() {
            String::new()
        } else {
            format!("trigger keys: cannot use {}", refused.join("; "))
        };
        if summary != self.said && !summary.is_empty() {
            tracing::warn!("{}", crate::base::clip::clip(&summary));
        }
        self.said = summary;
    }

    /// Reads what device `id` has waiting into `pending`; drops it when it is gone.
    fn read(&mut self, id: u64) {
        let Some(dev) = self.devices.get_mut(&id) else {
            return;
        };
        match dev.read() {
            Ok(events) => {
                for e in events {
                    self.pending.push_back(match e {
                        KeyRead::Key { code, down, at } if self.codes.contains(&code) => {
                            Seen::Key {
                                key: KeyId { device: id, code },
                                down,
                                at,
                            }
                        }
                        KeyRead::Key { .. } => continue,
                        KeyRead::Dropped => Seen::Lost { device: id },
                    });
                }
            }
            Err(e) => {
                let Some(dev) = self.devices.remove(&id) else {
                    return;
                };
                self.pending.push_back(Seen::Lost { device: id });
                if e.raw_os_error() == Some(libc::ENODEV) {
                    tracing::info!(
                        "trigger keys: {} ({}) went away",
                        dev.path.display(),
                        dev.name
                    );
                    // Says what is left (the gone node cannot be opened again: ENODEV).
                    self.said.clear();
                    self.scan();
                } else {
                    // Not reopened until /dev/input changes: a device failing every read would
                    // otherwise be reopened and fail again, round and round.
                    tracing::warn!(
                        "trigger keys: {} ({}): {e}; not used until /dev/input changes",
                        dev.path.display(),
                        dev.name
                    );
                }
            }
        }
    }

    /// Empties the inotify queue; whether anything happened in /dev/input.
    fn drain_inotify(&mut self) -> bool {
        let Some(fd) = &self.inotify else {
            return false;
        };
        let mut buf = [0u8; 4096];
        let mut any = false;
        loop {
            match rustix::io::read(fd, &mut buf) {
                Ok(n) if n > 0 => any = true,
                _ => return any,
            }
        }
    }
}

impl Keys for EvdevKeys {
    fn wait(&mut self, until: Option<Nanos>) -> Option<Seen> {
        loop {
            if let Some(s) = self.pending.pop_front() {
                return Some(s);
            }
            if self.devices.is_empty() && self.inotify.is_none() {
                return None;
            }
            let now = crate::backend::sys::monotonic_now();
            let timeout_ms = match until {
                Some(t) if t <= now => return Some(Seen::Timeout { now }),
                // Rounded up, so the deadline has passed when poll returns.
                Some(t) => ((t - now + 999_999) / 1_000_000).min(i32::MAX as Nanos) as i32,
                None => -1,
            };
            let ids: Vec<u64> = self.devices.keys().copied().collect();
            let mut fds: Vec<libc::pollfd> = ids
                .iter()
                .map(|id| self.devices[id].as_fd().as_raw_fd())
                .chain(self.inotify.as_ref().map(|f| f.as_raw_fd()))
                .map(|fd| libc::pollfd {
                    fd,
                    events: libc::POLLIN,
                    revents: 0,
                })
                .collect();
            // SAFETY: `fds` is a valid array of pollfd of the length passed.
            let r = unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, timeout_ms) };
            if r < 0 {
                let e = std::io::Error::last_os_error();
                if e.kind() != std::io::ErrorKind::Interrupted {
                    tracing::error!("trigger keys: poll: {e}; no more key triggers");
                    return None;
                }
                continue;
            }
            for (id, p) in ids.iter().zip(&fds) {
                if p.revents != 0 {
                    self.read(*id);
                }
            }
            if fds.last().is_some_and(|p| p.revents != 0)
                && self.inotify.is_some()
                && self.drain_inotify()
            {
                self.scan();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::sys::monotonic_now;

    #[test]
    fn what_is_not_an_input_device_is_said_and_a_new_node_is_looked_at() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("event0"), "").unwrap();
        std::fs::write(dir.path().join("mouse0"), "").unwrap();
        let mut keys = EvdevKeys::open_in(&TriggerConfig::default(), dir.path());
        assert!(keys.devices.is_empty());
        assert!(
            keys.said
                .starts_with("trigger keys: no input device reports KEY_CAMERA; cannot use ")
                && keys.said.contains("event0: not a character device")
                && !keys.said.contains("mouse0"),
            "{}",
            keys.said
        );
        assert!(matches!(
            keys.wait(Some(monotonic_now())),
            Some(Seen::Timeout { .. })
        ));
        // A node appearing wakes the wait (inotify, queued before the wait begins), which looks
        // at it; the wait then runs to its deadline.
        std::fs::write(dir.path().join("event1"), "").unwrap();
        let until = monotonic_now() + 200_000_000;
        assert!(matches!(keys.wait(Some(until)), Some(Seen::Timeout { .. })));
        assert!(
            keys.said.contains("event1: not a character device"),
            "{}",
            keys.said
        );
    }

    #[test]
    fn a_named_device_that_is_missing_is_said() {
        let dir = tempfile::tempdir().unwrap();
        let config = TriggerConfig {
            device: Some(dir.path().join("event7").display().to_string()),
            ..TriggerConfig::default()
        };
        let keys = EvdevKeys::open_in(&config, dir.path());
        assert!(
            keys.said.contains("is not in use; cannot use ")
                && keys.said.contains("event7: No such file"),
            "{}",
            keys.said
        );
    }
}
