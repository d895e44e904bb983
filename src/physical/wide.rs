//! Format 6's wide hierarchy (spec §8.7): the internal nodes of the octree, in the top tree
//! and in each block, as 8-wide nodes with quantised child boxes (the [`ClusterNode`] record of
//! the clusters, Ylitie, Karras and Laine's compressed wide BVH), a node with few children
//! adopting its grandchildren (`adopt`), so that one loop walks from the root to the
//! triangle groups.
//!
//! The wide nodes are a function of the octree's records and the clusters: [`lay_block`] and
//! [`lay_top`] compute them, the writer stores what they return, and `verify` computes them
//! again and compares bytes. Both are idempotent (a block laid out once comes back unchanged),
//! so the passes that decode a block and store it again (ropes, occluders, updates) keep it.

use super::format::{
    CLUSTER_EXP_RANGE, CLUSTER_WIDTH, ClusterNode, KIND_EMPTY, KIND_INTERNAL, KIND_LINK,
    KIND_SOLID, LevelEntry, NodeRecord, WideLink,
};

/// An axis-aligned box in world units, `(lo, hi)`.
pub type WorldBox = ([f32; 3], [f32; 3]);

/// A block's wide nodes and what changed with them.
#[derive(Debug)]
pub struct BlockWide {
    /// The block's wide nodes (its cluster nodes part): its roots at `0..root_count`, then the
    /// rest of the octree's region in breadth-first order, then the clusters' other nodes.
    pub nodes: Vec<ClusterNode>,
    /// The node records, each solid leaf's `payload` now the index of its cluster's root.
    pub records: Vec<NodeRecord>,
    /// The box of each root, the union of its wide node's child boxes.
    pub roots: Vec<WorldBox>,
    /// The octree's region of `nodes`: its roots, the octree's wide nodes and the clusters'
    /// roots, before the clusters' other nodes.
    pub region: usize,
}

/// The union of `a` and `b`.
fn union(a: WorldBox, b: WorldBox) -> WorldBox {
    (
        std::array::from_fn(|k| a.0[k].min(b.0[k])),
        std::array::from_fn(|k| a.1[k].max(b.1[k])),
    )
}

/// The box of wide node `n`: the union of its children's boxes (exact f32 faces).
pub fn node_box(n: &ClusterNode) -> Option<WorldBox> {
    (0..(n.child_count as usize).min(CLUSTER_WIDTH))
        .map(|i| n.child_box(i))
        .reduce(union)
}

/// One node of the octree being laid out: where it is and what it becomes.
#[derive(Clone, Copy)]
enum Slot {
    /// Nothing below it: dropped from its parent.
    Empty,
    /// A solid leaf: the cluster whose root is old node `root`, with its box.
    Cluster { root: u32, bx: WorldBox },
    /// An internal node with at least one child that is not empty: its wide node (in
    /// `octree`), with its box.
    Inner { wide: u32, bx: WorldBox },
}

