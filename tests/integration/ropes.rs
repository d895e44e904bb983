//! Ropes (format-spec §8.4): files with ropes verify, the walk that follows them gives exactly
//! the answers of the walk that computes each neighbour from Morton codes and of the top-down
//! walk, on real meshes and architecture, with clusters and with leaf lists; those answers
//! agree with the f64 brute force (which shares no code with any walk); and verify catches a
//! rope that names the wrong node.

use crate::common;

use crate::common::{bin, compare_with_reference, load_shared, run, shared_scene};
use oavm::geom::Hit;
use oavm::logical::{SceneOptions, Walk};
use oavm::pack::{BuildOptions, LeafKind};
use oavm::physical::format::{
    Header, KIND_INTERNAL, NodeRecord, ROPE_TOP, RopeRecord, SectionEntry, SectionKind,
};
use oavm::physical::{AlignedBytes, OavmFile};
use oavm::rays::{Camera, random_rays};
use oavm::{Mesh, Ray, Scene};

/// The file of `mesh` as `oavm-pack` writes it, without and with ropes.
fn files(mesh: &Mesh, leaf: LeafKind) -> (AlignedBytes, AlignedBytes) {
    let mut opts = BuildOptions::with_leaf(leaf);
    // A mesh of a few dozen triangles (the Cornell box) would be one leaf: no faces to cross.
    opts.leaf_size = opts.leaf_size.min(mesh.triangles.len() as u32 / 8).max(1);
    let (parts, _) = oavm::pack::build(mesh, &opts, &oavm::pack::Quiet).expect("build");
    let plain = oavm::pack::encode(&parts).expect("encode");
    let file = OavmFile::open(AlignedBytes::from_slice(plain.as_ref())).expect("open");
    let (roped, _, report) = oavm::pack::ropes::add_ropes(&file, Vec::new()).expect("ropes");
    assert!(report.ropes > 0 && report.ropes == 6 * report.roped_nodes);
    (plain, AlignedBytes::from_slice(&roped))
}

fn open(bytes: &AlignedBytes, walk: Walk) -> Scene<AlignedBytes> {
    let scene = Scene::from_bytes_with(
        AlignedBytes::from_slice(bytes.as_ref()),
        "test.oavm",
        &SceneOptions {
            walk,
            ..SceneOptions::default()
        },
    )
    .expect("open");
    let report = scene.verify().expect("verify");
    assert!(report.is_ok(), "verify: {:?}", report.defects);
    scene
}

fn rays_for(mesh: &Mesh, random: usize) -> Vec<Ray> {
    let b = common::bounds(mesh);
    let mut rays = random_rays(&b, random, 5);
    rays.extend(Camera::framing(&b).primary_rays(64, 48));
    rays
}

fn answers(scene: &Scene<AlignedBytes>, rays: &[Ray]) -> (Vec<Hit>, Vec<u8>, u64) {
    let mut hits = vec![Hit::MISS; rays.len()];
    let c = scene.intersect_batch(rays, &mut hits).expect("trace");
    let mut occ = vec![0u8; rays.len()];
    scene.occluded_batch(rays, &mut occ).expect("trace any");
    (hits, occ, c.ropes_followed)
}

