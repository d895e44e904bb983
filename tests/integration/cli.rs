//! End-to-end tests of the two binaries, the ripgrep way: every test runs the real `oavm-pack` /
//! `oavm-trace` (built by Cargo for this test, `CARGO_BIN_EXE_*`) on files in its own temporary
//! directory, and checks the exit status, the files left behind, the reports on stdout and the
//! messages on stderr. Batch answers are compared with the library's own, bit for bit.
//!
//! Inputs: the bundled bunny (`data/bunny.ply`, 69,451 triangles), two of `../shared/scenes`,
//! and small meshes written here. Images and ray sets are kept small so the whole file runs in
//! seconds. Hostile inputs and outputs (files changed while read, outputs that must not be
//! replaced, caps) are in `tests/integration/safety.rs`.

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use oavm::rays::{self, Bounds, Camera};
use oavm::{Hit, Ray, Scene};
use serde_json::Value;
use tempfile::TempDir;

const BUNNY_TRIANGLES: u64 = 69_451;
const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];

// ---------------------------------------------------------------------------------------------
// Running the binaries

fn bunny_ply() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/bunny.ply")
}

fn oavm_pack() -> Command {
    Command::new(env!("CARGO_BIN_EXE_oavm-pack"))
}

fn oavm_trace() -> Command {
    Command::new(env!("CARGO_BIN_EXE_oavm-trace"))
}

/// Runs `cmd` to completion with no stdin; stdout and stderr are captured.
fn run(cmd: &mut Command) -> Output {
    cmd.stdin(Stdio::null())
        .output()
        .expect("cannot spawn the binary")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn describe(o: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}--- stderr\n{}",
        o.status,
        text(&o.stdout),
        text(&o.stderr)
    )
}

#[track_caller]
fn assert_success(o: &Output) {
    assert!(o.status.success(), "expected success, got {}", describe(o));
}

/// Asserts a clean failure: a non-zero exit code (not a signal, not a panic, whose exit code is
/// 101). Returns stderr.
#[track_caller]
fn assert_failure(o: &Output) -> String {
    let code = o.status.code();
    assert!(
        matches!(code, Some(c) if c != 0 && c != 101),
        "expected a clean non-zero exit, got {}",
        describe(o)
    );
    let err = text(&o.stderr);
    assert!(!err.contains("panicked"), "a panic: {}", describe(o));
    err
}

/// Asserts a failure reported by `main_with`: one message prefixed `PROGRAM: error: ` that names
/// `path`. Returns stderr.
#[track_caller]
fn assert_error(o: &Output, program: &str, path: &Path) -> String {
    let err = assert_failure(o);
    assert!(
        err.starts_with(&format!("{program}: error: ")),
        "stderr does not start with `{program}: error: `: {}",
        describe(o)
    );
    assert!(
        err.contains(&path.display().to_string()),
        "stderr does not name {}: {}",
        path.display(),
        describe(o)
    );
    assert!(o.stdout.is_empty(), "output on stdout: {}", describe(o));
    err
}

/// Asserts a usage error from the argument parser (clap exits with 2).
#[track_caller]
fn assert_usage_error(o: &Output) -> String {
    let err = assert_failure(o);
    assert_eq!(o.status.code(), Some(2), "{}", describe(o));
    assert!(err.starts_with("error: "), "{}", describe(o));
    assert!(err.contains("--help"), "{}", describe(o));
    err
}

#[track_caller]
fn json_of(o: &Output) -> Value {
    assert_success(o);
    // One JSON object and nothing else: `from_slice` rejects trailing data.
    let v: Value = serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("stdout is not one JSON value ({e}): {}", describe(o)));
    assert!(v.is_object(), "not a JSON object: {v}");
    v
}

#[track_caller]
fn num(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("`{key}` is not a number in {v:#}"))
}

#[track_caller]
fn uint(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("`{key}` is not an unsigned integer in {v:#}"))
}

/// Packs the bundled bunny into `dir/name` with `extra` options; asserts success.
fn pack_bunny(dir: &Path, name: &str, extra: &[&str]) -> (PathBuf, Output) {
    let out = dir.join(name);
    let o = run(oavm_pack().arg(bunny_ply()).arg(&out).args(extra));
    assert_success(&o);
    assert!(out.is_file(), "{} was not written", out.display());
    (out, o)
}

