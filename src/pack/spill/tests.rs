//! The bucket spill of the streaming pack ([`SpillBuckets`]) against a model
//! (one `Vec` per bucket): the same records per bucket, in push order, with the buffers within
//! their budget and nothing ever visible in the spill directory.

use std::path::Path;

use super::SpillBuckets;
use crate::physical::format::TriRecord;

/// A small deterministic generator (PCG-style LCG, high bits).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 32
    }
}

fn record(i: u64) -> TriRecord {
    let f = i as f32;
    TriRecord {
        v: [[f, -f, 0.5], [f * 2.0, 1.0, -3.0], [0.0, f + 0.25, 7.0]],
        prim: i as u32,
    }
}

fn entries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect()
}

/// Pushes `n` records to random buckets (skewed: a few buckets get most), checking the model
/// as it goes and at the end.
fn run(buckets: usize, buffer_bytes: usize, n: u64, seed: u64) {
    let dir = tempfile::tempdir().unwrap();
    let mut spill = SpillBuckets::new(dir.path(), buckets, buffer_bytes).unwrap();
    let bound = buffer_bytes.max(buckets * size_of::<TriRecord>());
    let mut model: Vec<Vec<TriRecord>> = vec![Vec::new(); buckets];
    let mut rng = Rng(seed);
    for i in 0..n {
        let b = if rng.next().is_multiple_of(4) {
            (rng.next() % 3) as usize
        } else {
            (rng.next() % buckets as u64) as usize
        };
        let r = record(i);
        spill.push(b as u32, &r).unwrap();
        model[b].push(r);
        assert!(
            spill.buffered_bytes() <= bound,
            "{} bytes buffered",
            spill.buffered_bytes()
        );
        if i.is_multiple_of(5003) {
            // Readable while pushing, buffers included; the directory shows nothing.
            assert_eq!(spill.read(b as u32).unwrap(), model[b]);
            assert!(entries(dir.path()).is_empty());
        }
    }
    for (b, want) in model.iter().enumerate() {
        assert_eq!(spill.len(b as u32), want.len() as u64);
    }
    spill.finish().unwrap();
    assert_eq!(spill.buffered_bytes(), 0, "finish frees the buffers");
    assert_eq!(spill.disk_bytes(), n * size_of::<TriRecord>() as u64);
    for (b, want) in model.iter().enumerate() {
        assert_eq!(spill.len(b as u32), want.len() as u64);
        let got = spill.read(b as u32).unwrap();
        assert!(
            got == *want,
            "bucket {b}: {} records, want {}",
            got.len(),
            want.len()
        );
    }
    assert!(entries(dir.path()).is_empty(), "{:?}", entries(dir.path()));
    drop(spill);
    assert!(entries(dir.path()).is_empty());
}

#[test]
fn one_record_per_bucket() {
    run(50, 0, 20_000, 1);
}

#[test]
fn small_buffers_many_buckets() {
    run(3000, 1 << 20, 150_000, 2);
}

#[test]
fn buffers_larger_than_the_data() {
    run(16, 64 << 20, 10_000, 3);
}

#[test]
fn uneven_division() {
    // 1000 bytes among 7 buckets: 142 bytes each, 3 records.
    run(7, 1000, 5_000, 4);
}

#[test]
fn pushes_after_finish_and_empty_buckets() {
    let dir = tempfile::tempdir().unwrap();
    let mut spill = SpillBuckets::new(dir.path(), 4, 400).unwrap();
    assert!(spill.is_empty());
    assert_eq!(spill.read(2).unwrap(), vec![]);
    for i in 0..25 {
        spill.push(1, &record(i)).unwrap();
    }
    spill.finish().unwrap();
    for i in 25..30 {
        spill.push(1, &record(i)).unwrap();
    }
    assert_eq!(
        spill.read(1).unwrap(),
        (0..30).map(record).collect::<Vec<_>>()
    );
    spill.finish().unwrap();
    assert_eq!(spill.read(1).unwrap().len(), 30);
    assert_eq!(spill.len(0), 0);
    assert_eq!(spill.read(0).unwrap(), vec![]);
    assert!(!spill.is_empty());
}

#[test]
fn bad_buckets_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut spill = SpillBuckets::new(dir.path(), 3, 4096).unwrap();
    let err = spill.push(3, &record(0)).unwrap_err().to_string();
    assert!(err.contains("bucket 3"), "{err}");
    assert!(spill.read(7).is_err());
    assert_eq!(spill.len(7), 0);
    let mut none = SpillBuckets::new(dir.path(), 0, 4096).unwrap();
    assert!(none.push(0, &record(0)).is_err());
    none.finish().unwrap();
}

#[test]
fn io_errors_name_the_directory() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-such-dir");
    let err = SpillBuckets::new(&missing, 8, 4096)
        .unwrap_err()
        .to_string();
    assert!(err.contains("no-such-dir"), "{err}");
    assert!(err.contains("spill file"), "{err}");
}

/// The file has no name, so it cannot outlive the process: a child that is killed while its
/// spill file holds data leaves nothing behind.
#[test]
fn killed_process_leaves_nothing() {
    if let Some(dir) = std::env::var_os("OAVM_SPILL_CHILD") {
        let mut spill = SpillBuckets::new(Path::new(&dir), 10, 400).unwrap();
        for i in 0..10_000 {
            spill.push((i % 10) as u32, &record(i)).unwrap();
        }
        println!("spilled {}", spill.disk_bytes());
        std::process::abort();
    }
    let dir = tempfile::tempdir().unwrap();
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "pack::spill::tests::killed_process_leaves_nothing",
            "--nocapture",
        ])
        .env("OAVM_SPILL_CHILD", dir.path())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("spilled 400000"), "{stdout}");
    assert!(entries(dir.path()).is_empty(), "{:?}", entries(dir.path()));
}
