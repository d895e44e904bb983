//! Corrupted `.oavm` files (format-spec.md §11): damage to the block directory (§8.2: its
//! entries rewritten field by field, made free, two blocks in each other's place) and to the
//! blocks (§8.3): zstd frames that lie, damaged blocks traced under a memory budget of a few
//! blocks, the tree's records inside them (§4.3 rank words, in the top tree too; §7.1–§7.2
//! cluster nodes and triangle groups, cycles among them) and the padding between their parts.
//!
//! What must hold, the files damaged and how the runs report are in `tests/corruption/fixtures`
//! (its module doc), with the fixtures and the harness these files share.

use oavm::Scene;
use oavm::logical::{SceneOptions, Walk};
use oavm::physical::AlignedBytes;

use crate::fixtures::*;

// ---------------------------------------------------------------------------------------------
// The block directory (§8.2)

/// Every field of a directory entry rewritten (checksums recomputed over whatever the entry
/// now describes): the file opens (the directory is not read at open), verify names the block,
/// and tracing, which needs the block, fails naming it: the pager checks the entry, the
/// checksum and the decoding, and the block's header is checked against its entry (all but the
/// `triangles` of a block of clusters, which only verify checks: [`triangles_checked_by_pager`]).
#[test]
fn directory_entries_rewritten_field_by_field_are_caught() {
    let mut problems = Vec::new();
    for fix in [
        default_file(),
        default_zstd_file(),
        list_file(),
        deep_zstd_file(),
    ] {
        for &blk in &fix.detailed {
            let e = fix.dir[blk];
            let entry = dir_entry_at(&fix.bytes, blk);
            let neighbour = fix.dir[if blk == 0 { 1 } else { blk - 1 }];
            let (hs, hr) = (e.head_stored_len as u64, e.head_raw_len as u64);
            let u64_cases: [(usize, &str, Vec<u64>); 5] = [
                (
                    DIR_OFFSET,
                    "offset",
                    vec![
                        0,
                        e.offset as u64 + 64,
                        e.offset as u64 - 64,
                        e.offset as u64 + 4096,
                        neighbour.offset as u64,
                        fix.bytes.len() as u64,
                        u64::MAX - 7,
                    ],
                ),
                (
                    DIR_STORED_LEN,
                    "stored_len",
                    vec![
                        0,
                        1,
                        e.stored_len as u64 - 1,
                        e.stored_len as u64 + 1,
                        e.stored_len as u64 + 64,
                        u64::MAX,
                    ],
                ),
                (
                    DIR_RAW_LEN,
                    "raw_len",
                    vec![
                        0,
                        63,
                        e.raw_len as u64 - 8,
                        e.raw_len as u64 + 8,
                        fix.max_raw + 1,
                        1 << 30,
                        u64::MAX,
                    ],
                ),
                // §8.2: the head's lengths (the head checksum recomputed over the head the
                // entry now gives; the chunks' offsets count from its end).
                (
                    DIR_HEAD_STORED_LEN,
                    "head_stored_len",
                    vec![
                        0,
                        1,
                        hs - 1,
                        hs + 1,
                        hs + 64,
                        e.stored_len as u64,
                        e.stored_len as u64 + 1,
                        u64::MAX,
                    ],
                ),
                (
                    DIR_HEAD_RAW_LEN,
                    "head_raw_len",
                    vec![
                        0,
                        hr - 1,
                        hr + 1,
                        hr + 160,
                        hr.saturating_sub(4096),
                        hr + 4096,
                        e.raw_len as u64,
                        e.raw_len as u64 + 1,
                        u64::MAX,
                    ],
                ),
            ];
            let u32_cases: [(usize, &str, Vec<u32>); 4] = [
                (DIR_CODEC, "codec", vec![1 - e.codec, 2, u32::MAX]),
                (
                    DIR_ROOT_LEVEL,
                    "root_level",
                    vec![0, e.root_level + 1, e.root_level - 1, 21, 22, u32::MAX],
                ),
                (
                    DIR_ROOT_COUNT,
                    "root_count",
                    vec![0, e.root_count + 1, e.root_count - 1, u32::MAX],
                ),
                (
                    DIR_TRIANGLES,
                    "triangles",
                    vec![0, read_u32(&fix.bytes, entry + DIR_TRIANGLES) + 1, u32::MAX],
                ),
            ];
            let mut cases: Vec<(String, usize, Vec<u8>)> = Vec::new();
            for (at, name, values) in u64_cases {
                for v in values {
                    cases.push((format!("{name} {v}"), at, v.to_le_bytes().to_vec()));
                }
            }
            for (at, name, values) in u32_cases {
                for v in values {
                    cases.push((format!("{name} {v}"), at, v.to_le_bytes().to_vec()));
                }
            }
            for (change, at, new) in cases {
                let mut b = fix.bytes.clone();
                b[entry + at..entry + at + new.len()].copy_from_slice(&new);
                fix_checksums(&mut b);
                if b == fix.bytes {
                    continue; // root_count - 1 of 1 root is 0, and so on
                }
                let what = format!("{}: block {blk}'s entry: {change}", fix.name);
                let defect = format!("block {blk}");
                let fails_on = match at {
                    DIR_TRIANGLES if !triangles_checked_by_pager(fix) => vec![],
                    _ => vec![blk],
                };
                expect_caught(fix, what, b, &defect, &fails_on, &mut problems);
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Free directory entries (§8.2: all 64 bytes zero, what an update leaves where it removed a
/// block): a file as packed has none, so an entry zeroed there is reported, naming the block,
/// and tracing, which needs it, fails naming it. A later generation may have them (the updated
/// fixture has some and verifies clean), but no link may lead to one (nor, in a file of
/// clusters, the wide link beside it, §8.7, which the walk follows).
#[test]
fn free_entries_are_checked() {
    let mut problems = Vec::new();
    for fix in [default_file(), list_zstd_file(), updatable_file()] {
        let blk = fix.largest;
        let mut b = fix.bytes.clone();
        let e = dir_entry_at(&b, blk);
        b[e..e + DIR_LEN].fill(0);
        fix_checksums(&mut b);
        let what = format!("{}: block {blk}'s entry made free", fix.name);
        let defect = format!("block {blk}: a free entry in a generation-1 file");
        expect_caught(fix, what, b, &defect, &[blk], &mut problems);
    }
    let fix = updated_file();
    let free: Vec<usize> = (0..fix.dir.len()).filter(|&b| fix.dir[b].free).collect();
    assert!(!free.is_empty(), "{}: no free entry", fix.name);
    for &blk in &free {
        // The link to a block's first root (a ray of the fixture starts inside its bounds, so
        // its walk takes the link), sent to the free entry.
        let firsts: Vec<&Link> = fix.links.iter().filter(|l| l.root == 0).collect();
        let l = *firsts[firsts.len() / 2];
        let mut b = fix.bytes.clone();
        relink(&mut b, l.node, (l.block, l.root), (blk as u32, 0));
        fix_checksums_at(&mut b, fix.slot);
        let what = format!(
            "{}: the link to block {} root {} sent to free entry {blk}",
            fix.name, l.block, l.root
        );
        expect_caught(fix, what, b, &format!("block {blk}"), &[blk], &mut problems);
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Two blocks' directory entries swapped (each entry then describes the other block's bytes,
/// checksums and all): each block's header names its own id, so the exchange is caught.
#[test]
fn a_block_in_another_blocks_place_is_caught() {
    let mut problems = Vec::new();
    for fix in [default_file(), list_file(), deep_zstd_file()] {
        let n = fix.dir.len();
        // Two neighbours alike in their entries' other fields, if there are; else the first two.
        let pair = (0..n - 1)
            .map(|i| (i, i + 1))
            .find(|&(i, j)| {
                let (a, b) = (fix.dir[i], fix.dir[j]);
                a.root_level == b.root_level && a.root_count == b.root_count
            })
            .unwrap_or((0, 1));
        let (i, j) = pair;
        let mut b = fix.bytes.clone();
        let (ei, ej) = (dir_entry_at(&b, i), dir_entry_at(&b, j));
        let old_i = b[ei..ei + DIR_LEN].to_vec();
        b.copy_within(ej..ej + DIR_LEN, ei);
        b[ej..ej + DIR_LEN].copy_from_slice(&old_i);
        fix_checksums(&mut b);
        let what = format!("{}: entries of blocks {i} and {j} swapped", fix.name);
        expect_caught(fix, what, b, "another block's id", &[i, j], &mut problems);
        // The same with the stored bytes swapped in place instead (raw blocks of one size
        // only): the directory is intact, the bytes are not the blocks it describes.
        if fix.dir[i].codec == CODEC_RAW {
            let same_len = (0..n)
                .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
                .find(|&(i, j)| fix.dir[i].stored_len == fix.dir[j].stored_len);
            if let Some((i, j)) = same_len {
                let mut b = fix.bytes.clone();
                let (ri, rj) = (fix.dir[i].stored(), fix.dir[j].stored());
                let old_i = b[ri.clone()].to_vec();
                b.copy_within(rj.clone(), ri.start);
                b[rj].copy_from_slice(&old_i);
                fix_checksums(&mut b);
                let what = format!("{}: bytes of blocks {i} and {j} swapped", fix.name);
                expect_caught(fix, what, b, "block", &[i, j], &mut problems);
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Compressed blocks, and blocks under a budget (§8.2, §8.3)

/// Compressed blocks whose head's frame lies about the head (§8.2; checksums recomputed):
/// content longer or shorter than `head_raw_len`, a truncated frame, two frames, another
/// block's head, a frame that decodes to far more than `max_block_raw_len` (which must not be
/// allocated), garbage. Verify names the block, tracing fails naming it. And a frame without a
/// recorded content size, which the spec allows, is read as the intact block. Then the same for
/// one chunk's frame (§8.3: the chunk table made to describe the lying chunk, its checksum
/// recomputed, the head compressed again): the error names the block and the chunk.
#[test]
fn zstd_frames_that_lie_are_caught() {
    let mut problems = Vec::new();
    for fix in [default_zstd_file(), list_zstd_file(), deep_zstd_file()] {
        let blk = fix.largest;
        let e = fix.dir[blk];
        let raw = &fix.decoded[blk];
        let head = &raw[..e.head_raw_len];
        let frame = &fix.bytes[e.head()];
        let chunks = &fix.bytes[e.head().end..e.stored().end];
        let other = fix.dir[if blk == 0 { 1 } else { 0 }];
        let stored = |lie: &[u8]| StoredBlock {
            bytes: [lie, chunks].concat(),
            head_stored_len: lie.len(),
            head_raw_len: e.head_raw_len,
            raw_len: e.raw_len,
        };
        for (what, lie) in lies(head, frame, &fix.bytes[other.head()]) {
            let b = relayout(&fix.bytes, blk, &stored(&lie));
            let what = format!("{}: block {blk}'s head: {what}", fix.name);
            expect_caught(fix, what, b, &format!("block {blk}"), &[blk], &mut problems);
        }
        // No content size in the frame: the same block.
        let bare = bare_frame(head);
        assert_ne!(bare, frame, "the frame changed");
        let b = relayout(&fix.bytes, blk, &stored(&bare));
        let what = format!("{}: block {blk}'s head without its content size", fix.name);
        expect_intact(fix, what, b, &mut problems);

        // A chunk's frame (§8.3): the first compressed chunk of the block, and its last chunk
        // if that is compressed too.
        let table = chunk_table(head);
        let compressed: Vec<usize> = (0..table.len())
            .filter(|&c| table[c].stored_len < fix.chunk_raw_len(blk, c))
            .collect();
        if fix.clusters {
            assert!(
                !compressed.is_empty(),
                "{}: block {blk} has no compressed chunk ({} chunks)",
                fix.name,
                table.len()
            );
        }
        let mut tried = compressed.first().copied().into_iter().collect::<Vec<_>>();
        tried.extend(compressed.last().copied().filter(|&c| c + 1 == table.len()));
        tried.dedup();
        for c in tried {
            let ce = table[c];
            let groups = &raw[e.head_raw_len..][c * fix.chunk_groups * TRI_GROUP_LEN..]
                [..fix.chunk_raw_len(blk, c)];
            let frame = &chunks[ce.offset..ce.offset + ce.stored_len];
            let another = &chunks[..table[0].stored_len];
            let stored_with = |lie: &[u8]| {
                let mut stored: Vec<Vec<u8>> = table
                    .iter()
                    .map(|ce| chunks[ce.offset..ce.offset + ce.stored_len].to_vec())
                    .collect();
                stored[c] = lie.to_vec();
                let mut head = head.to_vec();
                write_chunk_table(&mut head, &stored);
                store_head(&head, &stored, CODEC_ZSTD, e.raw_len)
            };
            let mut cases = lies(groups, frame, another);
            // A raw chunk one byte short (§8.3: shorter than its groups, so taken for a frame).
            cases.push(("its groups raw, one byte short", groups[1..].to_vec()));
            for (what, lie) in cases {
                if lie == frame {
                    continue; // another chunk's frame, when the chunk is the first
                }
                let b = relayout(&fix.bytes, blk, &stored_with(&lie));
                let what = format!("{}: block {blk} chunk {c}: {what}", fix.name);
                let said = format!("block {blk}: chunk {c}: ");
                let reported = |d: &str| d.starts_with(&said);
                expect_reported(fix, what, b, &said, &reported, &[blk], &mut problems);
            }
            let b = relayout(&fix.bytes, blk, &stored_with(&bare_frame(groups)));
            let what = format!(
                "{}: block {blk} chunk {c} without its content size",
                fix.name
            );
            expect_intact(fix, what, b, &mut problems);
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// zstd frames that lie about `raw`, whose frame is `frame` (§8.2, §8.3): content longer or
/// shorter, cut, twice, `another` frame, a frame of 64 MiB of zeros, garbage after the magic,
/// nothing.
fn lies(raw: &[u8], frame: &[u8], another: &[u8]) -> Vec<(&'static str, Vec<u8>)> {
    let mut longer = raw.to_vec();
    longer.extend_from_slice(&[0u8; 100]);
    let mut twice = frame.to_vec();
    twice.extend_from_slice(frame);
    let mut garbage = frame.to_vec();
    for (i, x) in garbage.iter_mut().enumerate().skip(4) {
        *x = (i * 131) as u8;
    }
    vec![
        ("content 100 bytes longer", zstd_frame(&longer)),
        (
            "content 64 bytes shorter",
            zstd_frame(&raw[..raw.len() - 64]),
        ),
        ("frame cut by 1 byte", frame[..frame.len() - 1].to_vec()),
        ("frame cut in half", frame[..frame.len() / 2].to_vec()),
        ("the frame twice", twice),
        ("another frame", another.to_vec()),
        ("64 MiB of zeros", zstd_frame(&vec![0u8; 64 << 20])),
        ("garbage after the magic", garbage),
        ("empty", Vec::new()),
    ]
}

/// `raw` compressed as the writer does (zstd level 3), but without the content size in the
/// frame (which the spec allows).
fn bare_frame(raw: &[u8]) -> Vec<u8> {
    let mut c = zstd::bulk::Compressor::new(3).expect("zstd");
    c.set_parameter(zstd::zstd_safe::CParameter::ContentSizeFlag(false))
        .expect("zstd parameter");
    c.compress(raw).expect("compress")
}

/// `bytes` must read as the intact file: open as its generation, trace (unbounded and under a
/// tight budget) as it does, verify clean.
fn expect_intact(fix: &'static Fixture, what: String, bytes: Vec<u8>, problems: &mut Vec<String>) {
    match evaluate_guarded(fix, bytes, true, &what) {
        Ok(Verdict::Opened {
            generation,
            traced: Ok(Traced::Same),
            tight: Some(Ok(Traced::Same)),
            defects: Ok(d),
        }) if d.is_empty() && generation == fix.generation => {}
        v => problems.push(format!("{what}: should read as the intact file: {v:?}")),
    }
}

/// Under a budget of a few blocks on 2 threads, the intact files trace as without a budget
/// (blocks evicted and read again); with three blocks damaged on disk, every batch fails,
/// naming a damaged block, again and again (a failed block stays failed), and never panics.
/// Streamed, and chunked where the file has chunks (§8.3: heads paged, chunks read as walks
/// reach them, a damaged one named with its block).
#[test]
fn damaged_blocks_under_a_tiny_budget_fail_by_name() {
    let fixtures = [
        default_file(),
        default_zstd_file(),
        list_zstd_file(),
        deep_file(),
        roped_file(),
        occluded_zstd_file(),
    ];
    for (fix, chunks) in fixtures.into_iter().flat_map(|f| [(f, false), (f, true)]) {
        let opts = SceneOptions {
            chunks,
            ..tight_options(fix)
        };
        let scene =
            Scene::from_bytes_with(AlignedBytes::from_slice(&fix.bytes), "tight.oavm", &opts)
                .expect("opens");
        let walks_clusters =
            fix.clusters && matches!(fix.walk, Walk::Auto | Walk::Wide | Walk::TopDown);
        assert_eq!(
            scene.chunked(),
            chunks && walks_clusters,
            "{}: chunked",
            fix.name
        );
        for round in 0..2 {
            let t = pool2().install(|| trace(fix, &scene));
            assert_eq!(t, Traced::Same, "{}: intact, round {round}", fix.name);
        }
        let budget = scene.budget();
        assert_eq!(budget, 5 * fix.held, "{}: never raised", fix.name);
        // (Chunked, a thread also needs a chunk's slot: the budget may hold one thread.)
        if !scene.chunked() {
            assert_eq!(scene.threads(), 2, "{}", fix.name);
        }
        assert!(
            scene.peak_resident_bytes() <= budget,
            "{}: peak {} over the budget {budget}",
            fix.name,
            scene.peak_resident_bytes()
        );

        let mut damaged = vec![0, fix.largest, fix.dir.len() / 2];
        damaged.sort_unstable();
        damaged.dedup();
        let mut b = fix.bytes.clone();
        // What the pager says of each: its head's checksum or a chunk's (§8.2, §8.3).
        let mut errors = Vec::new();
        for &blk in &damaged {
            let at = fix.dir[blk].offset + fix.dir[blk].stored_len / 2;
            b[at] ^= 0x40;
            errors.push(fix.checksum_error(blk, at));
        }
        let what = format!("{}: blocks {damaged:?} damaged, chunks {chunks}", fix.name);
        let w = what.clone();
        let result = guarded(&|| w.clone(), move || {
            let scene = Scene::from_bytes_with(AlignedBytes::from_slice(&b), "tight.oavm", &opts)
                .expect("opens");
            (0..3)
                .map(|_| pool2().install(|| trace(fix, &scene)))
                .collect::<Vec<Traced>>()
        });
        match result {
            Err(panic) => panic!("{what}: {panic}"),
            Ok(rounds) => {
                for t in rounds {
                    match t {
                        Traced::Error(e) if errors.iter().any(|x| e.contains(x.as_str())) => {}
                        t => panic!("{what}: should fail naming a damaged block: {t:?}"),
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Chunks (§8.2, §8.3): a block's groups stored in chunks, each under its own checksum in the
//    head's chunk table

/// The chunks of block `blk` tried: the first, one in the middle and the last; the block
/// must have several (the fixtures cut blocks into chunks of 8 groups).
fn tried_chunks(fix: &Fixture, blk: usize) -> Vec<usize> {
    let e = fix.dir[blk];
    let n = chunk_table(&fix.decoded[blk][..e.head_raw_len]).len();
    assert!(
        n >= 3,
        "{}: block {blk} has {n} chunks, want several",
        fix.name
    );
    let mut tried = vec![0, n / 2, n - 1];
    tried.dedup();
    tried
}

/// A chunk's stored bytes damaged (§8.3): a byte flipped on disk, nothing recomputed (in the
/// middle of the chunk, and its last byte); its groups changed with every other checksum
/// recomputed (a compressed block decoded, changed, stored again: the chunk's new bytes under
/// its old checksum); its checksum in the head's chunk table changed, every other checksum
/// recomputed. In raw and compressed blocks, and in an updated file's block: the pager refuses
/// the block and verify reports it, naming the block and the chunk, word for word.
#[test]
fn damaged_chunks_are_caught_by_their_checksum() {
    let mut problems = Vec::new();
    for fix in [
        default_file(),
        default_zstd_file(),
        default_lean_file(),
        deep_file(),
        deep_zstd_file(),
        updated_file(),
    ] {
        let blk = fix.largest;
        let e = fix.dir[blk];
        let raw = &fix.decoded[blk];
        let table = chunk_table(&raw[..e.head_raw_len]);
        for c in tried_chunks(fix, blk) {
            let ce = table[c];
            let text = format!("block {blk}: chunk {c}: checksum mismatch");
            let start = e.head().end + ce.offset;
            for at in [start + ce.stored_len / 2, start + ce.stored_len - 1] {
                assert_eq!(fix.chunk_of(blk, at), Some(c));
                let mut b = fix.bytes.clone();
                b[at] ^= 0x08;
                let what = format!("{}: block {blk} chunk {c}: byte {at} flipped", fix.name);
                expect_error_text(fix, what, b, &text, &mut problems);
            }
            // The lowest bit of the first x of the chunk's first group (§7.2), the chunk
            // stored again and every checksum but its own recomputed.
            let group = e.head_raw_len + c * fix.chunk_groups * TRI_GROUP_LEN;
            let b = fix.rewrite_with(Space::Block(blk), group, &[raw[group] ^ 1], false);
            let what = format!(
                "{}: block {blk} chunk {c}: its first group changed, its checksum kept",
                fix.name
            );
            expect_error_text(fix, what, b, &text, &mut problems);
            let sum = ce.at + CE_CHECKSUM;
            for (how, at, new) in [
                ("bit 0 flipped", sum, raw[sum] ^ 1),
                ("byte 7 zeroed", sum + 7, 0),
            ] {
                if raw[at] == new {
                    continue;
                }
                let b = fix.rewrite_with(Space::Block(blk), at, &[new], false);
                assert!(b != fix.bytes, "{}: nothing changed", fix.name);
                let what = format!(
                    "{}: block {blk} chunk {c}: its checksum's {how}, the head's recomputed",
                    fix.name
                );
                expect_error_text(fix, what, b, &text, &mut problems);
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// A lean chunk (§7.3) whose bytes are malformed under a right checksum (every checksum
/// recomputed, as a tool that wrote it would): a group's width code 3, a slot past the corners
/// it stores, and a group cut short (the chunk's last byte dropped). The pager refuses the
/// block and verify reports it, naming the block, the chunk and the group, word for word.
#[test]
fn malformed_lean_chunks_are_caught() {
    let mut problems = Vec::new();
    let fix = default_lean_file();
    let blk = fix.largest;
    let e = fix.dir[blk];
    let table = chunk_table(&fix.decoded[blk][..e.head_raw_len]);
    for c in tried_chunks(fix, blk) {
        let ce = table[c];
        let start = e.head().end + ce.offset;
        let b0 = fix.bytes[start];
        let corners = (b0 >> 3 & 7) as usize + 1;
        let count = (b0 & 7) as usize + 1;
        let prefix = format!("block {blk}: chunk {c}: lean group 0 (byte 0): ");
        // Group 0's byte 0: width code 3; one corner fewer than its slots name (the highest
        // slot is then past them).
        let mut cases = vec![(
            "width code 3".to_string(),
            vec![b0 | 0xC0],
            format!("{prefix}a group with an unknown id width"),
        )];
        if corners > 1 {
            cases.push((
                "one corner fewer".to_string(),
                vec![b0 - 8],
                format!("{prefix}lane"),
            ));
        }
        for (what, new, text) in cases {
            let b = fix.rewrite(Space::File, start, &new);
            let what = format!(
                "{}: block {blk} chunk {c}: {what} ({count} lanes)",
                fix.name
            );
            expect_error_text(fix, what, b, &text, &mut problems);
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// A chunk table entry's `offset` or `stored_len` rewritten (§8.3; every checksum recomputed
/// over what the entries then give, the head's too): chunks must follow each other from the
/// head's end, each as long as its groups (raw) or shorter and within 64 times (a frame, in a
/// compressed block only), the last ending the block. The pager refuses the block and verify
/// reports it, naming the block and the first chunk that breaks the rule, word for word.
#[test]
fn chunk_table_entries_rewritten_are_caught() {
    let mut problems = Vec::new();
    for fix in [
        default_file(),
        default_zstd_file(),
        deep_zstd_file(),
        updated_file(),
    ] {
        let blk = fix.largest;
        let e = fix.dir[blk];
        let raw = &fix.decoded[blk];
        let table = chunk_table(&raw[..e.head_raw_len]);
        let n = table.len();
        for c in tried_chunks(fix, blk) {
            let ce = table[c];
            let raw_len = fix.chunk_raw_len(blk, c);
            // (what, field, new value, the text the error must contain)
            let mut cases: Vec<(String, usize, u32, String)> = Vec::new();
            let chunk_c = format!("block {blk}: chunk {c}: ");
            let off = ce.offset as u32;
            let mut offsets = vec![off + 1, off + 64, u32::MAX, 0];
            offsets.extend(off.checked_sub(1));
            offsets.extend(table.get(c + 1).map(|n| n.offset as u32));
            for v in offsets.into_iter().filter(|&v| v != off) {
                // Where the chunk was expected, and is not (§8.3).
                let text = format!(
                    "{chunk_c}{} bytes stored at {v} after the head",
                    ce.stored_len
                );
                cases.push((format!("offset {v}"), CE_OFFSET, v, text));
            }
            let len = ce.stored_len as u32;
            let mut lens = vec![0, len + 1, raw_len as u32 + 1, raw_len as u32, u32::MAX];
            lens.extend(len.checked_sub(1));
            for v in lens.into_iter().filter(|&v| v != len) {
                let v64 = v as usize;
                let fits = v64 == raw_len
                    || e.codec == CODEC_ZSTD && v64 < raw_len && raw_len <= MAX_ZSTD_RATIO * v64;
                // A length the chunk cannot have is its own error; one it could have moves
                // the next chunk, or the end of the chunks, off the block's.
                let text = match (fits, c + 1 < n) {
                    (false, _) => format!("{chunk_c}{v} bytes stored at {off}"),
                    (true, true) => format!(
                        "block {blk}: chunk {}: {} bytes stored at {} after the head",
                        c + 1,
                        table[c + 1].stored_len,
                        table[c + 1].offset
                    ),
                    (true, false) => format!(
                        "block {blk}: chunks end {} bytes after the head",
                        ce.offset + v64
                    ),
                };
                cases.push((format!("stored_len {v}"), CE_STORED_LEN, v, text));
            }
            for (change, field, v, text) in cases {
                let b = fix.rewrite(Space::Block(blk), ce.at + field, &v.to_le_bytes());
                assert!(b != fix.bytes, "{}: {change}: nothing changed", fix.name);
                let what = format!("{}: block {blk} chunk {c}'s entry: {change}", fix.name);
                expect_error_text(fix, what, b, &text, &mut problems);
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Cluster nodes and triangle groups (§7.1, §7.2)

/// §4.2, §7.1: the cluster roots of a decoded block, the `payload` of each solid leaf, in the
/// order of the block's node records.
fn cluster_roots(raw: &[u8]) -> Vec<usize> {
    let nodes = block_parts(raw)[1].clone();
    nodes
        .step_by(8)
        .filter(|&at| read_u32(raw, at + 4) >> 30 == KIND_SOLID)
        .map(|at| read_u32(raw, at) as usize)
        .collect()
}

/// Cluster nodes and triangle groups (§7.1, §7.2) rewritten one field at a time, checksums
/// recomputed, in the largest block of each file of clusters: children sent back to the node
/// itself or to its parent (a cycle), past the block's nodes or groups, child counts out of
/// range, a bad exponent, a box turned inside out or shrunk off its triangles, groups with no
/// lanes, too many, a corner slot past the eight, a corner that is not finite. Verify names the
/// block; tracing (unverified, and under a tight budget) returns, answers or an error, never a
/// panic or an endless walk.
#[test]
fn cluster_nodes_and_groups_rewritten_are_caught() {
    let mut problems = Vec::new();
    for fix in [default_file(), default_zstd_file(), deep_file()] {
        let blk = fix.largest;
        let raw = &fix.decoded[blk];
        let parts = block_parts(raw);
        let (nodes, groups) = (
            parts[PART_CLUSTER_NODES].clone(),
            parts[PART_GROUPS].clone(),
        );
        let (n_nodes, n_groups) = (nodes.len() / CLUSTER_NODE_LEN, groups.len() / TRI_GROUP_LEN);
        let node_at = |i: usize| nodes.start + i * CLUSTER_NODE_LEN;
        let group_at = |i: usize| groups.start + i * TRI_GROUP_LEN;
        // The first cluster's root, and a node with an inner child and one with a group.
        let root = cluster_roots(raw)[0];
        let inner_count = |i: usize| raw[node_at(i) + CN_INNER_COUNT];
        let child_count = |i: usize| raw[node_at(i) + CN_CHILD_COUNT];
        let with_inner = (0..n_nodes).find(|&i| inner_count(i) > 0);
        let with_group = (0..n_nodes)
            .find(|&i| inner_count(i) < child_count(i))
            .expect("a node with a group");
        let u32le = |v: u32| v.to_le_bytes().to_vec();
        // (what, offset in the block, new bytes)
        let mut cases: Vec<(String, usize, Vec<u8>)> = vec![
            (
                format!("root {root}'s first child is the root itself"),
                node_at(root) + CN_NODE_BASE,
                [
                    u32le(root as u32),
                    raw[node_at(root) + 20..node_at(root) + 24].to_vec(),
                    vec![1],
                ]
                .concat(),
            ),
            (
                format!("node {with_group}'s groups start past the block's {n_groups}"),
                node_at(with_group) + CN_GROUP_BASE,
                u32le(n_groups as u32),
            ),
            (
                format!("node {with_group}'s groups start at u32::MAX"),
                node_at(with_group) + CN_GROUP_BASE,
                u32le(u32::MAX),
            ),
            (
                format!("node {root} has no children"),
                node_at(root) + CN_CHILD_COUNT,
                vec![0],
            ),
            (
                format!("node {root} has 9 children"),
                node_at(root) + CN_CHILD_COUNT,
                vec![9],
            ),
            (
                format!("node {root} has more inner children than children"),
                node_at(root) + CN_INNER_COUNT,
                vec![child_count(root) + 1],
            ),
            (
                format!("node {root}'s x exponent is 101"),
                node_at(root) + CN_EXP,
                vec![101],
            ),
            (
                format!("node {root}'s x origin is NaN"),
                node_at(root) + CN_ORIGIN,
                f32::NAN.to_le_bytes().to_vec(),
            ),
            (
                format!("node {root}'s first child box has lo 1 > hi 0 along x"),
                node_at(root) + CN_LO,
                {
                    let mut v = raw[node_at(root) + CN_LO..=node_at(root) + CN_HI].to_vec();
                    (v[0], v[CN_HI - CN_LO]) = (1, 0);
                    v
                },
            ),
            (
                format!("node {with_group}'s boxes shrunk to their lowest corner"),
                node_at(with_group) + CN_HI,
                vec![0; 24],
            ),
            (
                "group 0 has no lanes".into(),
                group_at(0) + TG_COUNT,
                u32le(0),
            ),
            (
                "group 0 has 9 lanes".into(),
                group_at(0) + TG_COUNT,
                u32le(9),
            ),
            (
                "group 0's first lane's first corner is slot 8".into(),
                group_at(0) + TG_TRI,
                vec![8],
            ),
            (
                "group 0's first lane's first corner is slot 255".into(),
                group_at(0) + TG_TRI,
                vec![255],
            ),
            (
                "group 0's first corner's x is infinite".into(),
                group_at(0) + TG_CORNER,
                f32::INFINITY.to_le_bytes().to_vec(),
            ),
            (
                format!("group {}'s reserved word is not zero", n_groups - 1),
                group_at(n_groups - 1) + TG_COUNT + 4,
                u32le(1),
            ),
        ];
        if let Some(p) = with_inner {
            let child = read_u32(raw, node_at(p) + CN_NODE_BASE);
            cases.extend([
                (
                    format!("node {p}'s first inner child {child} has node {p} as its child"),
                    node_at(child as usize) + CN_NODE_BASE,
                    [
                        u32le(p as u32),
                        raw[node_at(child as usize) + 20..node_at(child as usize) + 24].to_vec(),
                        vec![inner_count(child as usize).max(1)],
                    ]
                    .concat(),
                ),
                (
                    format!("node {p}'s inner children start past the block's {n_nodes} nodes"),
                    node_at(p) + CN_NODE_BASE,
                    u32le(n_nodes as u32),
                ),
                (
                    format!("node {p}'s inner children start at u32::MAX"),
                    node_at(p) + CN_NODE_BASE,
                    u32le(u32::MAX),
                ),
            ]);
        }
        for (what, at, new) in cases {
            let b = fix.rewrite(Space::Block(blk), at, &new);
            assert!(b != fix.bytes, "{}: {what}: nothing changed", fix.name);
            let what = format!("{}: block {blk}: {what}", fix.name);
            expect_caught(fix, what, b, &format!("block {blk}"), &[], &mut problems);
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Every cluster root of every block (§7.1) made its own only child, with a box of its whole
/// grid (so a ray that reaches any of its triangles takes it), checksums recomputed: every
/// walk into a cluster goes round in a circle. Tracing must stop it (§11: more nodes visited
/// than the block has, or deeper than 16 levels) with an error naming a block, not loop or
/// overflow its stack; verify must report each cycle.
#[test]
fn cluster_cycles_end_the_walk_with_an_error() {
    let mut problems = Vec::new();
    for fix in [default_file(), deep_file()] {
        let mut b = fix.bytes.clone();
        let mut cycles = 0;
        for (blk, raw) in fix.decoded.iter().enumerate() {
            assert_eq!(fix.dir[blk].codec, CODEC_RAW, "{}", fix.name);
            let nodes = block_parts(raw)[PART_CLUSTER_NODES].start;
            for root in cluster_roots(raw) {
                let at = fix.dir[blk].offset + nodes + root * CLUSTER_NODE_LEN;
                b[at + CN_CHILD_COUNT] = 1;
                write_u32(&mut b, at + CN_NODE_BASE, root as u32);
                b[at + CN_INNER_COUNT] = 1;
                b[at + CN_LO..at + CLUSTER_NODE_LEN].fill(0);
                for k in 0..3 {
                    b[at + CN_HI + 8 * k] = 255;
                }
                cycles += 1;
            }
        }
        fix_checksums(&mut b);
        let all: Vec<usize> = (0..fix.dir.len()).collect();
        let what = format!("{}: {cycles} cluster roots made their own child", fix.name);
        expect_caught(fix, what, b, "not after it", &all, &mut problems);
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Rank words (§4.3), in the top tree and in blocks: a regression

/// Regression: a rank word whose `rank` is at least `2^61` used to overflow `rank + popcount`
/// and `rank * 8` in the tracer's descent and in verify: a panic with overflow checks on, a
/// wrapped index otherwise. Now the arithmetic is checked and the answer is a corruption error.
/// In the top tree's rank words and in a block's (raw and compressed).
#[test]
fn huge_rank_in_a_rank_word_is_an_error_not_a_panic() {
    let mut problems = Vec::new();
    type Case = (&'static str, usize, fn(u64) -> u64, bool);
    let cases: [Case; 4] = [
        (
            "bit 61 of rank flipped, checksums as they were",
            1,
            |r| r ^ 1 << 61,
            false,
        ),
        ("rank 2^61, checksums recomputed", 0, |_| 1 << 61, true),
        (
            "rank u64::MAX - 7, checksums recomputed",
            1,
            |_| u64::MAX - 7,
            true,
        ),
        ("rank u64::MAX, checksums recomputed", 2, |_| u64::MAX, true),
    ];
    for fix in [default_file(), list_file(), deep_file(), deep_zstd_file()] {
        let blk = fix.largest;
        let regions = [
            fix.region("ranks section").clone(),
            fix.region(&format!("block {blk} ranks")).clone(),
        ];
        for region in &regions {
            let words = region.range.len() / 16;
            for (what, word, f, rewrite) in cases {
                let word = word.min(words - 1);
                let at = region.range.start + 16 * word + 8;
                let bytes = fix.space(region.space);
                let rank = f(read_u64(bytes, at)).to_le_bytes();
                let b = match (rewrite, fix.file_at(region.space, at)) {
                    (true, _) => fix.rewrite(region.space, at, &rank),
                    (false, Some(at)) => {
                        let mut b = fix.bytes.clone();
                        b[at..at + 8].copy_from_slice(&rank);
                        b
                    }
                    (false, None) => continue, // a compressed block: bits flip in the frame
                };
                let what = format!("{}: {} word {word}: {what}", fix.name, region.name);
                let verdict = evaluate_guarded(fix, b, false, &what);
                let (traced, defects) = match verdict {
                    Err(panic) => {
                        problems.push(format!("{what}: {panic}"));
                        continue;
                    }
                    Ok(Verdict::Rejected(e)) => {
                        problems.push(format!("{what}: open does not read rank words: {e}"));
                        continue;
                    }
                    Ok(Verdict::Opened {
                        traced, defects, ..
                    }) => (traced, defects),
                };
                if let Err(panic) = traced {
                    problems.push(format!("{what}: tracing: {panic}"));
                }
                let expected = match (rewrite, region.space) {
                    (false, Space::Block(b)) => format!("block {b}: checksum mismatch"),
                    _ => "rank word".to_string(),
                };
                match defects {
                    Err(panic) => problems.push(format!("{what}: verify: {panic}")),
                    Ok(d) if d.iter().any(|d| d.contains(&expected)) => {}
                    Ok(d) => problems.push(format!("{what}: verify does not report it: {d:?}")),
                }
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Library bugs these runs found, one small reproduction each, kept as regression tests now
//    that they are fixed (the mutation runs no longer skip them: see `known_bug`,
//    anywhere.rs).

/// Was a bug (verify missed a defect): format-spec.md §8.3 lays a block's parts out "each at the next
/// multiple of 64 bytes from the block's start, zero padding between them", but verify checks
/// zero padding only between sections and between blocks (§11), not between the parts of a
/// block. A non-zero byte between two parts, with the block's checksum recomputed, passes
/// verify (the rewritten runs list these as "unseen, answers unchanged": "block N padding
/// before its nodes", ... in every detailed block, raw and compressed). Damage on disk is still
/// caught by the block's checksum; a rewritten file is not. Either verify should check it (as
/// §8.3 and "every byte of a valid file is covered by a checksum or by the zero-padding rule",
/// §1, suggest), or §8.3/§11 should say that padding inside a block is not checked.
#[test]
fn verify_checks_padding_inside_a_block() {
    let mut problems = Vec::new();
    for fix in [default_file(), default_zstd_file(), list_file()] {
        let pads: Vec<Region> = fix
            .regions
            .iter()
            .filter(|r| matches!(r.kind, RegionKind::BlockPadding(_)))
            .cloned()
            .collect();
        assert!(!pads.is_empty(), "{}: no padding inside blocks", fix.name);
        for r in pads {
            let b = fix.rewrite(r.space, r.range.start, &[0x5a]);
            let scene = open(&b).expect("opens");
            let defects = scene
                .verify()
                .map(|r| r.defects)
                .unwrap_or_else(|e| vec![e.to_string()]);
            if defects.is_empty() {
                problems.push(format!(
                    "{}: {} byte 0 set to 0x5a, checksums recomputed: verify reports nothing",
                    fix.name, r.name
                ));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// The octree's wide nodes in a block (§8.7)

/// §8.7: the indices of a decoded block's octree wide nodes: its cluster nodes but those of
/// its clusters (each reached from a solid leaf's payload, its root, through inner children).
fn octree_wide_nodes(raw: &[u8]) -> Vec<usize> {
    let nodes = block_parts(raw)[PART_CLUSTER_NODES].clone();
    let n = nodes.len() / CLUSTER_NODE_LEN;
    let node_at = |i: usize| nodes.start + i * CLUSTER_NODE_LEN;
    let mut in_cluster = vec![false; n];
    let mut stack = cluster_roots(raw);
    while let Some(i) = stack.pop() {
        in_cluster[i] = true;
        let base = read_u32(raw, node_at(i) + CN_NODE_BASE) as usize;
        stack.extend(base..base + raw[node_at(i) + CN_INNER_COUNT] as usize);
    }
    (0..n).filter(|&i| !in_cluster[i]).collect()
}

/// A child box of an octree wide node of a block (§8.7) grown or shrunk by one step along an
/// axis, checksums recomputed: nothing but the layout of the block's wide nodes says what those
/// boxes are (no triangle is checked against them, and a grown box changes no answer), so only
/// verify's laying the block's wide nodes out again can tell. It must report the node by index
/// and the child's box; tracing returns, answers or an error, never a panic or an endless walk.
#[test]
fn octree_wide_nodes_rewritten_are_caught() {
    let mut problems = Vec::new();
    // The deep files: the default file's blocks each hold solid roots only, so no octree wide
    // node (`oavm-inspect --levels` counts them).
    for fix in [deep_file(), deep_zstd_file(), occluded_file()] {
        // The block with the most octree wide nodes (a block whose roots are all solid leaves
        // has none).
        let blk = (0..fix.dir.len())
            .max_by_key(|&b| octree_wide_nodes(&fix.decoded[b]).len())
            .expect("blocks");
        let raw = &fix.decoded[blk];
        let nodes = block_parts(raw)[PART_CLUSTER_NODES].start;
        let octree = octree_wide_nodes(raw);
        assert!(
            octree.len() >= 3 && octree[0] == 0,
            "{}: block {blk}'s octree wide nodes {octree:?} (its first root's first)",
            fix.name
        );
        for &i in &[
            octree[0],
            octree[octree.len() / 2],
            octree[octree.len() - 1],
        ] {
            let at = nodes + i * CLUSTER_NODE_LEN;
            let count = raw[at + CN_CHILD_COUNT] as usize;
            // (what, byte offset in the block, new byte, the child)
            let mut cases: Vec<(String, usize, u8, usize)> = Vec::new();
            let (lo, hi) = (at + CN_LO, at + CN_HI);
            if raw[hi] < 255 {
                cases.push(("child 0's box grown along +x".into(), hi, raw[hi] + 1, 0));
            } else if raw[lo] > 0 {
                cases.push(("child 0's box grown along -x".into(), lo, raw[lo] - 1, 0));
            }
            // The last child along y (lo[1][c], hi[1][c]): shrunk if it can be.
            let c = count - 1;
            let (lo_y, hi_y) = (lo + 8 + c, hi + 8 + c);
            if raw[lo_y] < raw[hi_y] {
                cases.push((
                    format!("child {c}'s box shrunk along -y"),
                    lo_y,
                    raw[lo_y] + 1,
                    c,
                ));
            }
            assert!(!cases.is_empty(), "{}: node {i}: no case", fix.name);
            for (what, at, new, child) in cases {
                let b = fix.rewrite(Space::Block(blk), at, &[new]);
                let what = format!("{}: block {blk}: octree wide node {i}: {what}", fix.name);
                let defect = format!("block {blk}: wide node {i}: child {child}'s box");
                let reported = |d: &str| d.starts_with(&defect);
                expect_reported(fix, what, b, &defect, &reported, &[], &mut problems);
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
