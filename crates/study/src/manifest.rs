//! What a step's output holds, recorded in its completion marker: every file below the output
//! with its size and a hash of its contents. A step whose output no longer matches (a file
//! lost, added or changed, as when two processes wrote the same study: equally long trials
//! have equal sizes, so sizes alone would miss a swapped file) is not complete and is redone,
//! where a marker that hashed only the settings kept wrong results. Hashing a paper study's
//! outputs (about 0.7 GB) takes well under a second.

use std::collections::BTreeMap;
use std::path::Path;

/// Files that are not part of an output: the one-writer lock a command may leave there.
const IGNORED: [&str; 1] = [fishprobe_io::lock::LOCK_FILE];

/// Every file below `out`: relative path with `/` → `"<size>:<hash>"`; a single entry `""`
/// when `out` is a file; empty when it does not exist.
pub fn manifest(out: &Path) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    match std::fs::symlink_metadata(out) {
        Ok(md) if md.is_dir() => walk(out, "", &mut m),
        Ok(_) => {
            m.insert(String::new(), fingerprint(out));
        }
        Err(_) => {}
    }
    m
}

/// `"<size>:<hash>"` of a file's contents: FNV-1a over 8-byte words (a checksum that is the
/// same on every build, not a cryptographic hash); `"unreadable"` when it cannot be read.
fn fingerprint(path: &Path) -> String {
    use std::io::Read;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let Ok(mut f) = std::fs::File::open(path) else {
        return "unreadable".into();
    };
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut size = 0u64;
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = match f.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(_) => return "unreadable".into(),
        };
        size += n as u64;
        // Reads of a regular file fill the buffer except at the end, so the word boundaries
        // do not depend on how the reads fall.
        let mut words = buf[..n].chunks_exact(8);
        for w in &mut words {
            let w = u64::from_le_bytes(w.try_into().expect("chunks of 8"));
            h = (h ^ w).wrapping_mul(PRIME);
        }
        for &b in words.remainder() {
            h = (h ^ u64::from(b)).wrapping_mul(PRIME);
        }
    }
    format!("{size}:{h:016x}")
}

fn walk(dir: &Path, prefix: &str, m: &mut BTreeMap<String, String>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for e in rd.filter_map(Result::ok) {
        let name = e.file_name().to_string_lossy().into_owned();
        if IGNORED.contains(&name.as_str()) {
            continue;
        }
        let rel = format!("{prefix}{name}");
        match e.metadata() {
            Ok(md) if md.is_dir() => walk(&e.path(), &format!("{rel}/"), m),
            _ => {
                m.insert(rel, fingerprint(&e.path()));
            }
        }
    }
}

/// Whether a marker's recorded outputs (`"outputs"`, as [`manifest`] wrote it) match `now`.
/// A marker without the record (written by fishprobe before 0.1.1) never matches, so its step
/// is redone once (training steps resume from their checkpoints).
pub fn matches(marker: &serde_json::Value, now: &BTreeMap<String, String>) -> bool {
    let Some(rec) = marker.get("outputs").and_then(|o| o.as_object()) else {
        return false;
    };
    rec.len() == now.len()
        && rec.iter().all(|(k, v)| {
            v.as_str()
                .is_some_and(|v| now.get(k).is_some_and(|n| n == v))
        })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_lost_added_or_resized_file_breaks_the_match() {
        let d = std::env::temp_dir().join(format!("fishprobe-manifest-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("sub")).unwrap();
        std::fs::write(d.join("a.hdf5"), b"abc").unwrap();
        std::fs::write(d.join("sub/b.json"), b"{}").unwrap();
        std::fs::write(d.join(fishprobe_io::lock::LOCK_FILE), b"pid").unwrap();
        let m = manifest(&d);
        assert_eq!(m.len(), 2, "{m:?}");
        assert!(m["a.hdf5"].starts_with("3:"), "{m:?}");
        assert!(m["sub/b.json"].starts_with("2:"), "{m:?}");
        let marker = serde_json::json!({ "outputs": m });
        assert!(matches(&marker, &manifest(&d)));
        assert!(
            !matches(&serde_json::json!({"hash": "x"}), &m),
            "legacy marker"
        );
        std::fs::write(d.join("a.hdf5"), b"abcd").unwrap();
        assert!(!matches(&marker, &manifest(&d)), "resized");
        std::fs::write(d.join("a.hdf5"), b"abd").unwrap();
        assert!(
            !matches(&marker, &manifest(&d)),
            "same size, other contents"
        );
        std::fs::write(d.join("a.hdf5"), b"abc").unwrap();
        std::fs::write(d.join("c.hdf5"), b"").unwrap();
        assert!(!matches(&marker, &manifest(&d)), "added");
        std::fs::remove_file(d.join("c.hdf5")).unwrap();
        std::fs::remove_file(d.join("sub/b.json")).unwrap();
        assert!(!matches(&marker, &manifest(&d)), "lost");
        std::fs::remove_dir_all(&d).ok();
    }
}
