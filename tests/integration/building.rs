//! Building: the streaming pack (`oavm-pack --mem-budget`) against the in-memory pack (a small
//! budget splits the bunny into hundreds of chunks, and the file must still verify and answer
//! every ray exactly as the in-memory pack's file does), its memory bound measured on the real
//! binary, temporary files that never outlive a pack, bad input that leaves no output, and the
//! writer's limits.

use std::fs;
use std::path::{Path, PathBuf};

use crate::common::*;
use oavm::pack::{self, PackOptions, Quiet};
use oavm::physical::BlockOptions;
use oavm::rays::{self, Bounds, Camera};
use oavm::{Hit, Scene};
use tempfile::TempDir;

fn bunny() -> oavm::mesh::Mesh {
    load_shared("bunny/bun_zipper.ply")
}

fn write_binary_ply(mesh: &oavm::mesh::Mesh, path: &Path) {
    fs::write(path, binary_ply(mesh)).unwrap();
}

/// Packs `ply` into `out` within `budget` (streaming) with `blocks`.
fn pack_streaming(
    ply: &Path,
    out: &Path,
    blocks: BlockOptions,
    budget: u64,
) -> Result<pack::PackReport, oavm::Error> {
    let opts = PackOptions {
        blocks,
        mem_budget: Some(budget),
        ..PackOptions::default()
    };
    pack::pack(ply, out, &opts, &Quiet)
}

fn ray_sets(mesh: &oavm::mesh::Mesh) -> Vec<oavm::Ray> {
    let b = Bounds::of_points(mesh.positions.iter().copied());
    let mut all = rays::random_rays(&b, 20_000, 7);
    all.extend(Camera::framing(&b).primary_rays(160, 120));
    all
}

fn answers(path: &Path, rays: &[oavm::Ray]) -> (Vec<Hit>, Vec<u8>) {
    let scene = Scene::open(path).expect("open");
    let mut hits = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(rays, &mut hits).expect("trace");
    let mut occ = vec![0u8; rays.len()];
    scene.occluded_batch(rays, &mut occ).expect("trace");
    (hits, occ)
}

