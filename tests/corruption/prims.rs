//! Corrupted `.oavm` files (format-spec.md §11): damage to the primitive table (§8.6): its
//! chunk directory and the primitives' records, in a file packed `--updatable` and in that file
//! updated.
//!
//! What must hold, the files damaged and how the runs report are in `tests/corruption/fixtures`
//! (its module doc), with the fixtures and the harness these files share.

use std::collections::BTreeMap;

use crate::fixtures::*;

/// The primitive table (§8.6) rewritten, checksums recomputed (the chunk directory's section
/// checksum, each chunk's in the directory, the header's): each field of a chunk directory
/// entry set to values that break §8.6 (an offset moved, misaligned, outside the data region,
/// over a block; a count off by one; the reserved word), and primitives' records changed: a
/// stored triangle's corner moved by an ulp, its record made absent or degenerate, and the
/// record of a primitive no block stores made a triangle. Verify reports each: the chunk, or
/// the table; a changed corner as a stored triangle that differs from the table, naming a block
/// that stores it. The tracer does not read the table: the answers stay as they were.
#[test]
fn primitive_tables_rewritten_are_caught() {
    let mut problems = Vec::new();
    for fix in [updatable_file(), updatable_zstd_file(), updated_file()] {
        let (pdir, _) = section_of(&fix.bytes, KIND_PRIMS).expect("a primitive table");
        let region_end = {
            let (o, l) = section(&fix.bytes, BLOCKS);
            o + l
        };
        // The blocks that store each primitive.
        let mut stored_in: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
        for b in (0..fix.dir.len()).filter(|&b| !fix.dir[b].free) {
            for t in block_triangles(&fix.decoded[b]) {
                let blocks = stored_in.entry(read_u32(&t, 36)).or_default();
                if !blocks.contains(&b) {
                    blocks.push(b);
                }
            }
        }
        // (what, file offset, new bytes, what verify must report)
        type Case = (String, usize, Vec<u8>, Box<dyn Fn(&str) -> bool>);
        let mut cases: Vec<Case> = Vec::new();
        let last = fix.chunks.len() - 1;
        for c in [0, last] {
            let ch = fix.chunks[c];
            let e = pdir + c * PRIM_CHUNK_LEN;
            let first_block = fix.dir.iter().find(|e| !e.free).expect("a block").offset;
            let offsets = [
                ch.offset + 64,
                ch.offset - 64,
                ch.offset + 4,
                0,
                BLOCKS_START,
                first_block,
                region_end,
                fix.bytes.len(),
            ];
            for v in offsets.map(|v| v as u64).into_iter().chain([u64::MAX - 7]) {
                cases.push((
                    format!("chunk {c}'s offset {v}"),
                    e + PC_OFFSET,
                    v.to_le_bytes().to_vec(),
                    Box::new(|d: &str| d.contains("primitive")),
                ));
            }
            let count = ch.count as u64;
            for v in [count + 1, count - 1, 0, 1 << 40, u64::MAX] {
                cases.push((
                    format!("chunk {c}'s count {v}"),
                    e + PC_COUNT,
                    v.to_le_bytes().to_vec(),
                    Box::new(move |d: &str| d.contains(&format!("primitive chunk {c}"))),
                ));
            }
            cases.push((
                format!("chunk {c}'s reserved word 1"),
                e + PC_RESERVED,
                1u64.to_le_bytes().to_vec(),
                Box::new(move |d: &str| d.contains(&format!("primitive chunk {c}"))),
            ));
        }
        // Records: primitives stored in one block and in two, in the first chunk and the last.
        let in_one = stored_in.iter().find(|(_, b)| b.len() == 1);
        let in_two = stored_in.iter().rev().find(|(_, b)| b.len() >= 2);
        for (&p, blocks) in in_one.into_iter().chain(in_two) {
            let at = prim_record_at(&fix.bytes, p as usize);
            let rec = &fix.bytes[at..at + PRIM_RECORD_LEN];
            let first_corner = rec[..12].to_vec();
            let ulp = (read_u32(rec, 4) ^ 1).to_le_bytes().to_vec();
            let blocks = blocks.clone();
            let differs = move |d: &str| {
                d.contains("stored triangles differ from the primitive table")
                    && blocks.iter().any(|&b| names_block(d, b))
            };
            let differs = std::sync::Arc::new(differs);
            let (d1, d2, d3) = (differs.clone(), differs.clone(), differs);
            cases.push((
                format!("primitive {p}'s y of its first corner moved by an ulp"),
                at + 4,
                ulp,
                Box::new(move |d: &str| d1(d)),
            ));
            cases.push((
                format!("primitive {p}'s record made absent"),
                at,
                [PRIM_ABSENT.to_le_bytes(); 9].concat(),
                Box::new(move |d: &str| d2(d)),
            ));
            cases.push((
                format!("primitive {p}'s record made degenerate"),
                at,
                first_corner.repeat(3),
                Box::new(move |d: &str| d3(d)),
            ));
        }
        // A primitive no block stores (removed by the update, or degenerate) given a stored
        // triangle's corners: a triangle the table says is in some block, and that none holds.
        let n = read_u64(&fix.bytes, fix.slot + INPUT_TRIANGLES_AT) as u32;
        if let Some(p) = (0..n).find(|p| !stored_in.contains_key(p)) {
            let at = prim_record_at(&fix.bytes, p as usize);
            let (&q, _) = stored_in.iter().next().expect("a stored triangle");
            let from = prim_record_at(&fix.bytes, q as usize);
            cases.push((
                format!("primitive {p}, in no block, given primitive {q}'s triangle"),
                at,
                fix.bytes[from..from + PRIM_RECORD_LEN].to_vec(),
                Box::new(|d: &str| d.contains("primitive table: 1 triangles are in no block")),
            ));
        } else if fix.generation > 1 {
            problems.push(format!("{}: the removed primitives are stored", fix.name));
        }
        for (change, at, new, reported) in cases {
            let b = fix.rewrite(Space::File, at, &new);
            let what = format!("{}: {change}", fix.name);
            match evaluate_guarded(fix, b, false, &what) {
                Ok(Verdict::Opened {
                    generation,
                    traced: Ok(Traced::Same),
                    defects: Ok(d),
                    ..
                }) if generation == fix.generation => {
                    if !d.iter().any(|d| reported(d)) {
                        problems.push(format!("{what}: verify does not report it: {d:?}"));
                    }
                }
                v => problems.push(format!(
                    "{what}: should open, answer as before and be reported: {v:?}"
                )),
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
