//! The mapping layer on a real tree: `(level, Morton code) -> index`, parent, child, point
//! location and face neighbours, each checked against an answer computed independently.

use crate::common::*;
use oavm::BuildOptions;
use oavm::mapping::morton::{self, MAX_LEVEL, cell_origin, cell_size};
use oavm::mapping::{LevelInfos, TreeMap};
use oavm::physical::format::{NodeKind, SectionKind};
use oavm::rays::SplitMix64;

/// Every node of the tree with its level, index and code, generated top-down by rank.
fn all_nodes(map: &TreeMap) -> Vec<(u32, u64, u64, NodeKind)> {
    let mut out = Vec::new();
    let mut level_nodes = vec![(0u64, 0u64)]; // (index, code) of level 0
    for l in 0..map.level_count() {
        let mut next = Vec::new();
        for &(idx, code) in &level_nodes {
            let kind = map.node(l, idx).unwrap().kind().unwrap();
            if kind == NodeKind::Internal {
                for o in 0..8 {
                    next.push((map.child(l, idx, o).unwrap(), code << 3 | o as u64));
                }
            }
            out.push((l, idx, code, kind));
        }
        level_nodes = next;
    }
    out
}

fn boxes_touch_on_face(
    a: ([u32; 3], u32),
    b: ([u32; 3], u32),
    axis: usize,
    positive: bool,
) -> bool {
    let (alo, asz) = a;
    let (blo, bsz) = b;
    let face_ok = if positive {
        blo[axis] == alo[axis] + asz
    } else {
        blo[axis] + bsz == alo[axis]
    };
    // The boxes' projections on the other two axes must overlap with positive area.
    face_ok
        && (0..3)
            .filter(|&k| k != axis)
            .all(|k| blo[k] < alo[k] + asz && alo[k] < blo[k] + bsz)
}

#[test]
fn mapping_queries_on_a_real_tree() {
    let mesh = oavm::mesh::load(&shared_scene("dragon/dragon_vrip_res4.ply")).unwrap();
    let scene = build_scene(
        &mesh,
        &BuildOptions {
            leaf_size: 4,
            ..BuildOptions::default()
        },
    );
    let file = scene.file();
    let infos = LevelInfos::new(file.levels(), 0);
    let map = TreeMap::new(
        &infos,
        file.levels(),
        file.records(SectionKind::Nodes),
        file.records(SectionKind::Ranks),
    );
    let nodes = all_nodes(&map);
    assert_eq!(nodes.len() as u64, file.section(SectionKind::Nodes).count);
    assert!(
        map.level_count() >= 6,
        "want a deep tree, got {} levels",
        map.level_count()
    );

    // (L, M) -> index for every node; parent inverts child.
    for &(l, idx, code, _) in &nodes {
        assert_eq!(
            map.index_of(l, code).unwrap(),
            Some(idx),
            "level {l} code {code:o}"
        );
        if l > 0 {
            let parent = map.parent(l, idx).unwrap();
            assert_eq!(map.index_of(l - 1, code >> 3).unwrap(), Some(parent));
            assert_eq!(map.child(l - 1, parent, (code & 7) as u32).unwrap(), idx);
        }
    }
    assert!(map.parent(0, 0).is_err());

    // A node below a leaf does not exist.
    let leaves: Vec<_> = nodes.iter().filter(|n| n.3 != NodeKind::Internal).collect();
    let &&(l, _, code, _) = leaves.iter().find(|n| n.0 + 1 < map.level_count()).unwrap();
    assert_eq!(map.index_of(l + 1, code << 3).unwrap(), None);

    // Point location: the leaf found contains the point.
    let mut rng = SplitMix64::new(5);
    for _ in 0..20_000 {
        let q: [u32; 3] = std::array::from_fn(|_| (rng.next_u64() >> 43) as u32);
        let (l, idx, _) = map.leaf_at(q).unwrap();
        let code = morton::code_at_level(q, l);
        assert_eq!(map.index_of(l, code).unwrap(), Some(idx));
        let lo = cell_origin(code, l);
        assert!((0..3).all(|k| lo[k] <= q[k] && q[k] < lo[k] + cell_size(l)));
    }

    // Face neighbours against brute force over all leaves, for a sample of leaves.
    type LeafBox = ((u32, u64), ([u32; 3], u32));
    let leaf_boxes: Vec<LeafBox> = leaves
        .iter()
        .map(|&&(l, idx, code, _)| ((l, idx), (cell_origin(code, l), cell_size(l))))
        .collect();
    for &&(l, _, code, _) in leaves.iter().step_by(97) {
        let me = (cell_origin(code, l), cell_size(l));
        for axis in 0..3 {
            for positive in [false, true] {
                let got = map.face_neighbours(l, code, axis as u32, positive).unwrap();
                let mut want: Vec<(u32, u64)> = leaf_boxes
                    .iter()
                    .filter(|(_, b)| boxes_touch_on_face(me, *b, axis, positive))
                    .map(|(id, _)| *id)
                    .collect();
                want.sort_unstable();
                assert_eq!(
                    got, want,
                    "leaf level {l} code {code:o}, axis {axis}, positive {positive}"
                );
            }
        }
    }
}

#[test]
fn neighbour_codes_are_right_across_parents_at_every_level() {
    // Dilated-integer neighbours agree with plain coordinate arithmetic on random codes at
    // every level, including the deepest (the exhaustive small-grid test is in morton.rs).
    let mut rng = SplitMix64::new(9);
    for level in 1..=MAX_LEVEL {
        for _ in 0..2_000 {
            let n = 1u64 << level;
            let c: [u64; 3] = std::array::from_fn(|_| rng.next_u64() % n);
            let shift = MAX_LEVEL - level;
            let code = morton::code_at_level(c.map(|v| (v as u32) << shift), level);
            for axis in 0..3 {
                for positive in [false, true] {
                    let mut d = c.map(|v| v as i64);
                    d[axis] += if positive { 1 } else { -1 };
                    let want = (d[axis] >= 0 && d[axis] < n as i64)
                        .then(|| morton::code_at_level(d.map(|v| (v as u32) << shift), level));
                    assert_eq!(morton::neighbour(code, level, axis as u32, positive), want);
                }
            }
        }
    }
}
