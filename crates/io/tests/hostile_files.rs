//! Files made to hurt a reader: tiny files declaring gigabytes, a FIFO, a device behind a
//! symbolic link, a 3 GB sparse file, directories and dangling or looping links named
//! `*.hdf5`. Every one must end in an error naming the file, quickly, with memory bounded
//! by what the file really holds: the reads run in a child process under an address-space
//! limit (`ulimit -v`, 1 GiB), where allocating a declared 3.2 GB aborts the child.

#![allow(clippy::unwrap_used)] // test helpers may unwrap: a failure is a test failure

use fishprobe_io::backend::{to_bytes, AttrOut, Data, GroupSpec};
use fishprobe_io::{read_legacy, read_trial};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Rows the small files really hold; patched to `HUGE_ROWS` in the header afterwards.
const REAL_ROWS: u64 = 12_345;
const HUGE_ROWS: u64 = 400_000_000;

/// Bob Jenkins' lookup3 `hashlittle` with seed 0: the checksum of HDF5's version-2 metadata.
fn lookup3(k: &[u8]) -> u32 {
    let word = |b: &[u8]| {
        let mut w = [0u8; 4];
        w[..b.len()].copy_from_slice(b);
        u32::from_le_bytes(w)
    };
    let init = 0xdead_beefu32.wrapping_add(k.len() as u32);
    let (mut a, mut b, mut c) = (init, init, init);
    let mut rest = k;
    while rest.len() > 12 {
        a = a.wrapping_add(word(&rest[0..4]));
        b = b.wrapping_add(word(&rest[4..8]));
        c = c.wrapping_add(word(&rest[8..12]));
        a = a.wrapping_sub(c);
        a ^= c.rotate_left(4);
        c = c.wrapping_add(b);
        b = b.wrapping_sub(a);
        b ^= a.rotate_left(6);
        a = a.wrapping_add(c);
        c = c.wrapping_sub(b);
        c ^= b.rotate_left(8);
        b = b.wrapping_add(a);
        a = a.wrapping_sub(c);
        a ^= c.rotate_left(16);
        c = c.wrapping_add(b);
        b = b.wrapping_sub(a);
        b ^= a.rotate_left(19);
        a = a.wrapping_add(c);
        c = c.wrapping_sub(b);
        c ^= b.rotate_left(4);
        b = b.wrapping_add(a);
        rest = &rest[12..];
    }
    if rest.is_empty() {
        return c;
    }
    let mut tail = [0u8; 12];
    tail[..rest.len()].copy_from_slice(rest);
    a = a.wrapping_add(word(&tail[0..4]));
    b = b.wrapping_add(word(&tail[4..8]));
    c = c.wrapping_add(word(&tail[8..12]));
    c ^= b;
    c = c.wrapping_sub(b.rotate_left(14));
    a ^= c;
    a = a.wrapping_sub(c.rotate_left(11));
    b ^= a;
    b = b.wrapping_sub(a.rotate_left(25));
    c ^= b;
    c = c.wrapping_sub(b.rotate_left(16));
    a ^= c;
    a = a.wrapping_sub(c.rotate_left(4));
    b ^= a;
    b = b.wrapping_sub(a.rotate_left(14));
    c ^= b;
    c = c.wrapping_sub(b.rotate_left(24));
    c
}

/// Recomputes the checksum of every version-2 object header ("OHDR", first chunk) in `bytes`,
/// so that a patched header still reads as intact; returns how many it found.
fn fix_object_header_checksums(bytes: &mut [u8]) -> usize {
    let mut n = 0;
    let mut i = 0;
    while i + 6 < bytes.len() {
        if &bytes[i..i + 4] != b"OHDR" || bytes[i + 4] != 2 {
            i += 1;
            continue;
        }
        let flags = bytes[i + 5];
        let mut at = i + 6;
        if flags & 0x20 != 0 {
            at += 16; // access, modification, change and birth times
        }
        if flags & 0x10 != 0 {
            at += 4; // attribute phase change values
        }
        let width = 1usize << (flags & 0x03);
        let mut size = [0u8; 8];
        size[..width].copy_from_slice(&bytes[at..at + width]);
        let end = at + width + u64::from_le_bytes(size) as usize;
        if end + 4 > bytes.len() {
            i += 1;
            continue;
        }
        let sum = lookup3(&bytes[i..end]);
        bytes[end..end + 4].copy_from_slice(&sum.to_le_bytes());
        n += 1;
        i = end + 4;
    }
    n
}

/// Replaces every little-endian u64 `from` in `bytes` by `to`; returns how many.
fn patch_u64(bytes: &mut [u8], from: u64, to: u64) -> usize {
    let (f, t) = (from.to_le_bytes(), to.to_le_bytes());
    let mut n = 0;
    for i in 0..bytes.len().saturating_sub(7) {
        if bytes[i..i + 8] == f {
            bytes[i..i + 8].copy_from_slice(&t);
            n += 1;
        }
    }
    n
}

