//! Corrupted `.oavm` files (format-spec.md §11): damage to the top tree's links (§8.1) and to
//! ropes (§8.4), in the top tree's ropes section and in a block.
//!
//! What must hold, the files damaged and how the runs report are in `tests/corruption/fixtures`
//! (its module doc), with the fixtures and the harness these files share.

use crate::fixtures::*;

/// Links of the top tree (§8.1) rewritten, checksums recomputed: to a block past the
/// directory, to a root past its block's roots, to a block whose roots are at another level,
/// and to a root another link already names (leaving one root unlinked); in a file of clusters
/// the wide link beside the link too (§8.7: the walk follows the wide links). Verify reports
/// each; tracing fails naming the block where the link cannot be followed, in a file of lists
/// (for the walk of a file of clusters, see [`wide_links_rewritten_fail_the_trace_by_name`]).
#[test]
fn links_rewritten_are_caught() {
    let fixes = [
        default_file(),
        list_zstd_file(),
        deep_file(),
        deep_zstd_file(),
    ];
    let problems = links_rewritten(&fixes, |fix| !fix.clusters);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Bug (the wide walk, `src/logical/trace/wide.rs`, format 6): the links of
/// [`links_rewritten_are_caught`] in a file of clusters, where the walk follows the wide links
/// (§8.7): verify reports each, but tracing does not fail naming the block where the link
/// cannot be followed. A wide link to a block past the directory fails with "wide link to a
/// block the directory lacks (level 0, node 0)", which names neither the block nor the link; a
/// wide link to a root past its block's roots is followed to a wide node that is not a root
/// (wrong answers: §11 has the trace check links against the block's roots); one to a block
/// whose roots are at another level is followed as if it were right (wrong answers; §11 has the
/// trace check the root level, which the wide walk does not need: the spec or the walk should
/// change).
#[test]
#[ignore = "bug: the wide walk follows a wide link to a block whose roots are at another \
            level (a wide link carries no level to check; verify reports it); links past the \
            directory or the block's roots fail naming the block since 90c6339"]
fn wide_links_rewritten_fail_the_trace_by_name() {
    let problems = links_rewritten(&[default_file(), deep_file()], |_| true);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The cases of [`links_rewritten_are_caught`] on `fixes`; tracing must fail naming the block
/// in the fixtures `traced` accepts (else only return). The problems found.
fn links_rewritten(fixes: &[&'static Fixture], traced: fn(&Fixture) -> bool) -> Vec<String> {
    let mut problems = Vec::new();
    for &fix in fixes {
        let nodes = section(&fix.bytes, NODES).0;
        let n = fix.dir.len() as u32;
        let link = |block: u32, root: u32| {
            let mut v = block.to_le_bytes().to_vec();
            v.extend_from_slice(&(KIND_LINK << 30 | root).to_le_bytes());
            v
        };
        // A block's first root (the block's own ray starts in its cell, so it meets the link),
        // at a level with other links.
        let first = *fix
            .links
            .iter()
            .find(|l| {
                l.root == 0
                    && fix
                        .links
                        .iter()
                        .any(|m| m.level == l.level && (m.block, m.root) != (l.block, l.root))
            })
            .expect("a first root at a level of two links");
        let other_level = fix
            .links
            .iter()
            .find(|l| l.level != first.level)
            .copied()
            .expect("links at two levels");
        let sibling = fix
            .links
            .iter()
            .find(|l| l.level == first.level && (l.block, l.root) != (first.block, first.root))
            .copied()
            .expect("two links at one level");
        let roots_of = |b: u32| fix.dir[b as usize].root_count;
        // (what, link rewritten, new record, defect, the block tracing must fail on)
        type Case<'a> = (&'a str, Link, Vec<u8>, &'a str, Vec<usize>);
        let cases: [Case; 5] = [
            (
                "to a block past the directory",
                first,
                link(n, 0),
                "past the",
                vec![n as usize],
            ),
            (
                "to block u32::MAX",
                first,
                link(u32::MAX, 0),
                "past the",
                vec![u32::MAX as usize],
            ),
            (
                "to a root past its block's roots",
                first,
                link(first.block, roots_of(first.block)),
                &format!("a link to root {}", roots_of(first.block)),
                vec![first.block as usize],
            ),
            (
                "to a block whose roots are at another level",
                first,
                link(other_level.block, 0),
                "whose roots are at level",
                vec![other_level.block as usize],
            ),
            (
                "to a root another link names",
                first,
                link(sibling.block, sibling.root),
                "linked twice",
                vec![],
            ),
        ];
        for (what, l, new, defect, fails_on) in cases {
            // The link record, and in a file of clusters its wide link (§8.7: the walk follows
            // the wide links).
            let mut b = fix.bytes.clone();
            let to = (read_u32(&new, 0), read_u32(&new, 4) & LINK_ROOT_MASK);
            relink(&mut b, l.node, (l.block, l.root), to);
            assert_eq!(b[nodes + 8 * l.node..nodes + 8 * l.node + 8], new[..]);
            fix_checksums(&mut b);
            let what = format!(
                "{}: the link at level {} to block {} root {} rewritten {what}",
                fix.name, l.level, l.block, l.root
            );
            let fails_on = if traced(fix) { fails_on } else { Vec::new() };
            expect_caught(fix, what, b, defect, &fails_on, &mut problems);
        }
    }
    problems
}

/// Ropes (§8.4) rewritten one at a time, checksums recomputed, in the top tree's ropes section
/// and in the largest block: a link's or a leaf's rope made the exit where the face is inside
/// the root cube, an exit rope made a node, a rope to the node that holds it (which does not
/// hold the cells across), to a node past its unit's, a top-tree rope without its top bit, a
/// block's rope sent to the other unit, an internal node given ropes; and the block header's
/// `rope_count` made 0 or one more than its nodes. Verify reports each ("rope", or the block
/// for its header); tracing by ropes returns, answers or an error, never a panic or an endless
/// walk, and fails naming the block whose header lies.
#[test]
fn ropes_rewritten_are_caught() {
    let mut problems = Vec::new();
    for fix in [roped_file(), roped_list_zstd_file()] {
        let u32le = |v: u32| v.to_le_bytes().to_vec();
        // (what, space, offset in the space, new bytes, defect, blocks tracing must fail on)
        type Case = (String, Space, usize, Vec<u8>, String, Vec<usize>);
        let mut cases: Vec<Case> = Vec::new();
        let kinds =
            |nodes: &[u8]| -> Vec<u32> { nodes.chunks(8).map(|r| read_u32(r, 4) >> 30).collect() };
        // The top tree: a link's ropes, and the root's (internal: all 0).
        let top = fix.region("ropes section").range.start;
        let (nodes_at, nodes_len) = section(&fix.bytes, NODES);
        let top_kinds = kinds(&fix.bytes[nodes_at..nodes_at + nodes_len]);
        let top_nodes = top_kinds.len() as u32;
        // A link with a face inside the root cube and, if there is one, a face on its boundary.
        let rope = |b: &[u8], record: usize, f: usize| read_u32(b, record + 4 * f);
        let link = fix
            .links
            .iter()
            .find(|l| (0..6).any(|f| rope(&fix.bytes, top + ROPE_LEN * l.node, f) != ROPE_EXIT))
            .expect("a link inside the root cube");
        let rec = top + ROPE_LEN * link.node;
        let inner = (0..6)
            .find(|&f| rope(&fix.bytes, rec, f) != ROPE_EXIT)
            .expect("a face inside");
        let old = rope(&fix.bytes, rec, inner);
        assert!(
            old & ROPE_TOP != 0,
            "{}: a top-tree rope has bit 31",
            fix.name
        );
        let place = format!("the link at node {} face {inner}", link.node);
        let f = Space::File;
        cases.extend(
            [
                (
                    format!("{place}: the exit"),
                    f,
                    rec + 4 * inner,
                    u32le(ROPE_EXIT),
                ),
                (
                    format!("{place}: without its top bit"),
                    f,
                    rec + 4 * inner,
                    u32le(old & !ROPE_TOP),
                ),
                (
                    format!("{place}: past the top tree's {top_nodes} nodes"),
                    f,
                    rec + 4 * inner,
                    u32le(ROPE_TOP | top_nodes),
                ),
                (
                    format!("{place}: the link itself"),
                    f,
                    rec + 4 * inner,
                    u32le(ROPE_TOP | link.node as u32),
                ),
            ]
            .map(|(w, s, a, n)| (w, s, a, n, "rope".to_string(), vec![])),
        );
        if let Some(exit) = (0..6).find(|&f| rope(&fix.bytes, rec, f) == ROPE_EXIT) {
            cases.push((
                format!(
                    "the link at node {} face {exit}: the root, not the exit",
                    link.node
                ),
                f,
                rec + 4 * exit,
                u32le(ROPE_TOP),
                "rope".into(),
                vec![],
            ));
        }
        assert_eq!(
            top_kinds[0], KIND_INTERNAL,
            "{}: the root is internal",
            fix.name
        );
        cases.push((
            "the top tree's root given a rope".into(),
            f,
            top,
            u32le(ROPE_TOP | 1),
            "rope".into(),
            vec![],
        ));

        // The largest block: a leaf's ropes, an internal node's, the header's rope_count.
        let blk = fix.largest;
        let raw = &fix.decoded[blk];
        let parts = block_parts(raw);
        let (ropes, b) = (parts[PART_ROPES].start, Space::Block(blk));
        let block_kinds = kinds(&raw[parts[1].clone()]);
        let n = block_kinds.len() as u32;
        // A leaf (solid or empty) with a face inside the root cube.
        let leaf = (0..block_kinds.len())
            .filter(|&i| block_kinds[i] != KIND_INTERNAL && block_kinds[i] != KIND_LINK)
            .find(|&i| (0..6).any(|f| rope(raw, ropes + ROPE_LEN * i, f) != ROPE_EXIT))
            .expect("a leaf inside the root cube");
        let rec = ropes + ROPE_LEN * leaf;
        let inner = (0..6)
            .find(|&f| rope(raw, rec, f) != ROPE_EXIT)
            .expect("a face inside");
        let old = rope(raw, rec, inner);
        let place = format!("block {blk}'s leaf {leaf} face {inner} (rope {old:#x})");
        cases.extend(
            [
                (
                    format!("{place}: the exit"),
                    b,
                    rec + 4 * inner,
                    u32le(ROPE_EXIT),
                ),
                (
                    format!("{place}: to the other unit"),
                    b,
                    rec + 4 * inner,
                    u32le(old ^ ROPE_TOP),
                ),
                (
                    format!("{place}: past the block's {n} nodes"),
                    b,
                    rec + 4 * inner,
                    u32le(n),
                ),
                (
                    format!("{place}: the leaf itself"),
                    b,
                    rec + 4 * inner,
                    u32le(leaf as u32),
                ),
            ]
            .map(|(w, s, a, n)| (w, s, a, n, "rope".to_string(), vec![])),
        );
        if let Some(i) = block_kinds.iter().position(|&k| k == KIND_INTERNAL) {
            cases.push((
                format!("block {blk}'s internal node {i} given a rope"),
                b,
                ropes + ROPE_LEN * i,
                u32le(1),
                "rope".into(),
                vec![],
            ));
        }
        for (what, v) in [("0", 0u64), ("one more than its nodes", n as u64 + 1)] {
            cases.push((
                format!("block {blk}'s header: rope_count {what}"),
                b,
                BH_ROPE_COUNT,
                v.to_le_bytes().to_vec(),
                format!("block {blk}"),
                vec![blk],
            ));
        }
        eprintln!(
            "{}: {} rewritten ropes and rope counts",
            fix.name,
            cases.len()
        );
        for (what, space, at, new, defect, fails_on) in cases {
            let bytes = fix.rewrite(space, at, &new);
            assert!(bytes != fix.bytes, "{}: {what}: nothing changed", fix.name);
            let what = format!("{}: {what}", fix.name);
            expect_caught(fix, what, bytes, &defect, &fails_on, &mut problems);
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The top tree's wide nodes and wide links (§8.7) rewritten, checksums recomputed: a child box
/// of the root's wide node and of the last wide node grown or shrunk by one step, and a wide
/// link's box moved by the smallest step (as a block changed by hand would leave it). Nothing
/// but the layout says what those boxes are: verify lays the top tree's wide nodes out again
/// and compares each block root's box with its wide link's, and must report each, by index
/// (the wide node) or by block and root (the link); tracing returns, answers or an error,
/// never a panic or an endless walk.
#[test]
fn top_wide_nodes_and_links_rewritten_are_caught() {
    let mut problems = Vec::new();
    for fix in [default_file(), default_zstd_file(), deep_file()] {
        let (nodes, len) = section_of(&fix.bytes, KIND_WIDE_NODES).expect("wide nodes");
        let count = len / CLUSTER_NODE_LEN;
        assert!(count >= 2, "{}: {count} top wide nodes", fix.name);
        for i in [0, count - 1] {
            let at = nodes + i * CLUSTER_NODE_LEN;
            let (lo, hi) = (at + CN_LO, at + CN_HI);
            let b0 = &fix.bytes;
            let (what, at, new) = match (b0[hi] < 255, b0[lo] < b0[hi]) {
                (true, _) => ("child 0's box grown along +x", hi, b0[hi] + 1),
                (false, true) => ("child 0's box shrunk along -x", lo, b0[lo] + 1),
                (false, false) => ("child 0's box grown along -x", lo, b0[lo] - 1),
            };
            let b = fix.rewrite(Space::File, at, &[new]);
            let what = format!("{}: top wide node {i}: {what}", fix.name);
            let defect = format!("wide nodes section node {i}: child 0's box");
            let reported = |d: &str| d.starts_with(&defect);
            expect_reported(fix, what, b, &defect, &reported, &[], &mut problems);
        }
        let links = wide_links(&fix.bytes);
        for w in [links[0], links[links.len() / 2], links[links.len() - 1]] {
            for (k, side) in [(0, "lo x"), (2, "hi z")] {
                // The next f32 outward: lower for lo, higher for hi.
                let (at, x) = match side {
                    "lo x" => (w.at + WL_LO + 4 * k, w.lo[k]),
                    _ => (w.at + WL_HI + 4 * k, w.hi[k]),
                };
                let down = side.starts_with("lo");
                let moved = match (x == 0.0, (x > 0.0) == down) {
                    (true, _) => f32::from_bits(if down { 0x8000_0001 } else { 1 }),
                    (false, true) => f32::from_bits(x.to_bits() - 1),
                    (false, false) => f32::from_bits(x.to_bits() + 1),
                };
                assert!(moved.is_finite() && (moved < x) == down && moved != x);
                let b = fix.rewrite(Space::File, at, &moved.to_le_bytes());
                let what = format!(
                    "{}: the wide link of block {} root {}: {side} {x} -> {moved}",
                    fix.name, w.block, w.root
                );
                let defect = format!("block {}: root {}'s wide link has the box", w.block, w.root);
                let reported = |d: &str| d.starts_with(&defect);
                expect_reported(fix, what, b, &defect, &reported, &[], &mut problems);
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
