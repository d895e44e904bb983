//! The cluster checker: re-derives from the bytes alone that a cluster is well-formed and that
//! its boxes contain what they must. Shares nothing with the builder but [`triangle_box`] (the
//! definition of what a box must contain) and the records, so a test can corrupt a box or an
//! index and see it fail, and `verify` can run it on a file's blocks.

use crate::geom::tribox::triangle_box;
use crate::physical::format::{
    CLUSTER_EXP_RANGE, CLUSTER_WIDTH, ClusterNode, GROUP_CORNERS, GROUP_LANES, KIND_INTERNAL,
    KIND_SOLID, LevelEntry, MAX_CLUSTER_DEPTH, NodeRecord, TriGroup,
};

/// What a well-formed cluster occupies. In a block (spec §8.7) its root is among the octree's
/// wide nodes and the nodes below it follow them, so a block's clusters should tile the rest of
/// its cluster nodes, and its groups, in leaf order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ClusterShape {
    /// The nodes reached from the root but the root: exactly these, each once, all after the
    /// root (`root + 1..root + 1` when the root's children are all groups). A cluster as the
    /// builder makes it is `root` followed by these.
    pub below: std::ops::Range<u32>,
    /// The groups reached: exactly these, each once.
    pub groups: std::ops::Range<u32>,
    /// Lanes in use over all groups (triangles).
    pub triangles: u64,
    /// Depth of the deepest node (the root's is 0).
    pub depth: u32,
}

/// Checks the cluster whose root is `nodes[root]`, for the leaf whose widened cell is `clip`
/// (bit for bit as given to the builder):
///
/// - every node reached has 1 to 8 children, `inner_count <= child_count`, exponents in
///   [`CLUSTER_EXP_RANGE`], an origin that is a multiple of `2^exp` with
///   `|origin / 2^exp| + 255 < 2^24`, `lo <= hi` in used slots, zero in unused slots and
///   reserved bytes;
/// - inner children are in range and after their parent, nodes are at most
///   [`MAX_CLUSTER_DEPTH`] deep, and the nodes below the root and the groups reached are
///   contiguous ranges, each reached once (some range of `nodes[root + 1..]` and some range of
///   `groups`: the root need not be next to the nodes below it, spec §8.7);
/// - every group has 1 to 8 lanes, corner slots below 8, finite corners, zero in unused lanes,
///   unused corner slots and reserved bytes;
/// - for every lane, the box its triangle must have ([`triangle_box`]) is inside the box of
///   its group's slot and of every slot on the way from the root.
///
/// Never panics, whatever the bytes. Returns the first defect found, in words.
pub fn check_cluster(
    nodes: &[ClusterNode],
    groups: &[TriGroup],
    root: u32,
    clip: ([f64; 3], [f64; 3]),
) -> Result<ClusterShape, String> {
    check_with_depth(nodes, groups, root, clip, MAX_CLUSTER_DEPTH)
}

/// An empty-or-not box: the intersection of the slot boxes on a path.
type Bounds = ([f32; 3], [f32; 3]);