/// Lays out the wide nodes of a block of clusters (spec §8.7) from its node records and its
/// clusters (in any layout: as the cluster builder appends them, or already laid out). Errors
/// name what is inconsistent; the builder never makes such a block.
pub fn lay_block(
    levels: &[LevelEntry],
    records: &[NodeRecord],
    clusters: &[ClusterNode],
) -> Result<BlockWide, String> {
    // The clusters' nodes: each reachable from one solid leaf's payload. Their roots move into
    // the octree's region; the others keep their order after it.
    let mut role = vec![0u8; clusters.len()]; // 0 unreached, 1 root, 2 inner
    for rec in records.iter().filter(|r| r.kind_bits() == KIND_SOLID) {
        mark_cluster(clusters, rec.payload, &mut role)?;
    }
    // Bottom up: each node's slot (empty, a cluster, or an inner wide node made now).
    let mut octree: Vec<ClusterNode> = Vec::new();
    let mut octree_kids: Vec<Vec<Slot>> = Vec::new();
    let below = bottom_up(
        levels,
        records,
        |rec| match rec.kind_bits() {
            KIND_EMPTY => Ok(Slot::Empty),
            KIND_SOLID => {
                let root = clusters
                    .get(rec.payload as usize)
                    .ok_or("a solid leaf's cluster root is past the cluster nodes")?;
                let bx = node_box(root).ok_or("a cluster root without children")?;
                Ok(Slot::Cluster {
                    root: rec.payload,
                    bx,
                })
            }
            _ => Err("a link or an invalid record in a block".into()),
        },
        |kids| {
            let mut live: Vec<Slot> = kids
                .iter()
                .copied()
                .filter(|s| !matches!(s, Slot::Empty))
                .collect();
            if live.is_empty() {
                return Ok(Slot::Empty);
            }
            adopt(&mut live, |s| match s {
                Slot::Inner { wide, bx } => Some((octree_kids[*wide as usize].as_slice(), *bx)),
                _ => None,
            });
            let (n, bx) = wide_node(live.len(), live.iter().map(slot_box))?;
            octree.push(n);
            octree_kids.push(live);
            Ok(Slot::Inner {
                wide: (octree.len() - 1) as u32,
                bx,
            })
        },
    )?;
    // Top down, breadth first: the roots at 0.., each node's children consecutively after.
    let mut order: Vec<Slot> = below.clone();
    let mut roots = Vec::with_capacity(below.len());
    for s in &below {
        match s {
            Slot::Empty => return Err("a block root with nothing below it".into()),
            Slot::Cluster { bx, .. } | Slot::Inner { bx, .. } => roots.push(*bx),
        }
    }
    let mut placed: Vec<ClusterNode> = Vec::new();
    let mut new_root = vec![u32::MAX; clusters.len()];
    let mut i = 0;
    while i < order.len() {
        let node = match order[i] {
            Slot::Inner { wide, .. } => {
                let mut n = octree[wide as usize];
                n.node_base = u32::try_from(order.len()).map_err(|_| "too many wide nodes")?;
                order.extend_from_slice(&octree_kids[wide as usize]);
                n
            }
            Slot::Cluster { root, .. } => {
                if new_root[root as usize] != u32::MAX {
                    return Err("two solid leaves share a cluster".into());
                }
                new_root[root as usize] = i as u32;
                clusters[root as usize]
            }
            Slot::Empty => unreachable!("empty slots are dropped"),
        };
        placed.push(node);
        i += 1;
    }
    // The clusters' other nodes, in their order, after the octree's region.
    let mut new_index = new_root;
    let mut tail = Vec::new();
    for (old, r) in role.iter().enumerate() {
        if *r == 2 {
            new_index[old] = u32::try_from(placed.len() + tail.len()).map_err(|_| "too many")?;
            tail.push(clusters[old]);
        }
    }
    placed.extend(tail);
    // Cluster nodes' inner children, renumbered (they stay consecutive).
    let region = order.len();
    for (j, n) in placed.iter_mut().enumerate() {
        let is_octree = j < region && matches!(order[j], Slot::Inner { .. });
        if is_octree || n.inner_count.min(n.child_count) == 0 {
            continue;
        }
        let Some(&first) = new_index.get(n.node_base as usize) else {
            return Err("a cluster node's children are past the cluster nodes".into());
        };
        for c in 0..n.inner_count.min(n.child_count).min(8) as u32 {
            let at = n
                .node_base
                .checked_add(c)
                .map(|i| new_index.get(i as usize));
            if at != Some(Some(&first.wrapping_add(c))) || first == u32::MAX {
                return Err("a cluster node's children are not consecutive".into());
            }
        }
        n.node_base = first;
    }
    let records = records
        .iter()
        .map(|r| {
            let mut r = *r;
            if r.kind_bits() == KIND_SOLID {
                r.payload = match new_index.get(r.payload as usize) {
                    Some(&i) if i != u32::MAX => i,
                    _ => return Err("a solid leaf outside the tree of the block's roots"),
                };
            }
            Ok(r)
        })
        .collect::<Result<_, _>>()?;
    Ok(BlockWide {
        nodes: placed,
        records,
        roots,
        region,
    })
}

