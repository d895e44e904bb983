//! The top-down walk of a file of clusters ([`super::Walk::TopDown`]): the octree taken as a
//! tree of 8-wide nodes whose children's boxes are their cells (widened by the cell margin),
//! visited nearest first with a stack, as a BVH is; empty leaves are skipped by their kind,
//! links and solid leaves culled by their bounds, clusters traversed where the ray meets them.
//! The walk of the OAVM paper (neighbour steps through merged volumes, [`super::neighbours`]) is
//! what files of leaf lists use.
//!
//! Bounded whatever the bytes: children are on the next level (at most 22 levels), and
//! distinct internal nodes have distinct children (their ranks differ), so the nodes reached
//! form a tree, each visited at most once. One block is held at a time: a block's nodes are all
//! above the top-tree nodes on the stack, and are done with before them.

use super::cluster::{ClusterFail, trace_cluster};
use super::ray::{Best, RayCtx, box_may_hit, leaf_may_hit};
use super::{Chunked, Counters, Held, HitInfo, TraceError, Tree};
use crate::geom::Ray;
use crate::mapping::morton::{self, MAX_LEVEL};
use crate::mapping::{Corruption, TreeMap};
use crate::os::Simd8;
use crate::physical::format::{
    CELL_MARGIN, KIND_EMPTY, KIND_INTERNAL, KIND_LINK, KIND_SOLID, NodeRecord,
};

/// The stack's mark for a node of the top tree (no block).
pub(super) const TOP: u32 = u32::MAX;

/// What a stack entry of the top-down walk is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) enum EntryKind {
    #[default]
    Internal,
    /// A solid leaf whose bounds the ray meets.
    Solid,
    /// A block's root, at the place of its link (index: the root's).
    Root,
}

/// A node waiting on the stack of the top-down walk: where the ray enters its cell, the cell,
/// and the node's place.
#[derive(Clone, Copy, Debug, Default)]
pub(in crate::logical) struct Entry {
    t: f64,
    lo: [u32; 3],
    pub(super) index: u32,
    pub(super) level: u8,
    /// The block it is in ([`TOP`]: the top tree).
    pub(super) block: u32,
    kind: EntryKind,
}

impl Entry {
    /// Bytes that break the format, at this entry's node.
    fn bad(&self, what: &'static str) -> TraceError {
        TraceError::Corrupt(Corruption {
            what,
            block: (self.block != TOP).then_some(self.block),
            level: self.level as u32,
            index: self.index as u64,
        })
    }
}

/// The eight children of an internal node (at `level`): the first's index on the next level,
/// which are internal (bit per octant), their records and the edge of their cells.
pub(super) struct Children<'m> {
    pub(super) level: u32,
    pub(super) first: u64,
    pub(super) internal: u8,
    pub(super) recs: &'m [NodeRecord; 8],
    pub(super) half: u32,
}

impl Children<'_> {
    fn is_internal(&self, o: usize) -> bool {
        (self.internal >> o) & 1 == 1
    }
}

/// The stacks of a thread's walks, kept between rays.
#[derive(Default)]
struct Stacks {
    octree: Vec<Entry>,
    cluster: Vec<(u32, f32, u8)>,
}

thread_local! {
    static STACKS: std::cell::Cell<Stacks> = const {
        std::cell::Cell::new(Stacks {
            octree: Vec::new(),
            cluster: Vec::new(),
        })
    };
}