pub(crate) fn check_with_depth(
    nodes: &[ClusterNode],
    groups: &[TriGroup],
    root: u32,
    clip: ([f64; 3], [f64; 3]),
    max_depth: usize,
) -> Result<ClusterShape, String> {
    if root as usize >= nodes.len() {
        return Err(format!("root {root} is past the {} nodes", nodes.len()));
    }
    let everything: Bounds = ([f32::NEG_INFINITY; 3], [f32::INFINITY; 3]);
    // (node, depth, the intersection of the slot boxes above it)
    let mut stack = vec![(root, 0u32, everything)];
    let mut seen_nodes: Vec<u32> = Vec::new();
    let mut seen_groups: Vec<u32> = Vec::new();
    // Children come after parents, so a node reached twice would be a DAG whose walk can grow
    // exponentially: stop once more nodes were reached than there are.
    let budget = nodes.len() - root as usize;
    let (mut triangles, mut depth) = (0u64, 0u32);
    while let Some((at, d, env)) = stack.pop() {
        if seen_nodes.len() == budget {
            return Err(format!(
                "more nodes reached than the {budget} from the root on: some are reached twice"
            ));
        }
        seen_nodes.push(at);
        depth = depth.max(d);
        let node = &nodes[at as usize];
        check_node(node).map_err(|e| format!("node {at}: {e}"))?;
        let count = node.child_count as usize;
        let inner = node.inner_count as usize;
        for i in 0..count {
            let b = node.child_box(i);
            let env = (
                std::array::from_fn(|k| env.0[k].max(b.0[k])),
                std::array::from_fn(|k| env.1[k].min(b.1[k])),
            );
            if i < inner {
                let c = node
                    .node_base
                    .checked_add(i as u32)
                    .filter(|&c| (c as usize) < nodes.len())
                    .ok_or_else(|| {
                        format!(
                            "node {at}: inner child {i} is past the {} nodes",
                            nodes.len()
                        )
                    })?;
                if c <= at {
                    return Err(format!(
                        "node {at}: inner child {i} is node {c}, not after it"
                    ));
                }
                if d as usize + 1 > max_depth {
                    return Err(format!(
                        "node {at}: a child at depth {} is deeper than {max_depth}",
                        d + 1
                    ));
                }
                stack.push((c, d + 1, env));
            } else {
                let g = node
                    .group_base
                    .checked_add((i - inner) as u32)
                    .filter(|&g| (g as usize) < groups.len())
                    .ok_or_else(|| {
                        format!(
                            "node {at}: leaf child {i} is past the {} groups",
                            groups.len()
                        )
                    })?;
                if seen_groups.len() >= groups.len() {
                    return Err(format!("node {at}: groups are reached more than once"));
                }
                seen_groups.push(g);
                let group = &groups[g as usize];
                check_group(group).map_err(|e| format!("group {g}: {e}"))?;
                triangles += group.count as u64;
                for l in 0..group.count as usize {
                    let tri = group.triangle(l);
                    let Some((lo, hi)) = triangle_box(&tri, &clip) else {
                        continue;
                    };
                    if !(0..3).all(|k| env.0[k] <= lo[k] && hi[k] <= env.1[k]) {
                        return Err(format!(
                            "node {at} slot {i}: group {g} lane {l} (primitive {}) needs the box \
                             {lo:?}..{hi:?}, which is not inside the slot's box and its \
                             ancestors' ({:?}..{:?})",
                            group.prim[l], env.0, env.1
                        ));
                    }
                }
            }
        }
    }
    // The root is reached first and once (every child is after its parent, so after the root).
    let below = match &mut seen_nodes[1..] {
        [] => root + 1..root + 1,
        rest => {
            contiguous(rest).ok_or("nodes reached below the root are not one range each once")?
        }
    };
    let groups_range =
        contiguous(&mut seen_groups).ok_or("groups reached are not one range each once")?;
    Ok(ClusterShape {
        below,
        groups: groups_range,
        triangles,
        depth,
    })
}

/// The range `ids` covers if it covers one, each once (`ids` is sorted).
fn contiguous(ids: &mut [u32]) -> Option<std::ops::Range<u32>> {
    ids.sort_unstable();
    let first = *ids.first()?;
    let ok = ids.windows(2).all(|w| w[1] == w[0].wrapping_add(1));
    let end = first.checked_add(u32::try_from(ids.len()).ok()?)?;
    ok.then_some(first..end)
}