/// Marks the nodes of the cluster whose root is `root` (1: the root, 2: below it).
fn mark_cluster(clusters: &[ClusterNode], root: u32, role: &mut [u8]) -> Result<(), String> {
    let mut stack = vec![(root, 1u8)];
    while let Some((i, r)) = stack.pop() {
        let slot = role
            .get_mut(i as usize)
            .ok_or("a cluster node index past the cluster nodes")?;
        if *slot != 0 {
            return Err("cluster nodes that do not form trees".into());
        }
        *slot = r;
        let n = &clusters[i as usize];
        for c in 0..n.inner_count.min(n.child_count).min(8) as u32 {
            stack.push((n.node_base.wrapping_add(c), 2));
        }
    }
    Ok(())
}

fn slot_box(s: &Slot) -> WorldBox {
    match s {
        Slot::Cluster { bx, .. } | Slot::Inner { bx, .. } => *bx,
        Slot::Empty => ([0.0; 3], [0.0; 3]),
    }
}

/// The top tree's wide nodes and links (spec §8.7), from its node records and each link's
/// root box (`root_box(block, root)`). Node 0 is the root's: a root that is a link gets a
/// node with that one link. A tree with no link gets none.
pub fn lay_top(
    levels: &[LevelEntry],
    records: &[NodeRecord],
    root_box: impl Fn(u32, u32) -> Option<WorldBox>,
) -> Result<(Vec<ClusterNode>, Vec<WideLink>), String> {
    #[derive(Clone, Copy)]
    enum Top {
        Empty,
        Link(WideLink),
        Inner { wide: u32, bx: WorldBox },
    }
    let top_box = |t: &Top| match t {
        Top::Link(w) => (w.lo, w.hi),
        Top::Inner { bx, .. } => *bx,
        Top::Empty => ([0.0; 3], [0.0; 3]),
    };
    let mut made: Vec<(ClusterNode, Vec<Top>)> = Vec::new();
    let below = bottom_up(
        levels,
        records,
        |rec| match rec.kind_bits() {
            KIND_EMPTY => Ok(Top::Empty),
            KIND_LINK => {
                let (block, root) = rec.link_bits();
                let (lo, hi) = root_box(block, root)
                    .ok_or_else(|| format!("no box for root {root} of block {block}"))?;
                Ok(Top::Link(WideLink {
                    block,
                    root,
                    lo,
                    hi,
                }))
            }
            _ => Err("a solid leaf or an invalid record in the top tree".into()),
        },
        |kids| {
            let mut kids: Vec<Top> = kids
                .iter()
                .copied()
                .filter(|t| !matches!(t, Top::Empty))
                .collect();
            adopt(&mut kids, |t| match t {
                Top::Inner { wide, bx } => Some((made[*wide as usize].1.as_slice(), *bx)),
                _ => None,
            });
            // Inner children first, then links (spec §7.1's slot order).
            let mut live: Vec<Top> = kids
                .iter()
                .copied()
                .filter(|t| matches!(t, Top::Inner { .. }))
                .collect();
            let inner = live.len();
            live.extend(kids.iter().copied().filter(|t| matches!(t, Top::Link(_))));
            if live.is_empty() {
                return Ok(Top::Empty);
            }
            let (n, bx) = wide_node(inner, live.iter().map(top_box))?;
            made.push((n, live));
            Ok(Top::Inner {
                wide: (made.len() - 1) as u32,
                bx,
            })
        },
    )?;
    let root = match below.first() {
        None | Some(Top::Empty) => return Ok((Vec::new(), Vec::new())),
        Some(Top::Link(w)) => {
            let (n, _) = wide_node(0, std::iter::once((w.lo, w.hi)))?;
            return Ok((vec![n], vec![*w]));
        }
        Some(t) => *t,
    };
    let mut order = vec![root];
    let mut nodes = Vec::new();
    let mut links = Vec::new();
    let mut i = 0;
    while i < order.len() {
        let Top::Inner { wide, .. } = order[i] else {
            unreachable!("only inner nodes are queued")
        };
        let (mut n, kids) = made[wide as usize].clone();
        n.node_base = order.len() as u32;
        n.group_base = links.len() as u32;
        for k in &kids {
            match k {
                Top::Inner { .. } => order.push(*k),
                Top::Link(w) => links.push(*w),
                Top::Empty => {}
            }
        }
        nodes.push(n);
        i += 1;
    }
    Ok((nodes, links))
}

