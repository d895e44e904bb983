//! Full verification of an opened file (`oavm-trace FILE --verify`, `oavm-inspect --verify`;
//! format-spec §11, "Verify"): every byte is covered by a checksum or a check. Opening already
//! validated the header, the section table (both under the header checksum) and the top tree's
//! level table. This drives the rest: the byte-level checks of the physical layer (section
//! checksums, padding, block placement; every block read as the pager reads it, checksum and
//! decoding included) and, here, the invariants of spec §10 on the contents of the top tree and
//! of every block (rank words, leaf order, volumes, tight bounds, link bounds, and in a file of
//! clusters the wide nodes of §8.7, laid out again and compared byte for byte) and the links
//! between them, which need the mapping layer's view of the tree.

use rayon::prelude::*;
use serde::Serialize;

use crate::geom::tribox::{clipped_bounds, triangle_overlaps_box};
use crate::mapping::ClusterGeometry;
use crate::mapping::morton::{self, cell_origin, cell_size};
use crate::mapping::{LevelInfos, TreeMap};
use crate::physical::format::*;
use crate::physical::verify::{
    Defects, check_block_padding, check_block_placement, check_prim_chunks, check_sections,
};
use crate::physical::wide::{self, WorldBox};
use crate::physical::{BlockReader, BlockView, OavmFile};
use crate::physical::{check_cluster, check_node, wide_region};

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

/// Verifies everything open did not.
pub fn verify<D: AsRef<[u8]> + Sync>(file: &OavmFile<D>) -> VerifyReport {
    let mut d = Defects::default();
    let sections_checked = check_sections(file, &mut d);
    check_structure(file, &mut d);
    VerifyReport {
        bytes_checked: file.bytes().len() as u64,
        sections_checked,
        defects: d.into_list(),
    }
}

/// A unit to check: the top tree, or one block's subtrees.
struct Unit<'a> {
    /// "top tree" or "block N", to start its defects with.
    label: String,
    map: TreeMap<'a>,
    /// Morton codes of its level-0 nodes.
    root_codes: Vec<u64>,
    volumes: &'a [VolumeRecord],
    refs: &'a [u32],
    tris: &'a [TriRecord],
    /// A file of clusters (spec §7.1): where the lattice lies, and the block's cluster parts.
    clusters: Option<ClusterGeometry>,
    cluster_nodes: &'a [ClusterNode],
    /// Where the clusters' nodes below their roots start in `cluster_nodes`: after the octree's
    /// region of the block's wide nodes (spec §8.7), counted from the node records (`None` if
    /// they cannot be counted, a defect reported with the records).
    below_start: Option<u64>,
    groups: &'a [TriGroup],
    top: bool,
    /// Ropes (spec §8.4), by node record; empty without them.
    ropes: &'a [RopeRecord],
}

/// The top tree as ropes name it: its map and every node's code, by level.
struct TopNodes<'a> {
    map: TreeMap<'a>,
    codes: Vec<Vec<u64>>,
}

/// What a unit contributes to the file's totals.
#[derive(Default)]
struct UnitTotals {
    empty: u64,
    solid: u64,
    /// Links (top tree only): block, root, level, code, index in the node records.
    links: Vec<(u32, u32, u32, u64, u64)>,
    lo: [f32; 3],
    hi: [f32; 3],
    triangles: u64,
}

impl UnitTotals {
    /// Grows the bounds to hold triangle `v`.
    fn grow(&mut self, v: &[[f32; 3]; 3]) {
        for p in v {
            for (k, &c) in p.iter().enumerate() {
                self.lo[k] = self.lo[k].min(c);
                self.hi[k] = self.hi[k].max(c);
            }
        }
    }
}

/// The block roots the top tree links to, by (block, root): each link's code and bounds.
type Roots = std::collections::HashMap<(u32, u32), (u64, LinkBounds)>;

/// The box each wide link gives its block root (spec §8.7), by (block, root): the links whose
/// box is well-formed.
type WideBoxes = std::collections::HashMap<(u32, u32), WorldBox>;

/// Checks the contents of the top tree and of every block, the links between them, and the
/// header's totals against what they hold.
fn check_structure<D: AsRef<[u8]> + Sync>(file: &OavmFile<D>, d: &mut Defects) {
    let header = file.header();
    check_root_cube(header, d);

    // The top tree.
    let top_infos = LevelInfos::new(file.levels(), 0);
    let top = Unit {
        label: "top tree".into(),
        map: TreeMap::new(
            &top_infos,
            file.levels(),
            file.records(SectionKind::Nodes),
            file.records(SectionKind::Ranks),
        ),
        root_codes: vec![0],
        volumes: file.records(SectionKind::Volumes),
        refs: &[],
        tris: &[],
        clusters: None,
        cluster_nodes: &[],
        below_start: Some(0),
        groups: &[],
        top: true,
        ropes: file.records(SectionKind::Ropes),
    };
    let top_totals = check_unit(&top, header, d);
    let top_index = TopNodes {
        map: top.map,
        codes: level_codes(&top, &mut Defects::default()),
    };
    check_ropes(&top, &top_index.codes, &top_index, None, header, d);

    // Links: every block root linked exactly once, from its level.
    check_link_bounds(file, d);
    let roots = linked_roots(file, &top_totals.links, d);
    let wide_boxes = check_top_wide(file, &top_totals.links, d);

    // The blocks: stored one after another inside the blocks section, each read as the pager
    // reads it (entry, checksum, decoding) and checked like the top tree.
    let placed = check_block_placement(file, d);
    let prims = check_prim_chunks(file, d);
    let (plausible, prims_seen) = prim_bits(header, file.bytes().len(), d);
    let seen = Seen {
        bits: &prims_seen,
        table: &prims,
    };
    let linked = Linked {
        roots: &roots,
        wide_boxes: &wide_boxes,
    };
    let results = check_blocks(file, &placed, &linked, &top_index, &seen);

    let (totals, bounded) = sum_totals(top_totals, results, d);
    check_totals(header, &totals, bounded, plausible, &seen, d);
}

/// The root cube holds the mesh (spec §2: fitted to it, or to bounds given at pack time that
/// hold it; an update keeps the cube).
fn check_root_cube(header: &Header, d: &mut Defects) {
    let inside = (0..3).all(|k| {
        header.mesh_min[k] as f64 > header.root_min[k]
            && (header.mesh_max[k] as f64) < header.root_min[k] + header.root_size
    });
    if !inside {
        d.push(format!(
            "header: mesh bounds {:?}..{:?} are not inside the root cube (min {:?}, size {})",
            header.mesh_min, header.mesh_max, header.root_min, header.root_size
        ));
    }
}

/// Link bounds: well-formed on links, zero elsewhere (open checked there is one per node);
/// each link's are compared with its block's leaves when the block is checked.
fn check_link_bounds<D: AsRef<[u8]>>(file: &OavmFile<D>, d: &mut Defects) {
    let link_bounds: &[LinkBounds] = file.records(SectionKind::LinkBounds);
    let top_nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    for (i, (rec, lb)) in top_nodes.iter().zip(link_bounds).enumerate() {
        let is_link = matches!(rec.kind(), Some(NodeKind::Link { .. }));
        if is_link && !lb.is_valid() {
            d.push(format!(
                "top tree node {i}: link bounds {lb:?} have lo > hi or reserved bytes set"
            ));
        } else if !is_link && *lb != LinkBounds::default() {
            d.push(format!(
                "top tree node {i}: link bounds {lb:?} on a node that is not a link"
            ));
        }
    }
}