/// Names in `dir` that an unfinished output would have (`oavm::output`: `.NAME.oavm-tmp-PID-N`;
/// and the names of earlier versions' temporary files).
fn leftover_temporaries(dir: &Path) -> Vec<String> {
    fs::read_dir(dir)
        .expect("read_dir")
        .map(|e| {
            e.expect("dir entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|n| n.starts_with(".oavm-pack-") || n.contains(".oavm-tmp-"))
        .collect()
}

fn bounds_of(scene: &Scene) -> Bounds {
    let h = scene.file().header();
    Bounds {
        min: h.mesh_min,
        max: h.mesh_max,
    }
}

/// The records of a batch file, checked by hand against RAYS.md: magic, version 1, count, and a
/// size of exactly `16 + count * record_size`.
#[track_caller]
fn batch_records(path: &Path, magic: &[u8; 4], record_size: usize) -> Vec<u8> {
    let bytes = fs::read(path).expect("read batch file");
    assert!(
        bytes.len() >= 16,
        "{}: {} bytes",
        path.display(),
        bytes.len()
    );
    assert_eq!(&bytes[..4], magic, "{}: magic", path.display());
    assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), 1);
    let count = u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize;
    assert_eq!(
        bytes.len(),
        16 + count * record_size,
        "{}: size",
        path.display()
    );
    bytes[16..].to_vec()
}

// ---------------------------------------------------------------------------------------------
// oavm-pack

#[test]
fn pack_reports_in_words_and_in_json() {
    let dir = TempDir::new().unwrap();

    let (out, o) = pack_bunny(dir.path(), "bunny.oavm", &[]);
    let size = fs::metadata(&out).unwrap().len();
    let report = text(&o.stdout);
    let line = |key: &str| -> &str {
        report
            .lines()
            .find(|l| l.starts_with(key) && l[key.len()..].starts_with(' '))
            .unwrap_or_else(|| panic!("no `{key}` line in the report:\n{report}"))
    };
    assert!(line("triangles").contains(&BUNNY_TRIANGLES.to_string()));
    let depth: usize = line("depth")
        .split_whitespace()
        .last()
        .unwrap()
        .parse()
        .expect("depth is a number");
    let per_level = line("nodes per level")["nodes per level".len()..]
        .split_whitespace()
        .map(|n| n.parse::<u64>().expect("a node count"))
        .collect::<Vec<_>>();
    assert_eq!(per_level.len(), depth + 1, "{report}");
    assert_eq!(per_level[0], 1, "one root: {report}");
    assert!(line("merged volumes").contains("empty leaves per volume"));
    assert!(line("stored pointers").contains("pointer octree"));
    assert!(line("file").contains(&format!("{size} bytes")), "{report}");
    let time = line("time");
    for phase in ["parse", "build", "merge", "write", "total"] {
        assert!(time.contains(phase), "no {phase} time: {time}");
    }
    assert!(o.stderr.is_empty(), "{}", describe(&o));

    // The same run in JSON, over the existing file.
    let (out, o) = pack_bunny(dir.path(), "bunny.oavm", &["--json"]);
    let v = json_of(&o);
    let size = fs::metadata(&out).unwrap().len();
    assert_eq!(uint(&v, "input_triangles"), BUNNY_TRIANGLES);
    assert_eq!(
        uint(&v, "triangles") + uint(&v, "degenerate_triangles"),
        BUNNY_TRIANGLES
    );
    assert_eq!(uint(&v, "file_bytes"), size);
    assert_eq!(v["output"], out.display().to_string());
    let per_level: Vec<u64> = v["nodes_per_level"]
        .as_array()
        .expect("nodes_per_level")
        .iter()
        .map(|n| n.as_u64().unwrap())
        .collect();
    assert_eq!(per_level.len() as u64, uint(&v, "depth") + 1);
    assert_eq!(per_level.iter().sum::<u64>(), uint(&v, "nodes"));
    let volumes = uint(&v, "volumes");
    assert!(volumes > 0 && volumes < uint(&v, "empty_leaves"), "{v:#}");
    let p = &v["pointers"];
    assert_eq!(uint(p, "child_pointers"), 0);
    assert_eq!(
        uint(p, "total"),
        uint(p, "rank_entries") + uint(p, "leaf_offsets")
    );
    assert!(uint(p, "pointer_octree_total") > uint(p, "total"), "{p:#}");
    for key in [
        "parse_seconds",
        "build_seconds",
        "merge_seconds",
        "layout_seconds",
        "write_seconds",
        "total_seconds",
    ] {
        assert!(num(&v, key) >= 0.0, "{key}");
    }
    // The defaults: clusters (format-spec.md §7.1) of up to 512 triangles.
    assert_eq!(v["options"]["max_depth"], 16);
    assert_eq!(v["options"]["leaf_size"], 512);
    assert_eq!(v["options"]["merge"], true);
    assert_eq!(v["options"]["leaf"], "cluster");
    // `--leaf list`, the paper's leaves, has its own default leaf size; the header says which
    // kind the file holds (§2, flag `CLUSTERS`).
    let (list, o) = pack_bunny(dir.path(), "list.oavm", &["--leaf", "list", "--json"]);
    let l = json_of(&o);
    assert_eq!(l["options"]["max_depth"], 16);
    assert_eq!(l["options"]["leaf_size"], 32);
    assert_eq!(l["options"]["merge"], true);
    assert_eq!(l["options"]["leaf"], "list");
    assert!(uint(&l["pointers"], "pointer_octree_total") > uint(&l["pointers"], "total"));
    let flags = |p: &Path| Scene::open(p).unwrap().file().header().flags;
    let clusters = oavm::physical::format::FLAG_CLUSTERS;
    assert_eq!(
        flags(&out) & clusters,
        clusters,
        "the default file holds clusters"
    );
    assert_eq!(flags(&list) & clusters, 0, "a file of lists holds none");
    assert!(leftover_temporaries(dir.path()).is_empty());
}

#[test]
fn pack_options_reach_the_file() {
    let dir = TempDir::new().unwrap();
    let (out, o) = pack_bunny(
        dir.path(),
        "shallow.oavm",
        &[
            "--max-depth",
            "5",
            "--leaf-size",
            "64",
            "--no-merge",
            "--json",
        ],
    );
    let v = json_of(&o);
    assert!(uint(&v, "depth") <= 5, "{v:#}");
    assert_eq!(v["options"]["max_depth"], 5);
    assert_eq!(v["options"]["leaf_size"], 64);
    assert_eq!(v["options"]["merge"], false);
    // Without merging every empty leaf is its own volume.
    assert_eq!(uint(&v, "volumes"), uint(&v, "empty_leaves"));
    // The header records them too.
    let scene = Scene::open(&out).unwrap();
    let h = scene.file().header();
    assert_eq!((h.max_depth, h.leaf_size), (5, 64));
    assert_eq!(h.input_triangles, BUNNY_TRIANGLES);
}

#[test]
fn pack_is_deterministic_for_any_thread_count() {
    let dir = TempDir::new().unwrap();
    let (one, _) = pack_bunny(dir.path(), "t1.oavm", &["--threads", "1"]);
    let (two, _) = pack_bunny(dir.path(), "t2.oavm", &["--threads", "2"]);
    let (again, _) = pack_bunny(dir.path(), "t2-again.oavm", &["--threads", "2"]);
    let one = fs::read(one).unwrap();
    assert!(one == fs::read(two).unwrap(), "--threads 1 and 2 differ");
    assert!(one == fs::read(again).unwrap(), "two runs differ");
}

#[test]
fn pack_reads_ply_and_obj_scenes() {
    let dir = TempDir::new().unwrap();
    let scenes = common::shared_scene("");

    // The bundled bunny is the ascii original converted to binary with the same geometry: the
    // two encodings must pack to the same bytes.
    let (bundled, _) = pack_bunny(dir.path(), "bundled.oavm", &[]);
    let ascii = dir.path().join("ascii.oavm");
    let o = run(oavm_pack()
        .arg(scenes.join("bunny/bun_zipper.ply"))
        .arg(&ascii)
        .arg("--json"));
    assert_eq!(uint(&json_of(&o), "input_triangles"), BUNNY_TRIANGLES);
    assert!(
        fs::read(&bundled).unwrap() == fs::read(&ascii).unwrap(),
        "ascii and binary PLY of the same mesh pack differently"
    );

    // An OBJ with quads, negative indices, groups and a material library: 18 quads, 36
    // triangles; it renders.
    let cornell = dir.path().join("cornell.oavm");
    let o = run(oavm_pack()
        .arg(scenes.join("cornell_box/CornellBox-Original.obj"))
        .arg(&cornell)
        .arg("--json"));
    let v = json_of(&o);
    assert_eq!(uint(&v, "input_triangles"), 36);
    assert_eq!(uint(&v, "triangles"), 36);
    let o = run(oavm_trace()
        .arg(&cornell)
        .args(["--width", "32", "--height", "24", "--json"]));
    let v = json_of(&o);
    assert!(uint(&v["render"], "hits") > 32 * 24 / 10, "{v:#}");
    assert_eq!(png_size(&dir.path().join("cornell.png")), (32, 24));
}

/// Writes `contents` to `dir/name`, packs it to `dir/out.oavm` (over `previous` if given) and
/// checks the failure: the message, no output, no temporary file. Returns stderr.
#[track_caller]
fn pack_fails(dir: &Path, name: &str, contents: Option<&[u8]>, previous: Option<&[u8]>) -> String {
    let mesh = dir.join(name);
    if let Some(c) = contents {
        fs::write(&mesh, c).unwrap();
    }
    let out = dir.join("out.oavm");
    match previous {
        Some(p) => fs::write(&out, p).unwrap(),
        None => {
            let _ = fs::remove_file(&out);
        }
    }
    let o = run(oavm_pack().arg(&mesh).arg(&out));
    let err = assert_error(&o, "oavm-pack", &mesh);
    match previous {
        Some(p) => assert!(
            fs::read(&out).unwrap() == p,
            "{name}: the old output changed"
        ),
        None => assert!(!out.exists(), "{name}: an output file was left: {err}"),
    }
    let left = leftover_temporaries(dir);
    assert!(left.is_empty(), "{name}: temporary files left: {left:?}");
    err
}

#[test]
fn pack_rejects_bad_meshes_and_leaves_nothing() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();

    let err = pack_fails(d, "missing.ply", None, None);
    assert!(err.contains("cannot read"), "{err}");

    let garbage: Vec<u8> = (0..4096u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    let err = pack_fails(d, "garbage.ply", Some(&garbage), None);
    assert!(err.contains("PLY magic"), "{err}");
    let err = pack_fails(d, "garbage.bin", Some(&garbage), None);
    assert!(err.contains("unknown mesh format"), "{err}");

    // 10^12 vertices declared in a file of a few hundred bytes: a clear error, no allocation.
    let huge = "ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty float x\n\
                property float y\nproperty float z\nelement face 1\n\
                property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let err = pack_fails(d, "huge.ply", Some(huge.as_bytes()), None);
    assert!(err.contains("1000000000000"), "{err}");

    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n";
    let err = pack_fails(d, "index.obj", Some(obj.as_bytes()), None);
    assert!(err.contains("vertex 4") || err.contains(" 4"), "{err}");
    assert!(err.contains("3 vertices"), "{err}");

    let err = pack_fails(d, "empty.obj", Some(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"), None);
    assert!(err.contains("no triangles"), "{err}");
    let empty_ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                     property float z\nelement face 0\nproperty list uchar int vertex_indices\n\
                     end_header\n0 0 0\n1 0 0\n0 1 0\n";
    let err = pack_fails(d, "empty.ply", Some(empty_ply.as_bytes()), None);
    assert!(err.contains("no triangles"), "{err}");

    // STL, OFF and glTF: each error names the file, the format and the place.
    let mut stl = b"binary".to_vec();
    stl.resize(80, b' ');
    stl.extend_from_slice(&3u32.to_le_bytes());
    stl.extend_from_slice(&[0u8; 50]);
    let err = pack_fails(d, "short.stl", Some(&stl), None);
    assert!(
        err.contains("short.stl") && err.contains("3 facets"),
        "{err}"
    );
    let ascii = "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 x\n";
    let err = pack_fails(d, "bad.stl", Some(ascii.as_bytes()), None);
    assert!(err.contains("bad.stl") && err.contains("line 5"), "{err}");
    let off = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    let err = pack_fails(d, "index.off", Some(off.as_bytes()), None);
    assert!(err.contains("index.off") && err.contains("line 6"), "{err}");
    let gltf = r#"{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],
        "nodes":[{"mesh":0}],"buffers":[{"byteLength":12,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAA"}],
        "bufferViews":[{"buffer":0,"byteLength":12}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}]}"#;
    let err = pack_fails(d, "past.gltf", Some(gltf.as_bytes()), None);
    assert!(
        err.contains("past.gltf") && err.contains("accessor 0") && err.contains("past its view"),
        "{err}"
    );
    let err = pack_fails(
        d,
        "missing.gltf",
        Some(
            gltf.replace(
                "data:application/octet-stream;base64,AAAAAAAAAAAAAAAA",
                "nowhere.bin",
            )
            .as_bytes(),
        ),
        None,
    );
    assert!(
        err.contains("buffer 0") && err.contains("nowhere.bin"),
        "{err}"
    );
    let err = pack_fails(d, "trunc.glb", Some(b"glTF\x02\0\0\0\xff\0\0\0"), None);
    assert!(err.contains("trunc.glb") && err.contains("glTF"), "{err}");

    // A failed pack over an existing output leaves the old file as it was.
    let old = b"the previous output, which must survive".as_slice();
    pack_fails(d, "garbage.ply", Some(&garbage), Some(old));
    pack_fails(d, "index.obj", Some(obj.as_bytes()), Some(old));
}

#[test]
fn pack_rejects_bad_options() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("out.oavm");
    for (args, what) in [
        (&["--max-depth", "40"][..], "--max-depth"),
        (&["--leaf-size", "0"][..], "--leaf-size"),
    ] {
        let o = run(oavm_pack().arg(bunny_ply()).arg(&out).args(args));
        let err = assert_failure(&o);
        assert!(err.contains(what), "{args:?}: {}", describe(&o));
        assert!(!out.exists(), "{args:?}: an output file was written");
    }
    let o = run(oavm_pack().arg(bunny_ply()));
    assert_usage_error(&o);
    let o = run(oavm_pack().arg(bunny_ply()).arg(&out).arg("--threads=x"));
    assert_usage_error(&o);
    assert!(leftover_temporaries(dir.path()).is_empty());
}

// ---------------------------------------------------------------------------------------------
// oavm-trace: rendering

/// The width and height in a PNG's IHDR chunk, after checking the signature and chunk layout.
#[track_caller]
fn png_size(path: &Path) -> (u32, u32) {
    let b = fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(b.len() > 33, "{}: {} bytes", path.display(), b.len());
    assert_eq!(b[..8], PNG_SIGNATURE, "{}: PNG signature", path.display());
    assert_eq!(u32::from_be_bytes(b[8..12].try_into().unwrap()), 13);
    assert_eq!(&b[12..16], b"IHDR");
    let w = u32::from_be_bytes(b[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(b[20..24].try_into().unwrap());
    assert_eq!((b[24], b[25]), (8, 2), "8-bit RGB");
    (w, h)
}

#[test]
fn trace_renders_a_png() {
    let dir = TempDir::new().unwrap();
    let (file, _) = pack_bunny(dir.path(), "bunny.oavm", &["--max-depth", "8"]);
    let small = ["--width", "64", "--height", "48", "--threads", "2"];

    // Default output: the file's name with .png.
    let o = run(oavm_trace().arg(&file).args(small));
    assert_success(&o);
    let png = dir.path().join("bunny.png");
    assert_eq!(png_size(&png), (64, 48));
    let said = text(&o.stdout);
    assert!(
        said.starts_with(&format!("wrote {} (64x48)", png.display())),
        "{said}"
    );

    // -o and --json.
    let custom = dir.path().join("custom.png");
    let o = run(oavm_trace()
        .arg(&file)
        .args(small)
        .arg("-o")
        .arg(&custom)
        .arg("--json"));
    let v = json_of(&o);
    assert_eq!(png_size(&custom), (64, 48));
    assert_eq!(v["image"], custom.display().to_string());
    assert_eq!(uint(&v, "threads"), 2);
    assert!(num(&v, "open_ms") >= 0.0);
    assert!(num(&v, "mrays_per_s") > 0.0, "{v:#}");
    let r = &v["render"];
    assert_eq!((uint(r, "width"), uint(r, "height")), (64, 48));
    assert_eq!(uint(&r["primary"], "rays"), 64 * 48);
    let hits = uint(r, "hits");
    assert!(
        hits > 64 * 48 / 10 && hits < 64 * 48,
        "the framed bunny: {r:#}"
    );
    // One shadow ray per visible point that faces the light.
    let shadow = uint(&r["shadow"], "rays");
    assert!(shadow > 0 && shadow <= hits, "{r:#}");
    assert!(uint(r, "shadowed") <= shadow, "{r:#}");

    // The two runs rendered the same image, and it is not blank.
    let a = fs::read(&png).unwrap();
    assert!(a == fs::read(&custom).unwrap(), "renders differ");
    let decoder = png::Decoder::new(std::io::Cursor::new(a));
    let mut reader = decoder.read_info().expect("decode the PNG");
    let mut rgb = vec![0; reader.output_buffer_size().expect("buffer size")];
    let info = reader.next_frame(&mut rgb).expect("decode the PNG");
    let rgb = &rgb[..info.buffer_size()];
    assert_eq!(rgb.len(), 64 * 48 * 3);
    let distinct: std::collections::HashSet<&[u8]> = rgb.chunks(3).collect();
    assert!(distinct.len() > 50, "{} colours", distinct.len());

    // Rows or Morton tiles, any memory budget: the same image. The budget is the smallest the
    // tracer takes (room for three of the file's largest blocks), far below what the blocks
    // decode to, so blocks are evicted and read again while the image is rendered.
    let (tight, decoded) = {
        let scene = Scene::open(&file).unwrap();
        (3 * scene.held_block_bytes(), scene.decoded_bytes())
    };
    assert!(
        2 * tight < decoded,
        "a budget of {tight} holds the file ({decoded})"
    );
    let tight = tight.to_string();
    for extra in [
        &["--order", "none"][..],
        &["--mem-budget", tight.as_str()][..],
    ] {
        let other = dir.path().join("other.png");
        let o = run(oavm_trace()
            .arg(&file)
            .args(small)
            .arg("-o")
            .arg(&other)
            .args(extra));
        assert_success(&o);
        assert!(
            fs::read(&other).unwrap() == fs::read(&png).unwrap(),
            "{extra:?}: the image differs"
        );
    }

    // Bad render options fail cleanly and write no image.
    let bad = dir.path().join("bad.png");
    for args in [
        &["--width", "0"][..],
        &["--fov", "180"][..],
        &["--eye", "1,2,3", "--target", "1,2,3"][..],
    ] {
        let o = run(oavm_trace().arg(&file).arg("-o").arg(&bad).args(args));
        let err = assert_failure(&o);
        assert!(err.starts_with("oavm-trace: error: "), "{args:?}: {err}");
        assert!(!bad.exists(), "{args:?}: an image was written");
    }
    let o = run(oavm_trace().arg(&file).args(["--eye", "1,2"]));
    assert_usage_error(&o);
}

// ---------------------------------------------------------------------------------------------
// oavm-trace: batch mode

/// Random rays around the bunny, camera rays at it, and rays that must be misses whatever the
/// geometry: returns the rays and the indices of the invalid ones.
fn ray_set(bounds: &Bounds) -> (Vec<Ray>, Vec<usize>) {
    let mut rays = rays::random_rays(bounds, 3000, 17);
    rays.extend(Camera::framing(bounds).primary_rays(32, 24));
    let c = bounds.centre().map(|x| x as f32);
    let eye = Camera::framing(bounds).eye.map(|x| x as f32);
    let at_centre: [f32; 3] = std::array::from_fn(|k| c[k] - eye[k]);
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let invalid = [
        Ray::new([nan, eye[1], eye[2]], at_centre, 0.0, inf),
        Ray::new(eye, [0.0, 0.0, 0.0], 0.0, inf),
        Ray::new(eye, [-0.0, 0.0, -0.0], 0.0, inf),
        Ray::new(eye, at_centre, 2.0, 1.0),
        Ray::new(eye, at_centre, 0.5, nan),
        Ray::new(eye, at_centre, nan, inf),
        Ray::new(eye, [inf, at_centre[1], at_centre[2]], 0.0, inf),
        Ray::new(eye, [nan, at_centre[1], at_centre[2]], 0.0, inf),
        Ray::new([inf, eye[1], eye[2]], at_centre, 0.0, inf),
    ];
    let mut bad = Vec::new();
    for (i, r) in invalid.into_iter().enumerate() {
        // Interleave them with valid rays, so they share chunks with rays that hit.
        let at = 100 * i + 7;
        rays.insert(at, r);
        bad.push(at);
    }
    (rays, bad)
}

#[test]
fn trace_batch_matches_the_library() {
    let dir = TempDir::new().unwrap();
    let (file, _) = pack_bunny(dir.path(), "bunny.oavm", &[]);
    let scene = Scene::open(&file).unwrap();
    let (rays, invalid) = ray_set(&bounds_of(&scene));
    let rays_path = dir.path().join("set.rays");
    rays::write_rays(&rays_path, &rays).unwrap();
    assert_eq!(
        fs::read(&rays_path).unwrap(),
        rays::encode_records(&rays, b"RAYS")
    );

    let mut expected = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(&rays, &mut expected).unwrap();
    let mut expected_occ = vec![0u8; rays.len()];
    scene.occluded_batch(&rays, &mut expected_occ).unwrap();

    // Closest hits.
    let hits_path = dir.path().join("set.hits");
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--hits")
        .arg(&hits_path)
        .args(["--json", "--threads", "2"]));
    let v = json_of(&o);
    let body = batch_records(&hits_path, b"HITS", 8);
    let hits: Vec<Hit> = body
        .chunks_exact(8)
        .map(bytemuck::pod_read_unaligned)
        .collect();
    assert_eq!(hits.len(), rays.len());
    for (i, (got, want)) in hits.iter().zip(&expected).enumerate() {
        assert!(
            got.t.to_bits() == want.t.to_bits() && got.prim == want.prim,
            "ray {i} {:?}: oavm-trace {got:?}, library {want:?}",
            rays[i]
        );
        if got.is_hit() {
            assert!(
                got.t.is_finite() && (got.prim as u64) < BUNNY_TRIANGLES,
                "ray {i}"
            );
        } else {
            assert_eq!(got.t.to_bits(), 0x7f80_0000, "ray {i}: a miss is +inf");
        }
    }
    for &i in &invalid {
        assert_eq!(
            &body[8 * i..8 * i + 8],
            &[0x00, 0x00, 0x80, 0x7f, 0xff, 0xff, 0xff, 0xff],
            "invalid ray {i} {:?} is not a miss",
            rays[i]
        );
    }
    let n_hits = hits.iter().filter(|h| h.is_hit()).count() as u64;
    assert!(n_hits > 500, "only {n_hits} hits");
    assert_eq!(uint(&v, "hits"), n_hits);
    assert_eq!(uint(&v, "rays"), rays.len() as u64);
    assert_eq!(uint(&v, "threads"), 2);
    assert!(num(&v, "seconds") >= 0.0);
    assert!(num(&v, "mrays_per_s") > 0.0);
    assert!(num(&v, "open_ms") >= 0.0);
    assert!(uint(&v, "nodes_visited") >= rays.len() as u64 - invalid.len() as u64);
    assert!(uint(&v, "triangles_tested") >= n_hits);
    assert!(v.get("occluded").is_none(), "{v:#}");

    // Any hits.
    let occl_path = dir.path().join("set.occl");
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--occluded")
        .arg(&occl_path)
        .args(["--json", "--threads", "2"]));
    let v = json_of(&o);
    let occ = batch_records(&occl_path, b"OCCL", 1);
    assert!(
        occ == expected_occ,
        "oavm-trace and the library disagree on occlusion"
    );
    for (i, (&o, h)) in occ.iter().zip(&hits).enumerate() {
        assert_eq!(
            o,
            h.is_hit() as u8,
            "ray {i}: any hit and closest hit disagree"
        );
    }
    for &i in &invalid {
        assert_eq!(occ[i], 0, "invalid ray {i} {:?} is occluded", rays[i]);
    }
    assert_eq!(uint(&v, "occluded"), n_hits);
    assert_eq!(uint(&v, "rays"), rays.len() as u64);
    assert!(v.get("hits").is_none(), "{v:#}");
    for key in ["seconds", "mrays_per_s", "open_ms"] {
        num(&v, key);
    }
    for key in ["threads", "nodes_visited", "triangles_tested"] {
        uint(&v, key);
    }

    // The summary in words names the count and the output.
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--hits")
        .arg(&hits_path));
    assert_success(&o);
    let said = text(&o.stdout);
    assert!(
        said.starts_with(&format!("{} rays, {n_hits} hits", rays.len())),
        "{said}"
    );
    assert!(said.contains(&hits_path.display().to_string()), "{said}");
    assert!(o.stderr.is_empty(), "{}", describe(&o));

    // An empty ray file is fine: an empty answer.
    let none = dir.path().join("none.rays");
    rays::write_rays(&none, &[]).unwrap();
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&none)
        .arg("--hits")
        .arg(&hits_path)
        .arg("--json"));
    let v = json_of(&o);
    assert_eq!((uint(&v, "rays"), uint(&v, "hits")), (0, 0));
    assert!(batch_records(&hits_path, b"HITS", 8).is_empty());
}

