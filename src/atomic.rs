//! Files written atomically: a temporary file beside the target, flushed to disk, then
//! a rename, so a reader (or a crash) never sees half a file; and [`Batch`]es of files
//! that are replaced together or not at all. A failed write (disk full, read-only
//! folder) removes its temporary file and leaves the target as it was.

use std::io::Write;
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically.
pub fn write(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut batch = Batch::new();
    batch.add(path, bytes)?;
    batch.commit()
}

/// Writes `bytes` to the new file `tmp` and flushes it to disk; removes it on failure.
fn write_temporary(tmp: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let written = std::fs::File::create(tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    written.inspect_err(|_| {
        let _ = std::fs::remove_file(tmp);
    })
}

fn check_file_path(path: &Path) -> std::io::Result<()> {
    match path.file_name() {
        Some(_) => Ok(()),
        None => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{}: not a file path", path.display()),
        )),
    }
}

/// Files replaced together: each is first written in full to a temporary file beside
/// its target; [`Batch::commit`] renames them all into place once every one is written.
/// A batch dropped before its commit (an error on the way) removes its temporary files
/// and replaces nothing.
#[derive(Default)]
pub struct Batch {
    /// (temporary file, target), in the order added.
    staged: Vec<(PathBuf, PathBuf)>,
}

impl Batch {
    /// An empty batch.
    pub fn new() -> Batch {
        Batch::default()
    }

    /// Stages `bytes` for `path`.
    pub fn add(&mut self, path: &Path, bytes: &[u8]) -> std::io::Result<()> {
        check_file_path(path)?;
        let tmp = temporary(path);
        write_temporary(&tmp, bytes)?;
        self.staged.push((tmp, path.to_path_buf()));
        Ok(())
    }

    /// Stages the file that `write` writes to the temporary path it is given (for
    /// writers that need a path of their own, like image encoders).
    pub fn add_with<E>(
        &mut self,
        path: &Path,
        write: impl FnOnce(&Path) -> Result<(), E>,
    ) -> Result<(), E> {
        let tmp = temporary(path);
        match write(&tmp) {
            Ok(()) => {
                self.staged.push((tmp, path.to_path_buf()));
                Ok(())
            }
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(e)
            }
        }
    }

    /// Renames every staged file into place, in the order added.
    /// A target that is a folder fails the batch before anything is renamed.
    pub fn commit(mut self) -> std::io::Result<()> {
        if let Some((_, path)) = self.staged.iter().find(|(_, p)| p.is_dir()) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::IsADirectory,
                format!("{}: is a folder, not a file", path.display()),
            ));
        }
        let staged = std::mem::take(&mut self.staged);
        for (i, (tmp, path)) in staged.iter().enumerate() {
            if let Err(e) = std::fs::rename(tmp, path) {
                for (rest, _) in &staged[i..] {
                    let _ = std::fs::remove_file(rest);
                }
                return Err(std::io::Error::new(
                    e.kind(),
                    format!("{}: {e}", path.display()),
                ));
            }
        }
        Ok(())
    }
}

impl Drop for Batch {
    fn drop(&mut self) {
        for (tmp, _) in &self.staged {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// The temporary path beside `path` that [`write()`] and [`Batch`] use.
fn temporary(path: &Path) -> PathBuf {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map_or("file".into(), |n| n.to_string_lossy());
    dir.join(format!(".{name}.tmp{}", std::process::id()))
}
