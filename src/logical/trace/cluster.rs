//! A solid leaf's cluster (spec §7.1): a wide BVH of 8-wide nodes with quantized child boxes
//! over groups of up to eight triangles (§7.2), traversed nearest child first with a stack of
//! its own. Both walks enter clusters the same way, so they find the same hits.

use super::ray::{Best, RayCtx};
use super::{Chunked, Counters, Held, HitInfo};
use crate::geom::triangle::RayShear;
use crate::geom::wide_box::grown_exit;
use crate::os::Simd8;
use crate::physical::format::{CLUSTER_WIDTH, MAX_CLUSTER_DEPTH, TriGroup};

/// Why a cluster's walk stopped short: bytes that are not a cluster, or a chunk of groups that
/// could not be read.
pub(super) enum ClusterFail {
    Bad(&'static str),
    Page(super::PageError),
}

impl From<&'static str> for ClusterFail {
    fn from(what: &'static str) -> Self {
        ClusterFail::Bad(what)
    }
}

/// Traverses the cluster whose root is node `root` of the held block (spec §7.1), updating the
/// walk's closest hit (ties to the smallest primitive id); with `ANY`, stops at the first hit
/// and returns true. Bounded whatever the bytes: a tree visits each node at most once, so a
/// walk that visits more nodes than the block has, or goes deeper than
/// [`MAX_CLUSTER_DEPTH`], is reading something that is not a tree. `chunks`: where the groups
/// of a block of which only the head is held are read (spec §8.3).
#[inline(always)]
pub(super) fn trace_cluster<const ANY: bool, S: Simd8>(
    isa: S,
    r: &RayCtx,
    w: &mut Best,
    (h, chunks): (&Held<'_>, Option<Chunked<'_>>),
    root: u32,
    k: &mut Counters,
    stack: &mut Vec<(u32, f32, u8)>,
) -> Result<bool, ClusterFail> {
    stack.clear();
    stack.push((root, r.tmin, 0));
    let mut visits = 0usize;
    while let Some((ni, tnear, depth)) = stack.pop() {
        // The box test's entries are not lower bounds (they may exceed the exact entry by
        // about 2^-21 of it): a child whose box lies flat in the plane of the closest hit so
        // far may hold a closer one, so the entry is compared as the test compares it.
        if tnear > grown_exit(w.t_best) {
            continue;
        }
        let Some(n) = h.cluster_nodes.get(ni as usize) else {
            return Err("cluster node index out of range".into());
        };
        visits += 1;
        if visits > h.cluster_nodes.len() {
            return Err("cluster nodes do not form a tree".into());
        }
        k.cluster_nodes_visited += 1;
        let count = (n.child_count as usize).min(CLUSTER_WIDTH);
        k.boxes_tested += count as u64;
        let (mask, near) = r.boxes.node_hits_with(isa, n.view(), r.tmin, w.t_best);
        let inner = n.inner_count as u32;
        // Leaves first, nearest-first is not needed for them: all are tested now.
        let inner_bits = (1u32 << inner.min(8)) - 1;
        let mut leaf_mask = mask & !inner_bits;
        while leaf_mask != 0 {
            let i = leaf_mask.trailing_zeros();
            leaf_mask &= leaf_mask - 1;
            let gi = n.group_base as u64 + (i - inner) as u64;
            // A held head's groups are read chunk by chunk; the chunk is held for the test.
            let chunk;
            let g = match (h.groups.get(gi as usize), chunks) {
                (Some(g), _) => g,
                (None, Some(ch)) => {
                    chunk = ch.group(h.id, gi, &mut k.page).map_err(ClusterFail::Page)?;
                    chunk
                        .0
                        .groups()
                        .get(chunk.1)
                        .ok_or(ClusterFail::Bad("triangle group index out of range"))?
                }
                (None, None) => {
                    return Err(ClusterFail::Bad("triangle group index out of range"));
                }
            };
            if test_group::<ANY, S>(isa, (&r.shear, r.tmin), &mut w.best, &mut w.t_best, g, k) {
                return Ok(true);
            }
        }
        if mask & inner_bits != 0 {
            push_nearest_first(stack, mask & inner_bits, &near, n.node_base, depth)?;
        }
    }
    Ok(false)
}