// ---------------------------------------------------------------------------------------------
// oavm-trace: verification and errors

#[test]
fn trace_verify_finds_a_flipped_byte() {
    let dir = TempDir::new().unwrap();
    let (file, _) = pack_bunny(dir.path(), "bunny.oavm", &[]);

    let o = run(oavm_trace().arg(&file).arg("--verify"));
    assert_success(&o);
    let said = text(&o.stdout);
    assert!(
        said.starts_with(&format!("{}: ok", file.display())),
        "{said}"
    );
    let v = json_of(&run(oavm_trace().arg(&file).args(["--verify", "--json"])));
    assert_eq!(v["ok"], true);

    let mut bytes = fs::read(&file).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x10;
    let bad = dir.path().join("flipped.oavm");
    fs::write(&bad, &bytes).unwrap();
    let o = run(oavm_trace().arg(&bad).arg("--verify"));
    let err = assert_failure(&o);
    let name = bad.display().to_string();
    let last = err.lines().last().unwrap_or_default();
    assert!(
        last.starts_with(&format!("oavm-trace: error: {name}: verification failed")),
        "{err}"
    );
    let defects: Vec<&str> = err.lines().filter(|l| !l.contains(": error: ")).collect();
    assert!(!defects.is_empty(), "no defect listed: {err}");
    for d in &defects {
        assert!(d.starts_with(&format!("oavm-trace: {name}: ")), "{err}");
    }
    assert!(err.contains("checksum mismatch"), "{err}");
    assert!(!text(&o.stdout).contains("ok"), "{}", describe(&o));

    let o = run(oavm_trace().arg(&bad).args(["--verify", "--json"]));
    assert_failure(&o);
    let v: Value = serde_json::from_slice(&o.stdout).expect("JSON even on failure");
    assert_eq!(v["ok"], false);
}