/// The block roots the top tree's `links` name, with each link's code and bounds; a link past
/// the directory, from another level than its block's roots or to a root the block does not
/// have, and a root linked twice, are defects.
fn linked_roots<D: AsRef<[u8]>>(
    file: &OavmFile<D>,
    links: &[(u32, u32, u32, u64, u64)],
    d: &mut Defects,
) -> Roots {
    let directory = file.directory();
    let link_bounds: &[LinkBounds] = file.records(SectionKind::LinkBounds);
    // (The map holds one entry per link: its size follows the top tree's, never the
    // directory's claims.)
    let mut roots = Roots::new();
    for &(b, root, level, code, at) in links {
        let bounds = link_bounds.get(at as usize).copied().unwrap_or_default();
        let Some(entry) = directory.get(b as usize) else {
            d.push(format!(
                "top tree: a link at level {level} to block {b}, past the {} blocks",
                directory.len()
            ));
            continue;
        };
        if entry.root_level != level {
            d.push(format!(
                "top tree: a link at level {level} to block {b}, whose roots are at level {}",
                entry.root_level
            ));
        }
        if root >= entry.root_count {
            d.push(format!(
                "top tree: a link to root {root} of block {b}, which has {}",
                entry.root_count
            ));
        } else if roots.insert((b, root), (code, bounds)).is_some() {
            d.push(format!("block {b}: root {root} is linked twice"));
        }
    }
    roots
}

/// The bitset of distinct triangles the blocks hold, by primitive id: `input_triangles` bits,
/// at most as many bytes as the file has (a header claiming more is reported, and the bitset
/// left empty), so that no header makes verify allocate more than the file's size. Returns
/// whether the count is plausible, and the bitset.
fn prim_bits(
    header: &Header,
    file_len: usize,
    d: &mut Defects,
) -> (bool, Vec<std::sync::atomic::AtomicU64>) {
    let plausible = header.input_triangles <= 8 * file_len as u64;
    if !plausible {
        d.push(format!(
            "header: input_triangles {} is implausible for a file of {} bytes",
            header.input_triangles, file_len
        ));
    }
    let bits = (0..if plausible {
        header.input_triangles.div_ceil(64)
    } else {
        0
    })
        .map(|_| std::sync::atomic::AtomicU64::new(0))
        .collect();
    (plausible, bits)
}

/// Checks every placed block, in parallel (each decoded block is dropped when checked): the
/// defects and totals of each, in block order.
fn check_blocks<D: AsRef<[u8]> + Sync>(
    file: &OavmFile<D>,
    placed: &[bool],
    linked: &Linked<'_>,
    top: &TopNodes<'_>,
    seen: &Seen<'_>,
) -> Vec<(Defects, UnitTotals)> {
    let header = file.header();
    let directory = file.directory();
    let reader = BlockReader::new(file);
    (0..directory.len())
        .into_par_iter()
        .filter(|&b| placed[b])
        .map(|b| {
            let mut bd = Defects::default();
            let block = Block {
                reader: &reader,
                bytes: file.bytes(),
                id: b as u32,
                entry: directory[b],
            };
            let totals = check_block(&block, header, linked, top, seen, &mut bd);
            (bd, totals)
        })
        .collect()
}

/// The file's totals: the top tree's and the blocks' (whose defects are appended to `d`, in
/// block order); and whether some unit held triangles (else the bounds are not set).
fn sum_totals(
    top: UnitTotals,
    results: Vec<(Defects, UnitTotals)>,
    d: &mut Defects,
) -> (UnitTotals, bool) {
    let mut totals = top;
    let mut first_bounds = true;
    for (bd, t) in results {
        d.append(bd);
        totals.empty += t.empty;
        totals.solid += t.solid;
        totals.triangles += t.triangles;
        if t.triangles > 0 {
            for k in 0..3 {
                if first_bounds {
                    totals.lo[k] = t.lo[k];
                    totals.hi[k] = t.hi[k];
                } else {
                    totals.lo[k] = totals.lo[k].min(t.lo[k]);
                    totals.hi[k] = totals.hi[k].max(t.hi[k]);
                }
            }
            first_bounds = false;
        }
    }
    (totals, !first_bounds)
}

/// The header's counts against the file's totals: leaves, triangle records, distinct
/// triangles (if the header's count is `plausible`), the primitive table's completeness, and
/// the mesh bounds (if some unit held triangles: `bounded`).
fn check_totals(
    header: &Header,
    totals: &UnitTotals,
    bounded: bool,
    plausible: bool,
    seen: &Seen<'_>,
    d: &mut Defects,
) {
    if totals.empty != header.empty_leaves || totals.solid != header.solid_leaves {
        d.push(format!(
            "{} empty and {} solid leaves, the header says {} and {}",
            totals.empty, totals.solid, header.empty_leaves, header.solid_leaves
        ));
    }
    if totals.triangles != header.block_triangles {
        d.push(format!(
            "blocks hold {} triangle records, the header says {}",
            totals.triangles, header.block_triangles
        ));
    }
    let distinct: u64 = seen
        .bits
        .iter()
        .map(|w| w.load(std::sync::atomic::Ordering::Relaxed).count_ones() as u64)
        .sum();
    if plausible && distinct != header.stored_triangles {
        d.push(format!(
            "blocks hold {distinct} distinct triangles, the header says {}",
            header.stored_triangles
        ));
    }
    check_table_complete(seen.table, seen.bits, d);
    if bounded && (totals.lo != header.mesh_min || totals.hi != header.mesh_max) {
        d.push(format!(
            "header: mesh bounds {:?}..{:?} are not the triangles' bounds {:?}..{:?}",
            header.mesh_min, header.mesh_max, totals.lo, totals.hi
        ));
    }
}

/// Primitives seen in the blocks, and the primitive table (spec §8.6) by chunk, if the file
/// has one (a damaged chunk is empty).
struct Seen<'a> {
    bits: &'a [std::sync::atomic::AtomicU64],
    table: &'a [&'a [PrimRecord]],
}

/// Every primitive of the table that is present and not degenerate is stored in some block,
/// and every other is not (spec §8.6).
fn check_table_complete(
    table: &[&[PrimRecord]],
    seen: &[std::sync::atomic::AtomicU64],
    d: &mut Defects,
) {
    if table.is_empty() || seen.is_empty() {
        return;
    }
    let (mut missing, mut extra) = (0u64, 0u64);
    let mut first = None;
    for (c, chunk) in table.iter().enumerate() {
        for (i, r) in chunk.iter().enumerate() {
            let prim = c as u64 * PRIM_CHUNK + i as u64;
            let stored = seen.get(prim as usize / 64).is_some_and(|w| {
                w.load(std::sync::atomic::Ordering::Relaxed) >> (prim % 64) & 1 != 0
            });
            let should = !r.is_absent() && !crate::geom::triangle::is_degenerate(&r.v);
            if stored != should {
                if should {
                    missing += 1;
                } else {
                    extra += 1;
                }
                first.get_or_insert(prim);
            }
        }
    }
    if let Some(prim) = first {
        d.push(format!(
            "primitive table: {missing} triangles are in no block and {extra} stored triangles \
             are absent or degenerate in the table (primitive {prim}, first)"
        ));
    }
}