/// A robofish.io file whose positions, a chunked dataset, declare 400M x 2 (3.2 GB): the
/// missing chunks read as the fill value, so a reader that trusts the shape allocates it all.
fn huge_robofish() -> Vec<u8> {
    use hdf5_pure::{AttrValue, FileBuilder};
    let rows = REAL_ROWS as usize;
    let mut fb = FileBuilder::new();
    fb.set_attr("format_version", AttrValue::I32Array(vec![1, 0]));
    fb.set_attr("world_size_cm", AttrValue::F32Array(vec![100.0, 100.0]));
    let mut entities = fb.create_group("entities");
    let mut fish = entities.create_group("fish_1");
    fish.set_attr("category", AttrValue::VarLenString("fish".into()));
    for name in ["positions", "orientations"] {
        fish.create_dataset(name)
            .with_f32_data(&vec![0.5f32; rows * 2])
            .with_shape(&[REAL_ROWS, 2])
            .with_chunks(&[1000, 2]);
    }
    entities.add_group(fish.finish());
    fb.add_group(entities.finish());
    let mut samplings = fb.create_group("samplings");
    samplings.set_attr("default", AttrValue::VarLenString("25 hz".into()));
    let mut rate = samplings.create_group("25 hz");
    rate.set_attr("frequency_hz", AttrValue::F32(25.0));
    samplings.add_group(rate.finish());
    fb.add_group(samplings.finish());
    let mut b = fb.finish().unwrap();
    let original = b.clone();
    // The checksums are recomputed correctly: an unpatched file comes out unchanged.
    assert!(fix_object_header_checksums(&mut b) > 0);
    assert_eq!(b, original, "lookup3 disagrees with the writer's checksums");
    assert!(patch_u64(&mut b, REAL_ROWS, HUGE_ROWS) > 0);
    fix_object_header_checksums(&mut b);
    b
}

/// A legacy file whose dataset "1" declares 400M x 4 (6.4 GB).
fn huge_legacy() -> Vec<u8> {
    let spec = GroupSpec {
        attrs: vec![
            ("world".into(), AttrOut::F32s(vec![100.0, 100.0])),
            ("time_step".into(), AttrOut::F32(40.0)),
        ],
        datasets: vec![(
            "1".into(),
            Data::F32(vec![1.0; REAL_ROWS as usize * 4], vec![REAL_ROWS, 4]),
        )],
        groups: vec![],
    };
    let mut b = to_bytes(&spec).unwrap();
    assert!(patch_u64(&mut b, REAL_ROWS, HUGE_ROWS) > 0);
    fix_object_header_checksums(&mut b);
    b
}

/// Makes the corpus in `dir`; returns the paths.
fn make_corpus(dir: &Path) -> Vec<PathBuf> {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).unwrap();
    let mut v = Vec::new();
    let p = dir.join("huge_robofish.hdf5");
    std::fs::write(&p, huge_robofish()).unwrap();
    v.push(p);
    let p = dir.join("huge_legacy.hdf5");
    std::fs::write(&p, huge_legacy()).unwrap();
    v.push(p);
    // A 3 GB sparse file: nothing on disk, 3 GB to read.
    let p = dir.join("sparse.hdf5");
    let f = std::fs::File::create(&p).unwrap();
    f.set_len(3 << 30).unwrap();
    v.push(p);
    let p = dir.join("directory.hdf5");
    std::fs::create_dir_all(&p).unwrap();
    v.push(p);
    #[cfg(unix)]
    {
        use std::os::unix::fs::symlink;
        let p = dir.join("zero.hdf5");
        symlink("/dev/zero", &p).unwrap();
        v.push(p);
        let p = dir.join("dangling.hdf5");
        symlink(dir.join("nowhere.hdf5"), &p).unwrap();
        v.push(p);
        let (a, b) = (dir.join("loop_a.hdf5"), dir.join("loop_b.hdf5"));
        symlink(&b, &a).unwrap();
        symlink(&a, &b).unwrap();
        v.push(a);
        v.push(b);
        let p = dir.join("fifo.hdf5");
        let ok = std::process::Command::new("mkfifo")
            .arg(&p)
            .status()
            .unwrap()
            .success();
        assert!(ok, "mkfifo failed");
        v.push(p);
    }
    v
}

/// The reads, in the child process: every file must be an error naming it, within 10 s each.
fn read_all(dir: &Path) {
    for p in fishprobe_io::trial_files(dir) {
        let start = Instant::now();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        for e in [
            read_trial(&p).map(|_| ()).unwrap_err().to_string(),
            read_legacy(&p).map(|_| ()).unwrap_err().to_string(),
        ] {
            assert!(e.contains(&name), "error does not name {name}: {e}");
            println!("{name}: {e}");
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "{name} took {:?}",
            start.elapsed()
        );
    }
}

#[test]
fn hostile_files_child() {
    // Runs only as the child of `hostile_files_are_refused_within_a_memory_limit`.
    if let Some(dir) = std::env::var_os("FISHPROBE_HOSTILE_DIR") {
        read_all(Path::new(&dir));
    }
}

#[cfg(unix)]
#[test]
fn hostile_files_are_refused_within_a_memory_limit() {
    let dir = std::env::temp_dir().join(format!("fishprobe-hostile-{}", std::process::id()));
    let files = make_corpus(&dir);
    assert_eq!(fishprobe_io::trial_files(&dir).len(), files.len());
    let exe = std::env::current_exe().unwrap();
    // 1 GiB of address space: the test harness needs a few hundred MB, a declared 3.2 GB
    // dataset or a 3 GB file read whole would abort the child.
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 1048576 && exec \"$0\" hostile_files_child --exact --nocapture --test-threads 1")
        .arg(&exe)
        .env("FISHPROBE_HOSTILE_DIR", &dir)
        .output()
        .unwrap();
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "child failed: {:?}\n{text}",
        out.status
    );
    for needle in [
        "huge_robofish.hdf5: dataset /entities/fish_1/positions declares 400000000 frames",
        "huge_legacy.hdf5: dataset /1 declares 400000000 frames",
        "sparse.hdf5: 3221225472 bytes, more than the limit",
        "directory.hdf5: a directory, not a regular file",
        "zero.hdf5: a symbolic link to a device",
        "dangling.hdf5: a symbolic link that cannot be followed",
        "loop_a.hdf5: a symbolic link that cannot be followed",
        "fifo.hdf5: a FIFO (named pipe), not a regular file",
    ] {
        assert!(text.contains(needle), "missing `{needle}` in:\n{text}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