/// Every walk of `mesh`'s files (clusters and lists) gives the same answers, bit for bit, and
/// the rope walk really follows ropes; one in `stride` rays is checked against brute force.
fn same_answers(rel: &str, random: usize, stride: usize, min_hits: usize) {
    let mesh = load_shared(rel);
    let rays = rays_for(&mesh, random);
    for leaf in [LeafKind::Cluster, LeafKind::List] {
        let (plain, roped) = files(&mesh, leaf);
        let morton = answers(&open(&plain, Walk::Neighbours), &rays);
        let what = format!("{rel} {leaf:?}");
        for (walk, bytes) in [
            (Walk::Auto, &plain),
            (Walk::Auto, &roped),
            (Walk::Neighbours, &roped),
            (Walk::Ropes, &roped),
        ] {
            let got = answers(&open(bytes, walk), &rays);
            let differ = (0..rays.len())
                .filter(|&i| {
                    got.0[i].t.to_bits() != morton.0[i].t.to_bits()
                        || got.0[i].prim != morton.0[i].prim
                        || got.1[i] != morton.1[i]
                })
                .count();
            assert_eq!(differ, 0, "{what}: {walk:?} differs from the Morton walk");
            if walk == Walk::Ropes {
                // (In the closed kitchen most rays hit within a leaf or two.)
                assert!(
                    got.2 as usize > rays.len() / 2,
                    "{what}: the rope walk followed only {} ropes for {} rays",
                    got.2,
                    rays.len()
                );
            } else {
                assert_eq!(got.2, 0, "{what}: {walk:?} followed ropes");
            }
        }
        compare_with_reference(&mesh, &open(&roped, Walk::Ropes), &rays, stride).require(
            min_hits,
            0,
            &format!("{what}, ropes"),
        );
    }
}

#[test]
fn ropes_give_the_morton_walks_answers_on_the_bunny() {
    same_answers("bunny/bun_zipper.ply", 20_000, 10, 500);
}

#[test]
fn ropes_give_the_morton_walks_answers_on_architecture() {
    same_answers("bart/kitchen/kitchen.aff", 20_000, 40, 100);
    same_answers("bart/robot/Robot.aff", 20_000, 40, 100);
    same_answers("cornell_box/CornellBox-Original.obj", 20_000, 10, 1_000);
}

/// A file without ropes cannot be walked by them, and leaf lists cannot be walked top-down:
/// both are errors that say what to do, at open.
#[test]
fn walks_a_file_cannot_take_are_refused_at_open() {
    let mesh = load_shared("bunny/bun_zipper.ply");
    let (plain, _) = files(&mesh, LeafKind::Cluster);
    let err = Scene::from_bytes_with(
        plain,
        "plain.oavm",
        &SceneOptions {
            walk: Walk::Ropes,
            ..SceneOptions::default()
        },
    )
    .err()
    .expect("a file without ropes opened for the rope walk");
    assert!(err.to_string().contains("--ropes"), "{err}");
    let (lists, _) = files(&mesh, LeafKind::List);
    let err = Scene::from_bytes_with(
        lists,
        "lists.oavm",
        &SceneOptions {
            walk: Walk::TopDown,
            ..SceneOptions::default()
        },
    )
    .err()
    .expect("a file of lists opened for the top-down walk");
    assert!(err.to_string().contains("clusters"), "{err}");
}

/// Rewrites the top tree's rope record `node`, face `face`, to `rope`, and makes the section
/// checksum and the header checksum match again, so that only the rope check can catch it.
fn with_top_rope(bytes: &AlignedBytes, node: usize, face: usize, rope: u32) -> AlignedBytes {
    let file = OavmFile::open(AlignedBytes::from_slice(bytes.as_ref())).expect("open");
    let s = *file.section(SectionKind::Ropes);
    let mut out = bytes.as_ref().to_vec();
    let at = s.offset as usize + node * std::mem::size_of::<RopeRecord>() + 4 * face;
    out[at..at + 4].copy_from_slice(&rope.to_le_bytes());
    let section = &out[s.offset as usize..(s.offset + s.length) as usize];
    let sum = xxhash_rust::xxh3::xxh3_64(section);
    let hsize = std::mem::size_of::<Header>();
    let esize = std::mem::size_of::<SectionEntry>();
    let entry = hsize + (SectionKind::Ropes as usize - 1) * esize;
    let checksum_at = entry + std::mem::offset_of!(SectionEntry, checksum);
    out[checksum_at..checksum_at + 8].copy_from_slice(&sum.to_le_bytes());
    let table_end = hsize + SectionKind::count_for(file.header().flags) * esize;
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    h.update(&out[..oavm::physical::format::HEADER_CHECKED_LEN]);
    h.update(&out[hsize..table_end]);
    let digest = h.digest();
    let at = std::mem::offset_of!(Header, checksum);
    out[at..at + 8].copy_from_slice(&digest.to_le_bytes());
    AlignedBytes::from_slice(&out)
}