/// Collapses a wide node's children `live` (spec §8.7): while some inner child's own children
/// (`open(child)`: its children and its box; `None` for a child that is not an octree node)
/// fit in the node's eight slots in its place, the one of largest surface area among them is
/// replaced by its children, in its place. A ray that enters the node then meets those
/// children one level higher, and the opened node is left out of the tree.
fn adopt<'k, T: Copy + 'k>(live: &mut Vec<T>, open: impl Fn(&T) -> Option<(&'k [T], WorldBox)>) {
    let area = |(lo, hi): WorldBox| {
        let d: [f64; 3] = std::array::from_fn(|k| (hi[k] as f64 - lo[k] as f64).max(0.0));
        d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
    };
    loop {
        let mut best: Option<(usize, f64)> = None;
        for (i, c) in live.iter().enumerate() {
            if let Some((kids, bx)) = open(c)
                && live.len() - 1 + kids.len() <= CLUSTER_WIDTH
                && best.is_none_or(|(_, a)| area(bx) > a)
            {
                best = Some((i, area(bx)));
            }
        }
        let Some((i, _)) = best else { return };
        let Some((kids, _)) = open(&live[i]) else {
            return;
        };
        let mut merged = live[..i].to_vec();
        merged.extend_from_slice(kids);
        merged.extend_from_slice(&live[i + 1..]);
        *live = merged;
    }
}

/// The values of the octree of `levels` and `records`, bottom up: each leaf's (and link's)
/// from its record by `leaf`, each internal node's from its eight children's by `inner` (the
/// mapping rule of spec §4: the `r`-th internal node of a level has nodes `8r..8r + 8` of the
/// next); returns level 0's.
fn bottom_up<T>(
    levels: &[LevelEntry],
    records: &[NodeRecord],
    mut leaf: impl FnMut(&NodeRecord) -> Result<T, String>,
    mut inner: impl FnMut(&[T]) -> Result<T, String>,
) -> Result<Vec<T>, String> {
    let mut below: Vec<T> = Vec::new();
    for (l, e) in levels.iter().enumerate().rev() {
        let recs = records
            .get(e.node_start as usize..(e.node_start + e.node_count) as usize)
            .ok_or_else(|| format!("level {l} lies past the node records"))?;
        let mut here = Vec::with_capacity(recs.len());
        let mut rank = 0usize;
        for rec in recs {
            here.push(if rec.kind_bits() == KIND_INTERNAL {
                let kids = below
                    .get(8 * rank..8 * rank + 8)
                    .ok_or("an internal node's children are past the next level")?;
                rank += 1;
                inner(kids)?
            } else {
                leaf(rec)?
            });
        }
        below = here;
    }
    Ok(below)
}

/// A wide node over the children whose boxes are `boxes` (the first `inner_count` of them
/// inner), its bases left 0, and its own box.
fn wide_node(
    inner_count: usize,
    boxes: impl Iterator<Item = WorldBox> + Clone,
) -> Result<(ClusterNode, WorldBox), String> {
    let mut n: ClusterNode = bytemuck::Zeroable::zeroed();
    n.child_count = boxes.clone().count() as u8;
    n.inner_count = inner_count as u8;
    quantise(&mut n, boxes).map_err(|e| format!("a node's box cannot be quantised: {e}"))?;
    let bx = node_box(&n).ok_or("a wide node without children")?;
    Ok((n, bx))
}

/// Sets the grid and the child boxes of `node` from the children's f32 boxes (spec §7.1): per
/// axis the smallest exponent whose grid spans the node in 255 steps from an origin that is a
/// multiple of the step with `|origin / step| + 255 < 2^24`; faces rounded outward. All in
/// f64, where scaling by a power of two, `floor` and `ceil` are exact. On failure, the axis
/// and the span that no exponent of [`CLUSTER_EXP_RANGE`] covers.
pub fn quantise(
    node: &mut ClusterNode,
    boxes: impl Iterator<Item = WorldBox> + Clone,
) -> Result<(), QuantiseError> {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for (a, b) in boxes.clone() {
        // A box that is not one (NaN, infinite, or inverted) has no grid: refused, never
        // quantised to some bytes.
        if let Some(k) = (0..3).find(|&k| !(a[k].is_finite() && b[k].is_finite() && a[k] <= b[k])) {
            return Err(QuantiseError {
                axis: k,
                lo: a[k],
                hi: b[k],
            });
        }
        lo = std::array::from_fn(|k| lo[k].min(a[k]));
        hi = std::array::from_fn(|k| hi[k].max(b[k]));
    }
    for k in 0..3 {
        let (e, origin) = grid(lo[k], hi[k]).ok_or(QuantiseError {
            axis: k,
            lo: lo[k],
            hi: hi[k],
        })?;
        let s = pow2(-e);
        node.exp[k] = e as i8;
        node.origin[k] = (origin * pow2(e)) as f32;
        for (i, (a, b)) in boxes.clone().enumerate() {
            let ql = (a[k] as f64 * s).floor() - origin;
            let qh = (b[k] as f64 * s).ceil() - origin;
            debug_assert!((0.0..=255.0).contains(&ql) && (ql..=255.0).contains(&qh));
            node.lo[k][i] = ql as u8;
            node.hi[k][i] = qh as u8;
        }
    }
    Ok(())
}

/// A span no grid of [`CLUSTER_EXP_RANGE`] covers (spec §7.1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuantiseError {
    pub axis: usize,
    pub lo: f32,
    pub hi: f32,
}

