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
use super::temp::{claim, dir_of, live, remove_any, same_file, sweep_stale, temp_path};
use crate::stack::image::{Image, Sample};
use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

type Result<T> = std::result::Result<T, FileError>;

/// Creates `path`'s temporary file, exclusively, so the write never follows a link planted
/// under its name out of the directory; a stale one of this process's id (a crash of an
/// earlier process with the same id) is removed first.
fn create_temp(path: &Path) -> Result<(PathBuf, File)> {
    claim(path, |tmp| {
        OpenOptions::new().write(true).create_new(true).open(tmp)
    })
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
        let mut live = live();
        remove_any(&tmp);
        live.forget(&tmp);
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
    /// The directories whose stale temporary files have been removed.
    swept: Vec<PathBuf>,
}

impl Outputs {
    /// Checks every output location: its directory exists and takes a new file, it is not a
    /// directory, it is none of the `inputs` (compared by device and inode, so links and other
    /// spellings count), and no two outputs are the same file. Temporary files a killed run
    /// left in those directories are removed.
    pub fn check(outputs: &[&Path], inputs: &[&Path]) -> Result<Outputs> {
        let mut set = Outputs {
            staged: Vec::new(),
            swept: Vec::new(),
        };
        for &path in outputs {
            set.claim(path, inputs)?;
        }
        Ok(set)
    }

    /// Claims one more output, checked as [`Outputs::check`] checks them, for work that finds
    /// out what it writes only on the way (a capture's raw takes); it lands with the others.
    pub fn add(&mut self, path: &Path) -> Result<()> {
        self.claim(path, &[])
    }

    fn claim(&mut self, path: &Path, inputs: &[&Path]) -> Result<()> {
        let inode = |p: &Path| fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
        let dir = dir_of(path);
        if !dir.is_dir() {
            return Err(FileError::NoDirectory {
                path: shown(path),
                dir: shown(&dir),
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
        if !self.swept.contains(&dir) {
            sweep_stale(&dir);
            self.swept.push(dir);
        }
        let (tmp, file) = create_temp(path)?;
        let staged = Staged {
            path: path.to_path_buf(),
            tmp,
            file,
            written: false,
        };
        if let Some(other) = self.staged.iter().find(|s| same_file(&s.tmp, &staged.tmp)) {
            return Err(FileError::SameFile {
                path: shown(path),
                other: shown(&other.path),
            });
        }
        self.staged.push(staged);
        Ok(())
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

    /// Renames every output into place, once all of them are written. Where one rename fails
    /// (a card remounted read-only, a full disk), those already made are undone, a replaced
    /// file is put back, and every temporary file is removed: all land, or none.
    pub fn commit(mut self) -> Result<()> {
        if let Some(s) = self.staged.iter().find(|s| !s.written) {
            return Err(FileError::NothingWritten {
                path: shown(&s.path),
            });
        }
        // Held throughout, so an interruption waits for the renames (or the undoing).
        let mut live = live();
        let staged = std::mem::take(&mut self.staged);
        let result = rename_all(&staged);
        for s in &staged {
            if result.is_err() {
                let _ = fs::remove_file(&s.tmp);
            }
            live.forget(&s.tmp);
        }
        result
    }
}

/// Renames each staged file into place, keeping what it replaces under a second temporary
/// name until all are in, so a failed rename can undo the ones before it.
fn rename_all(staged: &[Staged]) -> Result<()> {
    let mut kept: Vec<Option<PathBuf>> = Vec::new();
    let mut result = Ok(());
    for s in staged {
        let kept_as = match keep_replaced(s) {
            Ok(k) => k,
            Err(e) => {
                result = Err(e);
                break;
            }
        };
        if let Err(error) = fs::rename(&s.tmp, &s.path) {
            if let Some(k) = &kept_as {
                put_back(k, &s.path);
            }
            result = Err(FileError::Write {
                path: shown(&s.path),
                error,
            });
            break;
        }
        kept.push(kept_as);
    }
    if result.is_err() {
        for (s, k) in staged.iter().zip(&kept) {
            match k {
                Some(k) => put_back(k, &s.path),
                None => {
                    let _ = fs::remove_file(&s.path);
                }
            }
        }
    } else {
        for k in kept.into_iter().flatten() {
            let _ = fs::remove_file(k);
        }
    }
    result
}

/// Puts the file kept as `kept` back under `path`. Where it is still there (a hard link of
/// the file under `path`) the second name is only removed; where it cannot be put back it is
/// left, so the user's file is never lost.
fn put_back(kept: &Path, path: &Path) {
    if same_file(kept, path) {
        let _ = fs::remove_file(kept);
    } else if let Err(e) = fs::rename(kept, path) {
        tracing::warn!(
            "{}: cannot put the earlier file back ({e}); it is kept as {}",
            path.display(),
            kept.display()
        );
    }
}

/// A file already under `s`'s final name, linked to a second temporary name (that of
/// `NAME.old`, so a killed run's is swept as stale) so that it can be put back.
fn keep_replaced(s: &Staged) -> Result<Option<PathBuf>> {
    if s.path.symlink_metadata().is_err() {
        return Ok(None);
    }
    let mut name = s.path.file_name().unwrap_or_default().to_os_string();
    name.push(".old");
    let old = temp_path(&s.path.with_file_name(name))?;
    remove_any(&old);
    // A file system without hard links (FAT on a card) moves it aside instead.
    fs::hard_link(&s.path, &old)
        .or_else(|_| fs::rename(&s.path, &old))
        .map_err(|error| FileError::Write {
            path: shown(&s.path),
            error,
        })?;
    Ok(Some(old))
}

impl Drop for Outputs {
    fn drop(&mut self) {
        let mut live = live();
        for s in &self.staged {
            let _ = fs::remove_file(&s.tmp);
            live.forget(&s.tmp);
        }
    }
}

/// A folder written whole under a temporary name beside its final one and renamed into place
/// at the end (a recorded bundle), or removed with everything in it if the work fails or the
/// command is interrupted.
pub struct StagedDir {
    path: PathBuf,
    tmp: PathBuf,
}

impl StagedDir {
    /// Claims `path`, which must not exist or be an empty folder, and creates its temporary
    /// folder.
    pub fn create(path: &Path) -> Result<StagedDir> {
        let dir = dir_of(path);
        if !dir.is_dir() {
            return Err(FileError::NoDirectory {
                path: shown(path),
                dir: shown(&dir),
            });
        }
        sweep_stale(&dir);
        let (tmp, ()) = claim(path, |tmp| fs::create_dir(tmp))?;
        Ok(StagedDir {
            path: path.to_path_buf(),
            tmp,
        })
    }

    /// Where the contents are written until [`StagedDir::commit`].
    pub fn writing_dir(&self) -> &Path {
        &self.tmp
    }

    /// Renames the folder into place (over an empty folder of that name, if there is one).
    pub fn commit(self) -> Result<()> {
        let mut live = live();
        let done = fs::rename(&self.tmp, &self.path);
        if done.is_ok() {
            live.forget(&self.tmp);
        }
        drop(live);
        done.map_err(|error| FileError::Write {
            path: shown(&self.path),
            error,
        })
        // On failure, dropping `self` removes the temporary folder.
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        let mut live = live();
        remove_any(&self.tmp);
        live.forget(&self.tmp);
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
}