#[test]
fn trace_rejects_bad_files_clearly() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (file, _) = pack_bunny(d, "bunny.oavm", &["--max-depth", "6"]);
    let bytes = fs::read(&file).unwrap();
    let hits = d.join("out.hits");
    let rays_path = d.join("one.rays");
    rays::write_rays(
        &rays_path,
        &[Ray::new([0.0; 3], [0.0, 0.0, 1.0], 0.0, f32::INFINITY)],
    )
    .unwrap();
    // Runs a batch trace of `file`, which must fail naming `named`; no HITS file may appear.
    let batch_fails = |file: &Path, rays: &Path, named: &Path| -> String {
        let _ = fs::remove_file(&hits);
        let o = run(oavm_trace()
            .arg(file)
            .arg("--rays")
            .arg(rays)
            .arg("--hits")
            .arg(&hits));
        let err = assert_error(&o, "oavm-trace", named);
        assert!(!hits.exists(), "a HITS file was written: {err}");
        assert!(leftover_temporaries(d).is_empty());
        err
    };

    let missing = d.join("missing.oavm");
    let err = batch_fails(&missing, &rays_path, &missing);
    assert!(err.contains("No such file"), "{err}");

    let half = d.join("half.oavm");
    fs::write(&half, &bytes[..bytes.len() / 2]).unwrap();
    let err = batch_fails(&half, &rays_path, &half);
    assert!(err.contains("truncated"), "{err}");

    let stub = d.join("stub.oavm");
    fs::write(&stub, &bytes[..100]).unwrap();
    let err = batch_fails(&stub, &rays_path, &stub);
    assert!(err.contains("truncated"), "{err}");

    // A mesh instead of a packed file.
    let err = batch_fails(&bunny_ply(), &rays_path, &bunny_ply());
    assert!(err.contains("not an .oavm file"), "{err}");

    // Another format version (the first, the previous one, or a future one): the version is
    // checked before the header checksum, and the message says what to do.
    let current = oavm::physical::format::VERSION;
    for version in [1u32, current - 1, current + 1] {
        let other = d.join(format!("v{version}.oavm"));
        let mut b = bytes.clone();
        b[8..12].copy_from_slice(&version.to_le_bytes());
        fs::write(&other, &b).unwrap();
        let err = batch_fails(&other, &rays_path, &other);
        assert!(err.contains(&format!("version {version}")), "{err}");
        assert!(err.contains(&format!("reads version {current}")), "{err}");
        assert!(err.contains("repack"), "{err}");
        assert!(!err.contains("checksum"), "{err}");
    }

    // A header bit flipped elsewhere: the header checksum.
    let flipped = d.join("flipped-header.oavm");
    let mut b = bytes.clone();
    b[72] ^= 0x01; // mesh_min
    fs::write(&flipped, &b).unwrap();
    let err = batch_fails(&flipped, &rays_path, &flipped);
    assert!(err.contains("checksum"), "{err}");

    // Bad ray files: one byte short, wrong magic, wrong version.
    let good_rays = fs::read(&rays_path).unwrap();
    let short = d.join("short.rays");
    fs::write(&short, &good_rays[..good_rays.len() - 1]).unwrap();
    let err = batch_fails(&file, &short, &short);
    assert!(err.contains("header says 1 records of 32 bytes"), "{err}");
    let long = d.join("long.rays");
    fs::write(&long, [&good_rays[..], &[0u8; 32]].concat()).unwrap();
    let err = batch_fails(&file, &long, &long);
    assert!(err.contains("80 bytes"), "{err}");
    let wrong = d.join("wrong-magic.rays");
    fs::write(&wrong, rays::encode_records(&[Hit::MISS], b"HITS")).unwrap();
    let err = batch_fails(&file, &wrong, &wrong);
    assert!(err.contains("magic"), "{err}");
    let v9 = d.join("v9.rays");
    let mut b = good_rays.clone();
    b[4] = 9;
    fs::write(&v9, &b).unwrap();
    let err = batch_fails(&file, &v9, &v9);
    assert!(err.contains("version 9"), "{err}");
    let missing_rays = d.join("missing.rays");
    batch_fails(&file, &missing_rays, &missing_rays);

    // Mode options that do not go together.
    let o = run(oavm_trace().arg(&file).arg("--rays").arg(&rays_path));
    let err = assert_failure(&o);
    assert!(
        err.contains("--hits") && err.contains("--occluded"),
        "{err}"
    );
    let o = run(oavm_trace().arg(&file).arg("--hits").arg(&hits));
    assert_usage_error(&o);
    let o = run(oavm_trace().arg(&file).arg("--occluded").arg(&hits));
    assert_usage_error(&o);
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--hits")
        .arg(&hits)
        .arg("--occluded")
        .arg(d.join("x.occl")));
    assert_usage_error(&o);
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--verify")
        .arg("--rays")
        .arg(&rays_path));
    assert_usage_error(&o);
    assert!(!hits.exists());
    let o = run(&mut oavm_trace());
    assert_usage_error(&o);
}

