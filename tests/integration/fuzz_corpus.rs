//! Replays the fuzz corpus and the crash reproducers on stable, through the very functions the
//! fuzz targets call (`fuzz/targets.rs`, see `fuzz/README.md`).
//!
//! For every target: every file of `fuzz/corpus/<target>/` (the minimised corpus, committed;
//! a missing or empty folder fails the test) and of `fuzz/regressions/<target>/` (inputs that
//! once crashed a target, kept after the bug they show is fixed). Each must return normally:
//! a panic is reported with the file's name and the test fails after trying every file. A
//! reproducer of a bug not yet fixed is listed in [`OPEN_BUGS`] with its diagnosis; it is not
//! replayed with the others but by [`open_bugs_still_fail`], which fails once the bug is gone
//! (then remove its entry, and the file joins the regressions that must pass).

// `targets.rs` includes the spec's layout (`tests/common/layout.rs`), which `common` holds too:
// two copies of the same constants in this binary, as the fuzz crate needs its own.
#[path = "../../fuzz/targets.rs"]
#[allow(clippy::duplicate_mod)]
mod targets;

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Reproducers (`fuzz/regressions/<target>/<file>`) of bugs found by fuzzing and not fixed yet:
/// `(target, file, the function that shows the bug, what fails)`. Each panics when replayed
/// through that function (see [`open_bugs_still_fail`]). None are open: the four listed here
/// until 2026-12-01 (session 8) were two oracle defects (an origin beside a sliver's edge was
/// not counted as grazing it; the `t` bound used another axis than the tracer's shear) and one
/// tracer defect (an edge function recomputed in f64 lost its sign when it underflowed f32);
/// they replay with the regressions now.
type OpenBug = (&'static str, &'static str, fn(&[u8]), &'static str);
const OPEN_BUGS: &[OpenBug] = &[];

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz")
}

/// The files of `dir`, sorted; `None` if it does not exist.
fn files(dir: &Path) -> Option<Vec<PathBuf>> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .map(|e| e.expect("a directory entry").path())
        .filter(|p| p.is_file())
        .collect();
    out.sort();
    Some(out)
}

fn is_open_bug(target: &str, file: &Path) -> bool {
    let name = file.file_name().and_then(|n| n.to_str()).unwrap_or("");
    OPEN_BUGS.iter().any(|&(t, f, ..)| t == target && f == name)
}