/// Checks one node on its own (spec §7.1): 1 to 8 children, `inner_count <= child_count`,
/// reserved bytes zero, exponents in [`CLUSTER_EXP_RANGE`], origins multiples of `2^exp` with
/// `|origin / 2^exp| + 255 < 2^24` (so every face is a finite f32), `lo <= hi` in used slots,
/// unused slots zero. Says nothing of its bases.
pub(crate) fn check_node(n: &ClusterNode) -> Result<(), String> {
    let count = n.child_count as usize;
    if !(1..=CLUSTER_WIDTH).contains(&count) {
        return Err(format!("{count} children"));
    }
    if n.inner_count > n.child_count {
        return Err(format!("{} inner children of {count}", n.inner_count));
    }
    if n.reserved != [0; 7] {
        return Err("reserved bytes are not zero".into());
    }
    for k in 0..3 {
        let e = n.exp[k];
        if !CLUSTER_EXP_RANGE.contains(&e) {
            return Err(format!("exponent {e} on axis {k}"));
        }
        let steps = n.origin[k] as f64 / 2f64.powi(e as i32);
        if !(steps.is_finite() && steps.fract() == 0.0 && steps.abs() + 255.0 < (1u32 << 24) as f64)
        {
            return Err(format!(
                "origin {} on axis {k} is not a multiple of 2^{e} below 2^24 steps",
                n.origin[k]
            ));
        }
        for i in 0..CLUSTER_WIDTH {
            let (lo, hi) = (n.lo[k][i], n.hi[k][i]);
            if i < count && lo > hi {
                return Err(format!("slot {i} axis {k}: lo {lo} > hi {hi}"));
            }
            if i >= count && (lo, hi) != (0, 0) {
                return Err(format!("unused slot {i} axis {k} is not zero"));
            }
        }
    }
    Ok(())
}

fn check_group(g: &TriGroup) -> Result<(), String> {
    let count = g.count as usize;
    if !(1..=GROUP_LANES).contains(&count) {
        return Err(format!("{count} lanes"));
    }
    if g.reserved != 0 {
        return Err("reserved bytes are not zero".into());
    }
    let mut used = [false; GROUP_CORNERS];
    for l in 0..GROUP_LANES {
        for c in 0..3 {
            let s = g.tri[c][l] as usize;
            if l < count {
                let slot = used
                    .get_mut(s)
                    .ok_or_else(|| format!("lane {l} corner {c} is slot {s}"))?;
                *slot = true;
            } else if s != 0 {
                return Err(format!("unused lane {l} has a corner slot"));
            }
        }
        if l >= count && g.prim[l] != 0 {
            return Err(format!("unused lane {l} has a primitive id"));
        }
    }
    for (j, &u) in used.iter().enumerate() {
        let p = [g.corner[0][j], g.corner[1][j], g.corner[2][j]];
        if u && !p.iter().all(|c| c.is_finite()) {
            return Err(format!("corner slot {j} is not finite: {p:?}"));
        }
        if !u && p.iter().any(|c| c.to_bits() != 0) {
            return Err(format!("unused corner slot {j} is not zero"));
        }
    }
    Ok(())
}

/// The internal nodes with a solid leaf below them and the solid leaves of a block, counted
/// from its node records alone: the size of its wide nodes' octree region (spec §8.7) before
/// adoption, which leaves some internal nodes out (an upper bound on it, then; verify and
/// inspect take the region as laid out). Returns `(internal, solid)`, or `None` if the records
/// do not fit the level table (a defect reported elsewhere).
pub fn wide_region(levels: &[LevelEntry], records: &[NodeRecord]) -> Option<(u64, u64)> {
    let (mut internal, mut solid) = (0u64, 0u64);
    // Whether each node of the level below has a solid leaf under it (or is one).
    let mut below: Vec<bool> = Vec::new();
    for e in levels.iter().rev() {
        let end = e.node_start.checked_add(e.node_count)?;
        let recs = records.get(usize::try_from(e.node_start).ok()?..usize::try_from(end).ok()?)?;
        let mut here = Vec::with_capacity(recs.len());
        let mut rank = 0usize;
        for r in recs {
            let live = match r.kind_bits() {
                KIND_SOLID => {
                    solid += 1;
                    true
                }
                KIND_INTERNAL => {
                    let kids = below.get(8 * rank..8 * rank + 8)?;
                    rank += 1;
                    let live = kids.iter().any(|&k| k);
                    internal += live as u64;
                    live
                }
                _ => false,
            };
            here.push(live);
        }
        below = here;
    }
    Some((internal, solid))
}