impl Tree<'_> {
    /// Closest hit (any hit with `ANY`) of `ray` by the top-down walk.
    #[inline(always)]
    pub(super) fn descend_all<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, TraceError> {
        c.rays += 1;
        let Some(r) = self.ray_ctx(ray) else {
            return Ok(None);
        };
        let mut w = Best::new(ray, &r);
        let Some(root) = self.root_entry(&r, w.t_best, c)? else {
            return Ok(None);
        };
        // The stacks are kept per thread, so that a ray costs no allocation and no
        // initialised array.
        let mut stacks = STACKS.take();
        stacks.octree.clear();
        stacks.octree.push(root);
        let result = self.descend_stack::<ANY, S>(isa, &r, &mut w, c, &mut stacks);
        STACKS.set(stacks);
        result.map(|()| w.best)
    }

    /// Runs the walk on `stacks` to its end, one block at a time: each turn holds one block
    /// (none at first) and its view, made once, and pops nodes of the top tree and of that block
    /// until one needs another block, which the next turn fetches after this turn's is let go.
    #[inline(always)]
    fn descend_stack<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &mut Best,
        k: &mut Counters,
        stacks: &mut Stacks,
    ) -> Result<(), TraceError> {
        let mut need: Option<u32> = None;
        loop {
            let fetched = match need.take() {
                None => None,
                Some(b) => Some(self.fetch(b, &mut k.page)?),
            };
            let view = self.held(&fetched);
            let (stack, cluster_stack) = (&mut stacks.octree, &mut stacks.cluster);
            need = self.run_held::<ANY, S>(isa, r, w, k, stack, cluster_stack, view.as_ref())?;
            if need.is_none() {
                return Ok(());
            }
        }
    }

    /// The first entry of a top-down walk: the root, internal, a link to a block (a tree small
    /// enough to be one block), or empty (a file without triangles: `None`, as for a ray that
    /// misses the root's box).
    #[inline(always)]
    pub(super) fn root_entry(
        &self,
        r: &RayCtx,
        t_best: f32,
        k: &mut Counters,
    ) -> Result<Option<Entry>, TraceError> {
        let root = self.top.node(0, 0)?;
        let (kind, block, index) = match root.kind_bits() {
            KIND_INTERNAL => {
                if !self.top_node_may_hit(r, t_best, 0) {
                    k.top_nodes_culled += 1;
                    return Ok(None);
                }
                (EntryKind::Internal, TOP, 0)
            }
            KIND_LINK => {
                let (b, i) = root.link_bits();
                self.check_link(b, 0, 0)?;
                (EntryKind::Root, b, i)
            }
            KIND_EMPTY => return Ok(None),
            _ => {
                return Err(TraceError::Corrupt(Corruption {
                    what: "invalid root record",
                    block: None,
                    level: 0,
                    index: 0,
                }));
            }
        };
        Ok(Some(Entry {
            t: r.t0,
            lo: [0; 3],
            index,
            level: 0,
            block,
            kind,
        }))
    }

    /// Pops the nodes of `stack` (of the top tree and of the block `view`, if any) until the
    /// ray is answered (`None`: its answer is in `w`) or the next node is in another block
    /// (`Some(block)`, that node left on top of the stack). What a walk is between two blocks
    /// is exactly `(r, w, stack)`: [`crate::logical::stream`] parks it there and resumes it
    /// later with the same result as if it had waited.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn run_held<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &mut Best,
        k: &mut Counters,
        stack: &mut Vec<Entry>,
        cluster_stack: &mut Vec<(u32, f32, u8)>,
        view: Option<&Held<'_>>,
    ) -> Result<Option<u32>, TraceError> {
        while let Some(e) = stack.pop() {
            if e.t > w.t_stop {
                continue;
            }
            // A node of a block other than the one held: the walk moves there first.
            let held = match view {
                _ if e.block == TOP => None,
                Some(h) if h.id == e.block => Some(h),
                _ => {
                    stack.push(e);
                    return Ok(Some(e.block));
                }
            };
            let kind = match e.kind {
                EntryKind::Root => match root_kind(&e, held)? {
                    Some(kind) => kind,
                    None => continue,
                },
                kind => kind,
            };
            if kind == EntryKind::Solid {
                let chunks = held.and_then(|h| self.chunked(h.id, h.raw));
                if enter_cluster::<ANY, S>(isa, r, w, k, &e, (held, chunks), cluster_stack)? {
                    return Ok(None);
                }
                continue;
            }
            // An internal node: its occluders first (spec §8.5: an any hit may stop there),
            // then its children's cells, nearest first.
            k.nodes_visited += 1;
            if ANY
                && self.occluders
                && let Some(h) = held
                && self.occluder_hit(r, w, k, h, &e)
            {
                return Ok(None);
            }
            self.push_children::<ANY, S>(isa, r, w, k, &e, held, stack)?;
        }
        Ok(None)
    }

    /// Pushes the children of the internal node of `e` that the ray meets and that may hold a
    /// hit, so that the nearest (SATO: the largest) is popped first.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn push_children<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &Best,
        k: &mut Counters,
        e: &Entry,
        held: Option<&Held<'_>>,
        stack: &mut Vec<Entry>,
    ) -> Result<(), TraceError> {
        const STACK: usize = 7 * (MAX_LEVEL as usize + 1) + 1;
        let level = e.level as u32;
        let map: &TreeMap<'_> = held.map_or(&self.top, |h| &h.map);
        if level >= MAX_LEVEL {
            return Err(e.bad("internal node on the deepest level"));
        }
        let (first, internal, recs) = map
            .children(level, e.index as u64)
            .ok_or_else(|| e.bad("rank directory points past the next level"))?;
        let kids = Children {
            level,
            first,
            internal,
            recs,
            half: morton::cell_size(level) / 2,
        };
        let mut hits: [(f64, u8, f64); 8] = [(0.0, 0, 0.0); 8];
        let n = self.children_met::<ANY, S>(isa, r, w, e, &kids, &mut hits);
        for &(t, o, _) in &hits[..n] {
            if let Some(child) = self.child_entry(r, w, k, e, &kids, o as usize, t)? {
                if stack.len() >= STACK {
                    return Err(e.bad("traversal deeper than the lattice"));
                }
                stack.push(child);
            }
        }
        Ok(())
    }

    /// The children whose widened cells the ray meets over `[tmin, t_stop]` and that are not
    /// empty leaves, as `(entry t, octant, order key)` in `hits`, in the order to push them: the
    /// key (the entry `t`, or with SATO minus the child's surface area) descending. Returns
    /// how many.
    #[inline(always)]
    fn children_met<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &Best,
        e: &Entry,
        kids: &Children<'_>,
        hits: &mut [(f64, u8, f64); 8],
    ) -> usize {
        let (enter_at, leave_at) = child_planes(r, e.lo, kids.half, morton::cell_size(kids.level));
        // The eight children at once; then only those met are looked at.
        let (met, enters) = isa.cell_hits(&enter_at, &leave_at, r.tmin as f64, w.t_stop);
        let mut mask = 0u32;
        let mut scan = met;
        while scan != 0 {
            let o = scan.trailing_zeros();
            scan &= scan - 1;
            let live =
                kids.is_internal(o as usize) || kids.recs[o as usize].kind_bits() != KIND_EMPTY;
            mask |= (live as u32) << o;
        }
        let mut n = 0usize;
        let sato = ANY && self.sato;
        while mask != 0 {
            let o = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let key = if sato {
                -self.sato_area(e, kids, o)
            } else {
                enters[o]
            };
            hits[n] = (enters[o], o as u8, key);
            n += 1;
        }
        // Nearest (SATO: largest) popped first: pushed farthest first.
        for i in 1..n {
            let mut j = i;
            while j > 0 && hits[j - 1].2 < hits[j].2 {
                hits.swap(j - 1, j);
                j -= 1;
            }
        }
        n
    }

    /// The stack entry of child `o` (entered at `t`), or `None` if its box culls it: an
    /// internal node of the top tree or a link by its box (`top_bounds`), a solid leaf by its
    /// tight bounds.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn child_entry(
        &self,
        r: &RayCtx,
        w: &Best,
        k: &mut Counters,
        e: &Entry,
        kids: &Children<'_>,
        o: usize,
        t: f64,
    ) -> Result<Option<Entry>, TraceError> {
        let (level, half) = (kids.level, kids.half);
        let rec = kids.recs[o];
        let child = kids.first + o as u64;
        let lo = [
            e.lo[0] + half * (o as u32 & 1),
            e.lo[1] + half * ((o as u32 >> 1) & 1),
            e.lo[2] + half * ((o as u32 >> 2) & 1),
        ];
        let (kind, block, index) = if kids.is_internal(o) {
            if e.block == TOP {
                let at = self.top.node_start(level + 1) + child;
                if !self.top_node_may_hit(r, w.t_best, at) {
                    k.top_nodes_culled += 1;
                    return Ok(None);
                }
            }
            (EntryKind::Internal, e.block, child)
        } else {
            match rec.kind_bits() {
                KIND_SOLID if e.block != TOP => {
                    let (_, b) = rec.solid_bits();
                    if !leaf_may_hit(r, w.t_best, lo, half, b) {
                        k.leaves_culled += 1;
                        return Ok(None);
                    }
                    (EntryKind::Solid, e.block, child)
                }
                KIND_LINK if e.block == TOP => {
                    let at = self.top.node_start(level + 1) + child;
                    if !self.top_node_may_hit(r, w.t_best, at) {
                        k.links_culled += 1;
                        return Ok(None);
                    }
                    let (b, root) = rec.link_bits();
                    self.check_link(b, level + 1, child)?;
                    (EntryKind::Root, b, root as u64)
                }
                _ => return Err(e.bad("invalid leaf record")),
            }
        };
        Ok(Some(Entry {
            t,
            lo,
            index: index as u32,
            level: (level + 1) as u8,
            block,
            kind,
        }))
    }

    /// Whether the ray may hit anything below top-tree node record `at` over `[tmin, t_best]`:
    /// its box (`top_bounds`): a link's bounds widened by the margin, an internal node's union
    /// of the link boxes below it. A record without a box lets the ray in.
    #[inline(always)]
    pub(super) fn top_node_may_hit(&self, r: &RayCtx, t_best: f32, at: u64) -> bool {
        match usize::try_from(at).ok().and_then(|i| self.top_boxes.get(i)) {
            Some((lo, hi)) => box_may_hit(r, t_best, *lo, *hi),
            None => true,
        }
    }

    /// A link (at `level`, node `index` of the top tree) to block `b`: `b` must be in the
    /// directory (which also keeps it from [`TOP`], the stack's mark for the top tree).
    #[inline(always)]
    fn check_link(&self, b: u32, level: u32, index: u64) -> Result<(), TraceError> {
        if (b as usize) < self.directory.len() {
            return Ok(());
        }
        Err(TraceError::Corrupt(Corruption {
            what: "link to a block the directory does not have",
            block: Some(b),
            level,
            index,
        }))
    }
}

