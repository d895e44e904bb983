//! Format 6's wide nodes (format-spec §8.7): files of clusters as packed verify clean, verify
//! laying every block's wide nodes and the top tree's out again and comparing bytes; with the
//! options that change what a block holds (small blocks and deep trees, compressed blocks, and
//! the passes that decode every block and store it again: ropes, occluders). Their layout is
//! also what the spec says of it, checked here from the records alone: every block root has one
//! wide link, and the top tree at most one wide node per internal node with a link below it
//! (adoption leaves some out; a test below requires that it does). The
//! corruption tests (`tests/corruption/blocks.rs`, `top.rs`) damage them.

use crate::common::{build_scene, load_shared};
use oavm::logical::SceneOptions;
use oavm::pack::{BuildOptions, LeafKind};
use oavm::physical::format::{
    ClusterNode, KIND_INTERNAL, KIND_LINK, NodeRecord, SectionKind, WideLink,
};
use oavm::physical::{AlignedBytes, BlockOptions, InspectOptions, OavmFile, inspect};
use oavm::{Mesh, Scene};

/// Opens `bytes` and requires verify to find nothing.
fn verified(bytes: &[u8], what: &str) -> Scene<AlignedBytes> {
    let scene = Scene::from_bytes_with(
        AlignedBytes::from_slice(bytes),
        "wide.oavm",
        &SceneOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{what}: {e}"));
    let report = scene.verify().expect("verify");
    assert!(report.is_ok(), "{what}: verify: {:?}", report.defects);
    scene
}

/// What §8.7 says of a file's wide sections, from its records alone: a wide link per link of
/// the top tree (per block root), and at most a top wide node per internal node with a link
/// below it (adoption leaves some out), at least as many as eight-wide nodes over the links;
/// and `oavm-inspect`'s counts of them, and of the blocks' (a cluster root per solid leaf, and
/// octree wide nodes if `octree`: blocks whose roots are all solid leaves have none).
fn check_counts(file: &OavmFile<AlignedBytes>, octree: bool, what: &str) {
    let nodes: &[ClusterNode] = file.records(SectionKind::WideNodes);
    let links: &[WideLink] = file.records(SectionKind::WideLinks);
    let roots: u64 = file.directory().iter().map(|e| e.root_count as u64).sum();
    assert_eq!(links.len() as u64, roots, "{what}: one wide link per root");
    let top: &[NodeRecord] = file.records(SectionKind::Nodes);
    assert_eq!(
        top.iter().filter(|r| r.kind_bits() == KIND_LINK).count(),
        links.len(),
        "{what}: one wide link per link"
    );
    // Every internal node of the top tree has a link below it in a packed file, so each has a
    // wide node but those adoption leaves out (§8.7); and an 8-wide tree over the links needs
    // at least one node per seven links past the first.
    let internal = top
        .iter()
        .filter(|r| r.kind_bits() == KIND_INTERNAL)
        .count();
    let least = links.len().saturating_sub(1).div_ceil(7).max(1);
    assert!(
        (least..=internal.max(1)).contains(&nodes.len()),
        "{what}: {} top wide nodes for {internal} internal nodes and {} links",
        nodes.len(),
        links.len()
    );
    let i = inspect(
        file,
        InspectOptions {
            levels: true,
            ..InspectOptions::default()
        },
    );
    let w = i
        .wide
        .expect("inspect shows the wide nodes of a file of clusters");
    assert_eq!(
        (w.top_nodes, w.links),
        (nodes.len() as u64, links.len() as u64),
        "{what}: inspect"
    );
    let blocks = w.blocks.expect("counted over the blocks with --levels");
    assert_eq!(
        blocks.cluster_roots,
        file.header().solid_leaves,
        "{what}: {blocks:?}"
    );
    assert!(
        blocks.cluster_nodes >= blocks.cluster_roots && (blocks.octree_nodes > 0) == octree,
        "{what}: {blocks:?}"
    );
}

fn packed(mesh: &Mesh, opts: &BuildOptions, blocks: &BlockOptions) -> AlignedBytes {
    let (parts, _) = oavm::pack::build(mesh, opts, &oavm::pack::Quiet).expect("build");
    oavm::pack::encode_with(&parts, blocks).expect("encode")
}

/// The bunny and the Cornell box (a few dozen triangles: one block, a top tree of one link)
/// verify clean as packed, with clusters, at the default block size, in blocks of 16 KiB, raw
/// and compressed, and in a deep tree of small leaves in blocks of 4 KiB.
#[test]
fn files_of_clusters_as_packed_verify_clean() {
    let bunny = load_shared("bunny/bun_zipper.ply");
    let cornell = load_shared("cornell_box/CornellBox-Original.obj");
    let deep = BuildOptions {
        leaf_size: 16,
        ..BuildOptions::default()
    };
    let small = |compress: bool| BlockOptions {
        block_size: 16384,
        compress: compress.then_some(3),
        chunk_groups: 8,
        lean: false,
    };
    for (name, mesh) in [("bunny", &bunny), ("cornell box", &cornell)] {
        // (case, build, blocks, whether blocks hold octree wide nodes: at 16 KiB or more the
        // bunny's blocks each hold one leaf per root, the Cornell box is one leaf)
        let cases = [
            (
                "default",
                BuildOptions::default(),
                BlockOptions::default(),
                true,
            ),
            (
                "16 KiB blocks",
                BuildOptions::default(),
                small(false),
                false,
            ),
            (
                "16 KiB blocks, zstd",
                BuildOptions::default(),
                small(true),
                false,
            ),
            (
                "leaf size 16, 4 KiB blocks",
                deep,
                BlockOptions {
                    block_size: 4096,
                    compress: None,
                    ..BlockOptions::default()
                },
                true,
            ),
        ];
        for (case, opts, blocks, octree) in cases {
            let what = format!("{name}, {case}");
            let bytes = packed(mesh, &opts, &blocks);
            let scene = verified(bytes.as_ref(), &what);
            let octree = octree && name == "bunny";
            check_counts(scene.file(), octree, &what);
        }
    }
    // Through the builder's own check too.
    build_scene(&cornell, &BuildOptions::default());
}

/// The passes that decode every block and store it again (ropes, occluders) keep the wide
/// nodes as verify lays them out (the layout is idempotent), the file's chunks of groups (16
/// here, not the default 128) and its blocks' codec (raw or lean); a file of lists has none.
#[test]
fn blocks_stored_again_and_files_of_lists_verify_clean() {
    let bunny = load_shared("bunny/bun_zipper.ply");
    for lean in [false, true] {
        let blocks = BlockOptions {
            block_size: 16384,
            compress: None,
            chunk_groups: 16,
            lean,
        };
        let plain = packed(&bunny, &BuildOptions::default(), &blocks);
        let file = OavmFile::open(AlignedBytes::from_slice(plain.as_ref())).expect("open");
        let codecs = |f: &OavmFile<&[u8]>| {
            let mut c: Vec<u32> = f.directory().iter().map(|e| e.codec).collect();
            c.dedup();
            c
        };
        let (roped, ..) = oavm::pack::ropes::add_ropes(&file, Vec::new()).expect("ropes");
        let scene = verified(&roped, "bunny with ropes");
        check_counts(scene.file(), false, "bunny with ropes");
        let (occluded, ..) = oavm::pack::occluders::add_occluders(
            &file,
            &oavm::pack::occluders::ShadowParams::default(),
            Vec::new(),
        )
        .expect("occluders");
        let scene = verified(&occluded, "bunny with occluders");
        check_counts(scene.file(), false, "bunny with occluders");
        for (what, bytes) in [("ropes", &roped), ("occluders", &occluded)] {
            let f = OavmFile::open(&bytes[..]).expect("open");
            assert_eq!(f.header().chunk_groups, 16, "lean {lean}, {what}");
            assert_eq!(codecs(&f), vec![lean as u32 * 2], "lean {lean}, {what}");
        }
    }
    let blocks = BlockOptions {
        block_size: 16384,
        compress: None,
        ..BlockOptions::default()
    };

    let lists = packed(&bunny, &BuildOptions::with_leaf(LeafKind::List), &blocks);
    let scene = verified(lists.as_ref(), "bunny, lists");
    let file = scene.file();
    assert!(
        file.records::<ClusterNode>(SectionKind::WideNodes)
            .is_empty()
    );
    assert!(file.records::<WideLink>(SectionKind::WideLinks).is_empty());
    assert!(
        inspect(file, InspectOptions::default()).wide.is_none(),
        "a file of lists has no wide nodes"
    );
}

/// Adoption (spec §8.7) happens: the dragon's top tree has fewer wide nodes than internal
/// nodes, and its blocks' octree regions fewer octree wide nodes than internal nodes with a
/// solid leaf below them; the file verifies (verify lays it out again) and a wide node never
/// holds more than eight children.
#[test]
fn adoption_leaves_out_nodes_whose_children_fit_in_their_parent() {
    let dragon = load_shared("dragon/dragon_vrip.ply");
    let bytes = packed(&dragon, &BuildOptions::default(), &BlockOptions::default());
    let scene = verified(bytes.as_ref(), "dragon");
    let file = scene.file();
    let nodes: &[ClusterNode] = file.records(SectionKind::WideNodes);
    let top: &[NodeRecord] = file.records(SectionKind::Nodes);
    let internal = top
        .iter()
        .filter(|r| r.kind_bits() == KIND_INTERNAL)
        .count();
    assert!(
        nodes.len() < internal,
        "{} top wide nodes, {internal} internal nodes",
        nodes.len()
    );
    assert!(nodes.iter().all(|n| (1..=8).contains(&n.child_count)));
    let i = inspect(
        file,
        InspectOptions {
            levels: true,
            ..InspectOptions::default()
        },
    );
    let blocks = i
        .wide
        .and_then(|w| w.blocks)
        .expect("counted over the blocks");
    // One wide node per internal node with a solid leaf below it, counted from the records.
    let mut unadopted = 0;
    let reader = oavm::physical::BlockReader::new(file);
    for (b, e) in file.directory().iter().enumerate() {
        let raw = reader.read(file.bytes(), b as u32, e).expect("read");
        let view = oavm::physical::BlockView::parse(&raw, b as u32, e).expect("parse");
        let (internal, _) = oavm::physical::wide_region(view.levels, view.nodes).expect("region");
        unadopted += internal;
    }
    assert!(
        blocks.octree_nodes < unadopted,
        "{blocks:?}: {unadopted} internal nodes with a solid leaf below"
    );
    check_counts(file, true, "dragon");
}
