//! Full verification of an opened file (`oavm-trace FILE --verify`): every byte is covered by a
//! checksum or a check. Opening already validated the header, the section table (both under the
//! header checksum) and the level table; this adds every section's checksum, zero padding, and
//! the invariants of format-spec §10 on the contents.

use serde::Serialize;

use super::file::OavmFile;
use super::format::*;
use crate::geom::tribox::{clipped_bounds, triangle_overlaps_box};
use crate::mapping::TreeMap;
use crate::mapping::morton::{LATTICE_SIZE, MAX_LEVEL, cell_origin, cell_size};

/// What verification found. `defects` is empty for a sound file.
#[derive(Clone, Debug, Default, Serialize)]
pub struct VerifyReport {
    pub bytes_checked: u64,
    pub sections_checked: u32,
    pub defects: Vec<String>,
}

impl VerifyReport {
    pub fn is_ok(&self) -> bool {
        self.defects.is_empty()
    }
}

/// At most this many defects are listed; the rest are counted.
const MAX_LISTED: usize = 50;

struct Defects {
    list: Vec<String>,
    more: usize,
}

impl Defects {
    fn push(&mut self, d: String) {
        if self.list.len() < MAX_LISTED {
            self.list.push(d);
        } else {
            self.more += 1;
        }
    }
}

/// Verifies everything open did not.
pub fn verify<D: AsRef<[u8]>>(file: &OavmFile<D>) -> VerifyReport {
    let mut d = Defects {
        list: Vec::new(),
        more: 0,
    };
    let bytes = file.bytes();
    let header = *file.header();

    // Checksums and padding: together with the header checksum they cover every byte.
    let mut covered = (std::mem::size_of::<Header>()
        + SectionKind::ALL.len() * std::mem::size_of::<SectionEntry>())
        as u64;
    let mut sections_checked = 0;
    for kind in SectionKind::ALL {
        let s = file.section(kind);
        if let Some(pad) = bytes.get(covered as usize..s.offset as usize)
            && pad.iter().any(|&b| b != 0)
        {
            d.push(format!(
                "padding before the {} section (bytes {covered}..{}) is not zero",
                kind.name(),
                s.offset
            ));
        }
        let computed = checksum(file.section_bytes(kind));
        if computed != s.checksum {
            d.push(format!(
                "{} section: checksum mismatch (stored {:#018x}, computed {computed:#018x})",
                kind.name(),
                s.checksum
            ));
        }
        sections_checked += 1;
        covered = s.offset + s.length;
    }
    if !file.is_aligned() {
        d.push("the buffer holding the file is not 8-byte aligned; records cannot be read".into());
    }

    check_structure(file, &header, &mut d);

    let mut defects = d.list;
    if d.more > 0 {
        defects.push(format!("... and {} more defects", d.more));
    }
    VerifyReport {
        bytes_checked: bytes.len() as u64,
        sections_checked,
        defects,
    }
}

