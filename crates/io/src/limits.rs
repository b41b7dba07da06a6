//! What a file may make fishprobe read: limits checked *before* anything is allocated, so a
//! tiny hostile file that declares gigabytes (a chunked dataset of 400 million rows "filled"
//! by a fill value, a legacy dataset declaring 400M x 4) is refused with an error naming it,
//! and memory stays bounded by what a file really holds.
//!
//! ```
//! use fishprobe_io::ReadLimits;
//! let l = ReadLimits::default();
//! assert_eq!(l.max_frames, 4_320_000); // 48 h at 25 Hz
//! assert!(l.check_declared(std::path::Path::new("x.hdf5"), "/d", 10 * 2, 4, false, 1000).is_ok());
//! ```

use crate::error::IoError;
use std::path::Path;

/// Upper bounds on what one trial file may declare. `Default` is what every reader of this
/// crate uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadLimits {
    /// Largest file read, in bytes. Default 1 GiB: a 15-minute trial is under 1 MB, a 48-hour
    /// recording of 8 fish at 25 Hz about 0.6 GB. Larger files are refused before reading.
    pub max_file_bytes: u64,
    /// Most frames (rows) one dataset may declare. Default 4,320,000 (48 hours at 25 Hz).
    pub max_frames: u64,
    /// How much larger than the whole file the decoded data of one compressed (filtered)
    /// dataset may be. Default 1,100: deflate's best case is about 1,032:1, so real data never
    /// comes near it. Uncompressed datasets may not declare more bytes than the file holds.
    pub max_expansion: u64,
}

impl Default for ReadLimits {
    fn default() -> Self {
        Self {
            max_file_bytes: 1 << 30,
            max_frames: 48 * 3600 * 25,
            max_expansion: 1_100,
        }
    }
}

impl ReadLimits {
    /// Checks a dataset's declared size before it is read: `elements` values of
    /// `element_bytes` each, stored `compressed` or not, in a file of `file_bytes`.
    pub fn check_declared(
        &self,
        path: &Path,
        dataset: &str,
        elements: u64,
        element_bytes: u64,
        compressed: bool,
        file_bytes: u64,
    ) -> Result<(), IoError> {
        let bytes = elements.checked_mul(element_bytes.max(1));
        let allowed = if compressed {
            file_bytes.saturating_mul(self.max_expansion)
        } else {
            file_bytes
        };
        match bytes {
            Some(b) if b <= allowed => Ok(()),
            _ => Err(IoError::format(
                path,
                format!(
                    "dataset {dataset} declares {elements} values ({}) but the file holds only \
                     {file_bytes} bytes{}: refused before reading (damaged or hostile file)",
                    bytes.map_or_else(|| "more than 2^64 bytes".to_string(), human_bytes),
                    if compressed { " even compressed" } else { "" }
                ),
            )),
        }
    }

    /// Checks a dataset's declared number of frames (its first dimension).
    pub fn check_frames(&self, path: &Path, dataset: &str, frames: u64) -> Result<(), IoError> {
        if frames > self.max_frames {
            return Err(IoError::format(
                path,
                format!(
                    "dataset {dataset} declares {frames} frames, more than the limit of {} \
                     (48 hours at 25 Hz; fishprobe_io::ReadLimits::max_frames)",
                    self.max_frames
                ),
            ));
        }
        Ok(())
    }
}

fn human_bytes(b: u64) -> String {
    const GIB: f64 = (1u64 << 30) as f64;
    const MIB: f64 = (1u64 << 20) as f64;
    match b as f64 {
        x if x >= GIB => format!("{:.1} GiB", x / GIB),
        x if x >= MIB => format!("{:.1} MiB", x / MIB),
        x => format!("{x} bytes"),
    }
}

/// Largest text file read whole by [`read_small_text`]: settings, study and analysis files,
/// JSON records. Default 16 MiB; fishprobe's own are a few kilobytes.
pub const MAX_TEXT_BYTES: u64 = 16 << 20;

/// A small text file (settings, a study file, a JSON record) read whole, as
/// `std::fs::read_to_string` does, but never more than [`MAX_TEXT_BYTES`]: a wrong path
/// (`/dev/zero`, a pipe that never ends, a 1 GB trial file given as settings) is refused once
/// that much is read, with an error that says so, instead of filling memory first. Works on
/// pipes too (`--settings <(...)`).
pub fn read_small_text(path: &Path) -> std::io::Result<String> {
    read_text_at_most(
        path,
        MAX_TEXT_BYTES,
        "not a settings or text file",
        "fishprobe_io::limits::MAX_TEXT_BYTES",
    )
}