/// What the top tree says of the block roots: their links, and their wide links' boxes.
struct Linked<'a> {
    roots: &'a Roots,
    wide_boxes: &'a WideBoxes,
}

/// A block of the file to check.
struct Block<'a> {
    reader: &'a BlockReader,
    bytes: &'a [u8],
    id: u32,
    entry: BlockEntry,
}

/// Checks block `b`: read as the pager reads it (entry, checksum, decoding), its header and
/// level table, the padding between its parts, then its contents as a unit whose roots have
/// the codes its links give.
fn check_block(
    block: &Block,
    header: &Header,
    linked_roots: &Linked<'_>,
    top: &TopNodes<'_>,
    seen: &Seen<'_>,
    d: &mut Defects,
) -> UnitTotals {
    let (b, e) = (block.id, block.entry);
    let raw = match block.reader.read(block.bytes, b, &e) {
        Ok(raw) => raw,
        Err(err) => {
            d.push(err.to_string());
            return UnitTotals::default();
        }
    };
    let view = match BlockView::parse(&raw, b, &e) {
        Ok(v) => v,
        Err(what) => {
            d.push(format!("block {b}: {what}"));
            return UnitTotals::default();
        }
    };
    check_block_padding(&raw, &view.header, b, d);
    let Some(linked) = (0..view.header.root_count)
        .map(|j| linked_roots.roots.get(&(b, j)).copied())
        .collect::<Option<Vec<(u64, LinkBounds)>>>()
    else {
        d.push(format!("block {b}: a root has no link in the top tree"));
        return UnitTotals::default();
    };
    check_root_bounds(&view, &linked, b, d);
    let clusters = header.flags & FLAG_CLUSTERS != 0;
    let region = match clusters {
        true => check_block_wide(&view, b, linked_roots.wide_boxes, d),
        false => None,
    };
    let root_codes = linked.iter().map(|&(code, _)| code).collect();
    let infos = LevelInfos::new(view.levels, view.header.root_level);
    let unit = Unit {
        label: format!("block {b}"),
        map: TreeMap::new(&infos, view.levels, view.nodes, view.ranks),
        root_codes,
        volumes: view.volumes,
        refs: view.refs,
        tris: view.triangles,
        clusters: clusters.then_some(ClusterGeometry {
            root_min: header.root_min,
            root_size: header.root_size,
        }),
        cluster_nodes: view.cluster_nodes,
        // The octree's region as check_block_wide laid it out (adoption, spec §8.7, leaves
        // out some internal nodes, which depends on their boxes); a block it could not lay out
        // (reported there) is counted from its records, one wide node per internal node.
        below_start: match (clusters, region) {
            (true, Some(region)) => Some(region),
            (true, None) => wide_region(view.levels, view.nodes).map(|(i, s)| i + s),
            (false, _) => Some(0),
        },
        groups: view.groups,
        top: false,
        ropes: view.ropes,
    };
    let mut totals = check_unit(&unit, header, d);
    let codes = level_codes(&unit, &mut Defects::default());
    check_ropes(&unit, &codes, top, Some(b), header, d);
    check_occluders(&unit, &codes, &view, header, d);
    if unit.clusters.is_none() {
        totals.triangles = view.triangles.len() as u64;
    }
    check_block_prims(&view, b, seen, d);
    check_leaf_kind(&view, b, &e, unit.clusters.is_some(), &totals, d);
    totals
}

/// Each link's bounds are exactly what the root's solid leaves give (spec §8.1); records that
/// give none are reported by the unit check.
fn check_root_bounds(view: &BlockView<'_>, linked: &[(u64, LinkBounds)], b: u32, d: &mut Defects) {
    if let Ok(computed) = crate::physical::bounds::root_bounds(view.levels, view.nodes) {
        for (j, (c, (_, stored))) in computed.iter().zip(linked).enumerate() {
            if c != stored {
                d.push(format!(
                    "block {b}: the link to root {j} has bounds {:?}..{:?}, its leaves give {:?}..{:?}",
                    stored.lo, stored.hi, c.lo, c.hi
                ));
            }
        }
    }
}

/// Spec §8.7: a block of clusters' wide nodes and solid leaves' payloads are exactly what
/// [`wide::lay_block`] makes of its node records and cluster nodes (which proves the octree's
/// wide nodes right: their boxes, bases, counts and order; that each solid leaf's payload is
/// its own cluster's root, in the octree's region; and that the clusters' other nodes follow,
/// each cluster's together), and the box of each root's wide node is its wide link's.
///
/// Returns the size of the octree's region as laid out (adoption makes it depend on boxes), or
/// `None` if the block's wide nodes could not be laid out (reported).
fn check_block_wide(
    view: &BlockView<'_>,
    b: u32,
    wide_boxes: &WideBoxes,
    d: &mut Defects,
) -> Option<u64> {
    // Nodes the layout could not read (it takes their boxes and bases as they are).
    if let Some((i, what)) = view
        .cluster_nodes
        .iter()
        .enumerate()
        .find_map(|(i, n)| check_node(n).err().map(|e| (i, e)))
    {
        d.push(format!(
            "block {b}: wide node {i}: {what} (the block's wide nodes are not laid out again)"
        ));
        return None;
    }
    let laid = match wide::lay_block(view.levels, view.nodes, view.cluster_nodes) {
        Ok(w) => w,
        Err(e) => {
            d.push(format!(
                "block {b}: its wide nodes cannot be laid out (spec §8.7): {e}"
            ));
            return None;
        }
    };
    compare_wide(
        &format!("block {b}: wide node"),
        view.cluster_nodes,
        &laid.nodes,
        d,
    );
    if let Some(k) =
        (0..view.nodes.len().min(laid.records.len())).find(|&k| view.nodes[k] != laid.records[k])
    {
        let base = view.header.root_level;
        let (l, i) = view
            .levels
            .iter()
            .enumerate()
            .find(|(_, e)| (k as u64).wrapping_sub(e.node_start) < e.node_count)
            .map_or((base, k as u64), |(ll, e)| {
                (base + ll as u32, k as u64 - e.node_start)
            });
        d.push(format!(
            "block {b} level {l} node {i}: payload {}, the layout of the block's wide nodes              gives {} (spec §8.7: a solid leaf's cluster root)",
            view.nodes[k].payload, laid.records[k].payload
        ));
    }
    for (j, bx) in laid.roots.iter().enumerate() {
        let Some(link) = wide_boxes.get(&(b, j as u32)) else {
            continue; // reported with the top tree's wide links
        };
        if !same_box(link, bx) {
            d.push(format!(
                "block {b}: root {j}'s wide link has the box {:?}..{:?}, its wide node's                  children give {:?}..{:?}",
                link.0, link.1, bx.0, bx.1
            ));
        }
    }
    Some(laid.region as u64)
}

/// Whether two boxes are the same, bit for bit.
fn same_box(a: &WorldBox, b: &WorldBox) -> bool {
    let bits = |x: &WorldBox| (x.0.map(f32::to_bits), x.1.map(f32::to_bits));
    bits(a) == bits(b)
}

