//! One writer per output directory: an OS advisory lock held for the whole command.
//!
//! Two commands writing into one directory (two `run --out S`, two `train --out T`, a
//! `train --resume` while another trains) mix their outputs. Every command that writes a
//! directory takes its [`DirLock`] first; a second writer is refused at once with the
//! directory and the holder's process id. The lock is the operating system's (`flock` on
//! Unix, `LockFileEx` on Windows, through `std::fs::File::try_lock`), so it is released when
//! the holder exits in any way, a SIGKILL included: a killed run never blocks the next one.
//!
//! ```
//! use fishprobe_io::DirLock;
//! let dir = std::env::temp_dir().join(format!("fishprobe-lock-doc-{}", std::process::id()));
//! let held = DirLock::acquire(&dir, "train")?;
//! let again = DirLock::acquire(&dir, "train");
//! assert!(again.unwrap_err().to_string().contains("in use by"));
//! drop(held);
//! assert!(DirLock::acquire(&dir, "train").is_ok());
//! # std::fs::remove_dir_all(&dir).ok();
//! # Ok::<(), fishprobe_io::LockError>(())
//! ```

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

/// The lock file's name inside a locked directory.
pub const LOCK_FILE: &str = ".fishprobe.lock";

/// Why a directory could not be locked.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another process holds the lock.
    #[error(
        "{}: in use by {holder}; wait for it to finish or choose another output directory",
        dir.display()
    )]
    Busy {
        /// The directory.
        dir: PathBuf,
        /// Who holds it, as the holder wrote it ("fishprobe run, PID 1234").
        holder: String,
    },
    /// A path on the way to the output is a file (or another non-directory), so the output
    /// directory cannot be made: `--out results.csv` where `results.csv` exists.
    #[error(
        "{}: exists and is not a directory{on_the_way}; name a directory (or a path that does \
         not exist yet) for the output",
        blocker.display()
    )]
    NotADirectory {
        /// The existing non-directory.
        blocker: PathBuf,
        /// Empty when the blocker is the output itself, else " (on the way to OUT)".
        on_the_way: String,
    },
    /// An output file's lock was asked for a path that names no file (`/`, `..`).
    #[error("{}: not a file path", path.display())]
    NotAFile {
        /// The path.
        path: PathBuf,
    },
    /// The lock file cannot be created or locked.
    #[error("{}: cannot lock: {reason}", path.display())]
    Io {
        /// The lock file.
        path: PathBuf,
        /// The OS error.
        reason: std::io::Error,
    },
}

/// An exclusive lock on a directory, released when dropped or when the process ends.
#[derive(Debug)]
pub struct DirLock {
    _file: File,
    path: PathBuf,
}

impl DirLock {
    /// Creates `dir` if needed and locks it for the command `what`.
    pub fn acquire(dir: &Path, what: &str) -> Result<Self, LockError> {
        Self::acquire_file(dir, &dir.join(LOCK_FILE), what)
    }

    /// The one-writer lock of an output *file* (`fit-convnet --out convnet.safetensors`): a
    /// hidden `.<name>.lock` beside it, so two commands writing the same file exclude each
    /// other and commands writing other files in the same directory do not.
    pub fn for_file(file: &Path, what: &str) -> Result<Self, LockError> {
        let name = file
            .file_name()
            .ok_or_else(|| LockError::NotAFile {
                path: file.to_path_buf(),
            })?
            .to_string_lossy();
        let lock = file.with_file_name(format!(".{name}.lock"));
        Self::acquire_file(file, &lock, what)
    }

    /// Locks the file `lock` (creating it and its directory), on behalf of `dir` in messages
    /// (a directory, or the output file the lock guards): for locks finer than a directory,
    /// such as one step of a study or one output file.
    pub fn acquire_file(dir: &Path, lock: &Path, what: &str) -> Result<Self, LockError> {
        let io = |reason| LockError::Io {
            path: lock.to_path_buf(),
            reason,
        };
        if let Some(parent) = lock.parent() {
            // The nearest existing ancestor must be a directory; say which one is not.
            if let Some(blocker) = parent
                .ancestors()
                .find(|a| !a.as_os_str().is_empty() && a.exists())
                .filter(|a| !a.is_dir())
            {
                return Err(LockError::NotADirectory {
                    blocker: blocker.to_path_buf(),
                    on_the_way: if blocker == dir {
                        String::new()
                    } else {
                        format!(" (on the way to {})", dir.display())
                    },
                });
            }
            std::fs::create_dir_all(parent).map_err(io)?;
        }
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(lock)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let mut holder = String::new();
                // The holder's line is short; a lock file that is not one (replaced by
                // something large) is read no further than this.
                let _ = (&file).take(4096).read_to_string(&mut holder);
                let holder = holder.trim();
                return Err(LockError::Busy {
                    dir: dir.to_path_buf(),
                    holder: if holder.is_empty() {
                        "another process".to_string()
                    } else {
                        holder.to_string()
                    },
                });
            }
            Err(TryLockError::Error(e)) => return Err(io(e)),
        }
        // The holder's name, for the refusal another process prints.
        let me = format!("fishprobe {what}, PID {}", std::process::id());
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| file.write_all(me.as_bytes()))
            .and_then(|()| file.flush())
            .map_err(io)?;
        Ok(Self {
            _file: file,
            path: lock.to_path_buf(),
        })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_second_writer_is_refused_with_the_holders_pid_and_the_lock_dies_with_its_holder() {
        let dir = std::env::temp_dir().join(format!("fishprobe-lock-{}", std::process::id()));
        let held = DirLock::acquire(&dir, "run").unwrap();
        let e = DirLock::acquire(&dir, "train").unwrap_err().to_string();
        assert!(e.contains(&dir.display().to_string()), "{e}");
        assert!(
            e.contains(&format!("fishprobe run, PID {}", std::process::id())),
            "{e}"
        );
        drop(held);
        let again = DirLock::acquire(&dir, "train").unwrap();
        assert_eq!(again.path(), dir.join(LOCK_FILE));
        // A finer lock in the same directory is independent of the directory's.
        let step = DirLock::acquire_file(&dir, &dir.join("steps/a.lock"), "run --step a").unwrap();
        assert!(DirLock::acquire_file(&dir, &dir.join("steps/a.lock"), "x").is_err());
        drop((again, step));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn an_output_path_through_a_file_names_the_file() {
        let dir = std::env::temp_dir().join(format!("fishprobe-lock-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("results.csv");
        std::fs::write(&file, "a,b\n").unwrap();
        for out in [file.clone(), file.join("sub")] {
            let e = DirLock::acquire(&out, "train").unwrap_err();
            assert!(matches!(&e, LockError::NotADirectory { blocker, .. } if *blocker == file));
            let e = e.to_string();
            assert!(
                e.contains("results.csv: exists and is not a directory"),
                "{e}"
            );
        }
        assert_eq!(
            std::fs::read_to_string(&file).unwrap(),
            "a,b\n",
            "the file was touched"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