/// A text file read whole, but never more than `max` bytes (see [`read_small_text`]); over
/// it, an `InvalidData` error says "larger than `max`: `what`" and names the limit's constant
/// (`limit_name`).
pub fn read_text_at_most(
    path: &Path,
    max: u64,
    what: &str,
    limit_name: &str,
) -> std::io::Result<String> {
    use std::io::Read;
    let file = std::fs::File::open(path)?;
    let mut bytes = Vec::new();
    file.take(max.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "larger than {}: {what} (reading stopped there; {limit_name})",
                human_bytes(max)
            ),
        ));
    }
    String::from_utf8(bytes).map_err(|e| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (invalid byte at offset {}): a text file was expected",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// What kind of file system object a path is, for an error message; `None` for a regular
/// file (following symbolic links).
pub fn not_regular(path: &Path) -> Option<String> {
    let link = match std::fs::symlink_metadata(path) {
        Err(e) => return Some(format!("cannot read: {e}")),
        Ok(m) => m,
    };
    if !link.file_type().is_symlink() {
        return (!link.is_file()).then(|| kind(&link.file_type()).to_string());
    }
    match std::fs::metadata(path) {
        Err(e) => Some(format!("a symbolic link that cannot be followed ({e})")),
        Ok(t) if t.is_file() => None,
        Ok(t) => Some(format!("a symbolic link to {}", kind(&t.file_type()))),
    }
}

fn kind(t: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe), not a regular file";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device, not a regular file";
        }
        if t.is_socket() {
            return "a socket, not a regular file";
        }
    }
    if t.is_dir() {
        "a directory, not a regular file"
    } else {
        "not a regular file"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn declared_sizes_are_checked_against_the_file() {
        let l = ReadLimits::default();
        let p = Path::new("t.hdf5");
        // 400M x 2 float32 in a 27 KB file: refused, compressed or not.
        assert!(l
            .check_declared(p, "/d", 800_000_000, 4, false, 27_000)
            .is_err());
        assert!(l
            .check_declared(p, "/d", 800_000_000, 4, true, 27_000)
            .is_err());
        // 1000 x 2 float32 in a 9 KB file: fine; compressed data may exceed the file.
        assert!(l.check_declared(p, "/d", 2_000, 4, false, 9_000).is_ok());
        assert!(l.check_declared(p, "/d", 2_000, 4, false, 7_999).is_err());
        assert!(l.check_declared(p, "/d", 2_000, 4, true, 1_000).is_ok());
        // Overflow is refused, not wrapped.
        let e = l
            .check_declared(p, "/d", u64::MAX, 8, true, 1 << 40)
            .unwrap_err()
            .to_string();
        assert!(e.contains("2^64") && e.contains("t.hdf5"), "{e}");
        assert!(l.check_frames(p, "/d", 4_320_000).is_ok());
        assert!(l.check_frames(p, "/d", 4_320_001).is_err());
    }

    #[test]
    fn only_regular_files_pass() {
        let d = std::env::temp_dir().join(format!("fishprobe-regular-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("temp dir");
        let f = d.join("a.hdf5");
        std::fs::write(&f, b"x").expect("write");
        assert_eq!(not_regular(&f), None);
        assert!(not_regular(&d).is_some_and(|s| s.contains("directory")));
        assert!(not_regular(&d.join("missing.hdf5")).is_some());
        #[cfg(unix)]
        {
            let link = d.join("zero.hdf5");
            let _ = std::fs::remove_file(&link);
            std::os::unix::fs::symlink("/dev/zero", &link).expect("symlink");
            assert!(not_regular(&link).is_some_and(|s| s.contains("device")));
            let dangling = d.join("dangling.hdf5");
            let _ = std::fs::remove_file(&dangling);
            std::os::unix::fs::symlink(d.join("nowhere"), &dangling).expect("symlink");
            assert!(not_regular(&dangling).is_some_and(|s| s.contains("cannot be followed")));
        }
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_small_text_is_read_and_an_endless_one_refused() {
        let d = crate::ScratchDir::for_test("small-text");
        let f = d.join("s.toml");
        std::fs::write(&f, "a = 1\n").expect("write");
        assert_eq!(read_small_text(&f).expect("read"), "a = 1\n");
        std::fs::write(&f, [b'a', 0xff, b'b']).expect("write");
        let e = read_small_text(&f).unwrap_err().to_string();
        assert!(e.contains("not UTF-8") && e.contains("offset 1"), "{e}");
        assert!(read_small_text(&d.join("missing")).is_err());
        #[cfg(unix)]
        {
            let e = read_small_text(Path::new("/dev/zero"))
                .unwrap_err()
                .to_string();
            assert!(e.contains("larger than 16.0 MiB"), "{e}");
        }
    }

    #[test]
    fn a_text_of_exactly_the_limit_is_read_and_one_byte_more_refused() {
        let d = crate::ScratchDir::for_test("text-at-most");
        let f = d.join("log.csv");
        std::fs::write(&f, "0123456789").expect("write");
        let read = |max| read_text_at_most(&f, max, "not a log", "the::LIMIT");
        assert_eq!(read(10).expect("read"), "0123456789");
        let e = read(9).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
        assert_eq!(
            e.to_string(),
            "larger than 9 bytes: not a log (reading stopped there; the::LIMIT)"
        );
        assert_eq!(
            read(u64::MAX).expect("no overflow at the largest limit"),
            "0123456789"
        );
    }
}