/// Reports the first of `stored` (what the file holds) that differs from `laid` (what the
/// layout gives), naming it `{what} {index}` and the first field that differs; or that their
/// counts differ.
fn compare_wide(what: &str, stored: &[ClusterNode], laid: &[ClusterNode], d: &mut Defects) {
    let bytes = |n: &ClusterNode| bytemuck::bytes_of(n).to_vec();
    if let Some(i) =
        (0..stored.len().min(laid.len())).find(|&i| bytes(&stored[i]) != bytes(&laid[i]))
    {
        let (s, l) = (&stored[i], &laid[i]);
        let field = if s.origin.map(f32::to_bits) != l.origin.map(f32::to_bits) {
            format!("origin {:?}, laid out {:?}", s.origin, l.origin)
        } else if s.exp != l.exp {
            format!("exp {:?}, laid out {:?}", s.exp, l.exp)
        } else if (s.child_count, s.inner_count) != (l.child_count, l.inner_count) {
            format!(
                "{} children ({} inner), laid out {} ({})",
                s.child_count, s.inner_count, l.child_count, l.inner_count
            )
        } else if (s.node_base, s.group_base) != (l.node_base, l.group_base) {
            format!(
                "node_base {} group_base {}, laid out {} and {}",
                s.node_base, s.group_base, l.node_base, l.group_base
            )
        } else if (s.lo, s.hi) != (l.lo, l.hi) {
            let slot = (0..8)
                .find(|&c| (0..3).any(|k| (s.lo[k][c], s.hi[k][c]) != (l.lo[k][c], l.hi[k][c])))
                .unwrap_or(0);
            let q = |n: &ClusterNode| {
                (
                    [0, 1, 2].map(|k| n.lo[k][slot]),
                    [0, 1, 2].map(|k| n.hi[k][slot]),
                )
            };
            format!("child {slot}'s box {:?}, laid out {:?}", q(s), q(l))
        } else {
            "reserved bytes".to_string()
        };
        d.push(format!(
            "{what} {i}: {field} (spec §8.7: not what the layout makes of the tree)"
        ));
    } else if stored.len() != laid.len() {
        d.push(format!(
            "{what}s: {} of them, the layout of spec §8.7 makes {}",
            stored.len(),
            laid.len()
        ));
    }
}

/// Spec §8.7: in a file of clusters, the top tree's wide nodes and wide links are exactly what
/// [`wide::lay_top`] makes of its node records and the wide links' boxes; so every link of the
/// top tree has exactly one wide link, and there is no other. (That each box is its block
/// root's is checked with the block, [`check_block_wide`].) A file of lists has neither.
/// Returns the wide links' boxes by (block, root).
fn check_top_wide<D: AsRef<[u8]>>(
    file: &OavmFile<D>,
    links: &[(u32, u32, u32, u64, u64)],
    d: &mut Defects,
) -> WideBoxes {
    let nodes: &[ClusterNode] = file.records(SectionKind::WideNodes);
    let wide_links: &[WideLink] = file.records(SectionKind::WideLinks);
    let mut boxes = WideBoxes::new();
    if file.header().flags & FLAG_CLUSTERS == 0 {
        if !nodes.is_empty() || !wide_links.is_empty() {
            d.push("wide nodes or wide links in a file of leaf lists".into());
        }
        return boxes;
    }
    let top_links: std::collections::HashSet<(u32, u32)> =
        links.iter().map(|&(b, r, ..)| (b, r)).collect();
    let mut named = std::collections::HashSet::new();
    for (i, w) in wide_links.iter().enumerate() {
        let key = (w.block, w.root);
        if !named.insert(key) {
            d.push(format!(
                "wide links section link {i}: block {} root {} has a wide link already",
                w.block, w.root
            ));
            continue;
        }
        if !top_links.contains(&key) {
            d.push(format!(
                "wide links section link {i}: block {} root {}, which no link of the top tree                  names",
                w.block, w.root
            ));
        }
        let finite = w.lo.iter().chain(&w.hi).all(|x| x.is_finite());
        if !finite || (0..3).any(|k| w.lo[k] > w.hi[k]) {
            d.push(format!(
                "wide links section link {i} (block {} root {}): box {:?}..{:?} is not finite                  with lo <= hi",
                w.block, w.root, w.lo, w.hi
            ));
            continue;
        }
        boxes.insert(key, (w.lo, w.hi));
    }
    let mut complete = true;
    for &(b, r, _, _, at) in links {
        if !named.contains(&(b, r)) {
            complete = false;
            d.push(format!(
                "top tree node {at}: its link to block {b} root {r} has no wide link"
            ));
        }
    }
    if !complete || boxes.len() != named.len() {
        return boxes; // the layout needs a box for every link
    }
    let top_nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    match wide::lay_top(file.levels(), top_nodes, |b, r| boxes.get(&(b, r)).copied()) {
        Err(e) => d.push(format!(
            "wide nodes section: the top tree's wide nodes cannot be laid out (spec §8.7): {e}"
        )),
        Ok((laid_nodes, laid_links)) => {
            compare_wide("wide nodes section node", nodes, &laid_nodes, d);
            if let Some(i) = (0..wide_links.len().min(laid_links.len()))
                .find(|&i| bytemuck::bytes_of(&wide_links[i]) != bytemuck::bytes_of(&laid_links[i]))
            {
                let (s, l) = (&wide_links[i], &laid_links[i]);
                d.push(format!(
                    "wide links section link {i}: block {} root {}, the layout of spec §8.7                      puts block {} root {} there",
                    s.block, s.root, l.block, l.root
                ));
            } else if wide_links.len() != laid_links.len() {
                d.push(format!(
                    "wide links section: {} links, the layout of spec §8.7 makes {}",
                    wide_links.len(),
                    laid_links.len()
                ));
            }
        }
    }
    boxes
}

/// Marks the primitives block `b` stores (triangle records, occluders and group lanes) as
/// seen, and compares each with the primitive table, which holds the triangle as the block
/// stores it (spec §8.6).
fn check_block_prims(view: &BlockView<'_>, b: u32, seen: &Seen<'_>, d: &mut Defects) {
    let lanes = view
        .groups
        .iter()
        .flat_map(|g| (0..g.count.min(8) as usize).map(move |l| (g.prim[l], g.triangle(l))));
    let records = view.triangles.iter().chain(view.occluders);
    let mut mismatched = 0u64;
    let mut example = None;
    for (prim, v) in records.map(|t| (t.prim, t.v)).chain(lanes) {
        if let Some(w) = seen.bits.get(prim as usize / 64) {
            w.fetch_or(1 << (prim % 64), std::sync::atomic::Ordering::Relaxed);
        }
        if !seen.table.is_empty() {
            let c = (prim as u64 / PRIM_CHUNK) as usize;
            let i = (prim as u64 % PRIM_CHUNK) as usize;
            let same = seen
                .table
                .get(c)
                .and_then(|chunk| chunk.get(i))
                .map(|r| r.same_bits(&PrimRecord { v }));
            // A damaged chunk (empty here) was reported already.
            if same == Some(false)
                || (same.is_none() && seen.table.get(c).is_some_and(|ch| !ch.is_empty()))
            {
                mismatched += 1;
                example.get_or_insert(prim);
            }
        }
    }
    if let Some(prim) = example {
        d.push(format!(
            "block {b}: {mismatched} stored triangles differ from the primitive table (primitive {prim}, first)"
        ));
    }
}

