//! Corrupted `.oavm` files (format-spec.md §11): damage to occluders (§8.5): the occluder
//! entries and occluders of a block, its header's counts, the header's `OCCLUDERS` flag.
//!
//! What must hold, the files damaged and how the runs report are in `tests/corruption/fixtures`
//! (its module doc), with the fixtures and the harness these files share.

use crate::fixtures::*;

/// §4, §8.1, §8.3: the level and Morton code of each node record of block `blk`, in record
/// order: its roots' from the links to them (in root order), each internal node's children
/// the next 8 nodes of the next level (§4).
fn block_node_codes(fix: &Fixture, blk: usize) -> Vec<(u32, u64)> {
    let raw = &fix.decoded[blk];
    let parts = block_parts(raw);
    let root_level = read_u32(raw, 8);
    let mut roots: Vec<&Link> = fix.links.iter().filter(|l| l.block == blk as u32).collect();
    roots.sort_by_key(|l| l.root);
    assert!(
        roots.iter().all(|l| l.level == root_level),
        "{}: block {blk}'s links are at its root level",
        fix.name
    );
    let mut codes: Vec<u64> = roots.iter().map(|l| l.code).collect();
    let mut out = vec![(0, 0); parts[PART_NODES].len() / 8];
    for l in 0..parts[0].len() / 32 {
        let e = parts[0].start + 32 * l;
        let (n, start) = (read_u64(raw, e) as usize, read_u64(raw, e + 16) as usize);
        assert_eq!(codes.len(), n, "{}: block {blk} level {l}", fix.name);
        let mut next = Vec::new();
        for (i, &code) in codes.iter().enumerate() {
            out[start + i] = (root_level + l as u32, code);
            let meta = read_u32(raw, parts[PART_NODES].start + 8 * (start + i) + 4);
            if meta >> 30 == KIND_INTERNAL {
                next.extend((0..8).map(|o| code << 3 | o));
            }
        }
        codes = next;
    }
    out
}

/// The cell of node `code` at `level` (§1: lattice and Morton codes, x lowest), widened by
/// `margin` lattice units on every side, in world units: `(lo, hi)`.
fn cell_box(b: &[u8], level: u32, code: u64, margin: f64) -> ([f64; 3], [f64; 3]) {
    let mut c = [0u64; 3];
    for i in 0..level {
        let g = code >> (3 * i);
        for (k, ck) in c.iter_mut().enumerate() {
            *ck |= ((g >> k) & 1) << i;
        }
    }
    let size = (1u64 << (21 - level)) as f64;
    let unit = f64::from_bits(read_u64(b, ROOT_SIZE_AT)) / (1u64 << 21) as f64;
    let min = |k: usize| f64::from_bits(read_u64(b, ROOT_MIN_AT + 8 * k));
    (
        std::array::from_fn(|k| min(k) + (c[k] as f64 * size - margin) * unit),
        std::array::from_fn(|k| min(k) + ((c[k] + 1) as f64 * size + margin) * unit),
    )
}

/// An occluder entry's first occluder (§8.5: block, entry, node, offset in the decoded block)
/// and a triangle of its block to put there: one whose box is clear of the node's cell widened
/// by 4 lattice units (the cell margin of §6 and 2 more), which verify must report; and
/// another, whose box is inside the cell, which is a valid occluder. Deepest nodes first, over
/// the blocks holding occluders.
type OccluderSwap = (usize, usize, u32, usize, [u8; TRI_LEN]);
fn occluder_swaps(fix: &Fixture) -> (Option<OccluderSwap>, Option<OccluderSwap>) {
    let (mut outside, mut inside) = (None, None);
    for (blk, raw) in fix.decoded.iter().enumerate() {
        let parts = block_parts(raw);
        let (entries, occ) = (&parts[PART_OCCLUDER_NODES], &parts[PART_OCCLUDERS]);
        if entries.is_empty() {
            continue;
        }
        let codes = block_node_codes(fix, blk);
        let tris = block_triangles(raw);
        let mut by_depth: Vec<usize> = (0..entries.len() / OCCLUDER_NODE_LEN).collect();
        let node_of = |i: usize| read_u32(raw, entries.start + OCCLUDER_NODE_LEN * i);
        by_depth.sort_by_key(|&i| std::cmp::Reverse(codes[node_of(i) as usize].0));
        for i in by_depth {
            let node = node_of(i);
            let (level, code) = codes[node as usize];
            let (lo, hi) = cell_box(&fix.bytes, level, code, 4.0);
            let (ilo, ihi) = cell_box(&fix.bytes, level, code, -1.0);
            let first = read_u32(raw, entries.start + OCCLUDER_NODE_LEN * i + 4) as usize;
            let at = occ.start + TRI_LEN * first;
            for t in &tris {
                let (tlo, thi) = tri_bounds(t);
                if outside.is_none() && (0..3).any(|k| thi[k] < lo[k] || tlo[k] > hi[k]) {
                    outside = Some((blk, i, node, at, *t));
                }
                if inside.is_none()
                    && t[..] != raw[at..at + TRI_LEN]
                    && (0..3).all(|k| tlo[k] > ilo[k] && thi[k] < ihi[k])
                {
                    inside = Some((blk, i, node, at, *t));
                }
            }
            if outside.is_some() && inside.is_some() {
                return (outside, inside);
            }
        }
    }
    (outside, inside)
}