/// A rope naming the wrong node (the root, which holds the cells across but is not the smallest
/// node that does; or past the nodes) is caught by verify, with the checksums made to match;
/// the tracer, given such a rope, still answers every ray without a panic.
#[test]
fn verify_catches_a_rope_to_the_wrong_node() {
    let mesh = load_shared("bart/robot/Robot.aff");
    let (_, roped) = files(&mesh, LeafKind::Cluster);
    let file = OavmFile::open(AlignedBytes::from_slice(roped.as_ref())).expect("open");
    let nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    let ropes: &[RopeRecord] = file.records(SectionKind::Ropes);
    // A top-tree leaf whose rope across some face leads to a node other than the root.
    let (node, face) = (0..nodes.len())
        .filter(|&i| nodes[i].kind_bits() != KIND_INTERNAL)
        .find_map(|i| {
            (0..6)
                .find(|&f| ropes[i].across[f] != u32::MAX && ropes[i].across[f] != ROPE_TOP)
                .map(|f| (i, f))
        })
        .expect("a top-tree leaf with a rope past the root");
    let rays = rays_for(&mesh, 2_000);
    for (rope, what) in [
        (ROPE_TOP, "is not the smallest"),
        (ROPE_TOP | 0x7fff_0000, "names no node"),
    ] {
        let bad = with_top_rope(&roped, node, face, rope);
        let scene = Scene::from_bytes_with(
            bad,
            "bad.oavm",
            &SceneOptions {
                walk: Walk::Ropes,
                ..SceneOptions::default()
            },
        )
        .expect("open");
        let report = scene.verify().expect("verify");
        assert!(
            report.defects.iter().any(|d| d.contains("rope")),
            "rope {rope:#x} ({what}) not caught: {:?}",
            report.defects
        );
        let mut hits = vec![Hit::MISS; rays.len()];
        scene.intersect_batch(&rays, &mut hits).expect("trace");
    }
}

/// `oavm-pack --ropes` writes a file that verifies and whose ropes `oavm-trace --walk ropes`
/// follows to the same answers, byte for byte, as `--walk neighbours` and the default walk.
#[test]
fn pack_and_trace_with_ropes_on_the_command_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mesh = shared_scene("cornell_box/CornellBox-Original.obj");
    let out = dir.path().join("c.oavm");
    let (o, stdout, stderr) =
        run(bin("oavm-pack")
            .arg(&mesh)
            .arg(&out)
            .args(["--ropes", "--leaf-size", "4"]));
    assert!(o.status.success(), "{stderr}");
    assert!(stdout.contains("ropes"), "{stdout}");
    let (o, _, stderr) = run(bin("oavm-trace").arg(&out).arg("--verify"));
    assert!(o.status.success(), "{stderr}");
    let m = load_shared("cornell_box/CornellBox-Original.obj");
    let rays = rays_for(&m, 5_000);
    let rays_path = dir.path().join("r.rays");
    oavm::rays::write_rays(&rays_path, &rays).expect("write rays");
    let mut digests = Vec::new();
    for walk in ["auto", "neighbours", "ropes"] {
        let hits = dir.path().join(format!("{walk}.hits"));
        let (o, _, stderr) = run(bin("oavm-trace")
            .arg(&out)
            .args(["--walk", walk, "--rays"])
            .arg(&rays_path)
            .arg("--hits")
            .arg(&hits));
        assert!(o.status.success(), "{walk}: {stderr}");
        digests.push(std::fs::read(&hits).expect("hits"));
    }
    assert!(digests.iter().all(|d| d == &digests[0]));
    assert!(digests[0].len() > 8 * rays.len(), "too small a hits file");
}
