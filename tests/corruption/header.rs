//! Corrupted `.oavm` files (format-spec.md §11): damage to the header and its two slots (§2,
//! §2.1: generations), the section table (§3) and the version (§12). Files truncated and
//! extended, the valid slot of the highest generation read, wrong magic or version (version 1
//! files included), header fields rewritten (`max_block_raw_len`, the root cube,
//! `input_triangles`), a damaged level table of the newest generation; files held in
//! misaligned buffers (§1); and first, the layout the tests take from the spec checked against
//! the code.
//!
//! What must hold, the files damaged and how the runs report are in `tests/corruption/fixtures`
//! (its module doc), with the fixtures and the harness these files share.

use oavm::pack::TreeParts;
use oavm::physical::AlignedBytes;
use oavm::physical::format::{
    BlockEntry, BlockHeader, ChunkEntry, ClusterNode, Header, LevelEntry, NodeRecord, OccluderNode,
    RankWord, RopeRecord, SectionEntry, SectionKind, TriGroup, TriRecord, VolumeRecord,
};
use oavm::{Error, FormatError, Hit, Scene};
use xxhash_rust::xxh3::xxh3_64;

use crate::fixtures::*;

// ---------------------------------------------------------------------------------------------
// The layout of the tests agrees with the code

#[test]
fn layout_matches_the_spec() {
    use std::mem::{offset_of, size_of};
    assert_eq!(size_of::<Header>(), HEADER_LEN);
    assert_eq!(offset_of!(Header, checksum), HEADER_CHECKSUM);
    assert_eq!(offset_of!(Header, version), VERSION_AT);
    assert_eq!(offset_of!(Header, flags), FLAGS_AT);
    use oavm::physical::format as f;
    assert_eq!(f::VERSION, VERSION, "§12");
    assert_eq!(f::MAGIC, *MAGIC);
    assert_eq!(f::FLAG_MERGED, FLAG_MERGED);
    assert_eq!(f::FLAG_COMPRESSED, FLAG_COMPRESSED);
    assert_eq!(f::FLAG_CLUSTERS, FLAG_CLUSTERS);
    assert_eq!(f::FLAG_ROPES, FLAG_ROPES);
    assert_eq!(f::FLAG_OCCLUDERS, FLAG_OCCLUDERS);
    assert_eq!(f::FLAG_PRIMS, FLAG_PRIMS);
    assert_eq!(offset_of!(Header, section_count), SECTION_COUNT_AT);
    assert_eq!(offset_of!(Header, section_table_offset), TABLE_OFFSET_AT);
    assert_eq!(offset_of!(Header, file_size), FILE_SIZE_AT);
    assert_eq!(offset_of!(Header, root_min), ROOT_MIN_AT);
    assert_eq!(offset_of!(Header, root_size), ROOT_SIZE_AT);
    assert_eq!(offset_of!(Header, input_triangles), INPUT_TRIANGLES_AT);
    assert_eq!(offset_of!(Header, max_block_raw_len), MAX_BLOCK_RAW_LEN_AT);
    assert_eq!(offset_of!(Header, generation), GENERATION_AT);
    let header_fields = [
        offset_of!(Header, block_count),
        offset_of!(Header, block_triangles),
        offset_of!(Header, stored_triangles),
        offset_of!(Header, generation),
        offset_of!(Header, chunk_groups),
        offset_of!(Header, reserved_u32),
        offset_of!(Header, reserved),
    ];
    assert_eq!(
        header_fields,
        [
            136,
            152,
            160,
            168,
            CHUNK_GROUPS_AT,
            RESERVED_U32_AT,
            RESERVED_AT
        ]
    );
    assert_eq!(f::MAX_CHUNK_GROUPS, MAX_CHUNK_GROUPS, "§2");
    assert_eq!(
        HEADER_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>(),
        [
            offset_of!(Header, magic),
            offset_of!(Header, version),
            offset_of!(Header, flags),
            offset_of!(Header, header_size),
            offset_of!(Header, section_count),
            offset_of!(Header, section_table_offset),
            offset_of!(Header, file_size),
            offset_of!(Header, root_min),
            offset_of!(Header, root_size),
            offset_of!(Header, mesh_min),
            offset_of!(Header, mesh_max),
            offset_of!(Header, input_triangles),
            offset_of!(Header, empty_leaves),
            offset_of!(Header, solid_leaves),
            offset_of!(Header, level_count),
            offset_of!(Header, lattice_bits),
            offset_of!(Header, max_depth),
            offset_of!(Header, leaf_size),
            offset_of!(Header, block_count),
            offset_of!(Header, max_block_raw_len),
            offset_of!(Header, block_triangles),
            offset_of!(Header, stored_triangles),
            offset_of!(Header, generation),
            offset_of!(Header, chunk_groups),
            offset_of!(Header, reserved_u32),
            offset_of!(Header, reserved),
            offset_of!(Header, checksum),
        ]
    );
    // §2: chunk_groups and reserved_u32 are u32, reserved u64[8], up to the checksum.
    assert_eq!(CHUNK_GROUPS_AT + 4, RESERVED_U32_AT);
    assert_eq!(RESERVED_U32_AT + 4, RESERVED_AT);
    assert_eq!(RESERVED_AT + 8 * 8, HEADER_CHECKSUM);
    // §2.1: the two header slots and the data region after them.
    assert_eq!(HEADER_SLOTS.map(|s| s as u64), f::HEADER_SLOTS);
    assert_eq!(HEADER_SLOTS[1], SLOT_LEN);
    assert_eq!(f::DATA_START, BLOCKS_START as u64);
    assert_eq!(BLOCKS_START, 2 * SLOT_LEN);
    assert_eq!(f::FIRST_GENERATION, 1);
    // §8.6: the primitive table.
    assert_eq!(size_of::<f::PrimChunk>(), PRIM_CHUNK_LEN);
    assert_eq!(
        [
            offset_of!(f::PrimChunk, offset),
            offset_of!(f::PrimChunk, count),
            offset_of!(f::PrimChunk, checksum),
            offset_of!(f::PrimChunk, reserved),
        ]
        .to_vec(),
        PRIM_CHUNK_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    assert_eq!(size_of::<f::PrimRecord>(), PRIM_RECORD_LEN);
    assert_eq!(f::PRIM_CHUNK, PRIMS_PER_CHUNK as u64);
    assert_eq!(f::PRIM_ABSENT, PRIM_ABSENT);
    assert_eq!(size_of::<SectionEntry>(), ENTRY_LEN);
    assert_eq!(offset_of!(SectionEntry, offset), ENTRY_OFFSET);
    assert_eq!(offset_of!(SectionEntry, length), ENTRY_LENGTH);
    assert_eq!(offset_of!(SectionEntry, checksum), ENTRY_CHECKSUM);
    assert_eq!(size_of::<BlockEntry>(), DIR_LEN);
    let dir_fields = [
        offset_of!(BlockEntry, offset),
        offset_of!(BlockEntry, stored_len),
        offset_of!(BlockEntry, raw_len),
        offset_of!(BlockEntry, codec),
        offset_of!(BlockEntry, root_level),
        offset_of!(BlockEntry, root_count),
        offset_of!(BlockEntry, triangles),
        offset_of!(BlockEntry, checksum),
        offset_of!(BlockEntry, head_stored_len),
        offset_of!(BlockEntry, head_raw_len),
    ];
    assert_eq!(
        dir_fields.to_vec(),
        DIR_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    assert_eq!(size_of::<BlockHeader>(), BLOCK_HEADER_LEN);
    let bh_fields = [
        offset_of!(BlockHeader, tag),
        offset_of!(BlockHeader, level_count),
        offset_of!(BlockHeader, root_level),
        offset_of!(BlockHeader, root_count),
        offset_of!(BlockHeader, node_count),
        offset_of!(BlockHeader, rank_count),
        offset_of!(BlockHeader, volume_count),
        offset_of!(BlockHeader, ref_count),
        offset_of!(BlockHeader, triangle_count),
        offset_of!(BlockHeader, cluster_node_count),
        offset_of!(BlockHeader, group_count),
        offset_of!(BlockHeader, block_id),
        offset_of!(BlockHeader, rope_count),
        offset_of!(BlockHeader, occluder_node_count),
        offset_of!(BlockHeader, occluder_count),
        offset_of!(BlockHeader, chunk_count),
    ];
    assert_eq!(
        bh_fields.to_vec(),
        BLOCK_HEADER_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    let part_sizes = [
        size_of::<LevelEntry>(),
        size_of::<NodeRecord>(),
        size_of::<RankWord>(),
        size_of::<VolumeRecord>(),
        size_of::<u32>(),
        size_of::<TriRecord>(),
        size_of::<ClusterNode>(),
        size_of::<RopeRecord>(),
        size_of::<OccluderNode>(),
        size_of::<TriRecord>(),
        size_of::<ChunkEntry>(),
        size_of::<TriGroup>(),
    ];
    assert_eq!(part_sizes, BLOCK_PARTS.map(|p| p.1));
    assert_eq!(part_sizes, PART_RECORD_LEN);
    // §8.3: the parts' indices, the groups' alignment and the chunk table's entries.
    assert_eq!(
        [
            f::PART_LEVELS,
            f::PART_NODES,
            f::PART_RANKS,
            f::PART_VOLUMES,
            f::PART_REFS,
            f::PART_TRIANGLES,
            f::PART_WIDE,
            f::PART_ROPES,
            f::PART_OCCLUDER_NODES,
            f::PART_OCCLUDERS,
            f::PART_CHUNKS,
            f::PART_GROUPS,
        ],
        [
            PART_LEVELS,
            PART_NODES,
            PART_RANKS,
            PART_VOLUMES,
            PART_REFS,
            PART_TRIANGLES,
            PART_CLUSTER_NODES,
            PART_ROPES,
            PART_OCCLUDER_NODES,
            PART_OCCLUDERS,
            PART_CHUNKS,
            PART_GROUPS,
        ]
    );
    assert_eq!(f::GROUPS_ALIGN, GROUPS_ALIGN as u64);
    assert_eq!(f::MAX_ZSTD_RATIO, MAX_ZSTD_RATIO as u64);
    assert_eq!(size_of::<ChunkEntry>(), CHUNK_ENTRY_LEN);
    assert_eq!(
        [
            offset_of!(ChunkEntry, offset),
            offset_of!(ChunkEntry, stored_len),
            offset_of!(ChunkEntry, checksum),
        ]
        .to_vec(),
        CHUNK_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    assert_eq!(
        [
            offset_of!(OccluderNode, node),
            offset_of!(OccluderNode, first)
        ]
        .to_vec(),
        OCCLUDER_NODE_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    assert_eq!(
        [offset_of!(TriRecord, v), offset_of!(TriRecord, prim)].to_vec(),
        TRI_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    assert_eq!(size_of::<RopeRecord>(), ROPE_LEN);
    assert_eq!(
        ROPE_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>(),
        (0..6)
            .map(|f| offset_of!(RopeRecord, across) + 4 * f)
            .collect::<Vec<_>>()
    );
    assert_eq!(oavm::physical::format::ROPE_EXIT, ROPE_EXIT);
    assert_eq!(oavm::physical::format::ROPE_TOP, ROPE_TOP);
    assert_eq!(oavm::physical::format::BLOCK_PARTS, BLOCK_PART_COUNT);
    let node_fields = [
        offset_of!(ClusterNode, origin),
        offset_of!(ClusterNode, exp),
        offset_of!(ClusterNode, child_count),
        offset_of!(ClusterNode, node_base),
        offset_of!(ClusterNode, group_base),
        offset_of!(ClusterNode, inner_count),
        offset_of!(ClusterNode, reserved),
        offset_of!(ClusterNode, lo),
        offset_of!(ClusterNode, hi),
    ];
    assert_eq!(
        node_fields.to_vec(),
        CLUSTER_NODE_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    let group_fields = [
        offset_of!(TriGroup, corner),
        offset_of!(TriGroup, tri),
        offset_of!(TriGroup, count),
        offset_of!(TriGroup, reserved),
        offset_of!(TriGroup, prim),
    ];
    assert_eq!(
        group_fields.to_vec(),
        GROUP_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    assert_eq!(SectionKind::ALL.len(), 12, "§3: twelve kinds");
    assert_eq!(
        SectionKind::Geometries as u32,
        KIND_GEOMETRIES,
        "§3: kind 12"
    );
    assert_eq!(
        SECTIONS[SECTION_GEOMETRIES].0,
        SectionKind::Geometries.name()
    );
    assert_eq!(size_of::<f::GeometryRecord>(), GEOMETRY_LEN);
    assert_eq!(
        [
            offset_of!(f::GeometryRecord, first_primitive),
            offset_of!(f::GeometryRecord, primitive_count),
            offset_of!(f::GeometryRecord, transform),
            offset_of!(f::GeometryRecord, name),
        ]
        .to_vec(),
        GEOMETRY_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    assert_eq!(f::FLAG_GEOMETRIES, FLAG_GEOMETRIES);
    assert_eq!(SectionKind::BASE, SECTION_COUNT);
    assert_eq!(SectionKind::count_for(FLAG_ROPES), SECTION_COUNT_ROPES);
    assert_eq!(SectionKind::Ropes as u32, KIND_ROPES, "§3: kind 8");
    assert_eq!(SectionKind::Prims as u32, KIND_PRIMS, "§3: kind 9");
    assert_eq!(section_position(FLAG_ROPES, KIND_ROPES), Some(ROPES));
    assert_eq!(SECTIONS[SECTION_ROPES].0, SectionKind::Ropes.name());
    assert_eq!(SECTIONS[SECTION_PRIMS].0, SectionKind::Prims.name());
    assert_eq!(
        SectionKind::WideNodes as u32,
        KIND_WIDE_NODES,
        "§3: kind 10"
    );
    assert_eq!(
        SectionKind::WideLinks as u32,
        KIND_WIDE_LINKS,
        "§3: kind 11"
    );
    assert_eq!(
        SECTIONS[SECTION_WIDE_NODES].0,
        SectionKind::WideNodes.name()
    );
    assert_eq!(
        SECTIONS[SECTION_WIDE_LINKS].0,
        SectionKind::WideLinks.name()
    );
    assert_eq!(size_of::<f::WideLink>(), WIDE_LINK_LEN);
    assert_eq!(
        [
            offset_of!(f::WideLink, block),
            offset_of!(f::WideLink, root),
            offset_of!(f::WideLink, lo),
            offset_of!(f::WideLink, hi),
        ]
        .to_vec(),
        WIDE_LINK_FIELDS.iter().map(|f| f.0).collect::<Vec<_>>()
    );
    // §3: the seven sections, then the wide nodes and links with CLUSTERS, then ropes with
    // ROPES, then the primitive table with PRIMS, then the geometry table with GEOMETRIES.
    for flags in 0..256 {
        let code: Vec<u32> = SectionKind::for_flags(flags).map(|k| k as u32).collect();
        assert_eq!(section_kinds(flags), code, "flags {flags:#x}");
        assert_eq!(
            SectionKind::count_for(flags),
            code.len(),
            "flags {flags:#x}"
        );
    }
    assert_eq!(
        (
            TABLE_END,
            table_range(0, FLAG_ROPES).end,
            table_range(HEADER_SLOTS[1], FLAG_PRIMS).end,
            table_range(0, FLAG_ROPES | FLAG_PRIMS).end,
            table_range(0, FLAG_CLUSTERS | FLAG_ROPES).end,
        ),
        (256 + 336, 256 + 384, 2048 + 256 + 384, 256 + 432, 256 + 480),
        "§2, §3"
    );
    assert_eq!(SectionKind::ALL[BLOCKS].record_size(), None);
    for kind in &SectionKind::ALL[1..] {
        let (name, size, _) = SECTIONS[*kind as usize - 2];
        assert_eq!((kind.name(), kind.record_size()), (name, Some(size as u64)));
    }
    assert_eq!(oavm::physical::format::CODEC_RAW, CODEC_RAW);
    assert_eq!(oavm::physical::format::CODEC_ZSTD, CODEC_ZSTD);
    assert_eq!(oavm::physical::format::CODEC_LEAN, CODEC_LEAN);
    assert_eq!(oavm::physical::format::FLAG_LEAN, FLAG_LEAN);
    assert_eq!(oavm::physical::format::RAW_BLOCK_ALIGN, RAW_ALIGN as u64);
    for fix in [
        default_file(),
        default_zstd_file(),
        default_lean_file(),
        list_file(),
        list_zstd_file(),
        deep_file(),
        deep_zstd_file(),
        roped_file(),
        roped_list_zstd_file(),
        occluded_file(),
        occluded_zstd_file(),
        updatable_file(),
        updatable_zstd_file(),
        updated_file(),
    ] {
        // The section table is as long as the flags say (§2, §3).
        assert_eq!(
            read_u32(&fix.bytes, fix.slot + SECTION_COUNT_AT) as usize,
            SECTION_COUNT + 2 * fix.clusters as usize + fix.ropes as usize + fix.prims as usize,
            "{}: section_count",
            fix.name
        );
        // §2.1: the section table follows its slot's header.
        assert_eq!(
            read_u64(&fix.bytes, fix.slot + TABLE_OFFSET_AT) as usize,
            fix.slot + HEADER_LEN,
            "{}: section_table_offset",
            fix.name
        );
        // Recomputing the checksums of an intact file changes nothing: the tests compute them
        // as the writer does.
        let mut b = fix.bytes.clone();
        fix_checksums(&mut b);
        assert!(
            b == fix.bytes,
            "{}: checksums recomputed differently",
            fix.name
        );
        // Laying the file out again, each detailed block stored again (its head and chunks
        // compressed as the writer compresses them, its chunk table written for them), gives
        // the same bytes: the tests lay files out as the writer does (a file as packed; an
        // update's blocks lie anywhere, §2.1); and stored again through `Fixture::restore`,
        // unchanged, too.
        for &blk in fix.detailed.iter().filter(|_| fix.generation == 1) {
            let e = fix.dir[blk];
            let stored = store_block(&fix.decoded[blk], e.codec, fix.chunk_groups);
            assert_eq!(
                (stored.head_stored_len, stored.head_raw_len, stored.raw_len),
                (e.head_stored_len, e.head_raw_len, e.raw_len),
                "{}: block {blk} stored differently",
                fix.name
            );
            let b = relayout(&fix.bytes, blk, &stored);
            assert!(
                b == fix.bytes,
                "{}: block {blk} laid out differently",
                fix.name
            );
            if e.codec != CODEC_RAW {
                let again = fix.restore(blk, &fix.decoded[blk], true);
                assert!(
                    again == stored,
                    "{}: block {blk} restored differently",
                    fix.name
                );
            }
        }
        // Every link is found, one per root of every block.
        let roots: usize = fix.dir.iter().map(|e| e.root_count as usize).sum();
        assert_eq!(fix.links.len(), roots, "{}: links", fix.name);
        // Blocks hold occluders only in a file whose flags say so (§8.5), and those fixtures'
        // do.
        let holding = fix
            .decoded
            .iter()
            .filter(|raw| !raw.is_empty() && !block_parts(raw)[PART_OCCLUDERS].is_empty())
            .count();
        assert_eq!(
            holding > 0,
            fix.occluders,
            "{}: {holding} blocks hold occluders",
            fix.name
        );
    }
    // After a change, recomputing the checksums leaves verify nothing to say about checksums,
    // in a raw block and in a compressed one, of clusters and of lists, with ropes and without.
    for fix in [
        default_file(),
        default_zstd_file(),
        list_file(),
        list_zstd_file(),
        roped_file(),
        roped_list_zstd_file(),
        occluded_file(),
        occluded_zstd_file(),
        updatable_zstd_file(),
        updated_file(),
    ] {
        let blk = fix.detailed[0];
        let r = fix
            .region(&format!("block {blk} {}", fix.mesh_part()))
            .range
            .start;
        let mut raw = fix.decoded[blk].clone();
        // The lowest mantissa bit of the block's first triangle's first x (§7), or of its
        // first group's first corner's (§7.2), the checksum that covers it left as it was: the
        // block's (§8.2: of its head, where a block of lists keeps its triangles) or its first
        // chunk's (§8.3: a block of clusters keeps its groups in chunks).
        raw[r] ^= 1;
        let e = fix.dir[blk];
        let b = match (e.codec, fix.clusters) {
            (CODEC_RAW, _) => {
                let mut b = fix.bytes.clone();
                b[e.offset + r] = raw[r];
                b
            }
            (_, true) => fix.rewrite_with(Space::Block(blk), r, &raw[r..r + 1], false),
            (_, false) => {
                let mut b = fix.rewrite(Space::Block(blk), r, &raw[r..r + 1]);
                // Leave the old checksum: relayout recomputed it.
                let at = dir_entry_at(&b, blk) + DIR_CHECKSUM;
                write_u64(&mut b, at, xxh3_64(&fix.bytes[e.head()]));
                let (o, l) = section(&b, DIRECTORY);
                let sum = xxh3_64(&b[o..o + l]);
                write_u64(
                    &mut b,
                    HEADER_LEN + DIRECTORY * ENTRY_LEN + ENTRY_CHECKSUM,
                    sum,
                );
                fix_header_checksum(&mut b);
                b
            }
        };
        let checksum_defect = |b: &[u8]| {
            let scene = open_walking(b, fix.walk).expect("opens");
            let defects = scene
                .verify()
                .map(|r| r.defects)
                .unwrap_or_else(|e| vec![e.to_string()]);
            defects.iter().any(|d| d.contains("checksum"))
        };
        assert!(
            checksum_defect(&b),
            "{}: the change is seen by the checksum",
            fix.name
        );
        let b = fix.rewrite(Space::Block(blk), r, &raw[r..r + 1]);
        assert!(
            !checksum_defect(&b),
            "{}: recomputed checksums are accepted",
            fix.name
        );
    }
    // The same for a primitive chunk's records (§8.6), whose checksum is in the chunk
    // directory: the change is seen by it, and, recomputed, by the comparison of the blocks'
    // triangles with the table.
    for fix in [updatable_file(), updatable_zstd_file(), updated_file()] {
        let c = fix.chunks.len() / 2;
        let at = fix.chunks[c].offset;
        let mut b = fix.bytes.clone();
        b[at] ^= 1;
        let defects = |b: &[u8]| {
            open(b)
                .expect("opens")
                .verify()
                .map(|r| r.defects)
                .unwrap_or_else(|e| vec![e.to_string()])
        };
        let d = defects(&b);
        assert!(
            d.iter()
                .any(|d| d.contains(&format!("primitive chunk {c}: checksum mismatch"))),
            "{}: {d:?}",
            fix.name
        );
        let b = fix.rewrite(Space::File, at, &[b[at]]);
        let d = defects(&b);
        assert!(
            !d.is_empty() && !d.iter().any(|d| d.contains("checksum")),
            "{}: recomputed checksums are accepted, the table is not: {d:?}",
            fix.name
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Truncated and extended files, generations (§2, §2.1)

#[test]
fn truncated_files_fail_at_open() {
    for fix in [
        default_file(),
        default_zstd_file(),
        list_file(),
        roped_file(),
        occluded_file(),
        updatable_file(),
        updated_file(),
    ] {
        truncated_file_fails_at_open(fix);
    }
}

/// A file cut short fails at open (§2: the file is at least `file_size` long), with an error
/// that says it is truncated; but an updated file cut after the end of its previous generation
/// opens as that generation (§2.1: its newest header slot records a longer file, so it is not
/// valid, and the reader takes the valid slot of the highest generation), which answers as it
/// did.
fn truncated_file_fails_at_open(fix: &'static Fixture) {
    let n = fix.bytes.len();
    // §2–§3: a file with ropes or a primitive table has a longer section table: cut at the end
    // of a table of seven entries, it still ends inside its own.
    let table_end = table_end(&fix.bytes);
    // The end of the previous generation, in the other slot (an updated file).
    let previous_end = match fix.generation {
        1 => None,
        _ => Some(read_u64(&fix.bytes, HEADER_SLOTS[1] - fix.slot + FILE_SIZE_AT) as usize),
    };
    let mut lengths = vec![
        0,
        1,
        7,
        8,
        9,
        100,
        HEADER_LEN - 1,
        HEADER_LEN,
        HEADER_LEN + 1,
        HEADER_LEN + ENTRY_LEN + 5,
        TABLE_END - 1,
        TABLE_END,
        TABLE_END + 1,
        table_end - 1,
        table_end,
        table_end + 1,
        HEADER_SLOTS[1] - 1,
        HEADER_SLOTS[1],
        HEADER_SLOTS[1] + HEADER_LEN,
        BLOCKS_START - 1,
        BLOCKS_START,
        BLOCKS_START + 1,
        n - 1,
    ];
    lengths.extend(
        previous_end
            .map(|e| [e - 1, e, e + 1])
            .into_iter()
            .flatten(),
    );
    for r in fix.regions.iter().filter(|r| r.space == Space::File) {
        let (a, b) = (r.range.start, r.range.end);
        lengths.extend([a, a + 1, (a + b) / 2, b - 1]);
    }
    lengths.sort_unstable();
    lengths.dedup();
    lengths.retain(|&l| l < n);
    // What the header slot the error is about records: slot 0's (a reader that finds no
    // valid slot reports slot 0's defect, §2.1).
    let recorded = read_u64(&fix.bytes, FILE_SIZE_AT) as usize;
    let mut previous_opened = 0;
    for &len in &lengths {
        if previous_end.is_some_and(|e| len >= e) {
            let what = format!("{}: {len} of {n} bytes", fix.name);
            match evaluate_guarded(fix, fix.bytes[..len].to_vec(), false, &what) {
                Ok(Verdict::Opened {
                    generation,
                    traced: Ok(Traced::Same),
                    defects: Ok(d),
                    ..
                }) if fix.is_previous(generation) && d.is_empty() => previous_opened += 1,
                v => panic!("{what}: should open as the previous generation, as it was: {v:?}"),
            }
            continue;
        }
        let mut bytes = AlignedBytes::from_slice(&fix.bytes);
        bytes.truncate(len);
        let err = match Scene::from_bytes(bytes, "cut.oavm") {
            Ok(_) => panic!("{}: {len} of {n} bytes: opened", fix.name),
            Err(Error::Format { source, .. }) => source,
            Err(e) => panic!("{}: {len} of {n} bytes: {e}", fix.name),
        };
        let msg = err.to_string();
        if len < HEADER_LEN {
            assert!(
                matches!(err, FormatError::TooShort { .. })
                    && msg.contains("truncated")
                    && msg.contains(&format!("{len} bytes")),
                "{len} bytes: {msg}"
            );
        } else {
            assert!(
                matches!(err, FormatError::Header(_))
                    && msg.contains("truncated")
                    && msg.contains(&format!("at least {recorded} bytes"))
                    && msg.contains(&format!("has {len} bytes")),
                "{}: {len} of {n} bytes: {msg}",
                fix.name
            );
        }
    }
    if previous_end.is_some() {
        assert!(
            previous_opened > 0,
            "{}: no cut after the previous generation",
            fix.name
        );
    }
    if fix.generation > 1 {
        return;
    }

    // Truncated, and the header's file size rewritten to match (checksum recomputed): the section
    // table then points past the end.
    for &len in lengths.iter().filter(|&&l| l >= HEADER_LEN) {
        let mut b = fix.bytes[..len].to_vec();
        write_u64(&mut b, FILE_SIZE_AT, len as u64);
        fix_header_checksum_at(&mut b, 0);
        let err = open_error(&b, &format!("{len} bytes, file_size patched"));
        let msg = err.to_string();
        if len < table_end {
            assert!(
                msg.contains("ends inside the section table"),
                "{len}: {msg}"
            );
        } else {
            assert!(
                matches!(err, FormatError::SectionTable(_))
                    && (msg.contains("run past the end") || msg.contains("the last section")),
                "{}: {len} bytes, file_size patched: {msg}",
                fix.name
            );
        }
    }
}

/// A file with bytes after its generation's end (§2, §2.1: `file_size` is where the
/// generation's sections end; a later generation, or an interrupted update, leaves bytes
/// after it) opens as the same generation, verifies clean and answers as before, bit for bit,
/// whatever those bytes are. With `file_size` rewritten to the longer length (checksum
/// recomputed) the sections no longer end the generation: that header is refused (a file as
/// packed fails at open; an updated one opens as its previous generation).
#[test]
fn extended_files_open_and_answer_as_before() {
    let mut problems = Vec::new();
    for fix in [
        default_file(),
        list_zstd_file(),
        deep_zstd_file(),
        roped_list_zstd_file(),
        occluded_zstd_file(),
        updatable_file(),
        updated_file(),
    ] {
        let n = fix.bytes.len();
        for extra in [1usize, 7, 64, 4096, 3 * 4096 + 5] {
            for garbage in [false, true] {
                let mut b = fix.bytes.clone();
                b.extend((0..extra).map(|i| match garbage {
                    true => (i * 131 + 7) as u8,
                    false => 0,
                }));
                let what = format!(
                    "{}: {extra} {} bytes appended",
                    fix.name,
                    if garbage { "garbage" } else { "zero" }
                );
                match evaluate_guarded(fix, b.clone(), extra == 4096, &what) {
                    Ok(Verdict::Opened {
                        generation,
                        traced: Ok(Traced::Same),
                        tight,
                        defects: Ok(d),
                    }) if generation == fix.generation
                        && d.is_empty()
                        && tight.as_ref().is_none_or(|t| *t == Ok(Traced::Same)) => {}
                    v => problems.push(format!(
                        "{what}: should open as generation {}, verify clean and answer as \
                         before: {v:?}",
                        fix.generation
                    )),
                }
                // With the file size and checksum rewritten, the sections no longer end the
                // generation.
                write_u64(&mut b, fix.slot + FILE_SIZE_AT, (n + extra) as u64);
                fix_header_checksum_at(&mut b, fix.slot);
                let what = format!("{what}, file_size patched");
                if fix.generation == 1 {
                    let err = open_error(&b, &what);
                    let last_section = |m: &str| m.contains("the last section ends at");
                    if !matches!(err, FormatError::SectionTable(ref m) if last_section(m)) {
                        problems.push(format!("{what}: {err}"));
                    }
                    continue;
                }
                match evaluate_guarded(fix, b, false, &what) {
                    Ok(Verdict::Opened {
                        generation,
                        traced: Ok(Traced::Same),
                        defects: Ok(d),
                        ..
                    }) if fix.is_previous(generation) && d.is_empty() => {}
                    v => problems.push(format!(
                        "{what}: should open as the previous generation, as it was: {v:?}"
                    )),
                }
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Generations (§2.1): a reader takes the valid header slot of the highest generation, so an
/// update that did not complete (its header not written, torn, or damaged since) leaves the
/// previous generation the file's, which reads as it did; the older slot's bytes do not
/// matter to the newer generation; a file with no valid slot is refused with slot 0's defect,
/// and two valid slots of one generation are an error.
#[test]
fn the_valid_slot_of_the_highest_generation_is_read() {
    let fix = updated_file();
    let before = updatable_file();
    assert_eq!((fix.generation, fix.slot), (2, HEADER_SLOTS[1]));
    let prev = fix
        .previous
        .as_ref()
        .expect("the previous generation")
        .generation;
    assert_eq!(prev, 1);
    let slot1 = HEADER_SLOTS[1]..BLOCKS_START;
    let mut problems = Vec::new();
    // (what, bytes, the generation it must open as)
    let mut cases: Vec<(String, Vec<u8>, u64)> = Vec::new();
    let mut b = fix.bytes.clone();
    b[slot1.clone()].fill(0);
    cases.push((
        "slot 1 zeroed (the update's header never written)".into(),
        b,
        1,
    ));
    let mut b = fix.bytes.clone();
    b[slot1.start + 100..slot1.end].fill(0);
    cases.push(("slot 1 torn after 100 bytes".into(), b, 1));
    let mut b = fix.bytes.clone();
    b[slot1.start + HEADER_CHECKSUM] ^= 1;
    cases.push(("slot 1's checksum wrong".into(), b, 1));
    let mut b = fix.bytes.clone();
    write_u64(&mut b, slot1.start + GENERATION_AT, 3);
    fix_header_checksum_at(&mut b, slot1.start);
    cases.push(("generation 3 in slot 1 (checksum recomputed)".into(), b, 1));
    let mut b = fix.bytes.clone();
    b[..HEADER_SLOTS[1]].fill(0);
    cases.push(("slot 0 zeroed".into(), b, 2));
    let mut b = fix.bytes.clone();
    b[HEADER_SLOTS[1] - 1] = 0xff;
    cases.push((
        "a byte after slot 0's table (not generation 2's)".into(),
        b,
        2,
    ));
    // Generation 1's own bytes where generation 2 does not refer to them: its section table
    // points at them, so they are older generations' bytes in generation 2's data region.
    let mut b = fix.bytes.clone();
    let (old_dir, _) = section_in(&b, 0, DIRECTORY);
    b[old_dir] ^= 0xff;
    cases.push(("generation 1's directory damaged".into(), b, 2));
    // The file as generation 1 left it, with what the update appended but no header for it
    // (a crash before step 3), then with bytes of a later, interrupted update after that.
    let mut b = before.bytes.clone();
    b.extend_from_slice(&fix.bytes[before.bytes.len()..]);
    cases.push((
        "generation 1 with the update's bytes appended".into(),
        b.clone(),
        1,
    ));
    b.extend((0..10_000).map(|i| (i * 7 + 1) as u8));
    b[slot1.clone()].copy_from_slice(&fix.bytes[slot1.clone()]);
    b[slot1.start + 300..slot1.end].fill(0xab);
    cases.push(("... and a torn header after them".into(), b, 1));
    for (what, b, generation) in cases {
        let what = format!("{}: {what}", fix.name);
        match evaluate_guarded(fix, b, true, &what) {
            Ok(Verdict::Opened {
                generation: g,
                traced: Ok(Traced::Same),
                tight: Some(Ok(Traced::Same)),
                defects: Ok(d),
            }) if g == generation && d.is_empty() => {}
            v => problems.push(format!(
                "{what}: should open as generation {generation}, verify clean and answer as it \
                 did: {v:?}"
            )),
        }
    }
    // No valid slot: slot 0's defect.
    let mut b = fix.bytes.clone();
    b[HEADER_SLOTS[1] + 5] ^= 1;
    b[5] ^= 1;
    match open(&b) {
        Err(Error::Format {
            source: FormatError::BadMagic { found },
            ..
        }) if found[5] == b[5] => {}
        r => problems.push(format!(
            "both slots' magic damaged: slot 0's defect: {:?}",
            r.err()
        )),
    }
    // The highest valid generation wins, whatever the slots hold: slot 0's header given
    // generation 3 (checksum recomputed) is read before slot 1's generation 2.
    let opened = |b: &[u8]| open(b).map(|s| (s.file().header().generation, s.file().slot()));
    let mut b = fix.bytes.clone();
    write_u64(&mut b, GENERATION_AT, 3);
    fix_header_checksum_at(&mut b, 0);
    match opened(&b) {
        Ok((3, 0)) => {}
        r => problems.push(format!("generation 3 in slot 0: {r:?}")),
    }
    // Generation g is in slot (g - 1) mod 2: generation 1 written into slot 1 (checksum
    // recomputed) makes that header invalid, and slot 0's generation 1 is read. (So two valid
    // slots never hold one generation: the reader's error for that cannot be reached.)
    let mut b = fix.bytes.clone();
    write_u64(&mut b, HEADER_SLOTS[1] + GENERATION_AT, 1);
    fix_header_checksum_at(&mut b, HEADER_SLOTS[1]);
    match opened(&b) {
        Ok((1, 0)) => {}
        r => problems.push(format!("generation 1 in slot 1: {r:?}")),
    }
    // The slots swapped: each header in the other's slot (generation and table offset say
    // otherwise), so no slot is valid: refused, with slot 0's defect.
    let mut b = fix.bytes.clone();
    b[..HEADER_SLOTS[1]].copy_from_slice(&fix.bytes[HEADER_SLOTS[1]..BLOCKS_START]);
    b[HEADER_SLOTS[1]..BLOCKS_START].copy_from_slice(&fix.bytes[..HEADER_SLOTS[1]]);
    match open(&b) {
        Err(Error::Format { source, .. }) if source.to_string().contains("slot 0") => {}
        r => problems.push(format!("slots swapped: slot 0's defect: {:?}", r.err())),
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The same through `Scene::open` on files on disk (memory-mapped; an empty file is not mapped).
#[test]
fn damaged_files_on_disk_fail_at_open() {
    let fix = default_file();
    let dir = tempfile::tempdir().expect("temporary directory");
    let n = fix.bytes.len();
    let mut flipped = fix.bytes.clone();
    flipped[HEADER_LEN + 3] ^= 4;
    let cases: [(&str, Vec<u8>, &str); 5] = [
        ("empty", Vec::new(), "shorter than a 256-byte header"),
        ("cut in the header", fix.bytes[..100].to_vec(), "truncated"),
        ("cut in a block", fix.bytes[..n / 2].to_vec(), "truncated"),
        (
            "bit flipped in the section table",
            flipped,
            "checksum mismatch",
        ),
        (
            "not an .oavm file",
            b"ply\nformat ascii 1.0\n".to_vec(),
            "not an .oavm file",
        ),
    ];
    for (what, bytes, expected) in cases {
        let path = dir.path().join(format!("{}.oavm", what.replace(' ', "_")));
        std::fs::write(&path, &bytes).expect("write");
        match Scene::open(&path) {
            Ok(_) => panic!("{what}: opened"),
            Err(e @ Error::Format { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(expected) && msg.contains(&path.display().to_string()),
                    "{what}: the error names the file and the problem: {msg}"
                );
            }
            Err(e) => panic!("{what}: not a format error: {e}"),
        }
    }
    let intact = dir.path().join("intact.oavm");
    std::fs::write(&intact, &fix.bytes).expect("write");
    let scene = Scene::open(&intact).expect("the intact file opens from disk");
    assert!(scene.verify().unwrap().is_ok());
    // A block damaged on disk: the file opens (blocks are not read at open); tracing the mapped
    // file fails naming the block, verify reports its checksum.
    let blk = fix.largest;
    let mut b = fix.bytes.clone();
    b[fix.dir[blk].offset + 100] ^= 0x10;
    let damaged = dir.path().join("damaged_block.oavm");
    std::fs::write(&damaged, &b).expect("write");
    let scene = Scene::open(&damaged).expect("a damaged block does not fail open");
    let mut hits = vec![Hit::MISS; fix.rays.len()];
    let err = scene
        .intersect_batch(&fix.rays, &mut hits)
        .expect_err("the damaged block is needed")
        .to_string();
    assert!(
        err.contains(&format!("block {blk}: checksum mismatch"))
            && err.contains(&damaged.display().to_string()),
        "{err}"
    );
    let defects = scene
        .verify()
        .map(|r| r.defects)
        .unwrap_or_else(|e| vec![e.to_string()]);
    assert!(
        defects
            .iter()
            .any(|d| d.contains(&format!("block {blk}: checksum mismatch"))),
        "{defects:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// Wrong magic, wrong version (§2, §12)

#[test]
fn wrong_magic_fails_at_open() {
    let fix = default_file();
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    for i in 0..8 {
        let mut b = fix.bytes.clone();
        b[i] ^= 0x20;
        cases.push((format!("magic byte {i} changed"), b));
    }
    let mut b = fix.bytes.clone();
    b[0] &= 0x7f;
    cases.push(("high bit stripped (7-bit transfer)".into(), b));
    // A text-mode transfer turns `\r\n` into `\n`: the magic, and everything after it, shifts.
    let mut b = fix.bytes.clone();
    b.remove(5);
    cases.push(("\\r\\n turned into \\n".into(), b));
    let mut b = fix.bytes.clone();
    b[..8].copy_from_slice(b"\x89PNG\r\n\x1a\n");
    cases.push(("a PNG".into(), b));
    let ply =
        std::fs::read(crate::common::shared_scene("dragon/dragon_vrip_res4.ply")).expect("ply");
    cases.push(("a PLY mesh".into(), ply[..4096].to_vec()));
    cases.push(("8 bytes of text".into(), b"ply\nform".to_vec()));
    cases.push(("zeros".into(), vec![0; fix.bytes.len()]));
    // A zstd frame (a compressed block on its own, say) is not a file either.
    cases.push(("a zstd frame".into(), zstd_frame(&fix.bytes)));
    for (what, b) in &cases {
        let err = open_error(b, what);
        assert!(
            matches!(err, FormatError::BadMagic { .. })
                && err.to_string().contains("not an .oavm file"),
            "{what}: {err}"
        );
    }
}

/// The version message names the version found and the one read, and says to repack.
fn assert_version_error(err: &FormatError, v: u32, what: &str) {
    assert!(
        matches!(err, FormatError::Version { expected, found }
            if *expected == oavm::physical::format::VERSION && *found == v),
        "{what}: {err}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains(&format!("version {v} "))
            && msg.contains(&format!("version {}", oavm::physical::format::VERSION))
            && msg.contains("repack"),
        "{what}: the message names both versions and says to repack: {msg}"
    );
}

#[test]
fn wrong_version_fails_at_open_and_says_to_repack() {
    let fix = default_file();
    // Every version but this one (§12: 7, the chunks of §8.3), 6 (the wide nodes of §8.7) the
    // one before it.
    for v in [0u32, 1, 2, 3, 4, 5, 6, 8, 0x100, u32::MAX] {
        for fix_checksum in [false, true] {
            let mut b = fix.bytes.clone();
            write_u32(&mut b, VERSION_AT, v);
            if fix_checksum {
                fix_header_checksum(&mut b);
            }
            let what = format!("version {v} (checksum recomputed: {fix_checksum})");
            assert_version_error(&open_error(&b, &what), v, &what);
            // The version is checked before anything a later version may have changed: the
            // header's other fields, the file size, the checksum.
            let mut b = b[..b.len() / 2].to_vec();
            for at in [16usize, 20, 24, 120, 136, 144, 168, 200] {
                write_u64(&mut b, at, u64::MAX);
            }
            let what = format!("version {v}, the rest of the header garbage, truncated");
            assert_version_error(&open_error(&b, &what), v, &what);
        }
    }
}

/// A version-1 file, laid out as the version-1 writer did (format-spec.md at version 1, §2–§3:
/// the same header without the block fields, then six flat sections: levels, nodes, ranks,
/// volumes, refs, triangles, each at a multiple of 64, checksummed).
fn encode_v1(parts: &TreeParts) -> Vec<u8> {
    let (p, h0) = (&parts.tree, &parts.header);
    let sections: [(&[u8], usize); 6] = [
        (bytemuck::cast_slice(&p.levels), p.levels.len()),
        (bytemuck::cast_slice(&p.nodes), p.nodes.len()),
        (bytemuck::cast_slice(&p.ranks), p.ranks.len()),
        (bytemuck::cast_slice(&p.volumes), p.volumes.len()),
        (bytemuck::cast_slice(&p.refs), p.refs.len()),
        (bytemuck::cast_slice(&p.triangles), p.triangles.len()),
    ];
    let mut out = vec![0u8; TABLE_END];
    for (i, (bytes, count)) in sections.into_iter().enumerate() {
        out.resize(out.len().next_multiple_of(ALIGN), 0);
        let e = HEADER_LEN + i * ENTRY_LEN;
        write_u32(&mut out, e, i as u32 + 1);
        let offset = out.len() as u64;
        write_u64(&mut out, e + ENTRY_OFFSET, offset);
        write_u64(&mut out, e + ENTRY_LENGTH, bytes.len() as u64);
        write_u64(&mut out, e + 24, count as u64);
        write_u64(&mut out, e + ENTRY_CHECKSUM, xxh3_64(bytes));
        out.extend_from_slice(bytes);
    }
    let len = out.len() as u64;
    let h = &mut out;
    h[..8].copy_from_slice(b"\x89OAVM\r\n\x1a");
    write_u32(h, VERSION_AT, 1);
    write_u32(h, 12, h0.flags & 1);
    write_u32(h, 16, HEADER_LEN as u32);
    write_u32(h, 20, 6);
    write_u64(h, 24, HEADER_LEN as u64);
    write_u64(h, FILE_SIZE_AT, len);
    for k in 0..3 {
        write_u64(h, ROOT_MIN_AT + 8 * k, h0.root_min[k].to_bits());
        write_u32(h, 72 + 4 * k, h0.mesh_min[k].to_bits());
        write_u32(h, 84 + 4 * k, h0.mesh_max[k].to_bits());
    }
    write_u64(h, ROOT_SIZE_AT, h0.root_size.to_bits());
    write_u64(h, 96, h0.input_triangles);
    write_u64(h, 104, h0.empty_leaves);
    write_u64(h, 112, h0.solid_leaves);
    write_u32(h, 120, p.levels.len() as u32);
    write_u32(h, 124, 21);
    write_u32(h, 128, h0.max_depth);
    write_u32(h, 132, h0.leaf_size);
    fix_header_checksum(h);
    out
}

#[test]
fn version_1_files_fail_at_open_and_say_to_repack() {
    let (parts, _) =
        oavm::pack::build(&dragon_part(600), &leaf4(), &oavm::pack::Quiet).expect("build");
    let v1 = encode_v1(&parts);
    assert_version_error(&open_error(&v1, "a version-1 file"), 1, "a version-1 file");
    // Truncated: the version is still what is reported (checked before the file size).
    let cut = &v1[..v1.len() / 3];
    assert_version_error(&open_error(cut, "a cut version-1 file"), 1, "a cut one");
    // From disk, through the map: the message names the file too.
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("v1.oavm");
    std::fs::write(&path, &v1).expect("write");
    match Scene::open(&path) {
        Ok(_) => panic!("a version-1 file opened"),
        Err(e @ Error::Format { .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains(&path.display().to_string())
                    && msg.contains("version 1 ")
                    && msg.contains("repack"),
                "{msg}"
            );
        }
        Err(e) => panic!("not a format error: {e}"),
    }
}

// ---------------------------------------------------------------------------------------------
// Header fields rewritten (§2), a regression among them

/// The header's `max_block_raw_len` (§2): above 2^30 the file fails at open, before the
/// checksum; below the largest block (checksum recomputed) the file opens, verify reports it,
/// and the pager refuses the block larger than it.
#[test]
fn max_block_raw_len_is_checked() {
    let mut problems = Vec::new();
    for fix in [default_file(), default_zstd_file(), list_file()] {
        for (v, fix_checksum) in [((1u64 << 30) + 1, false), (u64::MAX, true)] {
            let mut b = fix.bytes.clone();
            write_u64(&mut b, MAX_BLOCK_RAW_LEN_AT, v);
            if fix_checksum {
                fix_header_checksum(&mut b);
            }
            let msg = open_error(&b, "max_block_raw_len").to_string();
            assert!(msg.contains("max_block_raw_len"), "{msg}");
        }
        let largest = fix.largest;
        assert_eq!(fix.dir[largest].raw_len as u64, fix.max_raw);
        let mut b = fix.bytes.clone();
        write_u64(&mut b, MAX_BLOCK_RAW_LEN_AT, fix.max_raw - 1);
        fix_header_checksum(&mut b);
        let what = format!(
            "{}: max_block_raw_len one below the largest block",
            fix.name
        );
        expect_caught(fix, what, b, "max_block_raw_len", &[largest], &mut problems);
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The header's `chunk_groups` (§2, §8.3) and `reserved_u32`, checksum recomputed: beyond
/// `MAX_CHUNK_GROUPS`, non-zero in a file of lists, or `reserved_u32` non-zero, the file fails
/// at open naming the field. A value in range that cuts a block's groups into chunks other than
/// its chunk table's (the largest block of each file has several) is caught when the block is
/// read: the pager refuses it and verify reports it, naming the block and its table; 0 in a
/// file of clusters leaves its blocks' groups in a file without chunks, likewise.
#[test]
fn chunk_groups_is_checked() {
    let mut problems = Vec::new();
    let rewritten = |fix: &Fixture, at: usize, v: u32| {
        let mut b = fix.bytes.clone();
        write_u32(&mut b, at, v);
        fix_header_checksum(&mut b);
        b
    };
    for fix in [default_file(), default_zstd_file(), deep_file()] {
        assert_eq!(fix.chunk_groups, 8, "{}", fix.name);
        for v in [MAX_CHUNK_GROUPS + 1, 1 << 20, u32::MAX] {
            let what = format!("{}: chunk_groups {v}", fix.name);
            let msg = open_error(&rewritten(fix, CHUNK_GROUPS_AT, v), &what).to_string();
            if !msg.contains(&format!("chunk_groups is {v}")) {
                problems.push(format!("{what}: {msg}"));
            }
        }
        let blk = fix.largest;
        let e = fix.dir[blk];
        let groups = (e.raw_len - e.head_raw_len) / TRI_GROUP_LEN;
        let chunks = groups.div_ceil(fix.chunk_groups);
        assert!(chunks >= 3, "{}: block {blk}: {chunks} chunks", fix.name);
        // Every block that has groups needs chunks; a ray needs every block.
        let all: Vec<usize> = (0..fix.dir.len()).collect();
        // (A value that gives the block as many chunks would be caught by the chunks' lengths
        // instead: not tried.)
        let values: Vec<u32> = [1u32, 7, 9, 16, MAX_CHUNK_GROUPS]
            .into_iter()
            .filter(|&v| groups.div_ceil(v as usize) != chunks)
            .collect();
        assert!(
            values.len() >= 3,
            "{}: block {blk}: {groups} groups",
            fix.name
        );
        // Verify's report is capped (the largest block may be past the cap), so what it must
        // say is said of some block whose chunks the value changes, the largest described.
        let groups_of = |b: usize| (fix.dir[b].raw_len - fix.dir[b].head_raw_len) / TRI_GROUP_LEN;
        for v in values {
            let what = format!("{}: chunk_groups {v}", fix.name);
            let said = |b: usize| {
                let (g, per) = (groups_of(b), fix.chunk_groups);
                format!(
                    "block {b}: a head with {g} groups in {} chunks, where the entry says {g} \
                     groups in {}",
                    g.div_ceil(per),
                    g.div_ceil(v as usize)
                )
            };
            let texts: Vec<String> = (0..fix.dir.len())
                .filter(|&b| {
                    groups_of(b).div_ceil(fix.chunk_groups) != groups_of(b).div_ceil(v as usize)
                })
                .map(said)
                .collect();
            let text = said(blk);
            let b = rewritten(fix, CHUNK_GROUPS_AT, v);
            let reported = |d: &str| texts.iter().any(|t| d.contains(t.as_str()));
            expect_reported(fix, what, b, &text, &reported, &all, &mut problems);
        }
        let what = format!("{}: chunk_groups 0", fix.name);
        let texts: Vec<String> = (0..fix.dir.len())
            .filter(|&b| groups_of(b) > 0)
            .map(|b| {
                format!(
                    "block {b}: groups of {} bytes",
                    groups_of(b) * TRI_GROUP_LEN
                )
            })
            .collect();
        let text = format!(
            "block {blk}: groups of {} bytes",
            e.raw_len - e.head_raw_len
        );
        let reported =
            |d: &str| d.contains("without chunks") && texts.iter().any(|t| d.contains(t.as_str()));
        let b = rewritten(fix, CHUNK_GROUPS_AT, 0);
        expect_reported(fix, what, b, &text, &reported, &all, &mut problems);
    }
    for fix in [default_file(), list_file(), list_zstd_file()] {
        let what = format!("{}: reserved_u32 1", fix.name);
        let msg = open_error(&rewritten(fix, RESERVED_U32_AT, 1), &what).to_string();
        if !msg.contains("reserved fields are not zero") {
            problems.push(format!("{what}: {msg}"));
        }
    }
    for fix in [list_file(), list_zstd_file()] {
        assert_eq!(fix.chunk_groups, 0, "{}", fix.name);
        for v in [1, 8, MAX_CHUNK_GROUPS] {
            let what = format!("{}: chunk_groups {v} in a file of lists", fix.name);
            let msg = open_error(&rewritten(fix, CHUNK_GROUPS_AT, v), &what).to_string();
            if !msg.contains(&format!("chunk_groups is {v}")) {
                problems.push(format!("{what}: {msg}"));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Regression: verify used to pass a header whose `root_min` or `root_size` was rewritten
/// (checksum recomputed), though the tree no longer covered the mesh and rays missed. Verify now
/// checks `mesh_min..mesh_max` against the stored triangles and inside the root cube (spec §2:
/// since version 5 any cube that holds the mesh strictly inside, `oavm-pack --bounds`), and
/// reports a referenced triangle that misses its leaf's widened cell (a cube moved by a quarter
/// of its edge may still hold the mesh: that check is what catches it). In a file of lists the
/// answers change too; in a file of clusters the walk of §8.7 reads no cell and may not.
#[test]
fn verify_catches_a_moved_root_cube() {
    for fix in [default_file(), list_file()] {
        moved_root_cube_is_caught(fix);
    }
}

fn moved_root_cube_is_caught(fix: &'static Fixture) {
    let f64_at = |b: &[u8], at: usize| f64::from_bits(read_u64(b, at));
    let size = f64_at(&fix.bytes, ROOT_SIZE_AT);
    let cases: [(&str, usize, f64); 3] = [
        (
            "root_min.x moved by two root sizes",
            ROOT_MIN_AT,
            f64_at(&fix.bytes, ROOT_MIN_AT) + 2.0 * size,
        ),
        (
            "root_min.z moved by a quarter root size",
            ROOT_MIN_AT + 16,
            f64_at(&fix.bytes, ROOT_MIN_AT + 16) + 0.25 * size,
        ),
        ("root_size halved", ROOT_SIZE_AT, 0.5 * size),
    ];
    let mut problems = Vec::new();
    for (what, at, value) in cases {
        let mut b = fix.bytes.clone();
        write_u64(&mut b, at, value.to_bits());
        fix_header_checksum(&mut b);
        let scene = open(&b).expect("the header is well-formed");
        let traced = trace(fix, &scene);
        // The walk of a file of clusters (§8.7) takes its boxes from the wide nodes, in world
        // units: it reads no cell of the root cube, and may answer as before.
        assert!(
            fix.clusters || matches!(traced, Traced::Different(_)),
            "{}: {what}: the answers should change: {traced:?}",
            fix.name
        );
        let defects = scene
            .verify()
            .map(|r| r.defects)
            .unwrap_or_else(|e| vec![e.to_string()]);
        if defects.is_empty() {
            problems.push(format!(
                "{}: {what}: verify reports nothing; tracing gives {traced:?}",
                fix.name
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Misaligned buffers (§1)

#[test]
fn misaligned_buffers_give_errors_not_panics() {
    for fix in [default_file(), default_zstd_file(), list_file()] {
        for shift in 1..8usize {
            let what = format!("{}: file at buffer offset {shift}", fix.name);
            let w = what.clone();
            let result = guarded(&|| w.clone(), move || {
                let n = fix.bytes.len();
                let mut words = vec![0u64; n / 8 + 2];
                let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
                buf[shift..shift + n].copy_from_slice(&fix.bytes);
                let scene = Scene::from_bytes(&buf[shift..shift + n], "misaligned.oavm")
                    .map_err(|e| e.to_string())?;
                let mut out = Vec::new();
                if scene.file().is_aligned() {
                    out.push("the buffer is reported aligned".to_string());
                }
                if !scene
                    .file()
                    .records::<RankWord>(SectionKind::Ranks)
                    .is_empty()
                {
                    out.push("rank words were cast from a misaligned buffer".to_string());
                }
                if !scene.file().directory().is_empty() {
                    out.push("the directory was cast from a misaligned buffer".to_string());
                }
                let defects = scene
                    .verify()
                    .map(|r| r.defects)
                    .unwrap_or_else(|e| vec![e.to_string()]);
                if !defects.iter().any(|d| d.contains("not 8-byte aligned")) {
                    out.push(format!("verify does not report the alignment: {defects:?}"));
                }
                let mut hits = vec![Hit::MISS; fix.rays.len()];
                if scene.intersect_batch(&fix.rays, &mut hits).is_ok()
                    && hits.iter().any(|h| h.is_hit())
                {
                    out.push("closest hits found in a misaligned buffer".to_string());
                }
                let mut occ = vec![0u8; fix.rays.len()];
                if scene.occluded_batch(&fix.rays, &mut occ).is_ok() && occ.iter().any(|&o| o != 0)
                {
                    out.push("occlusion found in a misaligned buffer".to_string());
                }
                Ok::<_, String>(out)
            });
            match result {
                Err(panic) => panic!("{what}: {panic}"),
                Ok(Err(open)) => {
                    panic!("{what}: open reads the header unaligned, yet failed: {open}")
                }
                Ok(Ok(problems)) => assert!(problems.is_empty(), "{what}: {problems:?}"),
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Library bugs these runs found, one small reproduction each, kept as regression tests now
//    that they are fixed (the mutation runs no longer skip them: see `known_bug`,
//    anywhere.rs).

/// Was a bug: `verify` sized a bit set of the distinct triangles from the header's `input_triangles`
/// (`prims_seen` in `check_structure`, src/physical/verify.rs: `input_triangles / 64` words),
/// which open does not bound and the header checksum does not protect against a rewrite. A
/// header with `input_triangles = 2^61` (checksum recomputed) makes verify ask for 2^58 bytes
/// and abort the process ("memory allocation of 288230376151711744 bytes failed"); a value of
/// 2^40 would make it zero 128 GiB. Found by the rewritten-header runs (edge and random u64s
/// in `input_triangles`). Verify should check `input_triangles` against what the file can hold
/// (for instance, no more than a bound derived from `block_triangles`, or grow the set only to
/// the largest `prim` seen) before allocating, and report a defect.
#[test]
fn verify_does_not_allocate_by_input_triangles() {
    in_child_process(
        "header::verify_does_not_allocate_by_input_triangles",
        || {
            let fix = default_file();
            for v in [1u64 << 61, u64::MAX] {
                let mut b = fix.bytes.clone();
                write_u64(&mut b, 96, v);
                fix_header_checksum(&mut b);
                let scene = open(&b).expect("open does not check input_triangles");
                let defects = scene
                    .verify()
                    .map(|r| r.defects)
                    .unwrap_or_else(|e| vec![e.to_string()]);
                assert!(
                    !defects.is_empty(),
                    "input_triangles {v}: verify reports nothing"
                );
            }
        },
    );
}

/// Regression, found by `bit_flips_in_updated_file_are_caught`: a bit flipped in the level
/// table of the newest generation (§4.1; a byte generation 2 refers to, in its levels section)
/// made the file open as generation 1 with nothing reporting the damage, because open checked
/// the level table as part of a header slot's validity and so fell back to the older slot.
/// §2.1 makes a slot valid by its header and section table alone (what an interrupted update
/// can leave wrong; the data is synced before the header is written, so an interrupted update
/// cannot leave a valid header over a bad level table): damage after that is an error naming
/// the levels, or, if open cannot see it, a defect verify reports. Never the older generation.
#[test]
fn a_damaged_level_table_of_the_newest_generation_is_reported() {
    let fix = updated_file();
    let (levels, len) = section(&fix.bytes, LEVELS);
    let mut problems = Vec::new();
    for at in [levels, levels + len / 2, levels + len - 1] {
        let mut b = fix.bytes.clone();
        b[at] ^= 1;
        match open(&b) {
            Err(e) if e.to_string().contains("levels") => {}
            Err(e) => problems.push(format!("byte {at}: an error not naming the levels: {e}")),
            Ok(s) if s.file().header().generation == fix.generation => {
                let d = s.verify().map(|r| r.defects).unwrap_or_default();
                if !d.iter().any(|d| d.contains("levels")) {
                    problems.push(format!("byte {at}: verify does not report it: {d:?}"));
                }
            }
            Ok(s) => problems.push(format!(
                "byte {at} of generation {}'s levels section flipped: the file opens as \
                 generation {} (slot {}; the other slot: {:?}) and verifies {}",
                fix.generation,
                s.file().header().generation,
                s.file().slot(),
                s.file().other_slot(),
                match s.verify().map(|r| r.defects) {
                    Ok(d) if d.is_empty() => "clean".to_string(),
                    d => format!("{d:?}"),
                }
            )),
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