/// A block holds the parts of its file's kind of leaf only (leaf lists, or clusters:
/// `clusters`), and a block of clusters the triangles its directory entry `e` says (block
/// `b`'s `totals` count them).
fn check_leaf_kind(
    view: &BlockView<'_>,
    b: u32,
    e: &BlockEntry,
    clusters: bool,
    totals: &UnitTotals,
    d: &mut Defects,
) {
    if !clusters && (!view.cluster_nodes.is_empty() || !view.groups.is_empty()) {
        d.push(format!(
            "block {b}: cluster nodes or groups in a file of leaf lists"
        ));
    }
    if clusters && !(view.refs.is_empty() && view.triangles.is_empty()) {
        d.push(format!(
            "block {b}: references or triangle records in a file of clusters"
        ));
    }
    if clusters && totals.triangles != e.triangles as u64 {
        d.push(format!(
            "block {b}: its groups hold {} triangles, the directory says {}",
            totals.triangles, e.triangles
        ));
    }
}

/// A leaf of a unit, for the leaf-order checks: the Morton key of its cell's lowest corner
/// (the code at the deepest level), its level, index in the level, and kind.
type Leaf = (u64, u32, u64, NodeKind);

/// Checks one unit: node kinds, rank words, leaf order of references, volumes, triangles.
fn check_unit(u: &Unit, header: &Header, d: &mut Defects) -> UnitTotals {
    let mut totals = UnitTotals {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
        ..UnitTotals::default()
    };

    // Node kinds, rank directory, and the leaves (for the order checks below).
    let mut leaves: Vec<Leaf> = Vec::new();
    for (ll, lv) in u.map.levels().iter().enumerate() {
        check_level(u, ll, lv, &mut totals, &mut leaves, d);
    }

    // Leaf codes, for depth-first order: found from the roots by rank, never trusted from data.
    order_leaves(u, &mut leaves, &mut totals, d);

    // Solid leaves tile the references in depth-first order; empty leaves' volumes contain them.
    // (Triangles are marked used from the leaves' ranges: a count word is not a reference.)
    let mut walk = LeafWalk::new(u, header);
    for leaf in &leaves {
        walk.leaf(leaf, &mut totals, d);
    }
    walk.check_covered(d);

    check_volumes(u, &walk.volume_used, d);
    check_triangles(u, header, &walk.tri_used, &mut totals, d);
    totals
}

/// Checks the node records of local level `ll` (`lv` its level entry) and their rank words
/// and internal count; counts the leaves in `totals` and adds them to `leaves` (key 0, which
/// [`order_leaves`] sets).
fn check_level(
    u: &Unit,
    ll: usize,
    lv: &LevelEntry,
    totals: &mut UnitTotals,
    leaves: &mut Vec<Leaf>,
    d: &mut Defects,
) {
    let label = &u.label;
    let l = u.map.base() + ll as u32;
    let mut internal = 0u64;
    let mut rank = 0u64;
    for w in 0..lv.node_count.div_ceil(64) {
        let Some(word) = u.map.rank_word(l, w) else {
            d.push(format!("{label} level {l}: rank word {w} missing"));
            break;
        };
        let mut bits = 0u64;
        for i in 64 * w..(64 * w + 64).min(lv.node_count) {
            let Ok(rec) = u.map.node(l, i) else {
                break;
            };
            match rec.kind() {
                None => d.push(format!(
                    "{label} level {l} node {i}: invalid record {rec:?}"
                )),
                Some(NodeKind::Internal) => {
                    bits |= 1 << (i % 64);
                    internal += 1;
                }
                Some(NodeKind::Solid { .. }) if u.top => d.push(format!(
                    "{label} level {l} node {i}: a solid leaf in the top tree"
                )),
                Some(NodeKind::Link { .. }) if !u.top => {
                    d.push(format!("{label} level {l} node {i}: a link inside a block"))
                }
                Some(k) => {
                    match k {
                        NodeKind::Empty { .. } => totals.empty += 1,
                        NodeKind::Solid { .. } => totals.solid += 1,
                        _ => {}
                    }
                    leaves.push((0, l, i, k));
                }
            }
        }
        if word.internal != bits || word.rank != rank {
            d.push(format!(
                "{label} level {l} rank word {w}: stores bits {:#x} rank {}, the nodes give {bits:#x} and {rank}",
                word.internal, word.rank
            ));
        }
        rank += bits.count_ones() as u64;
    }
    if internal != lv.internal_count {
        d.push(format!(
            "{label} level {l}: {internal} internal nodes, the level table says {}",
            lv.internal_count
        ));
    }
}

/// Gives each leaf the key of its cell from the codes found from the roots by rank, records
/// the links in `totals`, and sorts the leaves into depth-first order.
fn order_leaves(u: &Unit, leaves: &mut [Leaf], totals: &mut UnitTotals, d: &mut Defects) {
    let base = u.map.base();
    let codes = level_codes(u, d);
    for leaf in leaves.iter_mut() {
        let (l, i) = (leaf.1, leaf.2);
        let code = codes
            .get((l - base) as usize)
            .and_then(|c| c.get(i as usize))
            .copied()
            .unwrap_or(0);
        leaf.0 = morton::encode(cell_origin(code, l));
        if let NodeKind::Link { block, root } = leaf.3 {
            totals
                .links
                .push((block, root, l, code, u.map.node_start(l) + i));
        }
    }
    leaves.sort_unstable_by_key(|&(key, ..)| key);
}

/// Where a leaf is: its level, index in the level, Morton key, and cell (lowest corner and
/// edge, lattice units).
struct LeafAt {
    l: u32,
    i: u64,
    key: u64,
    lo: [u32; 3],
    size: u32,
}

/// A solid leaf's record (see [`NodeKind::Solid`]).
#[derive(Clone, Copy)]
struct Solid {
    first: u32,
    inline_count: u32,
    bounds: LeafBounds,
}

/// The walk of a unit's leaves in depth-first order: the solid leaves must tile the
/// references (or, in a file of clusters, the cluster nodes and groups) in that order; the
/// triangles and volumes the leaves use.
struct LeafWalk<'u, 'a> {
    u: &'u Unit<'a>,
    header: &'u Header,
    merged: bool,
    tri_used: Vec<bool>,
    volume_used: Vec<bool>,
    /// Where the next solid leaf's references, cluster nodes below its root and groups must
    /// start; for the clusters, `None` after a cluster that is not sound (whose extent is not
    /// known: the next sound one starts them again).
    next_ref: u64,
    next_below: Option<u64>,
    next_group: Option<u64>,
}

impl<'u, 'a> LeafWalk<'u, 'a> {
    fn new(u: &'u Unit<'a>, header: &'u Header) -> Self {
        LeafWalk {
            u,
            header,
            merged: header.flags & FLAG_MERGED != 0,
            tri_used: vec![false; u.tris.len()],
            volume_used: vec![false; u.volumes.len()],
            next_ref: 0,
            next_below: u.below_start,
            next_group: Some(0),
        }
    }

    /// Checks the next leaf in depth-first order (links have nothing to check here).
    fn leaf(&mut self, &(key, l, i, kind): &Leaf, totals: &mut UnitTotals, d: &mut Defects) {
        let at = LeafAt {
            l,
            i,
            key,
            lo: morton::decode(key),
            size: cell_size(l),
        };
        match kind {
            NodeKind::Solid {
                first,
                inline_count,
                bounds,
            } => {
                let s = Solid {
                    first,
                    inline_count,
                    bounds,
                };
                if self.u.clusters.is_some() {
                    self.cluster_leaf(&at, s, totals, d);
                } else {
                    self.list_leaf(&at, s, d);
                }
            }
            NodeKind::Empty { volume, shape } => self.empty_leaf(&at, volume, shape, d),
            NodeKind::Internal | NodeKind::Link { .. } => {}
        }
    }