/// Tests the lanes of group `g` for the ray sheared as `shear`, keeping the closest hit in
/// `best` and its distance in `t_best` (ties to the smallest primitive id); with `ANY`, true at
/// the first hit. Every walk tests its groups here.
#[inline(always)]
pub(super) fn test_group<const ANY: bool, S: Simd8>(
    isa: S,
    (shear, tmin): (&RayShear, f32),
    best: &mut Option<HitInfo>,
    t_best: &mut f32,
    g: &TriGroup,
    k: &mut Counters,
) -> bool {
    k.groups_tested += 1;
    k.triangles_tested += g.count.min(8) as u64;
    let (mut hits, ts) = shear.intersect_group_with(isa, g.view(), tmin, *t_best);
    while hits != 0 {
        let l = hits.trailing_zeros() as usize;
        hits &= hits - 1;
        let (t, prim) = (ts[l], g.prim[l]);
        if ANY {
            *best = Some(HitInfo {
                t,
                prim,
                v: g.triangle(l),
            });
            return true;
        }
        let better = match best {
            None => true,
            Some(b) => (t, prim) < (b.t, b.prim),
        };
        if better {
            *t_best = t;
            *best = Some(HitInfo {
                t,
                prim,
                v: g.triangle(l),
            });
        }
    }
    false
}

/// Tests the lanes of group `g` for the ray sheared as `shear` in `[tmin, tmax]` and adds each
/// hit the triangle owns ([`RayShear::owns`]) to `out`: the walk for every hit along a ray.
#[inline(always)]
pub(super) fn collect_group<S: Simd8>(
    isa: S,
    (shear, tmin, tmax): (&RayShear, f32, f32),
    g: &TriGroup,
    out: &mut Vec<HitInfo>,
    k: &mut Counters,
) {
    k.groups_tested += 1;
    k.triangles_tested += g.count.min(8) as u64;
    let (mut hits, ts) = shear.intersect_group_with(isa, g.view(), tmin, tmax);
    while hits != 0 {
        let l = hits.trailing_zeros() as usize;
        hits &= hits - 1;
        let v = g.triangle(l);
        if shear.owns(&v) {
            out.push(HitInfo {
                t: ts[l],
                prim: g.prim[l],
                v,
            });
        }
    }
}

/// Pushes the inner children in `mask` (entered at `near`) of a node at `depth` whose inner
/// children start at node `base`, so that the nearest is popped first.
#[inline(always)]
fn push_nearest_first(
    stack: &mut Vec<(u32, f32, u8)>,
    mut mask: u32,
    near: &[f32; CLUSTER_WIDTH],
    base: u32,
    depth: u8,
) -> Result<(), &'static str> {
    const STACK: usize = (CLUSTER_WIDTH - 1) * MAX_CLUSTER_DEPTH + 1;
    if depth as usize + 1 >= MAX_CLUSTER_DEPTH {
        return Err("cluster deeper than the format allows");
    }
    let mut kids: [(f32, u32); CLUSTER_WIDTH] = [(0.0, 0); CLUSTER_WIDTH];
    let mut nk = 0;
    while mask != 0 {
        let i = mask.trailing_zeros();
        mask &= mask - 1;
        kids[nk] = (near[i as usize], base.wrapping_add(i));
        nk += 1;
    }
    kids[..nk].sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
    for &(t, c) in &kids[..nk] {
        if stack.len() >= STACK {
            return Err("cluster deeper than the format allows");
        }
        stack.push((c, t, depth + 1));
    }
    Ok(())
}
