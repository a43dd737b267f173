//! The user's Pictures folder, found as the desktop finds it, for the session service's default
//! output directory.
//!
//! xdg-user-dirs writes `~/.config/user-dirs.dirs` at the first login in the user's language
//! (`XDG_PICTURES_DIR="$HOME/Bilder"` on a phone set to German); a gallery (and the file chooser)
//! looks there. Without the file, or without the key, it is `$HOME/Pictures`.

use crate::files::bounded_read;
use std::path::{Path, PathBuf};

/// `$XDG_CONFIG_HOME/user-dirs.dirs` (default `$HOME/.config`)'s Pictures folder, or
/// `$HOME/Pictures`.
pub fn pictures_dir(home: &Path, config_home: Option<&Path>) -> PathBuf {
    let config = config_home.map_or_else(|| home.join(".config"), Path::to_path_buf);
    bounded_read::read_to_string(&config.join("user-dirs.dirs"), bounded_read::TEXT_CAP)
        .ok()
        .and_then(|text| from_user_dirs(&text, home))
        .unwrap_or_else(|| home.join("Pictures"))
}

/// The `XDG_PICTURES_DIR` of a `user-dirs.dirs` text. Its format (xdg-user-dirs): shell
/// assignments, one per line, `#` comments; a value is `"$HOME/relative"` or `"/absolute"`,
/// nothing else; a value of `"$HOME/"` alone means the folder is disabled.
pub fn from_user_dirs(text: &str, home: &Path) -> Option<PathBuf> {
    let value = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.strip_prefix("XDG_PICTURES_DIR="))
        .next_back()?;
    let value = value.strip_prefix('"')?.strip_suffix('"')?;
    let dir = if let Some(rest) = value.strip_prefix("$HOME") {
        let rest = rest.trim_start_matches('/');
        if rest.is_empty() {
            return None;
        }
        home.join(rest)
    } else if value.starts_with('/') {
        PathBuf::from(value)
    } else {
        return None;
    };
    Some(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_localised_pictures_folder() {
        let home = Path::new("/home/user");
        let text = "# This file is written by xdg-user-dirs-update\n\
                    XDG_DESKTOP_DIR=\"$HOME/Schreibtisch\"\n\
                    XDG_PICTURES_DIR=\"$HOME/Bilder\"\n";
        assert_eq!(
            from_user_dirs(text, home),
            Some(PathBuf::from("/home/user/Bilder"))
        );
        let absolute = "XDG_PICTURES_DIR=\"/media/sd/Photos\"\n";
        assert_eq!(
            from_user_dirs(absolute, home),
            Some(PathBuf::from("/media/sd/Photos"))
        );
    }

    #[test]
    fn a_missing_disabled_or_malformed_entry_gives_no_folder() {
        let home = Path::new("/home/user");
        for text in [
            "",
            "XDG_MUSIC_DIR=\"$HOME/Music\"\n",
            "#XDG_PICTURES_DIR=\"$HOME/Old\"\n",
            "XDG_PICTURES_DIR=\"$HOME/\"\n",
            "XDG_PICTURES_DIR=$HOME/Bilder\n",
            "XDG_PICTURES_DIR=\"relative/path\"\n",
        ] {
            assert_eq!(from_user_dirs(text, home), None, "{text:?}");
        }
    }

    #[test]
    fn falls_back_to_home_pictures() {
        let home = tempfile::tempdir().unwrap();
        assert_eq!(
            pictures_dir(home.path(), None),
            home.path().join("Pictures")
        );
        let config = home.path().join(".config");
        std::fs::create_dir_all(&config).unwrap();
        std::fs::write(
            config.join("user-dirs.dirs"),
            "XDG_PICTURES_DIR=\"$HOME/Imágenes\"\n",
        )
        .unwrap();
        assert_eq!(
            pictures_dir(home.path(), None),
            home.path().join("Imágenes")
        );
        // XDG_CONFIG_HOME elsewhere: the file there counts, not the one in ~/.config.
        let other = tempfile::tempdir().unwrap();
        assert_eq!(
            pictures_dir(home.path(), Some(other.path())),
            home.path().join("Pictures")
        );
    }
}
