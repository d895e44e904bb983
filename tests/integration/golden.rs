//! Golden files, tantivy's way (`compat_tests_data/`): one `.oavm` file per format version,
//! packed by that version's own `oavm-pack` from one small committed mesh, kept in
//! `tests/golden/` and reopened here by today's code. `tests/golden/README.md` says for each file
//! the commit and the command that made it and its sha256.
//!
//! - The current version (6) opens, verifies, and traces the committed ray set to answers
//!   byte-identical to the recorded ones, in the library and through `oavm-trace`: its files of
//!   clusters (the default leaves, format-spec.md §7.1), raw and zstd-compressed, to `v4.hits` /
//!   `v3.occl` (version 3's closest hits but at five ties, where clusters name the smallest
//!   primitive id, and its any-hit answers), as version 4 answered; its file of leaf lists
//!   (`--leaf list`) to version 3's own `v3.hits` / `v3.occl`, byte for byte; and a file packed
//!   `--updatable` and updated twice by `oavm-update` (format-spec.md §2.1: generation 3, the
//!   first two generations' bytes dead in it, its header in slot 0 again) to `v4.hits` /
//!   `v3.occl` too. The recorded answers are themselves checked: they hit often, agree with each
//!   other (a ray is occluded exactly when it has a closest hit) and with the f64 reference over
//!   the mesh's triangles (rays aimed at shared edges and vertices aside, where either triangle
//!   is right), and each recorded hit is at the `t` the triangle test gives for the triangle it
//!   names.
//! - Older versions (1 to 5) fail to open with `FormatError::Version { expected: 6, found }`
//!   and a message that names the file and says to repack, in the library and through
//!   `oavm-trace` (non-zero exit, nothing written).
//! - A golden file that is missing is a failure, never a skip.
//!
//! When the format moves to version 8, `CURRENT` becomes 8, `v8*.oavm` and their answers join
//! the golden files (made as the README says), and the `v7*.oavm` files move to the rejected
//! versions: the recorded answers stay (and their sha256 in the README), so the files keep
//! proving what version 7 answered.

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use oavm::geom::triangle::intersect_triangle;
use oavm::rays;
use oavm::{Error, FormatError, Hit, Ray, Scene};
use tempfile::TempDir;

/// The format version today's code writes and reads (`format-spec.md` §12). Written out rather
/// than taken from the crate: a version bump must come with a new golden file, and this test
/// failing is what says so.
const CURRENT: u32 = 7;

/// A golden file of the current version: its name, whether its solid leaves are clusters (the
/// header's `CLUSTERS` flag, format-spec.md §2), and the answers it must trace to.
struct Current {
    name: &'static str,
    clusters: bool,
    answers: Answers,
}

/// Recorded answers to [`RAYS`]: closest hits and any hit.
#[derive(Clone, Copy)]
struct Answers {
    hits: &'static str,
    occl: &'static str,
}

/// What version 3's `oavm-trace` answered on `v3.oavm`; a file of lists must answer it still.
const V3_ANSWERS: Answers = Answers {
    hits: "v3.hits",
    occl: "v3.occl",
};
/// What version 4's `oavm-trace` answers on `v4.oavm`, a file of clusters: closest hits that
/// differ from version 3's only at ties (see [`cluster_answers_are_version_3_s_with_ties_to_the_smallest_id`]),
/// and version 3's any-hit answers, byte for byte.
const V4_ANSWERS: Answers = Answers {
    hits: "v4.hits",
    occl: "v3.occl",
};

/// The golden files of the current version: clusters raw and with every block
/// zstd-compressed, leaf lists (which answer as version 3 did, byte for byte), and a file of
/// clusters packed `--updatable` then updated twice (to moved triangles and back: generation
/// 3, with the dead bytes of generations 1 and 2), which answers as the packed files do.
const CURRENT_FILES: [Current; 4] = [
    Current {
        name: "v7.oavm",
        clusters: true,
        answers: V4_ANSWERS,
    },
    Current {
        name: "v7-zstd.oavm",
        clusters: true,
        answers: V4_ANSWERS,
    },
    Current {
        name: "v7-list.oavm",
        clusters: false,
        answers: V3_ANSWERS,
    },
    Current {
        name: "v7-updated.oavm",
        clusters: true,
        answers: V4_ANSWERS,
    },
];

