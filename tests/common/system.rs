//! What the test process may do on this machine.

use std::process::Command;

/// Whether this process runs as root, without a libc binding: `id -u`.
pub fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}