fn check_structure<D: AsRef<[u8]>>(file: &OavmFile<D>, header: &Header, d: &mut Defects) {
    let levels = file.levels();
    let nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    let ranks: &[RankWord] = file.records(SectionKind::Ranks);
    let volumes: &[VolumeRecord] = file.records(SectionKind::Volumes);
    let refs: &[u32] = file.records(SectionKind::Refs);
    let tris: &[TriRecord] = file.records(SectionKind::Triangles);
    let map = TreeMap::new(levels, nodes, ranks);

    // The root cube follows from the mesh bounds (spec §2), and those from the triangles.
    let (root_min, root_size) = crate::build::root_cube(header.mesh_min, header.mesh_max);
    if root_min != header.root_min || root_size != header.root_size {
        d.push(format!(
            "header: root cube (min {:?}, size {}) is not the one the mesh bounds give (min {root_min:?}, size {root_size})",
            header.root_min, header.root_size
        ));
    }
    if !tris.is_empty() {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in tris.iter().flat_map(|t| t.v.iter()) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if lo != header.mesh_min || hi != header.mesh_max {
            d.push(format!(
                "header: mesh bounds {:?}..{:?} are not the triangles' bounds {lo:?}..{hi:?}",
                header.mesh_min, header.mesh_max
            ));
        }
    }
    let merged = header.flags & FLAG_MERGED != 0;

    // Node kinds, rank directory, and the leaves (for the order checks below).
    let mut leaves: Vec<(u64, u32, u64, NodeKind)> = Vec::new();
    let (mut empty, mut solid) = (0u64, 0u64);
    for (l, lv) in levels.iter().enumerate() {
        let l = l as u32;
        let mut internal = 0u64;
        let mut rank = 0u64;
        for w in 0..lv.node_count.div_ceil(64) {
            let Some(word) = ranks.get((lv.rank_start + w) as usize) else {
                d.push(format!("level {l}: rank word {w} missing"));
                break;
            };
            let mut bits = 0u64;
            for i in 64 * w..(64 * w + 64).min(lv.node_count) {
                let Some(rec) = nodes.get((lv.node_start + i) as usize) else {
                    break;
                };
                match rec.kind() {
                    None => d.push(format!("level {l} node {i}: invalid record {rec:?}")),
                    Some(NodeKind::Internal) => {
                        bits |= 1 << (i % 64);
                        internal += 1;
                    }
                    Some(k) => {
                        if let NodeKind::Empty { .. } = k {
                            empty += 1;
                        } else {
                            solid += 1;
                        }
                        leaves.push((0, l, i, k));
                    }
                }
            }
            if word.internal != bits || word.rank != rank {
                d.push(format!(
                    "level {l} rank word {w}: stores bits {:#x} rank {}, the nodes give {bits:#x} and {rank}",
                    word.internal, word.rank
                ));
            }
            rank += bits.count_ones() as u64;
        }
        if internal != lv.internal_count {
            d.push(format!(
                "level {l}: {internal} internal nodes, the level table says {}",
                lv.internal_count
            ));
        }
    }
    if empty != header.empty_leaves || solid != header.solid_leaves {
        d.push(format!(
            "{empty} empty and {solid} solid leaves, the header says {} and {}",
            header.empty_leaves, header.solid_leaves
        ));
    }

    // Leaf codes, for depth-first order: found from the root by rank, never trusted from data.
    fill_leaf_keys(&map, &mut leaves, d);
    leaves.sort_unstable_by_key(|&(key, ..)| key);

    // Solid leaves tile the references in depth-first order; empty leaves' volumes contain them.
    let mut next_ref = 0u64;
    let mut volume_used = vec![false; volumes.len()];
    for &(key, l, i, kind) in &leaves {
        let lo = crate::mapping::morton::decode(key);
        let size = cell_size(l);
        match kind {
            NodeKind::Solid {
                first,
                inline_count,
                bounds,
            } => {
                if first as u64 != next_ref {
                    d.push(format!(
                        "level {l} node {i}: references start at {first}, expected {next_ref} (leaf order)"
                    ));
                }
                match leaf_refs(refs, first, inline_count) {
                    None => {
                        d.push(format!("level {l} node {i}: references run past the refs section or have a bad count word"));
                        next_ref = first as u64 + inline_count.max(1) as u64;
                    }
                    Some((leaf, range)) => {
                        next_ref = range.end as u64;
                        if !leaf.windows(2).all(|w| w[0] < w[1]) {
                            d.push(format!(
                                "level {l} node {i}: references are not strictly increasing"
                            ));
                        }
                        if let Some(what) = bounds_defect(header, tris, leaf, lo, size, bounds) {
                            d.push(format!("level {l} node {i}: {what}"));
                        }
                    }
                }
            }
            NodeKind::Empty { volume, shape } => match volumes.get(volume as usize) {
                None => d.push(format!("level {l} node {i}: volume {volume} out of range")),
                Some(v) => {
                    volume_used[volume as usize] = true;
                    let contains = (0..3).all(|k| v.lo[k] <= lo[k] && lo[k] + size <= v.hi[k]);
                    if !contains {
                        d.push(format!(
                            "level {l} node {i}: volume {volume} does not contain the leaf"
                        ));
                    }
                    let (slo, shi) = shape.box_around(lo);
                    if !merged && (shape.level as u32 != l || shape.axes != 0) {
                        d.push(format!("level {l} node {i}: merged volume {shape:?} in a file built without merging"));
                    }
                    if shape.level as u32 > l || slo != v.lo || shi != v.hi {
                        d.push(format!(
                            "level {l} node {i}: volume shape {shape:?} gives {slo:?}..{shi:?}, the volume table {v:?}"
                        ));
                    }
                }
            },
            NodeKind::Internal => {}
        }
    }
    if next_ref != refs.len() as u64 {
        d.push(format!(
            "leaves reference {next_ref} of {} stored references",
            refs.len()
        ));
    }

    // Volumes: valid boxes in the lattice, used, and overlapping no solid leaf.
    for (i, v) in volumes.iter().enumerate() {
        if !(0..3).all(|k| v.lo[k] < v.hi[k] && v.hi[k] <= LATTICE_SIZE) {
            d.push(format!("volume {i}: {v:?} is not a box inside the lattice"));
            continue;
        }
        if !volume_used[i] {
            d.push(format!("volume {i}: referenced by no empty leaf"));
        }
        if let Some(what) = solid_leaf_inside(&map, v) {
            d.push(format!("volume {i}: {what}"));
        }
    }

    // References and triangles.
    let mut tri_used = vec![false; tris.len()];
    for (i, &r) in refs.iter().enumerate() {
        match tri_used.get_mut(r as usize) {
            Some(u) => *u = true,
            None => d.push(format!("reference {i}: triangle {r} out of range")),
        }
    }
    for (i, t) in tris.iter().enumerate() {
        if !t.v.iter().flatten().all(|c| c.is_finite()) {
            d.push(format!("triangle {i}: non-finite coordinates"));
        }
        if t.prim as u64 >= header.input_triangles {
            d.push(format!(
                "triangle {i}: primitive id {} beyond the input's {} triangles",
                t.prim, header.input_triangles
            ));
        }
        if !tri_used[i] {
            d.push(format!("triangle {i}: referenced by no leaf"));
        }
    }
}