// ---------------------------------------------------------------------------------------------
// Broken pipes

/// Runs `cmd` with stdout a pipe whose reading end is already closed, so every write to stdout
/// fails with EPIPE.
fn run_into_closed_pipe(cmd: &mut Command) -> Output {
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    cmd.stdin(Stdio::null())
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .expect("cannot spawn the binary")
}

#[test]
fn a_closed_stdout_is_not_an_error() {
    let dir = TempDir::new().unwrap();
    let file = dir.path().join("bunny.oavm");
    let o = run_into_closed_pipe(
        oavm_pack()
            .arg(bunny_ply())
            .arg(&file)
            .args(["--max-depth", "6"]),
    );
    assert!(o.status.success(), "oavm-pack: {}", describe(&o));
    assert!(o.stderr.is_empty(), "oavm-pack: {}", describe(&o));
    assert!(
        file.is_file(),
        "the file is written whether or not stdout is read"
    );

    let rays_path = dir.path().join("r.rays");
    let scene = Scene::open(&file).unwrap();
    rays::write_rays(&rays_path, &rays::random_rays(&bounds_of(&scene), 100, 1)).unwrap();
    let hits = dir.path().join("r.hits");
    let o = run_into_closed_pipe(
        oavm_trace()
            .arg(&file)
            .arg("--json")
            .arg("--rays")
            .arg(&rays_path)
            .arg("--hits")
            .arg(&hits),
    );
    assert!(o.status.success(), "oavm-trace: {}", describe(&o));
    assert!(o.stderr.is_empty(), "oavm-trace: {}", describe(&o));
    assert_eq!(batch_records(&hits, b"HITS", 8).len(), 800);

    let o = run_into_closed_pipe(oavm_trace().arg(&file).arg("--verify"));
    assert!(o.status.success(), "oavm-trace --verify: {}", describe(&o));
    assert!(o.stderr.is_empty(), "oavm-trace --verify: {}", describe(&o));
}

// ---------------------------------------------------------------------------------------------
// Outputs and their names

/// Every output (packed file, image, HITS and OCCL files) is created the way any new file is:
/// mode 0o666 less the umask, readable by whoever may read the directory. (Writing through a
/// temporary file must not narrow that to the temporary file's 0o600.)
#[cfg(unix)]
#[test]
fn outputs_get_the_permissions_of_any_new_file() {
    use std::os::unix::fs::PermissionsExt;
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let mode = |p: &Path| fs::metadata(p).unwrap().permissions().mode() & 0o777;
    let probe = d.join("probe");
    fs::write(&probe, b"").unwrap();
    let want = mode(&probe);

    let (file, _) = pack_bunny(d, "bunny.oavm", &["--max-depth", "5"]);
    let png = d.join("bunny.png");
    assert_success(&run(oavm_trace()
        .arg(&file)
        .args(["--width", "8", "--height", "8"])));
    let rays_path = d.join("r.rays");
    rays::write_rays(&rays_path, &[]).unwrap();
    let (hits, occl) = (d.join("r.hits"), d.join("r.occl"));
    assert_success(&run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--hits")
        .arg(&hits)));
    assert_success(&run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--occluded")
        .arg(&occl)));
    let wrong: Vec<String> = [&file, &png, &hits, &occl]
        .into_iter()
        .filter(|p| mode(p) != want)
        .map(|p| format!("{} has mode {:o}", p.display(), mode(p)))
        .collect();
    assert!(
        wrong.is_empty(),
        "a new file here gets mode {want:o}, but {}",
        wrong.join(", ")
    );
}