/// What a block's root at the place of its link (entry `e`, in the block `held`) is: internal,
/// a cluster, or (never written) empty (`None`: nothing to do).
#[inline(always)]
fn root_kind(e: &Entry, held: Option<&Held<'_>>) -> Result<Option<EntryKind>, TraceError> {
    let level = e.level as u32;
    let h = held.ok_or_else(|| e.bad("block not held"))?;
    if h.root_level != level {
        return Err(e.bad("block roots are not at the level of their link"));
    }
    if e.index >= h.root_count {
        return Err(e.bad("link to a root the block does not have"));
    }
    let rec = h
        .map
        .node(level, e.index as u64)
        .map_err(|_| e.bad("block root out of range"))?;
    Ok(match rec.kind_bits() {
        _ if rec.is_internal() => Some(EntryKind::Internal),
        KIND_SOLID => Some(EntryKind::Solid),
        KIND_EMPTY => None,
        _ => return Err(e.bad("invalid leaf record")),
    })
}

/// Traverses the cluster of the solid leaf of `e` (in the block `held`); true if `ANY` found a
/// hit (the walk is over).
#[inline(always)]
fn enter_cluster<const ANY: bool, S: Simd8>(
    isa: S,
    r: &RayCtx,
    w: &mut Best,
    k: &mut Counters,
    e: &Entry,
    (held, chunks): (Option<&Held<'_>>, Option<Chunked<'_>>),
    cluster_stack: &mut Vec<(u32, f32, u8)>,
) -> Result<bool, TraceError> {
    let h = held.ok_or_else(|| e.bad("cluster outside a block"))?;
    let rec = h
        .map
        .node(e.level as u32, e.index as u64)
        .map_err(|_| e.bad("node record out of range"))?;
    let (inline, _) = rec.solid_bits();
    if rec.kind_bits() != KIND_SOLID || inline != 0 {
        return Err(e.bad("invalid leaf record"));
    }
    k.leaves_visited += 1;
    k.clusters_entered += 1;
    let found = trace_cluster::<ANY, S>(isa, r, w, (h, chunks), rec.payload, k, cluster_stack)
        .map_err(|f| match f {
            ClusterFail::Bad(what) => e.bad(what),
            ClusterFail::Page(p) => TraceError::Page(p),
        })?;
    if ANY && found {
        return Ok(true);
    }
    w.t_stop = r.t1.min(w.t_best as f64);
    Ok(false)
}

