//! Writing output files so that nothing partial is ever left under a final name, and a
//! command's outputs land all together or not at all. Every file focusd writes goes through
//! here: images, depth maps, reports, transforms and replay bundles.
//!
//! `fuse` writes an image and perhaps a depth map and transforms; `capture` an image and perhaps
//! a report. A user who finds one of them trusts the others, and a bad output path should not be
//! found out at the last write after minutes of work. So [`Outputs::check`] checks every location
//! before the work and claims a temporary file beside each final name (which proves the
//! directory writable, whoever runs it), the work writes into those, and [`Outputs::commit`]
//! renames them all at the end; on any failure before that, dropping the set removes them.

use super::error::{shown, FileError};
use super::imageio;
use crate::stack::image::{Image, Sample};
use std::ffi::OsStr;
use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

type Result<T> = std::result::Result<T, FileError>;

/// Bytes of the final name kept in a temporary name: with the dot, the process id and `.tmp`
/// it stays under the 255 bytes a file name may have.
const NAME_BYTES_KEPT: usize = 200;

/// The temporary file an output is written through, beside it: `.NAME.PID.tmp`, with NAME cut
/// to [`NAME_BYTES_KEPT`] bytes.
pub fn temp_path(path: &Path) -> Result<PathBuf> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .ok_or_else(|| FileError::NotAFilePath { path: shown(path) })?
        .as_bytes();
    let mut end = name.len().min(NAME_BYTES_KEPT);
    // A UTF-8 name is cut between characters, so the temporary name stays readable.
    if let Ok(s) = std::str::from_utf8(name) {
        while !s.is_char_boundary(end) {
            end -= 1;
        }
    }
    let kept = OsStr::from_bytes(&name[..end]);
    let mut tmp = std::ffi::OsString::from(".");
    tmp.push(kept);
    tmp.push(format!(".{}.tmp", std::process::id()));
    Ok(dir.join(tmp))
}

/// Creates `path`'s temporary file. A stale one (a crash) or a link planted under its name is
/// removed, and the new one is created exclusively, so the write never follows a link out of
/// the directory.
fn create_temp(path: &Path) -> Result<(PathBuf, File)> {
    let tmp = temp_path(path)?;
    let _ = fs::remove_file(&tmp);
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .map_err(|error| FileError::Write {
            path: shown(path),
            error,
        })?;
    Ok((tmp, file))
}

/// Writes through a temporary file in the same directory and renames it into place, so a crash
/// or a full disk never leaves a partial file under the final name.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut set = Outputs::check(&[path], &[])?;
    set.write(path, bytes)?;
    set.commit()
}

/// Encodes `img` by `path`'s extension and writes it atomically.
pub fn save_image<T: Sample>(img: &Image<T>, path: &Path, quality: u8) -> Result<()> {
    let bytes = imageio::encode(img, imageio::format_for(path)?, quality)?;
    write_atomic(path, &bytes)
}

/// Removes `path`'s temporary file, if any: what a job abandoned without dropping its
/// [`Outputs`] (a thread blocked for good) leaves behind.
pub fn discard_temp(path: &Path) {
    if let Ok(tmp) = temp_path(path) {
        let _ = fs::remove_file(tmp);
    }
}

struct Staged {
    path: PathBuf,
    tmp: PathBuf,
    file: File,
    written: bool,
}

/// A command's outputs, claimed before the work and renamed into place together.
pub struct Outputs {
    staged: Vec<Staged>,
}

impl Outputs {
    /// Checks every output location: its directory exists and takes a new file, it is not a
    /// directory, it is none of the `inputs` (compared by device and inode, so links and other
    /// spellings count), and no two outputs are the same file.
    pub fn check(outputs: &[&Path], inputs: &[&Path]) -> Result<Outputs> {
        let inode = |p: &Path| fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
        let mut set = Outputs { staged: Vec::new() };
        for &path in outputs {
            let dir = match path.parent() {
                Some(d) if !d.as_os_str().is_empty() => d,
                _ => Path::new("."),
            };
            if !dir.is_dir() {
                return Err(FileError::NoDirectory {
                    path: shown(path),
                    dir: shown(dir),
                });
            }
            if path.is_dir() {
                return Err(FileError::IsADirectory { path: shown(path) });
            }
            if let Some(n) = inode(path) {
                if let Some(input) = inputs.iter().find(|p| inode(p) == Some(n)) {
                    return Err(FileError::IsAnInput {
                        path: shown(path),
                        input: shown(input),
                    });
                }
            }
            let (tmp, file) = create_temp(path)?;
            if let Some(other) = set.staged.iter().find(|s| same_file(&s.tmp, &tmp)) {
                return Err(FileError::SameFile {
                    path: shown(path),
                    other: shown(&other.path),
                });
            }
            set.staged.push(Staged {
                path: path.to_path_buf(),
                tmp,
                file,
                written: false,
            });
        }
        Ok(set)
    }