/// An output that cannot be written is named as the user gave it, not by the name of a
/// temporary file that was never created.
#[test]
fn unwritable_outputs_are_named_as_given() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (file, _) = pack_bunny(d, "bunny.oavm", &["--max-depth", "5"]);
    let rays_path = d.join("r.rays");
    rays::write_rays(&rays_path, &[]).unwrap();
    let nowhere = d.join("no-such-dir");

    let out = nowhere.join("x.oavm");
    let o = run(oavm_pack().arg(bunny_ply()).arg(&out));
    let pack_err = assert_error(&o, "oavm-pack", &nowhere);
    let png = nowhere.join("x.png");
    let o = run(oavm_trace()
        .arg(&file)
        .args(["--width", "8", "--height", "8", "-o"])
        .arg(&png));
    let png_err = assert_error(&o, "oavm-trace", &nowhere);
    let hits = nowhere.join("x.hits");
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--hits")
        .arg(&hits));
    let hits_err = assert_error(&o, "oavm-trace", &nowhere);
    assert!(!nowhere.exists());

    let mut confusing = Vec::new();
    for (err, path) in [(pack_err, out), (png_err, png), (hits_err, hits)] {
        if !err.contains(&path.display().to_string()) || err.contains(".oavm-pack-") {
            confusing.push(err);
        }
    }
    assert!(
        confusing.is_empty(),
        "messages that do not name the output, or name a temporary file:\n{}",
        confusing.concat()
    );
}

/// A directory given as the .oavm file is called a directory (mapping one fails with ENODEV,
/// "No such device", which says nothing useful).
#[test]
fn trace_says_when_the_file_is_a_directory() {
    let dir = TempDir::new().unwrap();
    let o = run(oavm_trace().arg(dir.path()).arg("--verify"));
    let err = assert_error(&o, "oavm-trace", dir.path());
    assert!(err.contains("directory"), "{err}");
}

/// The tracer's default thread count: one per core, or eight per core under a memory budget
/// smaller than the file's blocks (threads that wait on the disk) while their blocks take at
/// most a quarter of it, lowered to what the budget holds (two of the largest blocks a thread
/// and one more), never the budget raised;
/// `--threads` overrides the default, and is lowered the same way, with a note.
#[test]
fn trace_threads_default_to_more_under_a_budget_and_never_raise_it() {
    let d = TempDir::new().unwrap();
    let (file, _) = pack_bunny(d.path(), "bunny.oavm", &["--block-size", "16K"]);
    let scene = oavm::Scene::open(&file).unwrap();
    let max = scene.held_block_bytes();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as u64;
    // Roomy: eight threads per core keep at most a quarter of it for the blocks they read.
    let roomy = ((4 * 8 * cores + 1) * max).to_string();
    assert!(
        (4 * 8 * cores + 1) * max < scene.decoded_bytes(),
        "the budget must be smaller than the file"
    );
    // Half as roomy: the threads are cut to keep three quarters of it for the cache.
    let snug = ((2 * 8 * cores + 1) * max).to_string();
    let snug_threads = ((2 * 8 * cores + 1) / 4).max(cores);
    let (five, seven) = ((5 * max).to_string(), (7 * max).to_string());
    for (extra, expect, note) in [
        (&[][..], cores, false),
        (&["--mem-budget", roomy.as_str()][..], 8 * cores, false),
        (&["--mem-budget", snug.as_str()][..], snug_threads, false),
        (&["--mem-budget", five.as_str()][..], 2, false),
        (
            &["--mem-budget", seven.as_str(), "--threads", "3"][..],
            3,
            false,
        ),
        (
            &["--mem-budget", five.as_str(), "--threads", "3"][..],
            2,
            true,
        ),
    ] {
        let o = run(oavm_trace()
            .arg(&file)
            .args(["--random", "2000", "--json"])
            .args(extra));
        assert_success(&o);
        let v = json_of(&o);
        assert_eq!(uint(&v, "threads"), expect, "{extra:?}");
        if let Some(budget) = extra.get(1) {
            assert_eq!(
                uint(&v, "pager_budget").to_string(),
                *budget,
                "never raised"
            );
            assert!(uint(&v, "pager_peak_resident_bytes") <= uint(&v, "pager_budget"));
        }
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.contains("lowered to 2"), note, "{extra:?}: {err}");
    }
    // A budget that cannot hold three blocks is an error that says what the file needs.
    let o = run(oavm_trace()
        .arg(&file)
        .args(["--random", "20", "--mem-budget"])
        .arg((3 * max - 1).to_string()));
    let err = assert_error(&o, "oavm-trace", &file);
    assert!(
        err.contains(&format!("give a budget of {} bytes or more", 3 * max)),
        "{err}"
    );
}