/// Per axis, where the ray enters and leaves the low and the high half of the cell at `lo`
/// (edge `size`, halves `half`), widened by the margin (a half of an axis the ray does not
/// move along is entered at -inf if it holds the origin, else at +inf).
#[inline(always)]
fn child_planes(r: &RayCtx, lo: [u32; 3], half: u32, size: u32) -> ([[f64; 2]; 3], [[f64; 2]; 3]) {
    let m = CELL_MARGIN;
    let mut enter_at = [[0f64; 2]; 3];
    let mut leave_at = [[0f64; 2]; 3];
    for a in 0..3 {
        let lo = lo[a] as f64;
        if r.moves[a] {
            // The planes (exact: integers below 2^23) by the ray's direction.
            let (h, c) = (&r.cell_h[a], &r.cell_m[a]);
            let t: [f64; 4] =
                std::array::from_fn(|i| (lo + h[i] * half as f64 + c[i]) * r.inv[a] - r.oi[a]);
            enter_at[a] = [t[0], t[1]];
            leave_at[a] = [t[2], t[3]];
        } else {
            let (mid, hi) = (lo + half as f64, lo + size as f64);
            let o = r.o[a];
            let inside = |a: f64, b: f64| {
                if o >= a && o <= b {
                    f64::NEG_INFINITY
                } else {
                    f64::INFINITY
                }
            };
            enter_at[a] = [inside(lo - m, mid + m), inside(mid - m, hi + m)];
            leave_at[a] = [f64::INFINITY; 2];
        }
    }
    (enter_at, leave_at)
}