    /// A solid leaf of a file of clusters: its cluster is sound, the nodes below its root and
    /// its groups start where the previous leaf's ended (spec §8.7: the cluster roots are
    /// among the octree's wide nodes, in the layout's order, which [`check_block_wide`]
    /// checks; the nodes below them follow in leaf order, from `below_start`), and its tight
    /// bounds hold its lanes' triangles, which count in the unit's totals.
    fn cluster_leaf(&mut self, at: &LeafAt, s: Solid, totals: &mut UnitTotals, d: &mut Defects) {
        let u = self.u;
        let (label, l, i) = (&u.label, at.l, at.i);
        let Solid {
            first,
            inline_count,
            bounds,
        } = s;
        let geometry = u.clusters.unwrap_or(ClusterGeometry {
            root_min: [0.0; 3],
            root_size: 1.0,
        });
        if inline_count != 0 {
            d.push(format!(
                "{label} level {l} node {i}: a cluster's leaf with a reference count"
            ));
        }
        if let Some(region) = u.below_start
            && first as u64 >= region
        {
            d.push(format!(
                "{label} level {l} node {i}: cluster root {first}, not among the octree's \
                 {region} wide nodes and cluster roots (spec §8.7)"
            ));
        }
        let clip = geometry.widened_cell(l, at.key >> (3 * (MAX_LEVEL - l)));
        let shape = match check_cluster(u.cluster_nodes, u.groups, first, clip) {
            Err(what) => {
                d.push(format!("{label} level {l} node {i}: cluster: {what}"));
                (self.next_below, self.next_group) = (None, None);
                return;
            }
            Ok(shape) => shape,
        };
        if !shape.below.is_empty() {
            if let Some(next) = self.next_below
                && shape.below.start as u64 != next
            {
                d.push(format!(
                    "{label} level {l} node {i}: cluster nodes below root {first} start at {}, \
                     expected {next} (leaf order)",
                    shape.below.start
                ));
            }
            self.next_below = Some(shape.below.end as u64);
        }
        if let Some(next) = self.next_group
            && shape.groups.start as u64 != next
        {
            d.push(format!(
                "{label} level {l} node {i}: cluster groups start at {}, expected {next} (leaf order)",
                shape.groups.start
            ));
        }
        self.next_group = Some(shape.groups.end as u64);
        let groups = u
            .groups
            .get(shape.groups.start as usize..shape.groups.end as usize)
            .unwrap_or(&[]);
        let lanes: Vec<TriRecord> = groups
            .iter()
            .flat_map(|g| {
                (0..g.count.min(8) as usize).map(|l| TriRecord {
                    v: g.triangle(l),
                    prim: g.prim[l],
                })
            })
            .collect();
        let all: Vec<u32> = (0..lanes.len() as u32).collect();
        if let Some(what) = bounds_defect(self.header, &lanes, &all, at.lo, at.size, bounds) {
            d.push(format!("{label} level {l} node {i}: {what}"));
        }
        for t in &lanes {
            if let Some(what) = triangle_defect(self.header, t) {
                d.push(format!("{label} level {l} node {i}: a lane's {what}"));
            }
            totals.grow(&t.v);
        }
        totals.triangles += lanes.len() as u64;
    }

    /// A solid leaf of a file of leaf lists: its references start where the previous leaf's
    /// ended and name triangles of the unit in increasing order, which its tight bounds hold.
    fn list_leaf(&mut self, at: &LeafAt, s: Solid, d: &mut Defects) {
        let u = self.u;
        let (label, l, i) = (&u.label, at.l, at.i);
        let Solid {
            first,
            inline_count,
            bounds,
        } = s;
        let next_ref = self.next_ref;
        if first as u64 != next_ref {
            d.push(format!(
                "{label} level {l} node {i}: references start at {first}, expected {next_ref} (leaf order)"
            ));
        }
        let Some((leaf, range)) = leaf_refs(u.refs, first, inline_count) else {
            d.push(format!(
                "{label} level {l} node {i}: references run past the refs or have a bad count word"
            ));
            self.next_ref = first as u64 + inline_count.max(1) as u64;
            return;
        };
        self.next_ref = range.end as u64;
        for &t in leaf {
            match self.tri_used.get_mut(t as usize) {
                Some(used) => *used = true,
                None => d.push(format!(
                    "{label} level {l} node {i}: triangle {t} out of range"
                )),
            }
        }
        if !leaf.windows(2).all(|w| w[0] < w[1]) {
            d.push(format!(
                "{label} level {l} node {i}: references are not strictly increasing"
            ));
        }
        if let Some(what) = bounds_defect(self.header, u.tris, leaf, at.lo, at.size, bounds) {
            d.push(format!("{label} level {l} node {i}: {what}"));
        }
    }

    /// An empty leaf: its volume is in the table and contains its cell, and the leaf's shape
    /// gives that volume's box (its own cell's, in a file built without merging).
    fn empty_leaf(&mut self, at: &LeafAt, volume: u32, shape: VolumeShape, d: &mut Defects) {
        let (label, l, i, lo, size) = (&self.u.label, at.l, at.i, at.lo, at.size);
        let Some(v) = self.u.volumes.get(volume as usize) else {
            d.push(format!(
                "{label} level {l} node {i}: volume {volume} out of range"
            ));
            return;
        };
        self.volume_used[volume as usize] = true;
        let contains = (0..3).all(|k| v.lo[k] <= lo[k] && lo[k] + size <= v.hi[k]);
        if !contains {
            d.push(format!(
                "{label} level {l} node {i}: volume {volume} does not contain the leaf"
            ));
        }
        let (slo, shi) = shape.box_around(lo);
        if !self.merged && (shape.level as u32 != l || shape.axes != 0) {
            d.push(format!("{label} level {l} node {i}: merged volume {shape:?} in a file built without merging"));
        }
        if shape.level as u32 > l || slo != v.lo || shi != v.hi {
            d.push(format!(
                "{label} level {l} node {i}: volume shape {shape:?} gives {slo:?}..{shi:?}, the volume table {v:?}"
            ));
        }
    }

    /// After the last leaf: the solid leaves covered every reference, cluster node below a
    /// root (after the octree's region) and group; as far as known (a cluster that is not
    /// sound was reported).
    fn check_covered(&self, d: &mut Defects) {
        let u = self.u;
        let label = &u.label;
        let next_ref = self.next_ref;
        if next_ref != u.refs.len() as u64 {
            d.push(format!(
                "{label}: leaves reference {next_ref} of {} stored references",
                u.refs.len()
            ));
        }
        let (nodes, groups) = (u.cluster_nodes.len() as u64, u.groups.len() as u64);
        if let (Some(start), Some(next_below), Some(next_group)) =
            (u.below_start, self.next_below, self.next_group)
            && (next_below != nodes || next_group != groups)
        {
            d.push(format!(
                "{label}: clusters hold nodes {start}..{next_below} below their roots and groups \
                 0..{next_group} of {nodes} and {groups}"
            ));
        }
    }
}