/// Benchmark mode traces shadow rays in waves after their primary rays (`--wave`): the answers,
/// as digests, are those of one pass of each, in every order and under a budget.
#[test]
fn trace_waves_and_orders_do_not_change_the_answers() {
    let d = TempDir::new().unwrap();
    let (file, _) = pack_bunny(d.path(), "bunny.oavm", &["--block-size", "4K"]);
    let digests = |extra: &[&str]| -> Vec<String> {
        let o = run(oavm_trace()
            .arg(&file)
            .args(["--primary", "160x120", "--shadow", "--json"])
            .args(extra));
        assert_success(&o);
        let v = json_of(&o);
        let sets = v["sets"].as_array().expect("sets");
        assert_eq!(sets.len(), 2, "{v:#}");
        assert!(uint(&sets[1], "rays") > 1000, "{v:#}");
        sets.iter()
            .map(|s| s["answers_xxh3"].as_str().expect("digest").to_string())
            .collect()
    };
    let reference = digests(&["--wave", "0", "--order", "none"]);
    // The smallest budget the tracer takes: room for three of the file's largest blocks (a
    // cluster of up to 512 triangles is one block however small the target size).
    let (tight, decoded) = {
        let scene = Scene::open(&file).unwrap();
        (3 * scene.held_block_bytes(), scene.decoded_bytes())
    };
    assert!(
        8 * tight < decoded,
        "a budget of {tight} holds much of the file ({decoded})"
    );
    let tight = tight.to_string();
    for order in ["none", "morton", "blocks"] {
        for wave in ["0", "7", "777", "65536"] {
            for budget in [&[][..], &["--mem-budget", tight.as_str()][..]] {
                let got = digests(&[&["--order", order, "--wave", wave][..], budget].concat());
                assert_eq!(got, reference, "order {order}, wave {wave}, {budget:?}");
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Claims that were untested: the image's content, --camera-path, --compress=LEVEL,
// --no-block-checks on a damaged file, oavm-inspect

/// The rendered image shows what the f64 reference sees: each pixel whose ray hits the bunny
/// (by the reference) is shaded, each whose ray misses is the background of its row (the
/// leftmost pixel of the row, which misses); rays through edges aside.
#[test]
fn the_rendered_image_shows_what_the_reference_sees() {
    let dir = TempDir::new().unwrap();
    let (file, _) = pack_bunny(dir.path(), "bunny.oavm", &[]);
    let png = dir.path().join("b.png");
    let (w, h) = (96u32, 72u32);
    assert_success(&run(oavm_trace()
        .arg(&file)
        .args(["--width", &w.to_string(), "--height", &h.to_string(), "-o"])
        .arg(&png)));
    let decoder = png::Decoder::new(std::io::Cursor::new(fs::read(&png).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut rgb = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut rgb).unwrap();
    assert_eq!((info.width, info.height), (w, h));
    let pixel = |x: u32, y: u32| {
        let at = 3 * (y * w + x) as usize;
        [rgb[at], rgb[at + 1], rgb[at + 2]]
    };
    let mesh = oavm::mesh::load(&bunny_ply()).unwrap();
    let tris = mesh.corners();
    let scene = Scene::open(&file).unwrap();
    let camera = Camera::framing(&bounds_of(&scene));
    let pixels = camera.pixels(w, h);
    let (mut hits, mut wrong, mut grazing) = (0, Vec::new(), 0);
    for y in 0..h {
        assert!(
            !oavm::geom::reference::closest(&tris, &pixels.ray(0, y)).is_hit(),
            "the left column sees the background"
        );
        let background = pixel(0, y);
        for x in 0..w {
            let ray = pixels.ray(x, y);
            let sees = oavm::geom::reference::closest(&tris, &ray).is_hit();
            hits += sees as usize;
            if sees == (pixel(x, y) == background) {
                if oavm::geom::reference::grazes(&tris, &ray) {
                    grazing += 1;
                } else {
                    wrong.push((x, y, sees));
                }
            }
        }
    }
    assert!(hits > (w * h / 10) as usize, "{hits} pixels see the bunny");
    assert!(
        wrong.is_empty(),
        "pixels that show the wrong thing: {wrong:?}"
    );
    assert!(grazing <= 3, "{grazing} grazing pixels");
}

/// `--camera-path` takes the camera of the scene's animated path (`k camera`) at its first
/// frame, `--view` its `v` block: each frame equals the library's, traced from that camera, and
/// the two differ.
#[test]
fn view_and_camera_path_take_their_cameras() {
    let dir = TempDir::new().unwrap();
    let aff = common::shared_scene("bart/museum/museum5.aff");
    let file = dir.path().join("museum.oavm");
    assert_success(&run(oavm_pack().arg(&aff).arg(&file)));
    let scene = Scene::open(&file).unwrap();
    let loaded = oavm::mesh::load_aff(&aff, None).unwrap();
    let (v, path) = (loaded.view.unwrap(), loaded.camera_path.unwrap());
    let mut digests = Vec::new();
    for (flag, cam) in [(None, v), (Some("--camera-path"), path)] {
        let mut cmd = oavm_trace();
        cmd.arg(&file)
            .args(["--primary", "80x60", "--json", "--view"])
            .arg(&aff);
        if let Some(f) = flag {
            cmd.arg(f);
        }
        let o = run(&mut cmd);
        assert_success(&o);
        let got = json_of(&o)["sets"][0]["answers_xxh3"]
            .as_str()
            .unwrap()
            .to_string();
        let camera = Camera::look_at(cam.from, cam.at, cam.up, cam.angle_deg).unwrap();
        let rays = camera.primary_rays(80, 60);
        let mut hits = vec![Hit::MISS; rays.len()];
        scene.intersect_batch(&rays, &mut hits).unwrap();
        assert!(
            hits.iter().filter(|h| h.is_hit()).count() > 1000,
            "{flag:?}"
        );
        let want = format!(
            "{:016x}",
            xxhash_rust::xxh3::xxh3_64(bytemuck::cast_slice(&hits))
        );
        assert_eq!(got, want, "{flag:?}");
        digests.push(got);
    }
    assert_ne!(
        digests[0], digests[1],
        "the path's first frame is not the v block"
    );
}

/// `--compress=LEVEL` reaches the file, of clusters (the default) and of lists: both levels
/// compress every block that shrinks, a higher level gives a smaller file, the answers do not
/// change; a level zstd does not have is refused.
#[test]
fn compression_levels_reach_the_file() {
    let dir = TempDir::new().unwrap();
    // Level 1 leaves a file of lists under half its raw size (references, increasing, and
    // triangles stored in several blocks compress well); a file of clusters, whose groups share
    // corners and whose boxes are quantised to bytes, has less to lose: 0.55 of its raw size at
    // level 1 and 0.43 at level 19 when this was written.
    for (kind, extra, max_ratio) in [
        ("cluster", &[][..], (2, 3)),
        ("list", &["--leaf", "list"][..], (1, 2)),
    ] {
        let pack = |name: &str, level: &[&str]| {
            pack_bunny(
                dir.path(),
                &format!("{kind}-{name}"),
                &[extra, level].concat(),
            )
            .0
        };
        let raw = pack("raw.oavm", &[]);
        let fast = pack("fast.oavm", &["--compress=1"]);
        let small = pack("small.oavm", &["--compress=19"]);
        let info = |p: &Path| {
            let s = Scene::open(p).unwrap();
            let zstd = s
                .file()
                .directory()
                .iter()
                .filter(|e| e.codec == oavm::physical::format::CODEC_ZSTD)
                .count();
            (
                fs::metadata(p).unwrap().len(),
                zstd,
                s.file().directory().len(),
            )
        };
        let (raw_len, raw_zstd, _) = info(&raw);
        let (fast_len, fast_zstd, blocks) = info(&fast);
        let (small_len, small_zstd, _) = info(&small);
        assert_eq!(raw_zstd, 0, "{kind}");
        assert!(
            fast_zstd == blocks && small_zstd == blocks,
            "{kind}: {fast_zstd} {small_zstd} {blocks}"
        );
        assert!(
            small_len < fast_len && fast_len * max_ratio.1 < raw_len * max_ratio.0,
            "{kind}: {raw_len} {fast_len} {small_len}"
        );
        let rays = oavm::rays::random_rays(&bounds_of(&Scene::open(&raw).unwrap()), 5000, 2);
        let answers = |p: &Path| {
            let mut h = vec![Hit::MISS; rays.len()];
            Scene::open(p)
                .unwrap()
                .intersect_batch(&rays, &mut h)
                .unwrap();
            h
        };
        let want = answers(&raw);
        assert!(want.iter().filter(|h| h.is_hit()).count() > 500, "{kind}");
        assert!(answers(&fast) == want && answers(&small) == want, "{kind}");
    }
    let o = run(oavm_pack()
        .arg(bunny_ply())
        .arg(dir.path().join("x.oavm"))
        .arg("--compress=23"));
    let err = assert_failure(&o);
    assert!(err.contains("--compress=23"), "{err}");
    assert!(!dir.path().join("x.oavm").exists());
}

/// `--no-block-checks` on a file with a damaged raw block: no crash, whatever the damage gives
/// (an error naming the block, or answers); with checks, an error naming the block; and
/// `--verify` names it either way.
#[test]
fn unchecked_damaged_blocks_give_errors_or_answers_never_a_crash() {
    let dir = TempDir::new().unwrap();
    let (file, _) = pack_bunny(dir.path(), "bunny.oavm", &["--block-size", "16K"]);
    let scene = Scene::open(&file).unwrap();
    let dir_entries = scene.file().directory().to_vec();
    drop(scene);
    let mut bytes = fs::read(&file).unwrap();
    // Damage every block: bytes at a tenth, half and nine tenths of each, as many kinds of
    // record as that reaches (node records, ranks, references, triangles).
    for e in &dir_entries {
        for frac in [10, 2] {
            let at = (e.offset + e.stored_len / frac) as usize;
            bytes[at..at + 8].copy_from_slice(&0xdead_beef_dead_beefu64.to_le_bytes());
        }
    }
    let damaged = dir.path().join("damaged.oavm");
    fs::write(&damaged, &bytes).unwrap();
    let o = run(oavm_trace().arg(&damaged).args(["--random", "20000"]));
    let err = assert_error(&o, "oavm-trace", &damaged);
    assert!(err.contains("checksum mismatch"), "{err}");
    let o = run(oavm_trace()
        .arg(&damaged)
        .args(["--random", "20000", "--no-block-checks"]));
    match o.status.code() {
        Some(0) => {}
        Some(1) => {
            let err = text(&o.stderr);
            assert!(err.contains("block"), "{err}");
        }
        other => panic!("--no-block-checks: {other:?}\n{}", describe(&o)),
    }
    let o = run(oavm_trace().arg(&damaged).arg("--verify"));
    let err = assert_failure(&o);
    assert!(err.contains("checksum mismatch"), "{err}");
}

/// `oavm-inspect` shows a file's structure in words and in JSON, agreeing with the file; its
/// `--verify` finds damage.
#[test]
fn inspect_shows_the_structure() {
    let dir = TempDir::new().unwrap();
    let (file, _) = pack_bunny(
        dir.path(),
        "bunny.oavm",
        &["--block-size", "64K", "--compress"],
    );
    let (list, _) = pack_bunny(
        dir.path(),
        "list.oavm",
        &["--block-size", "64K", "--compress", "--leaf", "list"],
    );
    let inspect = || Command::new(env!("CARGO_BIN_EXE_oavm-inspect"));
    let words_of = |file: &Path| {
        let o = run(inspect().arg(file));
        assert_success(&o);
        text(&o.stdout)
    };
    let words = words_of(&file);
    let version = format!("version {}", oavm::physical::format::VERSION);
    for needle in [
        "format",
        version.as_str(),
        "sections:",
        "top tree:",
        "blocks:",
        "zstd",
    ] {
        assert!(words.contains(needle), "{needle}: {words}");
    }
    // What a block's triangles are depends on the leaf kind (format-spec.md §2, §8.2).
    let line = |words: &str, key: &str| -> String {
        words
            .lines()
            .find(|l| l.starts_with(key))
            .unwrap_or_else(|| panic!("no {key} line: {words}"))
            .to_string()
    };
    let clusters = [
        line(&words, "format"),
        line(&words, "triangles"),
        line(&words, "blocks:"),
    ];
    assert!(clusters[0].contains("clusters"), "{words}");
    assert!(clusters[1].contains("group lanes in blocks"), "{words}");
    assert!(clusters[2].ends_with(" group lanes"), "{words}");
    let list_words = words_of(&list);
    let lists = [
        line(&list_words, "format"),
        line(&list_words, "triangles"),
        line(&list_words, "blocks:"),
    ];
    assert!(
        lists[0].contains(&version) && !lists[0].contains("clusters"),
        "{list_words}"
    );
    assert!(lists[1].contains("records in blocks"), "{list_words}");
    assert!(lists[2].ends_with(" triangle records"), "{list_words}");
    // The wide nodes of a file of clusters (format-spec.md §8.7), in their sections and in
    // words; a file of lists has none.
    for needle in ["wide nodes ", "wide links ", "wide nodes: "] {
        assert!(words.contains(needle), "{needle}: {words}");
        assert!(!list_words.contains(needle), "{needle}: {list_words}");
    }
    let o = run(inspect()
        .arg(&file)
        .args(["--json", "--blocks", "--levels", "--verify"]));
    assert_success(&o);
    let v = json_of(&o);
    let scene = Scene::open(&file).unwrap();
    let h = scene.file().header();
    assert_eq!(v["header"]["version"], oavm::physical::format::VERSION);
    // A file as packed is generation 1 (format-spec.md §2.1).
    assert_eq!(v["header"]["generation"], 1);
    assert_eq!(v["header"]["flags"], h.flags);
    assert_ne!(h.flags & oavm::physical::format::FLAG_CLUSTERS, 0);
    assert_eq!(uint(&v["directory"], "blocks"), h.block_count);
    assert_eq!(v["blocks"].as_array().unwrap().len() as u64, h.block_count);
    // The seven sections, and the wide nodes and links of a file of clusters (§3, §8.7).
    assert_eq!(v["sections"].as_array().unwrap().len(), 9);
    let wide = |kind| scene.file().section(kind).count;
    use oavm::physical::format::SectionKind;
    assert_eq!(uint(&v["wide"], "top_nodes"), wide(SectionKind::WideNodes));
    assert_eq!(uint(&v["wide"], "links"), wide(SectionKind::WideLinks));
    let roots: u64 = (scene.file().directory().iter())
        .map(|e| e.root_count as u64)
        .sum();
    assert_eq!(uint(&v["wide"], "links"), roots);
    // --levels reads the blocks: their wide nodes, the octree's and the clusters'.
    let blocks = &v["wide"]["blocks"];
    assert_eq!(uint(blocks, "cluster_roots"), h.solid_leaves);
    assert!(uint(blocks, "cluster_nodes") >= h.solid_leaves, "{blocks}");
    assert!(blocks.get("octree_nodes").is_some(), "{blocks}");
    let levels = v["tree_levels"].as_array().unwrap();
    assert_eq!(levels.len() as u32, h.level_count);
    let (mut empty, mut solid) = (0, 0);
    for l in levels {
        empty += uint(l, "empty");
        solid += uint(l, "solid");
    }
    assert_eq!((empty, solid), (h.empty_leaves, h.solid_leaves));
    assert_eq!(v["verify"]["defects"].as_array().unwrap().len(), 0);
    let decoded: u64 = scene.file().directory().iter().map(|e| e.raw_len).sum();
    assert_eq!(uint(&v["directory"], "decoded_bytes"), decoded);
    // Damage: --verify fails and names the block.
    let mut bytes = fs::read(&file).unwrap();
    let e = scene.file().directory()[1];
    bytes[(e.offset + 20) as usize] ^= 0xff;
    let bad = dir.path().join("bad.oavm");
    fs::write(&bad, &bytes).unwrap();
    let o = run(inspect().arg(&bad).arg("--verify"));
    let err = assert_failure(&o);
    assert!(err.contains("block 1"), "{err}");
}

/// `--all-hits` writes a HITL file whose lists are the library's, byte for byte (the invalid
/// rays with none); `--count-hits` a HITC file of their lengths; the JSON counts both.
#[test]
fn trace_every_hit_matches_the_library() {
    let dir = TempDir::new().unwrap();
    let (file, _) = pack_bunny(dir.path(), "bunny.oavm", &[]);
    let scene = Scene::open(&file).unwrap();
    let (rays, invalid) = ray_set(&bounds_of(&scene));
    let rays_path = dir.path().join("set.rays");
    rays::write_rays(&rays_path, &rays).unwrap();
    let (want, _) = scene.list_intersections(&rays).unwrap();

    let lists = dir.path().join("set.hitl");
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--all-hits")
        .arg(&lists)
        .args(["--json", "--threads", "2"]));
    let v = json_of(&o);
    let bytes = fs::read(&lists).unwrap();
    assert_eq!(bytes, rays::encode_hit_lists(&want));
    let got = rays::read_hit_lists(&lists, u64::MAX).unwrap();
    assert!(got == want);
    for &i in &invalid {
        assert!(got.of(i).is_empty(), "invalid ray {i} has hits");
    }
    let several = (0..rays.len()).filter(|&i| got.of(i).len() >= 2).count();
    assert!(several > 300, "only {several} rays hit twice or more");
    assert_eq!(uint(&v, "all_hits"), want.hits.len() as u64);
    let hit = (0..rays.len()).filter(|&i| !got.of(i).is_empty()).count() as u64;
    assert_eq!(uint(&v, "hits"), hit);

    let counts = dir.path().join("set.hitc");
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--count-hits")
        .arg(&counts));
    let out = text(&o.stdout);
    assert!(
        out.contains(&format!("{} hits in all", want.hits.len())),
        "{out}"
    );
    let body = batch_records(&counts, b"HITC", 4);
    let n: Vec<u32> = body
        .chunks_exact(4)
        .map(bytemuck::pod_read_unaligned)
        .collect();
    assert_eq!(n, want.counts());

    // One answer file only; a HITL file cut short or grown is refused.
    let o = run(oavm_trace()
        .arg(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--all-hits")
        .arg(&lists)
        .arg("--count-hits")
        .arg(&counts));
    assert_usage_error(&o);
    for len in [bytes.len() - 1, 20, 10] {
        fs::write(&lists, &bytes[..len]).unwrap();
        let e = rays::read_hit_lists(&lists, u64::MAX)
            .expect_err("cut short")
            .to_string();
        assert!(e.contains("set.hitl"), "{e}");
    }
    let mut grown = bytes.clone();
    grown.push(0);
    fs::write(&lists, &grown).unwrap();
    assert!(rays::read_hit_lists(&lists, u64::MAX).is_err());
}