/// Replaces each leaf's key by the Morton code of its lowest lattice corner, found by walking
/// the tree from the root (so a corrupt rank directory shows as a defect, not a wrong key).
fn fill_leaf_keys(map: &TreeMap, leaves: &mut [(u64, u32, u64, NodeKind)], d: &mut Defects) {
    // Codes per level, generated top-down by rank: level L+1's codes are the children of level
    // L's internal nodes, in order.
    let mut codes: Vec<Vec<u64>> = vec![vec![0]];
    for (l, lv) in map.levels().iter().enumerate().skip(1) {
        let prev = &codes[l - 1];
        let mut next = Vec::with_capacity(lv.node_count as usize);
        for (i, &code) in prev.iter().enumerate() {
            if let Ok(rec) = map.node(l as u32 - 1, i as u64)
                && rec.kind() == Some(NodeKind::Internal)
            {
                next.extend((0..8).map(|o| code << 3 | o));
            }
        }
        if next.len() as u64 != lv.node_count {
            d.push(format!(
                "level {l}: {} nodes, but the level above has children for {}",
                lv.node_count,
                next.len()
            ));
        }
        codes.push(next);
    }
    for leaf in leaves.iter_mut() {
        let (l, i) = (leaf.1, leaf.2);
        let code = codes
            .get(l as usize)
            .and_then(|c| c.get(i as usize))
            .copied()
            .unwrap_or(0);
        leaf.0 = crate::mapping::morton::encode(cell_origin(code, l));
    }
}

/// Checks that a solid leaf's tight bounds contain every part of its triangles inside its cell
/// (recomputed by clipping, as the builder does).
fn bounds_defect(
    header: &Header,
    tris: &[TriRecord],
    leaf: &[u32],
    cell_lo: [u32; 3],
    size: u32,
    bounds: LeafBounds,
) -> Option<String> {
    let scale = LATTICE_SIZE as f64 / header.root_size;
    let m = CELL_MARGIN;
    let lo: [f64; 3] = std::array::from_fn(|k| cell_lo[k] as f64 - m);
    let hi: [f64; 3] = std::array::from_fn(|k| (cell_lo[k] + size) as f64 + m);
    let s16 = size as f64 / 16.0;
    for &t in leaf {
        let tri = tris.get(t as usize)?;
        let v: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|k| (tri.v[i][k] as f64 - header.root_min[k]) * scale)
        });
        // The triangle must overlap the widened cell by the builder's own exact test (spec §6).
        let c: [f64; 3] = std::array::from_fn(|k| (lo[k] + hi[k]) * 0.5);
        let h: [f64; 3] = std::array::from_fn(|k| (hi[k] - lo[k]) * 0.5);
        if !triangle_overlaps_box(&v, c, h) {
            return Some(format!(
                "references triangle {t}, which does not overlap its cell"
            ));
        }
        let Some((a, b)) = clipped_bounds(&v, lo, hi) else {
            continue;
        };
        for k in 0..3 {
            // The stored box, widened by the margin as the tracer widens it.
            let slo = cell_lo[k] as f64 + bounds.lo[k] as f64 * s16 - m;
            let shi = cell_lo[k] as f64 + (bounds.hi[k] as f64 + 1.0) * s16 + m;
            // Allow the rounding of recomputing the clip (far below the margin).
            if a[k] < slo - 1e-6 || b[k] > shi + 1e-6 {
                return Some(format!(
                    "tight bounds {bounds:?} do not contain triangle {t}"
                ));
            }
        }
    }
    None
}

/// Describes a solid leaf whose interior overlaps box `v`, if there is one.
fn solid_leaf_inside(map: &TreeMap, v: &VolumeRecord) -> Option<String> {
    let mut stack = vec![(0u32, 0u64, [0u32; 3])];
    let mut budget = map.levels().iter().map(|l| l.node_count).sum::<u64>();
    while let Some((l, idx, lo)) = stack.pop() {
        budget = budget.checked_sub(1)?;
        let size = cell_size(l);
        let overlaps = (0..3).all(|k| lo[k] < v.hi[k] && v.lo[k] < lo[k] + size);
        if !overlaps {
            continue;
        }
        match map.node(l, idx).ok()?.kind()? {
            NodeKind::Solid { .. } => {
                return Some(format!(
                    "covers part of solid leaf at level {l}, lattice {lo:?}"
                ));
            }
            NodeKind::Empty { .. } => {}
            NodeKind::Internal if l < MAX_LEVEL => {
                let half = cell_size(l + 1);
                for o in 0..8u32 {
                    let child = map.child(l, idx, o).ok()?;
                    let clo = std::array::from_fn(|k| lo[k] + ((o >> k) & 1) * half);
                    stack.push((l + 1, child, clo));
                }
            }
            NodeKind::Internal => return None,
        }
    }
    None
}