/// Volumes: valid boxes in the lattice, used (`used`, by an empty leaf), and overlapping no
/// solid leaf (nor, in the top tree, any block's subtree).
fn check_volumes(u: &Unit, used: &[bool], d: &mut Defects) {
    let label = &u.label;
    for (i, v) in u.volumes.iter().enumerate() {
        if !(0..3).all(|k| v.lo[k] < v.hi[k] && v.hi[k] <= LATTICE_SIZE) {
            d.push(format!(
                "{label} volume {i}: {v:?} is not a box inside the lattice"
            ));
            continue;
        }
        if !used[i] {
            d.push(format!("{label} volume {i}: referenced by no empty leaf"));
        }
        if let Some(what) = solid_leaf_inside(u, v) {
            d.push(format!("{label} volume {i}: {what}"));
        }
    }
}

/// Triangles: sound on their own, each referenced by some leaf's references (`used`, marked
/// by the leaf walk); their corners grow the unit's bounds.
fn check_triangles(
    u: &Unit,
    header: &Header,
    used: &[bool],
    totals: &mut UnitTotals,
    d: &mut Defects,
) {
    let label = &u.label;
    for (i, t) in u.tris.iter().enumerate() {
        if let Some(what) = triangle_defect(header, t) {
            d.push(format!("{label} triangle {i}: {what}"));
        }
        if !used[i] {
            d.push(format!("{label} triangle {i}: referenced by no leaf"));
        }
        totals.grow(&t.v);
    }
}

/// The Morton codes of a unit's nodes, by local level, generated from its roots by rank: level
/// `l + 1`'s codes are the children of level `l`'s internal nodes, in order.
fn level_codes(u: &Unit, d: &mut Defects) -> Vec<Vec<u64>> {
    let base = u.map.base();
    let mut codes: Vec<Vec<u64>> = vec![u.root_codes.clone()];
    for (ll, lv) in u.map.levels().iter().enumerate().skip(1) {
        let l = base + ll as u32;
        let prev = &codes[ll - 1];
        let mut next = Vec::with_capacity(lv.node_count.min(1 << 24) as usize);
        for (i, &code) in prev.iter().enumerate() {
            if let Ok(rec) = u.map.node(l - 1, i as u64)
                && rec.kind() == Some(NodeKind::Internal)
            {
                next.extend((0..8).map(|o| code << 3 | o));
            }
        }
        if next.len() as u64 != lv.node_count {
            d.push(format!(
                "{} level {l}: {} nodes, but the level above has children for {}",
                u.label,
                lv.node_count,
                next.len()
            ));
        }
        codes.push(next);
    }
    codes
}

/// Spec §8.5: a block's occluders are there only in a file that says so; their node entries
/// name internal nodes of the block, in increasing order, each with at least one occluder, and
/// tile the occluder records; and each occluder is a triangle of the block (a leaf of it holds
/// the same primitive id with the same corners) that overlaps its node's cell widened by the
/// cell margin (the exact triangle-box test of spec §6): so a ray stopped by one is stopped by
/// a triangle of the scene, where the walk would have met it below.
fn check_occluders(
    u: &Unit,
    codes: &[Vec<u64>],
    view: &BlockView<'_>,
    header: &Header,
    d: &mut Defects,
) {
    let label = &u.label;
    let (entries, occ) = (view.occluder_nodes, view.occluders);
    if header.flags & FLAG_OCCLUDERS == 0 {
        if !entries.is_empty() || !occ.is_empty() {
            d.push(format!("{label}: occluders in a file without them"));
        }
        return;
    }
    if entries.is_empty() {
        if !occ.is_empty() {
            d.push(format!("{label}: occluders with no node entry"));
        }
        return;
    }
    if u.clusters.is_none() {
        d.push(format!("{label}: occluders in a file of leaf lists"));
        return;
    }
    let tris = triangles_by_prim(u);
    let scale = LATTICE_SIZE as f64 / header.root_size;
    let m = CELL_MARGIN;
    for (i, e) in entries.iter().enumerate() {
        let end = entries
            .get(i + 1)
            .map_or(occ.len() as u64, |n| n.first as u64);
        let ordered = i == 0 && e.first == 0
            || i > 0 && e.node > entries[i - 1].node && e.first > entries[i - 1].first;
        if !ordered || e.first as u64 >= end || end > occ.len() as u64 {
            d.push(format!(
                "{label}: occluder entry {i} (node {}, first {}) is out of order or empty",
                e.node, e.first
            ));
            return;
        }
        let Some((level, code)) = occluder_node(u, codes, i, e, d) else {
            continue;
        };
        let lo = cell_origin(code, level).map(|x| x as f64 - m);
        let hi: [f64; 3] = std::array::from_fn(|k| lo[k] + cell_size(level) as f64 + 2.0 * m);
        let c: [f64; 3] = std::array::from_fn(|k| (lo[k] + hi[k]) * 0.5);
        let h: [f64; 3] = std::array::from_fn(|k| (hi[k] - lo[k]) * 0.5);
        for (j, t) in occ[e.first as usize..end as usize].iter().enumerate() {
            let at = e.first as usize + j;
            if tris.get(&t.prim) != Some(&t.v) {
                d.push(format!(
                    "{label}: occluder {at} (primitive {}) is not a triangle of the block",
                    t.prim
                ));
                continue;
            }
            let v: [[f64; 3]; 3] = std::array::from_fn(|i| {
                std::array::from_fn(|k| (t.v[i][k] as f64 - header.root_min[k]) * scale)
            });
            if !triangle_overlaps_box(&v, c, h) {
                d.push(format!(
                    "{label}: occluder {at} (primitive {}) does not lie in its node {} (level {level})",
                    t.prim, e.node
                ));
            }
        }
    }
}

/// The block's triangles by primitive id (a triangle of two leaves has the same corners in
/// both: verify checks the leaves against each other elsewhere).
fn triangles_by_prim(u: &Unit) -> std::collections::HashMap<u32, [[f32; 3]; 3]> {
    let mut tris: std::collections::HashMap<u32, [[f32; 3]; 3]> = std::collections::HashMap::new();
    for t in u.tris {
        tris.insert(t.prim, t.v);
    }
    for g in u.groups {
        for l in 0..(g.count as usize).min(8) {
            tris.insert(g.prim[l], g.triangle(l));
        }
    }
    tris
}

/// The level and code of the node occluder entry `i` (`e`) names; `None` where it names none
/// of the block's nodes or not an internal node (defects), or a node of no code.
fn occluder_node(
    u: &Unit,
    codes: &[Vec<u64>],
    i: usize,
    e: &OccluderNode,
    d: &mut Defects,
) -> Option<(u32, u64)> {
    let label = &u.label;
    // Level and index in the level of every node record.
    let levels = u.map.levels();
    let base = u.map.base();
    let locate = |at: u64| -> Option<(u32, u64)> {
        levels
            .iter()
            .enumerate()
            .find(|(_, e)| at >= e.node_start && at < e.node_start + e.node_count)
            .map(|(l, e)| (base + l as u32, at - e.node_start))
    };
    let Some((level, idx)) = locate(e.node as u64) else {
        d.push(format!(
            "{label}: occluder entry {i} names node {}, past the block's",
            e.node
        ));
        return None;
    };
    match u.map.node(level, idx) {
        Ok(rec) if rec.kind_bits() == KIND_INTERNAL => {}
        _ => {
            d.push(format!(
                "{label}: occluder entry {i} names node {}, not an internal node",
                e.node
            ));
            return None;
        }
    }
    let &code = codes
        .get((level - base) as usize)
        .and_then(|c| c.get(idx as usize))?;
    Some((level, code))
}