/// Runs `run` on each file; returns the names of those that panicked.
fn replay(run: fn(&[u8]), files: &[PathBuf]) -> Vec<String> {
    let mut failed = Vec::new();
    for f in files {
        let data = std::fs::read(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        if catch_unwind(AssertUnwindSafe(|| run(&data))).is_err() {
            failed.push(f.display().to_string());
        }
    }
    failed
}

#[test]
fn corpus_and_regressions_replay() {
    let dir = fuzz_dir();
    let mut failed = Vec::new();
    let mut summary = Vec::new();
    for &(target, run) in targets::TARGETS {
        let start = Instant::now();
        let corpus = files(&dir.join("corpus").join(target)).unwrap_or_else(|| {
            panic!(
                "fuzz/corpus/{target}/ is missing: every target keeps a corpus (tools/fuzz.sh cmin)"
            )
        });
        assert!(!corpus.is_empty(), "fuzz/corpus/{target}/ is empty");
        let regressions: Vec<PathBuf> = files(&dir.join("regressions").join(target))
            .unwrap_or_default()
            .into_iter()
            .filter(|f| !is_open_bug(target, f))
            .collect();
        failed.extend(replay(run, &corpus));
        failed.extend(replay(run, &regressions));
        summary.push(format!(
            "{target}: {} corpus files, {} regressions, {:.2} s",
            corpus.len(),
            regressions.len(),
            start.elapsed().as_secs_f64()
        ));
    }
    println!("{}", summary.join("\n"));
    assert!(
        failed.is_empty(),
        "{} inputs panicked:\n{}",
        failed.len(),
        failed.join("\n")
    );
}

#[test]
fn open_bugs_still_fail() {
    let dir = fuzz_dir();
    let mut fixed = Vec::new();
    for &(target, file, run, what) in OPEN_BUGS {
        let path = dir.join("regressions").join(target).join(file);
        assert!(
            path.is_file(),
            "OPEN_BUGS names a missing file {}",
            path.display()
        );
        if replay(run, std::slice::from_ref(&path)).is_empty() {
            fixed.push(format!("{} ({what})", path.display()));
        }
    }
    assert!(
        fixed.is_empty(),
        "fixed, so remove them from OPEN_BUGS (they then replay with the regressions):\n{}",
        fixed.join("\n")
    );
}

/// The corpora of the `.oavm` targets reach today's format, so that replaying them exercises
/// more than the version check: each holds files that open as the current version (for
/// `oavm_fixed`, after its checksum fix-up) and verify clean, some of clusters and some of leaf
/// lists (format-spec.md §2, flag `CLUSTERS`), some with the primitive table (flag `PRIMS`,
/// §8.6) and some of a generation after the first (§2.1: read from header slot 1). A format
/// change that leaves the corpora behind fails here: make the seeds again (`tools/fuzz.sh
/// seeds`) and merge them (`tools/fuzz.sh cmin`). Files of other versions stay in the corpora (they cover the version check) and must
/// be rejected by it: a `FormatError::Version` naming their version.
#[test]
fn oavm_corpora_reach_the_current_format() {
    use oavm::physical::AlignedBytes;
    use oavm::physical::format::{FLAG_CLUSTERS, FLAG_PRIMS, MAGIC, VERSION};
    use oavm::{Error, FormatError, Scene};

    let mut summary = Vec::new();
    for (target, fixed) in [("oavm", false), ("oavm_fixed", true)] {
        let dir = fuzz_dir().join("corpus").join(target);
        let corpus = files(&dir).unwrap_or_else(|| panic!("{} is missing", dir.display()));
        let (mut clusters, mut lists, mut current, mut other_versions) = (0, 0, 0, 0);
        let (mut prims, mut updated) = (0, 0);
        for f in &corpus {
            let data = std::fs::read(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            let mut bytes = AlignedBytes::from_slice(&data);
            if fixed {
                targets::fix_checksums(bytes.as_mut_slice());
            }
            // The version of a file with a whole header (format-spec.md §2: 256 bytes, the
            // version after the magic); a shorter one is refused for its length first.
            let b = bytes.as_ref();
            let version = (b.len() >= 256 && b[..8] == MAGIC)
                .then(|| u32::from_le_bytes(b[8..12].try_into().expect("4 bytes")));
            match (version, Scene::from_bytes(bytes, "corpus.oavm")) {
                (Some(v), Err(Error::Format { source, .. })) if v != VERSION => {
                    assert!(
                        matches!(source, FormatError::Version { found, .. } if found == v),
                        "{}: a version-{v} file fails with another error: {source}",
                        f.display()
                    );
                    other_versions += 1;
                }
                (Some(v), Ok(_)) if v != VERSION => {
                    panic!("{}: a version-{v} file opened", f.display())
                }
                (_, Ok(scene)) => {
                    current += 1;
                    if scene.verify().is_ok_and(|r| r.is_ok()) {
                        // The flags of the generation read (in either slot).
                        let flags = scene.file().header().flags;
                        match flags & FLAG_CLUSTERS != 0 {
                            true => clusters += 1,
                            false => lists += 1,
                        }
                        prims += (flags & FLAG_PRIMS != 0) as usize;
                        updated += (scene.file().header().generation > 1) as usize;
                    }
                }
                (_, Err(_)) => {}
            }
        }
        summary.push(format!(
            "{target}: {} files, {current} open as version {VERSION} ({clusters} of clusters \
             and {lists} of lists verify clean, {prims} of them with the primitive table, \
             {updated} of a later generation), {other_versions} of other versions rejected",
            corpus.len()
        ));
        assert!(
            clusters > 0 && lists > 0 && prims > 0 && updated > 0,
            "fuzz/corpus/{target}/ has {clusters} sound files of clusters and {lists} of lists \
             of version {VERSION}, {prims} with the primitive table and {updated} of a later \
             generation: the corpus is stale (tools/fuzz.sh seeds, then cmin)"
        );
    }
    println!("{}", summary.join("\n"));
}

/// The checksum fix-up of `oavm_fixed` (fuzz/README.md) does what it claims: on an intact file
/// it changes nothing (a file as packed, one with the primitive table, and one of generation 2,
/// with both header slots), it restores the checksums of either generation when they are
/// zeroed, and a raw file whose blocks are marked zstd comes out as a sound compressed file
/// (verify finds nothing) that answers the probe rays as the raw one does (with the blocks the
/// last items of the data region, and with the primitive chunks after them).
#[test]
fn checksum_fixup_keeps_files_sound() {
    use oavm::pack::encode_with;
    use oavm::pack::update::{UpdateOptions, Updater};
    use oavm::physical::{AlignedBytes, BlockOptions};
    use oavm::{BuildOptions, Hit, Scene};
    use targets::layout::*;

    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes/cornell_box/CornellBox-Original.obj");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mesh = oavm::mesh::parse_obj(&bytes, "cornell").expect("the Cornell box parses");
    let build = BuildOptions {
        leaf_size: 1,
        ..BuildOptions::default()
    };
    let (parts, _) = oavm::pack::build(&mesh, &build, &oavm::pack::Quiet).expect("build");
    let answers = |file: &[u8]| {
        let scene = Scene::from_bytes(AlignedBytes::from_slice(file), "test.oavm").expect("open");
        let report = scene.verify().expect("verify");
        assert!(report.is_ok(), "{:?}", report.defects);
        let h = scene.file().header();
        let rays = targets::probe_rays(h.mesh_min, h.mesh_max);
        let mut hits = vec![Hit::MISS; rays.len()];
        scene.intersect_batch(&rays, &mut hits).expect("trace");
        (scene.file().header().block_count, hits)
    };
    let fixed = |file: &[u8]| {
        let mut b = AlignedBytes::from_slice(file);
        targets::fix_checksums(b.as_mut_slice());
        b.as_ref().to_vec()
    };
    let u64_at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    // Every block marked zstd (§8.2 codec at entry offset 24), the header flagged COMPRESSED
    // (§2 flags at 12, bit 1): what the `_zmark` seeds are.
    let marked = |file: &[u8], blocks: u64| {
        let mut b = file.to_vec();
        b[FLAGS_AT] |= FLAG_COMPRESSED as u8;
        let dir = u64_at(&b, HEADER_LEN + DIRECTORY * ENTRY_LEN + ENTRY_OFFSET) as usize;
        for i in 0..blocks as usize {
            b[dir + DIR_LEN * i + DIR_CODEC] = CODEC_ZSTD as u8;
        }
        fixed(&b)
    };
    let dir = tempfile::tempdir().expect("temporary directory");
    let packed = dir.path().join("updatable.oavm");
    let opts = oavm::pack::PackOptions {
        build,
        blocks: BlockOptions {
            block_size: 4096,
            compress: None,
            ..BlockOptions::default()
        },
        updatable: true,
        ..oavm::pack::PackOptions::default()
    };
    oavm::pack::pack_mesh(mesh.clone(), "cornell", &packed, &opts, &oavm::pack::Quiet)
        .expect("pack --updatable");
    let updatable = std::fs::read(&packed).expect("read");
    let mut u = Updater::open(&packed).expect("open for an update");
    for p in 0..4 {
        let t = mesh.triangle(p);
        let c: [f32; 3] = std::array::from_fn(|k| (t[0][k] + t[1][k] + t[2][k]) / 3.0);
        u.set(
            p as u32,
            t.map(|v| std::array::from_fn(|k| (v[k] + c[k]) / 2.0)),
        )
        .expect("set");
    }
    u.commit(&UpdateOptions {
        block_size: 4096,
        compress: None,
    })
    .expect("commit");
    let updated = std::fs::read(&packed).expect("read");
    assert_eq!(u64_at(&updated, HEADER_SLOTS[1] + GENERATION_AT), 2);
    for compress in [None, Some(3)] {
        let opts = BlockOptions {
            block_size: 4096,
            compress,
            ..BlockOptions::default()
        };
        let file = encode_with(&parts, &opts).expect("encode");
        assert!(
            fixed(file.as_ref()) == file.as_ref(),
            "the fix-up changed an intact file"
        );
        if compress.is_some() {
            continue;
        }
        let (blocks, expected) = answers(file.as_ref());
        assert!(blocks > 1, "the test wants a file of several blocks");
        let (_, got) = answers(&marked(file.as_ref(), blocks));
        assert_eq!(
            got, expected,
            "the fixed-up compressed file answers differently"
        );
    }
    // With the primitive table, its chunks after the blocks (§8.6).
    assert!(
        fixed(&updatable) == updatable,
        "the fix-up changed an updatable file"
    );
    let (blocks, expected) = answers(&updatable);
    let (_, got) = answers(&marked(&updatable, blocks));
    assert_eq!(
        got, expected,
        "the fixed-up compressed updatable file answers differently"
    );
    // Generation 2, in slot 1, generation 1 in slot 0 (§2.1): both slots fixed up, each with
    // its own table.
    assert!(
        fixed(&updated) == updated,
        "the fix-up changed a file of generation 2"
    );
    answers(&updated);
    for slot in HEADER_SLOTS {
        let mut b = updated.clone();
        let flags = u32::from_le_bytes(b[slot + FLAGS_AT..slot + FLAGS_AT + 4].try_into().unwrap());
        let table = table_range(slot, flags);
        let chunks = section_position(flags, KIND_PRIMS).expect("a primitive table");
        let at = |i: usize| table.start + i * ENTRY_LEN;
        let dir_at = u64_at(&b, at(DIRECTORY) + ENTRY_OFFSET) as usize;
        let chunks_at = u64_at(&b, at(chunks) + ENTRY_OFFSET) as usize;
        for zero in [
            slot + HEADER_CHECKSUM,
            slot + FILE_SIZE_AT,
            at(DIRECTORY) + ENTRY_CHECKSUM,
            at(chunks) + ENTRY_CHECKSUM,
            dir_at + DIR_CHECKSUM,
            chunks_at + PC_CHECKSUM,
        ] {
            b[zero..zero + 8].fill(0);
        }
        assert!(
            fixed(&b) == updated,
            "the fix-up does not restore slot {slot}'s generation"
        );
    }
}