/// The bounding box of a triangle record's corners (§7), in f64.
fn tri_bounds(t: &[u8]) -> ([f64; 3], [f64; 3]) {
    let c = |i: usize, k: usize| f32::from_bits(read_u32(t, 12 * i + 4 * k)) as f64;
    (
        std::array::from_fn(|k| c(0, k).min(c(1, k)).min(c(2, k))),
        std::array::from_fn(|k| c(0, k).max(c(1, k)).max(c(2, k))),
    )
}

/// Occluders (§8.5) rewritten one field at a time, checksums recomputed, in the block holding
/// the most, raw and compressed: an occluder's corners moved far away or by one ulp, its id
/// changed, an occluder made a triangle of the block that lies outside its node's widened
/// cell; an entry naming a leaf, a node past the block, `u32::MAX`; entries out of order or
/// naming one node twice; a `first` that is not 0 for the first entry, that leaves an entry
/// without occluders, or that runs past the records; the block header's counts made
/// inconsistent (one 0 and not the other, more entries than nodes, one occluder more than the
/// block holds) or entries added over the padding; and the header's `OCCLUDERS` flag cleared
/// with the occluders left in the blocks. Verify reports each, naming the block (and for the
/// records, the occluders); tracing (the top-down walk, whose any-hit queries test the
/// occluders), unbounded and under a tight budget, returns answers or an error, never a panic
/// or an endless walk, and fails naming the block whose header the pager refuses. And an
/// occluder made another triangle of the block that does lie in its node's cell is valid:
/// verify reports nothing and the answers are the intact file's.
#[test]
fn occluders_rewritten_are_caught() {
    let mut problems = Vec::new();
    for fix in [occluded_file(), occluded_zstd_file()] {
        let blk = fix.occluder_block.expect("a block holds occluders");
        let raw = &fix.decoded[blk];
        let parts = block_parts(raw);
        let (entries, occ) = (
            parts[PART_OCCLUDER_NODES].clone(),
            parts[PART_OCCLUDERS].clone(),
        );
        let (n_entries, n_occ) = (entries.len() / OCCLUDER_NODE_LEN, occ.len() / TRI_LEN);
        assert!(
            n_entries >= 2,
            "{}: block {blk} has {n_entries} occluder entries, want two",
            fix.name
        );
        let entry_at = |i: usize| entries.start + OCCLUDER_NODE_LEN * i;
        let occ_at = |i: usize| occ.start + TRI_LEN * i;
        let node_of = |i: usize| read_u32(raw, entry_at(i));
        let first_of = |i: usize| read_u32(raw, entry_at(i) + 4);
        let kinds: Vec<u32> = parts[PART_NODES]
            .clone()
            .step_by(8)
            .map(|at| read_u32(raw, at + 4) >> 30)
            .collect();
        let n_nodes = kinds.len() as u32;
        let leaf = kinds
            .iter()
            .position(|&k| k != KIND_INTERNAL)
            .expect("a leaf") as u32;
        assert!(
            (0..n_entries).all(|i| kinds[node_of(i) as usize] == KIND_INTERNAL),
            "{}: block {blk}: occluder entries name internal nodes (§8.5)",
            fix.name
        );
        let u32le = |v: u32| v.to_le_bytes().to_vec();
        let u64le = |v: u64| v.to_le_bytes().to_vec();
        let b = Space::Block(blk);
        let last = n_entries - 1;
        // (what, space, offset in the space, new bytes, what verify must say besides the block,
        // whether the pager refuses the block)
        type Case = (String, Space, usize, Vec<u8>, &'static str, bool);
        let mut cases: Vec<Case> = Vec::new();
        // The records.
        let d = (f64::from_bits(read_u64(&fix.bytes, ROOT_SIZE_AT)) / 2.0) as f32;
        let mut far = raw[occ_at(0)..occ_at(0) + 36].to_vec();
        for c in 0..3 {
            let x = f32::from_le_bytes(far[12 * c..12 * c + 4].try_into().expect("4 bytes"));
            far[12 * c..12 * c + 4].copy_from_slice(&(x + d).to_le_bytes());
        }
        let x0 = f32::from_bits(read_u32(raw, occ_at(0)));
        let prim0 = read_u32(raw, occ_at(0) + 36);
        cases.extend([
            (
                "occluder 0 moved by half the root cube along x".to_string(),
                b,
                occ_at(0),
                far,
                "occluder",
                false,
            ),
            (
                "occluder 0's first corner's x moved by one ulp".into(),
                b,
                occ_at(0),
                u32le(f32::from_bits(x0.to_bits() + 1).to_bits()),
                "occluder",
                false,
            ),
            (
                format!("occluder 0's id {prim0} made {}", prim0 + 1),
                b,
                occ_at(0) + 36,
                u32le(prim0 + 1),
                "occluder",
                false,
            ),
            (
                format!("occluder {}'s id made u32::MAX", n_occ - 1),
                b,
                occ_at(n_occ - 1) + 36,
                u32le(u32::MAX),
                "occluder",
                false,
            ),
        ]);
        // The entries.
        cases.extend([
            (
                format!("entry 0 names leaf {leaf}"),
                b,
                entry_at(0),
                u32le(leaf),
                "occluder",
                false,
            ),
            (
                format!("entry {last} names node {n_nodes}, past the block's"),
                b,
                entry_at(last),
                u32le(n_nodes),
                "occluder",
                false,
            ),
            (
                format!("entry {last} names node u32::MAX"),
                b,
                entry_at(last),
                u32le(u32::MAX),
                "occluder",
                false,
            ),
            (
                "entries 0 and 1 swapped".into(),
                b,
                entry_at(0),
                [
                    raw[entry_at(1)..entry_at(2)].to_vec(),
                    raw[entry_at(0)..entry_at(1)].to_vec(),
                ]
                .concat(),
                "occluder",
                false,
            ),
            (
                "entries 0 and 1 name the same node".into(),
                b,
                entry_at(1),
                u32le(node_of(0)),
                "occluder",
                false,
            ),
            (
                "entry 0's first is 1".into(),
                b,
                entry_at(0) + 4,
                u32le(1),
                "occluder",
                false,
            ),
            (
                "entry 1's first made entry 0's (entry 0 holds none)".into(),
                b,
                entry_at(1) + 4,
                u32le(first_of(0)),
                "occluder",
                false,
            ),
            (
                format!("entry {last}'s first made occluder_count {n_occ} (it holds none)"),
                b,
                entry_at(last) + 4,
                u32le(n_occ as u32),
                "occluder",
                false,
            ),
            (
                format!("entry {last}'s first made u32::MAX"),
                b,
                entry_at(last) + 4,
                u32le(u32::MAX),
                "occluder",
                false,
            ),
        ]);
        // The block header's counts (§8.3): the pager refuses the block.
        let (bh_entries, bh_occ) = (n_entries as u64, n_occ as u64);
        for (what, at, v) in [
            ("occluder_count 0", BH_OCCLUDER_COUNT, 0),
            ("occluder_node_count 0", BH_OCCLUDER_NODE_COUNT, 0),
            (
                "occluder_node_count one more than its nodes",
                BH_OCCLUDER_NODE_COUNT,
                n_nodes as u64 + 1,
            ),
            ("occluder_count one more", BH_OCCLUDER_COUNT, bh_occ + 1),
            ("occluder_count 2^32", BH_OCCLUDER_COUNT, 1 << 32),
            ("occluder_count u64::MAX", BH_OCCLUDER_COUNT, u64::MAX),
            (
                "occluder_node_count u64::MAX",
                BH_OCCLUDER_NODE_COUNT,
                u64::MAX,
            ),
        ] {
            cases.push((format!("block header: {what}"), b, at, u64le(v), "", true));
        }
        // One entry more, over the padding before the occluders if there is room (the block's
        // length is unchanged: the extra entry reads zeros, {node 0, first 0}), else past it.
        let room = parts[PART_OCCLUDERS].start > entries.end;
        cases.push((
            format!(
                "block header: occluder_node_count one more ({})",
                if room {
                    "over the padding"
                } else {
                    "the block too short"
                }
            ),
            b,
            BH_OCCLUDER_NODE_COUNT,
            u64le(bh_entries + 1),
            if room { "occluder" } else { "" },
            !room,
        ));
        let mut cases: Vec<(usize, Case)> = cases.into_iter().map(|c| (blk, c)).collect();
        // The header's flag cleared: occluders in a file without them, in every block holding
        // some (verify lists the first 50 defects: the first such block is named). Tracing
        // ignores them.
        let flags = read_u32(&fix.bytes, FLAGS_AT);
        let first_holding = (0..fix.dir.len())
            .find(|&b| !block_parts(&fix.decoded[b])[PART_OCCLUDERS].is_empty())
            .expect("a block holds occluders");
        cases.push((
            first_holding,
            (
                "the header's OCCLUDERS flag cleared".into(),
                Space::File,
                FLAGS_AT,
                u32le(flags & !FLAG_OCCLUDERS),
                "occluders in a file without them",
                false,
            ),
        ));
        // An occluder made a triangle of its block outside its node's cell (widened by the
        // cell margin of §6, 2 lattice units, and 2 more to keep clear of rounding), at the
        // deepest such node of any block; and one made another triangle of its block inside
        // the cell (its box inside the cell), which is valid.
        let (outside, inside) = occluder_swaps(fix);
        let (ob, oi, onode, oat, t) = outside.expect("a triangle outside a node with occluders");
        cases.push((
            ob,
            (
                format!(
                    "entry {oi}'s first occluder made a triangle of the block outside node \
                     {onode}'s cell"
                ),
                Space::Block(ob),
                oat,
                t.to_vec(),
                "does not lie in its node",
                false,
            ),
        ));
        eprintln!(
            "{}: block {blk} ({n_entries} occluder entries, {n_occ} occluders): {} rewrites",
            fix.name,
            cases.len()
        );
        for (blk, (what, space, at, new, says, refused)) in cases {
            let bytes = fix.rewrite(space, at, &new);
            assert!(bytes != fix.bytes, "{}: {what}: nothing changed", fix.name);
            let what = format!("{}: block {blk}: {what}", fix.name);
            let reported = |d: &str| names_block(d, blk) && d.contains(says);
            let defect = format!("block {blk}: ...{says}");
            let fails_on = if refused { vec![blk] } else { vec![] };
            expect_reported(
                fix,
                what,
                bytes,
                &defect,
                &reported,
                &fails_on,
                &mut problems,
            );
        }
        // A valid rewrite: another triangle of the block, inside the node's cell.
        let (ib, ii, inode, iat, t) = inside.expect("a triangle inside a node with occluders");
        let what = format!(
            "{}: block {ib}: entry {ii}'s first occluder made another triangle of the block \
             inside node {inode}'s cell",
            fix.name
        );
        match evaluate_guarded(fix, fix.rewrite(Space::Block(ib), iat, &t), true, &what) {
            Ok(Verdict::Opened {
                generation,
                traced: Ok(Traced::Same),
                tight: Some(Ok(Traced::Same)),
                defects: Ok(d),
            }) if d.is_empty() && generation == fix.generation => {}
            v => problems.push(format!(
                "{what}: a valid occluder: should read as the intact file: {v:?}"
            )),
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