/// Every set of recorded answers.
const ALL_ANSWERS: [Answers; 2] = [V3_ANSWERS, V4_ANSWERS];

/// The golden files of earlier versions, which must be rejected, and their versions.
const REJECTED: [(&str, u32); 15] = [
    ("v1.oavm", 1),
    ("v2.oavm", 2),
    ("v3.oavm", 3),
    ("v3-zstd.oavm", 3),
    ("v4.oavm", 4),
    ("v4-zstd.oavm", 4),
    ("v4-list.oavm", 4),
    ("v5.oavm", 5),
    ("v5-zstd.oavm", 5),
    ("v5-list.oavm", 5),
    ("v5-updated.oavm", 5),
    ("v6.oavm", 6),
    ("v6-zstd.oavm", 6),
    ("v6-list.oavm", 6),
    ("v6-updated.oavm", 6),
];

/// The ray set (`RAYS.md`).
const RAYS: &str = "rays.rays";
/// The mesh every golden file was packed from (`tools/make_golden_inputs.py`).
const MESH: &str = "mesh.ply";

/// Of the 618 rays, 298 have a closest hit in each set of recorded answers, on 148 distinct
/// triangles:
/// the ray set is made to hit the mesh often (aimed rays, axis-parallel grids through it) and to
/// miss it often (rays past it, cut short, invalid). Far fewer of either means the answers or the
/// rays went wrong.
const MIN_HITS: usize = 250;
const MIN_MISSES: usize = 250;
const MIN_DISTINCT_PRIMS: usize = 120;

// ---------------------------------------------------------------------------------------------
// Files

/// The path of a golden file, which must exist: a missing golden file fails the test (with the
/// way to make it), it never skips it.
fn golden(name: &str) -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name);
    assert!(
        path.is_file(),
        "golden file {} is missing: the golden files are committed, never skipped; \
         tests/golden/README.md says how each was made",
        path.display()
    );
    path
}