    /// Writes `path`'s contents into its temporary file.
    pub fn write(&mut self, path: &Path, bytes: &[u8]) -> Result<()> {
        let s = self
            .staged
            .iter_mut()
            .find(|s| s.path == path)
            .ok_or_else(|| FileError::NotChecked { path: shown(path) })?;
        (|| {
            s.file.write_all(bytes)?;
            s.file.sync_all()
        })()
        .map_err(|error| FileError::Write {
            path: shown(path),
            error,
        })?;
        s.written = true;
        Ok(())
    }

    /// Renames every output into place, once all of them are written.
    pub fn commit(mut self) -> Result<()> {
        if let Some(s) = self.staged.iter().find(|s| !s.written) {
            return Err(FileError::NothingWritten {
                path: shown(&s.path),
            });
        }
        for s in std::mem::take(&mut self.staged) {
            let done = fs::rename(&s.tmp, &s.path);
            if let Err(e) = done {
                let _ = fs::remove_file(&s.tmp);
                return Err(FileError::Write {
                    path: shown(&s.path),
                    error: e,
                });
            }
        }
        Ok(())
    }
}

/// Two temporary files just created are the same file when their inodes are: the same output
/// spelled two ways gives the same temporary name.
fn same_file(a: &Path, b: &Path) -> bool {
    match (fs::metadata(a), fs::metadata(b)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

impl Drop for Outputs {
    fn drop(&mut self) {
        for s in &self.staged {
            let _ = fs::remove_file(&s.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn outputs_land_together_or_not_at_all() {
        let d = tempfile::tempdir().unwrap();
        let (a, b) = (d.path().join("a.jpg"), d.path().join("b.json"));
        // Dropped after one write (a failure between them): nothing lands, nothing is left.
        let mut set = Outputs::check(&[&a, &b], &[]).unwrap();
        set.write(&a, b"image").unwrap();
        drop(set);
        assert!(names(d.path()).is_empty(), "{:?}", names(d.path()));
        // An output never written stops the commit before any rename.
        let mut set = Outputs::check(&[&a, &b], &[]).unwrap();
        set.write(&a, b"image").unwrap();
        let e = set.commit().unwrap_err().to_string();
        assert!(e.contains("b.json"), "{e}");
        assert!(names(d.path()).is_empty(), "{:?}", names(d.path()));
        // Both written: both land.
        let mut set = Outputs::check(&[&a, &b], &[]).unwrap();
        set.write(&a, b"image").unwrap();
        set.write(&b, b"{}").unwrap();
        set.commit().unwrap();
        assert_eq!(names(d.path()), ["a.jpg", "b.json"]);
        assert_eq!(fs::read(&a).unwrap(), b"image");
    }

    #[test]
    fn an_output_that_is_an_input_or_another_output_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let input = d.path().join("in.png");
        fs::write(&input, "x").unwrap();
        let hard = d.path().join("hard.png");
        fs::hard_link(&input, &hard).unwrap();
        let e = Outputs::check(&[&hard], &[&input])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("is the input"), "{e}");
        let out = d.path().join("out.png");
        let again = d.path().join(".").join("out.png");
        let e = Outputs::check(&[&out, &again], &[])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("same file"), "{e}");
        assert_eq!(names(d.path()), ["hard.png", "in.png"]);
    }

    #[test]
    fn temporary_names_fit_in_255_bytes() {
        // 251 bytes, and byte 200 falls inside an "é".
        let long = Path::new("/tmp").join(format!("x{}", "é".repeat(125)));
        let tmp = temp_path(&long).unwrap();
        assert!(tmp.file_name().unwrap().len() <= 255);
        let tmp = tmp.to_str().expect("cut between characters");
        assert!(
            tmp.starts_with("/tmp/.xé") && tmp.ends_with(".tmp"),
            "{tmp}"
        );
    }
}