/// Every entry of `dir` (to check that no temporary file is left).
fn entries(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

#[test]
fn a_tiny_budget_gives_the_same_answers_as_the_in_memory_pack() {
    let dir = TempDir::new().unwrap();
    let mesh = bunny();
    let ply = dir.path().join("bunny.ply");
    write_binary_ply(&mesh, &ply);
    let in_memory = dir.path().join("memory.oavm");
    pack::pack(&ply, &in_memory, &PackOptions::default(), &Quiet).unwrap();
    let rays = ray_sets(&mesh);
    let expected = answers(&in_memory, &rays);

    // (budget, codec, at least this many chunks): 16 MiB leaves about 3 MiB for a chunk, a few
    // thousand triangles; 4 GiB holds the bunny in one chunk.
    for (budget, compress, min_chunks) in [
        (16u64 << 20, None, 10),
        (16 << 20, Some(3), 10),
        (4 << 30, None, 1),
    ] {
        let out = dir
            .path()
            .join(format!("streamed-{budget}-{compress:?}.oavm"));
        let blocks = BlockOptions {
            block_size: 16 << 10,
            compress,
            chunk_groups: 16,
            lean: false,
        };
        let report = pack_streaming(&ply, &out, blocks, budget).unwrap();
        let st = report.streaming.as_ref().expect("a streaming report");
        assert!(
            st.chunks >= min_chunks,
            "budget {budget}: only {} chunks",
            st.chunks
        );
        assert_eq!(report.stats.input_triangles, mesh.triangles.len() as u64);
        let scene = Scene::open(&out).unwrap();
        let v = scene.verify().unwrap();
        assert!(v.is_ok(), "budget {budget}: {:?}", v.defects);
        assert_eq!(
            answers(&out, &rays),
            expected,
            "budget {budget}: answers differ"
        );
    }
    // Only the inputs and outputs remain: the spill file had no name, the output's temporary
    // file was renamed.
    let names: Vec<String> = entries(dir.path())
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert!(
        names
            .iter()
            .all(|n| n.ends_with(".ply") || n.ends_with(".oavm")),
        "{names:?}"
    );
}

#[test]
fn bad_input_gives_an_error_and_no_output() {
    let dir = TempDir::new().unwrap();
    let mesh = bunny();
    let ply = dir.path().join("bunny.ply");
    write_binary_ply(&mesh, &ply);
    let bytes = fs::read(&ply).unwrap();

    // Truncated body; an index past the vertices; an ascii PLY (the streaming path reads binary
    // only); a missing file.
    let truncated = dir.path().join("truncated.ply");
    fs::write(&truncated, &bytes[..bytes.len() - 7]).unwrap();
    let mut bad_index = bytes.clone();
    let n = bad_index.len();
    bad_index[n - 4..].copy_from_slice(&(1i32 << 30).to_le_bytes());
    let out_of_range = dir.path().join("index.ply");
    fs::write(&out_of_range, &bad_index).unwrap();
    let ascii = shared_scene("bunny/bun_zipper.ply");
    let missing = dir.path().join("missing.ply");
    for (input, says) in [
        (&truncated, "truncated.ply"),
        (&out_of_range, "index.ply"),
        (&ascii, "binary PLY"),
        (&missing, "missing.ply"),
    ] {
        let out = dir.path().join("out.oavm");
        let err = pack_streaming(input, &out, BlockOptions::default(), 64 << 20)
            .err()
            .unwrap_or_else(|| panic!("{} packed", input.display()))
            .to_string();
        assert!(err.contains(says), "{}: {err}", input.display());
        assert!(!out.exists(), "{}: an output was left", input.display());
    }
    let names: Vec<PathBuf> = entries(dir.path());
    assert_eq!(names.len(), 3, "temporary files left: {names:?}");
}

/// The streaming pack from the command line keeps to its budget, measured: the dragon (871,414
/// triangles, 17 MB of binary PLY; packed in memory it peaks near 250 MB) at a budget of 64 MiB
/// peaks within it (`peak_rss_bytes`, the process's own `VmHWM`), and its file answers as the
/// in-memory pack's does. A budget four times smaller cuts more chunks but hardly grows the
/// file (before, the bunny at 16 MiB was cut into 2,588 chunks, a file 2.8 times larger).
#[test]
fn the_cli_streaming_pack_keeps_to_its_budget() {
    let dir = TempDir::new().unwrap();
    let dragon = load_shared("dragon/dragon_vrip.ply");
    let ply = dir.path().join("dragon.ply");
    write_binary_ply(&dragon, &ply);
    let json = |budget: Option<&str>, out: &Path| -> serde_json::Value {
        let mut cmd = bin("oavm-pack");
        cmd.arg(&ply).arg(out).arg("--json");
        if let Some(b) = budget {
            cmd.args(["--mem-budget", b]);
        }
        let (o, stdout, err) = run(&mut cmd);
        assert!(o.status.success(), "{err}");
        serde_json::from_str(&stdout).expect("one JSON object")
    };
    let in_memory = dir.path().join("memory.oavm");
    let m = json(None, &in_memory);
    let memory_size = m["file_bytes"].as_u64().unwrap();
    let rays = ray_sets(&dragon);
    let expected = answers(&in_memory, &rays);
    for (budget, bytes) in [("64M", 64u64 << 20), ("16M", 16 << 20)] {
        let out = dir.path().join(format!("streamed-{budget}.oavm"));
        let r = json(Some(budget), &out);
        let peak = r["peak_rss_bytes"].as_u64().expect("peak RSS");
        let chunks = r["streaming"]["chunks"].as_u64().unwrap();
        let size = r["file_bytes"].as_u64().unwrap();
        eprintln!("budget {budget}: peak {peak} bytes, {chunks} chunks, {size} bytes");
        if bytes >= 64 << 20 {
            assert!(peak <= bytes, "budget {budget}: peak RSS {peak}");
        }
        assert!(chunks > 1, "budget {budget}: one chunk");
        // Each block's head is padded to a page before its groups (format-spec §8.3), and a
        // small budget makes more, smaller blocks: about 2 KB more a block.
        assert!(
            size as f64 <= 1.03 * memory_size as f64,
            "budget {budget}: {size} bytes, in memory {memory_size}"
        );
        let v = Scene::open(&out).unwrap().verify().unwrap();
        assert!(v.is_ok(), "{:?}", v.defects);
        assert_eq!(answers(&out, &rays), expected, "budget {budget}");
    }
}