fn read(name: &str) -> Vec<u8> {
    let path = golden(name);
    fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The `version` field of an `.oavm` file's header, read from the bytes (`format-spec.md` §2:
/// the 8-byte magic, then a little-endian `u32`), so the test knows which version a golden
/// file really is without asking the code under test.
fn header_version(name: &str) -> u32 {
    let bytes = read(name);
    assert!(
        bytes.len() >= 12,
        "{name}: {} bytes, no header",
        bytes.len()
    );
    assert_eq!(
        bytes[..8],
        *b"\x89OAVM\r\n\x1a",
        "{name}: not an .oavm file"
    );
    u32::from_le_bytes(bytes[8..12].try_into().unwrap())
}

/// The `flags` field of an `.oavm` file's header (§2: after the version, a little-endian
/// `u32`).
fn header_flags(name: &str) -> u32 {
    let bytes = read(name);
    u32::from_le_bytes(bytes[12..16].try_into().unwrap())
}

/// §2: flag bit 2, `CLUSTERS`.
const FLAG_CLUSTERS: u32 = 4;

fn golden_rays() -> Vec<Ray> {
    rays::read_rays(&golden(RAYS), 1 << 20).unwrap_or_else(|e| panic!("{e}"))
}

fn recorded_hits(a: Answers) -> Vec<Hit> {
    rays::read_hits(&golden(a.hits), 1 << 20).unwrap_or_else(|e| panic!("{e}"))
}

fn recorded_occlusion(a: Answers) -> Vec<u8> {
    rays::read_occlusion(&golden(a.occl), 1 << 20).unwrap_or_else(|e| panic!("{e}"))
}

/// The rays whose answers differ (as `key` sees them), at most ten, for a failure message.
fn differences<T: std::fmt::Debug, K: PartialEq>(
    rays: &[Ray],
    recorded: &[T],
    got: &[T],
    key: impl Fn(&T) -> K,
) -> String {
    let diff: Vec<String> = (0..recorded.len().min(got.len()))
        .filter(|&i| key(&recorded[i]) != key(&got[i]))
        .take(10)
        .map(|i| {
            format!(
                "  ray {i} {:?}: recorded {:?}, got {:?}",
                rays[i], recorded[i], got[i]
            )
        })
        .collect();
    format!(
        "{} recorded answers, {} traced; first differences:\n{}",
        recorded.len(),
        got.len(),
        diff.join("\n")
    )
}

/// A hit as its bytes see it (`-0.0` and `0.0` differ).
fn hit_bits(h: &Hit) -> (u32, u32) {
    (h.t.to_bits(), h.prim)
}

// ---------------------------------------------------------------------------------------------
// The current version: opens, verifies, answers as recorded

#[test]
fn current_version_files_are_current() {
    for f in CURRENT_FILES {
        assert_eq!(header_version(f.name), CURRENT, "{}", f.name);
        assert_eq!(
            header_flags(f.name) & FLAG_CLUSTERS != 0,
            f.clusters,
            "{}: the CLUSTERS flag",
            f.name
        );
    }
}

#[test]
fn current_version_opens_and_verifies() {
    for Current { name, .. } in CURRENT_FILES {
        let scene = Scene::open(golden(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let report = scene.verify().unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(
            report.is_ok(),
            "{name}: verify found defects:\n{}",
            report.defects.join("\n")
        );
        assert!(report.bytes_checked > 0, "{name}: verify checked nothing");
    }
}

#[test]
fn current_version_traces_byte_identical_to_the_recorded_answers() {
    let rays = golden_rays();
    for Current { name, answers, .. } in CURRENT_FILES {
        let (hits_name, occl_name) = (answers.hits, answers.occl);
        let recorded_hits_bytes = read(hits_name);
        let recorded_occl_bytes = read(occl_name);
        let scene = Scene::open(golden(name)).unwrap_or_else(|e| panic!("{name}: {e}"));

        let mut hits = vec![Hit::MISS; rays.len()];
        scene
            .intersect_batch(&rays, &mut hits)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(
            rays::encode_records(&hits, b"HITS") == recorded_hits_bytes,
            "{name}: closest hits differ from {hits_name}: {}",
            differences(&rays, &recorded_hits(answers), &hits, hit_bits)
        );

        let mut occluded = vec![0u8; rays.len()];
        scene
            .occluded_batch(&rays, &mut occluded)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(
            rays::encode_records(&occluded, b"OCCL") == recorded_occl_bytes,
            "{name}: any-hit answers differ from {occl_name}: {}",
            differences(&rays, &recorded_occlusion(answers), &occluded, |&o| o)
        );
    }
}

/// The recorded answers, each set, are worth comparing with: many hits and many misses, spread
/// over the mesh; closest hit and any hit agree with each other; brute force over the mesh's
/// triangles (no tree, no file) gives the same answers; and each recorded hit lies on the
/// triangle it names, at the recorded `t` exactly.
#[test]
fn recorded_answers_are_sound() {
    for answers in ALL_ANSWERS {
        answers_are_sound(answers);
    }
}

fn answers_are_sound(a: Answers) {
    let (hits_name, occl_name) = (a.hits, a.occl);
    let rays = golden_rays();
    let hits = recorded_hits(a);
    let occluded = recorded_occlusion(a);
    assert_eq!(
        hits.len(),
        rays.len(),
        "{hits_name} answers another ray set"
    );
    assert_eq!(
        occluded.len(),
        rays.len(),
        "{occl_name} answers another ray set"
    );

    let hit_count = hits.iter().filter(|h| h.is_hit()).count();
    assert!(
        hit_count >= MIN_HITS,
        "{hits_name}: only {hit_count} of {} rays hit",
        rays.len()
    );
    assert!(
        rays.len() - hit_count >= MIN_MISSES,
        "{hits_name}: only {} of {} rays miss",
        rays.len() - hit_count,
        rays.len()
    );
    let mut prims: Vec<u32> = hits.iter().filter(|h| h.is_hit()).map(|h| h.prim).collect();
    prims.sort_unstable();
    prims.dedup();
    assert!(
        prims.len() >= MIN_DISTINCT_PRIMS,
        "{hits_name}: the hits fall on only {} triangles",
        prims.len()
    );

    let mesh = oavm::mesh::load(&golden(MESH)).unwrap_or_else(|e| panic!("{e}"));
    let mut wrong = Vec::new();
    for (i, ray) in rays.iter().enumerate() {
        let (hit, occl) = (hits[i], occluded[i]);
        assert!(occl <= 1, "ray {i}: occlusion byte {occl}");
        if hit.is_hit() != (occl == 1) {
            wrong.push(format!(
                "ray {i}: closest hit {hit:?} but occluded = {occl}"
            ));
        }
        if hit.is_hit() {
            let named = hit.prim as usize;
            assert!(
                named < mesh.triangles.len(),
                "ray {i}: primitive id {named} out of range"
            );
            // The tracer reports the triangle test's own t (a consistency check, not a
            // reference: the reference is the f64 comparison below).
            let on_named = intersect_triangle(ray, &mesh.triangle(named));
            if on_named.map(f32::to_bits) != Some(hit.t.to_bits()) {
                wrong.push(format!(
                    "ray {i}: recorded t {} on triangle {named}, which it hits at {on_named:?}",
                    hit.t
                ));
            }
        }
    }
    // The f64 reference, through today's tracer on a file that answers as recorded (above):
    // rays aimed at shared edges and vertices may be excused, at most one in ten.
    let traced = CURRENT_FILES
        .iter()
        .find(|f| f.answers.hits == hits_name)
        .expect("a current file answers as recorded")
        .name;
    let scene = Scene::open(golden(traced)).expect("open");
    common::compare_with_reference(&mesh, &scene, &rays, 1).require(250, rays.len() / 10, traced);
    assert!(
        wrong.is_empty(),
        "{hits_name}: {} problems:\n{}",
        wrong.len(),
        wrong.join("\n")
    );
}

/// The closest hits of clusters are version 3's but where two or more triangles are hit at the
/// same `t`, bit for bit: there clusters name the smallest primitive id hit at that `t`
/// (format-spec.md §7.2, the tie rule of a group's lanes and of the cluster walk), where the
/// lists of version 3 named the first found. `RAYS.md` allows either; this pins which rays
/// moved and why.
#[test]
fn cluster_answers_are_version_3_s_with_ties_to_the_smallest_id() {
    let rays = golden_rays();
    let (v3, v4) = (recorded_hits(V3_ANSWERS), recorded_hits(V4_ANSWERS));
    assert_eq!((v3.len(), v4.len()), (rays.len(), rays.len()));
    let mesh = oavm::mesh::load(&golden(MESH)).unwrap_or_else(|e| panic!("{e}"));
    let mut ties = Vec::new();
    for (i, ray) in rays.iter().enumerate() {
        if hit_bits(&v3[i]) == hit_bits(&v4[i]) {
            continue;
        }
        assert_eq!(
            v3[i].t.to_bits(),
            v4[i].t.to_bits(),
            "ray {i}: version 3 {:?}, clusters {:?}: not a tie",
            v3[i],
            v4[i]
        );
        let at_t: Vec<u32> = (0..mesh.triangles.len() as u32)
            .filter(|&p| {
                intersect_triangle(ray, &mesh.triangle(p as usize)).map(f32::to_bits)
                    == Some(v4[i].t.to_bits())
            })
            .collect();
        assert!(
            at_t.contains(&v3[i].prim) && at_t.first() == Some(&v4[i].prim),
            "ray {i}: version 3 {:?}, clusters {:?}; triangles hit at that t: {at_t:?}",
            v3[i],
            v4[i]
        );
        ties.push(i);
    }
    // The five rays aimed at shared vertices and edges that tests/golden/README.md lists.
    assert_eq!(ties, [277, 337, 493, 525, 567]);
}

// ---------------------------------------------------------------------------------------------
// Earlier versions: rejected, with a message that says to repack

#[test]
fn rejected_files_are_of_their_versions() {
    for (name, version) in REJECTED {
        assert_eq!(header_version(name), version, "{name}");
    }
}

fn assert_version_error<D>(name: &str, found: u32, result: Result<Scene<D>, Error>) {
    let err = match result {
        Ok(_) => panic!("{name} (version {found}) opened; it must be rejected"),
        Err(e) => e,
    };
    let text = err.to_string();
    match &err {
        Error::Format {
            path,
            source:
                FormatError::Version {
                    expected: CURRENT,
                    found: f,
                },
        } if *f == found => {
            assert!(
                path.ends_with(name),
                "{name}: the error names {}",
                path.display()
            );
        }
        _ => panic!(
            "{name}: expected a version error (expected {CURRENT}, found {found}), got {err:?}"
        ),
    }
    assert!(
        text.contains(name),
        "{name}: the message does not name the file: {text}"
    );
    assert!(
        text.contains("repack"),
        "{name}: the message does not say to repack: {text}"
    );
    assert!(
        text.contains(&format!("version {found}")) && text.contains(&format!("version {CURRENT}")),
        "{name}: the message does not name both versions: {text}"
    );
}

#[test]
fn earlier_versions_fail_to_open_with_a_repack_message() {
    for (name, version) in REJECTED {
        assert_version_error(name, version, Scene::open(golden(name)));
        // The same from bytes in memory (`Scene::from_bytes`, the path without a file map).
        let bytes = read(name);
        assert_version_error(name, version, Scene::from_bytes(&bytes[..], golden(name)));
    }
}

// ---------------------------------------------------------------------------------------------
// Through the CLI

fn oavm_trace(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_oavm-trace"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("cannot run oavm-trace")
}

fn describe(o: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}--- stderr\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// `oavm-trace` writes the recorded answers, byte for byte (it is how they were made).
#[test]
fn cli_traces_the_current_version_as_recorded() {
    let rays = golden(RAYS);
    for Current { name, answers, .. } in CURRENT_FILES {
        let dir = TempDir::new().unwrap();
        for (flag, out, recorded) in [
            ("--hits", "out.hits", answers.hits),
            ("--occluded", "out.occl", answers.occl),
        ] {
            let out = dir.path().join(out);
            let o = oavm_trace(&[
                golden(name).as_os_str(),
                "--rays".as_ref(),
                rays.as_os_str(),
                flag.as_ref(),
                out.as_os_str(),
            ]);
            assert!(o.status.success(), "{name} {flag}: {}", describe(&o));
            let written = fs::read(&out).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
            assert!(
                written == read(recorded),
                "{name} {flag}: output differs from {recorded}"
            );
        }
    }
}

/// Batch tracing or verifying an old file: a non-zero exit, one message that names the file, its
/// version and says to repack, and nothing written (not even a temporary file).
#[test]
fn cli_rejects_earlier_versions_with_a_repack_message_and_writes_nothing() {
    let rays = golden(RAYS);
    for (name, version) in REJECTED {
        let file = golden(name);
        let dir = TempDir::new().unwrap();
        let hits = dir.path().join("out.hits");
        let occl = dir.path().join("out.occl");
        let runs: [Vec<&std::ffi::OsStr>; 3] = [
            vec![
                file.as_os_str(),
                "--rays".as_ref(),
                rays.as_os_str(),
                "--hits".as_ref(),
                hits.as_os_str(),
            ],
            vec![
                file.as_os_str(),
                "--rays".as_ref(),
                rays.as_os_str(),
                "--occluded".as_ref(),
                occl.as_os_str(),
            ],
            vec![file.as_os_str(), "--verify".as_ref()],
        ];
        for args in runs {
            let o = oavm_trace(&args);
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert!(
                !o.status.success(),
                "{name} {args:?} succeeded: {}",
                describe(&o)
            );
            assert!(
                stderr.contains(&file.display().to_string()),
                "{name} {args:?}: the message does not name the file: {}",
                describe(&o)
            );
            assert!(
                stderr.contains("repack") && stderr.contains(&format!("version {version}")),
                "{name} {args:?}: the message does not say to repack: {}",
                describe(&o)
            );
            let left: Vec<_> = fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().path())
                .collect();
            assert!(
                left.is_empty(),
                "{name} {args:?} left files behind: {left:?}"
            );
        }
    }
}