/// Spec §8.4: a unit's ropes are there exactly when the file says so; an internal node's are
/// 0; and each rope of a leaf or link names the smallest node that holds every cell just across
/// that face of its walk box (found here from the codes of the nodes, not by the descent that
/// made the ropes): it contains those cells, it is internal only at their common level, and it
/// is a link only to another block (inside its own block a rope names the block's node).
fn check_ropes(
    u: &Unit,
    codes: &[Vec<u64>],
    top: &TopNodes<'_>,
    own: Option<u32>,
    header: &Header,
    d: &mut Defects,
) {
    let label = &u.label;
    let roped = header.flags & FLAG_ROPES != 0;
    let nodes: u64 = u.map.levels().iter().map(|l| l.node_count).sum();
    if !roped {
        if !u.ropes.is_empty() {
            d.push(format!("{label}: rope records in a file without ropes"));
        }
        return;
    }
    if u.ropes.len() as u64 != nodes {
        d.push(format!(
            "{label}: {} rope records for {nodes} nodes",
            u.ropes.len()
        ));
        return;
    }
    let targets = RopeTargets { u, codes, top, own };
    let base = u.map.base();
    let mut defects = 0usize;
    for (ll, e) in u.map.levels().iter().enumerate() {
        let level = base + ll as u32;
        let Some(level_codes) = codes.get(ll) else {
            break;
        };
        for (i, &code) in level_codes.iter().enumerate() {
            let at = e.node_start + i as u64;
            let (Ok(rec), Some(ropes)) = (u.map.node(level, i as u64), u.ropes.get(at as usize))
            else {
                break;
            };
            let mut fail = |what: String| {
                defects += 1;
                if defects <= 20 {
                    d.push(format!("{label} level {level} node {i}: {what}"));
                }
            };
            if rec.kind_bits() == KIND_INTERNAL {
                if ropes.across != [0; 6] {
                    fail("an internal node with ropes".into());
                }
                continue;
            }
            let cell = cell_origin(code, level);
            let (lo, hi) = if rec.kind_bits() == KIND_EMPTY {
                rec.shape_bits().box_around(cell)
            } else {
                (cell, cell.map(|x| x + cell_size(level)))
            };
            for (f, &rope) in ropes.across.iter().enumerate() {
                if let Some(what) = targets.defect(f, rope, lo, hi) {
                    fail(what);
                }
            }
        }
    }
    if defects > 20 {
        d.push(format!("{label}: {} more rope defects", defects - 20));
    }
}

/// What a unit's ropes may name: its own nodes (`codes`, by local level), and the top tree's;
/// `own` is the unit's block (`None`: the unit is the top tree).
struct RopeTargets<'a> {
    u: &'a Unit<'a>,
    codes: &'a [Vec<u64>],
    top: &'a TopNodes<'a>,
    own: Option<u32>,
}

impl RopeTargets<'_> {
    /// What is wrong with `rope`, across face `f` of the walk box `lo..hi` of a leaf or link:
    /// the rope must lead out exactly when the face is on the root's boundary, else name the
    /// smallest node that holds every cell just across the face.
    fn defect(&self, f: usize, rope: u32, lo: [u32; 3], hi: [u32; 3]) -> Option<String> {
        let (a, positive) = (f / 2, f % 2 == 1);
        let across = if positive {
            hi[a]
        } else {
            lo[a].wrapping_sub(1)
        };
        let outside = across >= LATTICE_SIZE || hi.iter().any(|&h| h > LATTICE_SIZE);
        if outside || rope == ROPE_EXIT {
            return (outside != (rope == ROPE_EXIT)).then(|| {
                format!(
                    "face {f}: rope {rope:#x}, but the face is {} the root's boundary",
                    if outside { "on" } else { "not on" }
                )
            });
        }
        let mut r_lo = lo;
        let mut r_hi = hi.map(|h| h - 1);
        r_lo[a] = across;
        r_hi[a] = across;
        let to_top = rope & ROPE_TOP != 0;
        if !to_top && self.own.is_none() {
            return Some(format!(
                "face {f}: a top-tree rope {rope:#x} without the top bit"
            ));
        }
        let (map, unit_codes): (&TreeMap<'_>, &[Vec<u64>]) = if to_top {
            (&self.top.map, &self.top.codes)
        } else {
            (&self.u.map, self.codes)
        };
        let index = (rope & !ROPE_TOP) as u64;
        let Some((tl, ti)) = locate_node(map, index) else {
            return Some(format!("face {f}: rope {rope:#x} names no node"));
        };
        let Some(&tcode) = unit_codes
            .get((tl - map.base()) as usize)
            .and_then(|c| c.get(ti as usize))
        else {
            return Some(format!("face {f}: rope {rope:#x} names a node of no code"));
        };
        let Ok(trec) = map.node(tl, ti) else {
            return Some(format!("face {f}: rope {rope:#x} names an unreadable node"));
        };
        let contains =
            morton::code_at_level(r_lo, tl) == tcode && morton::code_at_level(r_hi, tl) == tcode;
        let smallest = match trec.kind() {
            Some(NodeKind::Internal) => tl == morton::common_level(r_lo, r_hi),
            Some(NodeKind::Link { block, .. }) => Some(block) != self.own,
            _ => true,
        };
        (!contains || !smallest).then(|| {
            format!(
                "face {f}: rope {rope:#x} names node {ti} of level {tl}, which {} the \
                 cells across the face {r_lo:?}..={r_hi:?}",
                if contains {
                    "holds but is not the smallest node holding"
                } else {
                    "does not hold"
                }
            )
        })
    }
}

/// Level and index in the level of node record `index`, in a unit's map.
fn locate_node(map: &TreeMap<'_>, index: u64) -> Option<(u32, u64)> {
    let base = map.base();
    map.levels().iter().enumerate().find_map(|(ll, e)| {
        (index >= e.node_start && index - e.node_start < e.node_count)
            .then(|| (base + ll as u32, index - e.node_start))
    })
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
    // The stored box, widened by the margin as the tracer widens it.
    let (slo, shi) = bounds.lattice_box(cell_lo, size, m);
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
            // Allow the rounding of recomputing the clip (far below the margin).
            if a[k] < slo[k] - 1e-6 || b[k] > shi[k] + 1e-6 {
                return Some(format!(
                    "tight bounds {bounds:?} do not contain triangle {t}"
                ));
            }
        }
    }
    None
}

/// What is wrong with a stored triangle on its own: non-finite corners, a primitive id past
/// the input's.
fn triangle_defect(header: &Header, t: &TriRecord) -> Option<String> {
    if !t.v.iter().flatten().all(|c| c.is_finite()) {
        return Some("non-finite coordinates".into());
    }
    if t.prim as u64 >= header.input_triangles {
        return Some(format!(
            "primitive id {} beyond the input's {} triangles",
            t.prim, header.input_triangles
        ));
    }
    None
}

/// Describes a solid leaf (or, in the top tree, a block's subtree) whose interior overlaps box
/// `v`, if there is one.
fn solid_leaf_inside(u: &Unit, v: &VolumeRecord) -> Option<String> {
    let map = &u.map;
    let base = map.base();
    let mut stack: Vec<(u32, u64, [u32; 3])> = u
        .root_codes
        .iter()
        .enumerate()
        .map(|(j, &code)| (base, j as u64, cell_origin(code, base)))
        .collect();
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
            NodeKind::Link { block, .. } => {
                return Some(format!(
                    "covers part of block {block}'s subtree at level {l}, lattice {lo:?}"
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