impl std::fmt::Display for QuantiseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "axis {} spans {} to {}, which no grid of 2^{}..2^{} holds in 255 steps",
            self.axis,
            self.lo,
            self.hi,
            CLUSTER_EXP_RANGE.start(),
            CLUSTER_EXP_RANGE.end()
        )
    }
}

/// `2^e` for `|e| <= 1000`, exactly.
fn pow2(e: i32) -> f64 {
    f64::from_bits(((1023 + e) as u64) << 52)
}

/// The grid of one axis of a node spanning `lo..=hi`: the smallest exponent `e` in
/// [`CLUSTER_EXP_RANGE`] with `ceil(hi / 2^e) - floor(lo / 2^e) <= 255` and
/// `|floor(lo / 2^e)| + 255 < 2^24`, and the origin in steps, `floor(lo / 2^e)`.
pub fn grid(lo: f32, hi: f32) -> Option<(i32, f64)> {
    let (min, max) = (
        *CLUSTER_EXP_RANGE.start() as i32,
        *CLUSTER_EXP_RANGE.end() as i32,
    );
    // Start below both lower bounds: steps must cover the span in 255, and the origin needs
    // fewer than 24 bits, i.e. e > log2|lo| - 24 (and |lo| >= |hi| / 2, else the span bound is
    // the larger).
    let span = hi as f64 - lo as f64;
    let mut start = min;
    if span > 0.0 {
        start = start.max(floor_log2(span / 255.0) - 1);
    }
    let m = (lo.abs().max(hi.abs())) as f64;
    if m > 0.0 {
        start = start.max(floor_log2(m) - 26);
    }
    (start..=max).find_map(|e| {
        let s = pow2(-e);
        let ol = (lo as f64 * s).floor();
        let oh = (hi as f64 * s).ceil();
        (oh - ol <= 255.0 && ol.abs() + 255.0 < (1u32 << 24) as f64).then_some((e, ol))
    })
}

/// `floor(log2(x))` for a positive normal `x`: its exponent field.
fn floor_log2(x: f64) -> i32 {
    ((x.to_bits() >> 52) & 0x7ff) as i32 - 1023
}
