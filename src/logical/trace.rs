//! The tracer (OAVM paper §2.4–2.5): closest hit and any hit through the mapped tree.
//!
//! A ray is mapped into the lattice (`2^21` cells per axis over the root cube) in f64, where
//! cell faces are integers. It enters the root, and from then on is always *in* one lattice cell
//! `q`:
//!
//! 1. **Locate** the leaf containing `q`, descending by rank (the mapping layer) from the lowest
//!    common ancestor of `q` and the previous leaf, found from the coordinates
//!    ([`morton::common_level`]); the ancestors' indices are kept in `path`.
//! 2. **Cross** the leaf. An empty leaf's whole merged volume is clipped with the slab
//!    (Liang–Barsky) test and jumped past; a solid leaf's triangles are tested with the
//!    watertight test, keeping the closest hit so far.
//! 3. **Stop** when the exit `t` of that box reaches the closest hit (no later cell can hold a
//!    closer one) or `tmax`, or when the ray leaves the root.
//! 4. **Step** to the neighbour across the exit face: the face neighbour query on integer
//!    coordinates (the neighbour's lattice cell is `hi` or `lo - 1` along the exit axis, the
//!    exit point's cell along the others). This is the paper's neighbour step, on coordinates
//!    rather than on the interleaved code, so it is right across parent boundaries
//!    (see [`crate::mapping::morton`]).
//!
//! **Bounded, whatever the bytes.** Every box a walk crosses contains `q` (a leaf's cell does;
//! a volume is rebuilt around `q` from its shape, whose level is checked to be no finer than the
//! leaf's), and its faces lie on the grid of a level no deeper than the tree's depth `D`. A step
//! moves `q` along the exit axis past such a face, and along the other axes only forward (in the
//! ray's direction) and within the box. So no box is entered twice, and since `q` moves forward
//! to a new line of the level-`D` grid along one axis at every step, a walk takes at most
//! `3 * 2^D + 1` steps, for any file: the loop needs no step counter. Rounding in
//! the exit point can only move `q` to a cell the ray passes within about `2^-31` cells of,
//! and the builder references every triangle in every cell within [`CELL_MARGIN`] of it, so a
//! triangle is never missed for being just across a face.
//!
//! [`CELL_MARGIN`]: crate::physical::format::CELL_MARGIN

use std::hint::select_unpredictable;

use serde::Serialize;

use std::sync::OnceLock;

use super::held::{Held, ReadyMap};
use super::pager::{BlockBytes, PageCounters, PageError};
use super::scene::Walk;
use super::top_bounds::LatticeBox;
use crate::geom::triangle::RayShear;
use crate::geom::wide_box::grown_exit;
use crate::geom::{BoxRay, Ray};
use crate::mapping::morton::{self, LATTICE_SIZE, MAX_LEVEL};
use crate::mapping::{Corruption, TreeMap};
use crate::os::{Avx2, Simd8, WithAvx2};
use crate::physical::format::{
    BlockEntry, CELL_MARGIN, CLUSTER_WIDTH, FLAG_CLUSTERS, FLAG_OCCLUDERS, Header, KIND_EMPTY,
    KIND_INTERNAL, KIND_LINK, KIND_SOLID, MAX_CLUSTER_DEPTH, NodeRecord, ROPE_TOP, RopeRecord,
    leaf_refs,
};

/// Work counters of a batch of rays (summed over its rays).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counters {
    pub rays: u64,
    /// Node records read: the internal nodes of every descent and the leaves reached.
    pub nodes_visited: u64,
    /// Leaves entered (solid and empty).
    pub leaves_visited: u64,
    /// Merged empty volumes clipped and jumped past.
    pub volumes_crossed: u64,
    /// Solid leaves whose tight bounds the ray missed: their triangles were not tested.
    pub leaves_culled: u64,
    /// Links whose bounds (spec §8.1) the ray missed: their blocks were passed without being
    /// asked of the pager.
    pub links_culled: u64,
    /// Internal nodes of the top tree whose box (the union of the link bounds below them) the
    /// ray missed, in the top-down traversal of a file of clusters.
    pub top_nodes_culled: u64,
    /// Ray–triangle tests (in a file of clusters: the lanes in use of the groups tested).
    pub triangles_tested: u64,
    /// Clusters (spec §7.1) whose wide BVH a ray entered (its leaf's bounds were met).
    pub clusters_entered: u64,
    /// Cluster nodes whose children's boxes were tested.
    pub cluster_nodes_visited: u64,
    /// Child boxes tested (the children in use of the cluster nodes visited).
    pub boxes_tested: u64,
    /// Triangle groups (spec §7.2) tested.
    pub groups_tested: u64,
    /// Walks begun again from a node above the last one (the comparison KD-tree's kd-restart,
    /// push-down and short-stack traversals: each time the rest of the ray is walked down
    /// again).
    pub restarts: u64,
    /// Ropes followed by the leaf-to-leaf walk of [`Walk::Ropes`] (spec §8.4). (The comparison
    /// KD-tree's rope walks count theirs in `restarts`.)
    pub ropes_followed: u64,
    /// Occluders tested at inner nodes by the shadow-ray walk of a primitive index (the
    /// multi-index tree of Liang and Huang; also counted in `triangles_tested`).
    pub promoted_tested: u64,
    /// Blocks asked of the pager (each time a walk moves into another block), with its hits,
    /// misses and bytes.
    #[serde(flatten)]
    pub page: PageCounters,
    /// Streamed batches ([`super::Order::Stream`]): walks parked at a block, times a block's
    /// queue was served, and the most bytes the parked walks took at once.
    pub walks_parked: u64,
    pub blocks_served: u64,
    pub peak_parked_bytes: u64,
}

impl std::ops::AddAssign for Counters {
    fn add_assign(&mut self, o: Counters) {
        self.rays += o.rays;
        self.nodes_visited += o.nodes_visited;
        self.leaves_visited += o.leaves_visited;
        self.volumes_crossed += o.volumes_crossed;
        self.leaves_culled += o.leaves_culled;
        self.links_culled += o.links_culled;
        self.top_nodes_culled += o.top_nodes_culled;
        self.triangles_tested += o.triangles_tested;
        self.clusters_entered += o.clusters_entered;
        self.restarts += o.restarts;
        self.ropes_followed += o.ropes_followed;
        self.promoted_tested += o.promoted_tested;
        self.cluster_nodes_visited += o.cluster_nodes_visited;
        self.boxes_tested += o.boxes_tested;
        self.groups_tested += o.groups_tested;
        self.page += o.page;
        self.walks_parked += o.walks_parked;
        self.blocks_served += o.blocks_served;
        self.peak_parked_bytes = self.peak_parked_bytes.max(o.peak_parked_bytes);
    }
}

impl std::ops::Add for Counters {
    type Output = Counters;
    fn add(mut self, o: Counters) -> Counters {
        self += o;
        self
    }
}

/// A closest hit, with the triangle hit (for shading).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitInfo {
    pub t: f32,
    pub prim: u32,
    /// The corners of the triangle hit.
    pub v: [[f32; 3]; 3],
}

/// Why a walk stopped short: bytes that break the format, or a block the pager could not give.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TraceError {
    Corrupt(Corruption),
    Page(PageError),
}

impl From<Corruption> for TraceError {
    fn from(c: Corruption) -> Self {
        TraceError::Corrupt(c)
    }
}

impl From<PageError> for TraceError {
    fn from(e: PageError) -> Self {
        TraceError::Page(e)
    }
}

impl std::fmt::Display for TraceError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TraceError::Corrupt(c) => c.fmt(f),
            TraceError::Page(e) => e.fmt(f),
        }
    }
}

impl From<TraceError> for crate::error::FormatError {
    fn from(e: TraceError) -> Self {
        crate::error::FormatError::Corrupt(e.to_string())
    }
}

/// Where a tree's blocks come from: the pager of an opened file.
pub(crate) trait BlockFetch: Sync {
    /// The raw bytes of block `block` and its map, counting the request in `c`.
    fn fetch(
        &self,
        block: u32,
        c: &mut PageCounters,
    ) -> Result<(BlockBytes<'_>, &ReadyMap), PageError>;

    /// Whether block `block` is resident now (a hint).
    fn resident(&self, block: u32) -> bool;
}

/// The blocks of a file whose pager never evicts (every block raw, the budget holding them
/// all): an admitted block's bytes are read straight from the file, with no call to the pager.
#[derive(Clone, Copy)]
pub(crate) struct Direct<'a> {
    /// The whole file.
    pub file: &'a [u8],
    /// Per block, its map once admitted.
    pub ready: &'a [OnceLock<Box<ReadyMap>>],
}

/// A block's bytes, from the file or from the pager.
pub(super) enum Fetched<'a> {
    Direct(&'a [u8]),
    Paged(BlockBytes<'a>),
}

impl std::ops::Deref for Fetched<'_> {
    type Target = [u8];
    #[inline(always)]
    fn deref(&self) -> &[u8] {
        match self {
            Fetched::Direct(b) => b,
            Fetched::Paged(b) => b,
        }
    }
}

/// A read-only view of a file's tree, ready for tracing: the top tree (always resident) and the
/// blocks, reached through a pager. Cheap to make (no allocation, no scan).
#[derive(Clone, Copy)]
pub struct Tree<'a> {
    top: TreeMap<'a>,
    /// The top tree's nodes' boxes, by record (`top_bounds`); culls its internal nodes.
    top_boxes: &'a [LatticeBox],
    directory: &'a [BlockEntry],
    blocks: &'a dyn BlockFetch,
    direct: Option<Direct<'a>>,
    root_min: [f64; 3],
    /// Lattice cells per world unit.
    scale: f64,
    /// Solid leaves are clusters (spec §2 flag `CLUSTERS`), else lists of references.
    clusters: bool,
    /// Rays are walked top-down (clusters, [`Walk::Auto`] or [`Walk::TopDown`]), else leaf to
    /// leaf ([`Self::walk`]).
    top_down: bool,
    /// The leaf-to-leaf walk follows ropes ([`Walk::Ropes`]; spec §8.4).
    follow_ropes: bool,
    /// The top tree's ropes, by node record (empty in a file without them).
    top_ropes: &'a [RopeRecord],
    /// Any-hit queries of the top-down walk take a node's children in the SATO order (larger
    /// surface area first, whatever the ray's direction; [`Self::sato`]) instead of nearest
    /// first.
    sato: bool,
    /// Any-hit queries of the top-down walk test the occluders (spec §8.5) of each internal
    /// node of a block they enter, before its children ([`Self::occluders`]).
    occluders: bool,
    /// The CPU's AVX2, if it has it.
    avx2: Option<Avx2>,
}

/// The ray in lattice space, and what the walk derives from it once.
pub(super) struct RayCtx {
    o: [f64; 3],
    d: [f64; 3],
    inv: [f64; 3],
    oi: [f64; 3],
    moves: [bool; 3],
    fwd: [bool; 3],
    shear: RayShear,
    /// The ray in world units, for cluster boxes.
    boxes: BoxRay,
    tmin: f32,
    /// Per axis, the planes by which the ray enters the low and the high half of a cell and
    /// leaves them, in that order, as offsets from the cell's low face: `half * cell_h +
    /// cell_m` (the halves widened by the cell margin).
    cell_h: [[f64; 4]; 3],
    cell_m: [[f64; 4]; 3],
    /// Where the ray enters and leaves the root cube.
    t0: f64,
    t1: f64,
}

/// Where a walk is: its cell, the ancestors of its leaf, the block it is in, its best hit.
struct WalkState {
    q: [u32; 3],
    /// Level of the lowest common ancestor of `q` and the previous leaf.
    level: u32,
    /// Ancestors of the current leaf in the top tree, by absolute level (up to the link).
    tpath: [u64; 32],
    /// Ancestors of the current leaf inside its block, by absolute level (from the root).
    bpath: [u64; 32],
    /// The block of the current leaf and its roots' level, if it is in a block.
    cur: Option<(u32, u32)>,
    s: Best,
}

/// A walk's closest hit so far, and where it stops looking.
#[derive(Clone, Copy)]
pub(super) struct Best {
    pub(super) best: Option<HitInfo>,
    pub(super) t_best: f32,
    /// `min(t1, t_best)`: no cell entered at or past it can hold a closer hit.
    pub(super) t_stop: f64,
}

/// What a walk through the blocks it holds ends with.
enum Step {
    Done(Option<HitInfo>),
    /// It must move into this block.
    Need(u32),
}

impl<'a> Tree<'a> {
    /// A tree over a validated top tree, the (untrusted) block directory and a pager.
    pub(crate) fn new(
        top: TreeMap<'a>,
        top_boxes: &'a [LatticeBox],
        directory: &'a [BlockEntry],
        blocks: &'a dyn BlockFetch,
        direct: Option<Direct<'a>>,
        header: &Header,
    ) -> Tree<'a> {
        let clusters = header.flags & FLAG_CLUSTERS != 0;
        Tree {
            top_down: clusters,
            follow_ropes: false,
            top_ropes: &[],
            sato: false,
            occluders: header.flags & FLAG_OCCLUDERS != 0,
            top,
            top_boxes,
            directory,
            blocks,
            direct,
            root_min: header.root_min,
            scale: LATTICE_SIZE as f64 / header.root_size,
            clusters,
            avx2: Avx2::detect(),
        }
    }

    /// The same tree, walked by `walk` ([`Walk::Ropes`] follows `top_ropes` and the blocks'
    /// ropes; the scene checked at open that the file has them).
    pub(crate) fn walking(mut self, walk: Walk, top_ropes: &'a [RopeRecord]) -> Tree<'a> {
        self.top_down = match walk {
            Walk::Auto => self.clusters,
            Walk::TopDown => true,
            Walk::Neighbours | Walk::Ropes => false,
        };
        self.follow_ropes = walk == Walk::Ropes;
        self.top_ropes = top_ropes;
        self
    }

    /// The same tree, whose top-down walk answers any-hit queries taking a node's children in
    /// the SATO order (Nah and Manocha 2014: the child of larger surface area first, as likelier
    /// to hold an occluder) rather than nearest first. A child's surface area is that of the box
    /// the walk culls it by: a solid leaf's tight bounds (spec §4.2), a top-tree node's or a
    /// link's box (§8.1), an internal node of a block its whole cell. The answers are the same
    /// (an any hit does not depend on order); closest hits keep the nearest-first order.
    pub fn sato(mut self, on: bool) -> Tree<'a> {
        self.sato = on;
        self
    }

    /// The same tree, whose top-down walk tests, for any-hit queries, the occluders a node
    /// holds (spec §8.5) when it enters the node, and stops there if one is hit (the primitive
    /// index of Liang and Huang's multi-index tree). On by default in a file that has them; off,
    /// the walk ignores them (the triangles are in their leaves too). The answers are the same.
    pub fn occluders(mut self, on: bool) -> Tree<'a> {
        self.occluders = on;
        self
    }

    /// The top tree.
    pub fn map(&self) -> &TreeMap<'a> {
        &self.top
    }

    /// Closest hit of `ray` with `tmin <= t <= tmax`, or `None`.
    pub fn intersect(&self, ray: &Ray, c: &mut Counters) -> Result<Option<HitInfo>, TraceError> {
        self.dispatch::<false>(ray, c)
    }

    /// Whether any triangle is hit with `tmin <= t <= tmax`; stops at the first one found.
    pub fn occluded(&self, ray: &Ray, c: &mut Counters) -> Result<bool, TraceError> {
        Ok(self.dispatch::<true>(ray, c)?.is_some())
    }

    /// The walk compiled for the best instruction set the CPU has: AVX2 where it exists
    /// (detected once per tree), else what the build targets (SSE4.1, or eight scalars).
    #[inline(always)]
    fn dispatch<const ANY: bool>(
        &self,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, TraceError> {
        struct Job<'t, 'a, 'r, const ANY: bool> {
            tree: &'t Tree<'a>,
            ray: &'r Ray,
            c: &'r mut Counters,
        }
        impl<const ANY: bool> WithAvx2 for Job<'_, '_, '_, ANY> {
            type Output = Result<Option<HitInfo>, TraceError>;
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                if self.tree.top_down {
                    self.tree.descend_all::<ANY, Avx2>(isa, self.ray, self.c)
                } else {
                    self.tree.walk::<ANY, Avx2>(isa, self.ray, self.c)
                }
            }
        }
        match self.avx2 {
            Some(isa) => isa.vectorize(Job::<ANY> { tree: self, ray, c }),
            None if self.top_down => self.descend_all::<ANY, _>(baseline(), ray, c),
            None => self.walk::<ANY, _>(baseline(), ray, c),
        }
    }

    /// The first block `ray` needs (the block of the first link on its way whose bounds it
    /// meets), found in the top tree alone, without reading any block; `None` if it needs none
    /// (it misses the root cube, or passes every link by). [`super::Order::Blocks`] sorts rays by
    /// it.
    pub fn first_block(&self, ray: &Ray) -> Result<Option<u32>, Corruption> {
        let Some((ctx, mut w)) = self.start(ray) else {
            return Ok(None);
        };
        let mut k = Counters::default();
        Ok(
            match self.walk_in::<false, _>(baseline(), &ctx, &mut w, None, &mut k)? {
                Step::Need(b) => Some(b),
                Step::Done(_) => None,
            },
        )
    }

    #[inline(always)]
    fn walk<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, TraceError> {
        c.rays += 1;
        let Some((ctx, mut w)) = self.start(ray) else {
            return Ok(None);
        };
        let mut k = Counters::default();
        // Each turn holds one block (none at first): the walk goes on through the top tree and
        // that block until it needs another, whose bytes the next turn fetches after this
        // turn's are let go (so a thread never holds two blocks).
        let mut need: Option<u32> = None;
        let result = loop {
            let fetched = match need {
                None => None,
                Some(b) => match self.fetch(b, &mut k.page) {
                    Ok(f) => Some(f),
                    Err(e) => break Err(e),
                },
            };
            let held = fetched
                .as_ref()
                .map(|(b, bytes, ready)| Held::new(*b, ready, bytes));
            match self.walk_in::<ANY, S>(isa, &ctx, &mut w, held.as_ref(), &mut k) {
                Ok(Step::Done(best)) => break Ok(best),
                Ok(Step::Need(b)) => need = Some(b),
                Err(e) => break Err(e.into()),
            }
        };
        *c += k;
        result
    }

    /// Block `b`'s bytes and map: straight from the file if it was admitted and the pager never
    /// evicts, else from the pager (counted alike).
    #[inline(always)]
    pub(super) fn fetch(
        &self,
        b: u32,
        c: &mut PageCounters,
    ) -> Result<(u32, Fetched<'a>, &'a ReadyMap), TraceError> {
        if let Some(d) = &self.direct
            && let Some(ready) = d.ready.get(b as usize).and_then(OnceLock::get)
            && let Some(e) = self.directory.get(b as usize)
            && let Some(bytes) = d
                .file
                .get(e.offset as usize..(e.offset as usize).saturating_add(e.raw_len as usize))
        {
            c.requested += 1;
            c.hits += 1;
            return Ok((b, Fetched::Direct(bytes), ready));
        }
        let (bytes, ready) = self.blocks.fetch(b, c)?;
        Ok((b, Fetched::Paged(bytes), ready))
    }

    /// The ray in lattice space and the walk's start, clipped to the root cube; `None` for a
    /// ray that cannot hit anything (invalid, or missing the root cube).
    fn start(&self, ray: &Ray) -> Option<(RayCtx, WalkState)> {
        let ctx = self.ray_ctx(ray)?;
        let w = WalkState {
            q: std::array::from_fn(|k| {
                clamp_floor(ctx.o[k] + ctx.t0 * ctx.d[k], 0, LATTICE_SIZE - 1)
            }),
            level: 0,
            tpath: [0; 32],
            bpath: [0; 32],
            cur: None,
            s: Best {
                best: None,
                t_best: ray.tmax,
                t_stop: ctx.t1,
            },
        };
        Some((ctx, w))
    }

    /// The ray in lattice space, clipped to the root cube; `None` for a ray that cannot hit
    /// anything (invalid, or missing the root cube).
    #[inline(always)]
    fn ray_ctx(&self, ray: &Ray) -> Option<RayCtx> {
        if !ray.is_valid() {
            return None;
        }
        let n = LATTICE_SIZE as f64;
        // The ray in lattice space; `t` is unchanged by this affine map.
        let o: [f64; 3] =
            std::array::from_fn(|k| (ray.origin[k] as f64 - self.root_min[k]) * self.scale);
        let d: [f64; 3] = std::array::from_fn(|k| ray.dir[k] as f64 * self.scale);
        let moves: [bool; 3] = std::array::from_fn(|k| d[k] != 0.0);
        let fwd: [bool; 3] = std::array::from_fn(|k| d[k] > 0.0);
        // Plane crossings as `t = plane * inv - oi`. An axis the ray does not move along gets
        // `inv = 0`, `oi = -inf`: its planes are never crossed (`t = +inf`).
        let inv: [f64; 3] = std::array::from_fn(|k| if moves[k] { 1.0 / d[k] } else { 0.0 });
        let oi: [f64; 3] = std::array::from_fn(|k| {
            if moves[k] {
                o[k] * inv[k]
            } else {
                f64::NEG_INFINITY
            }
        });
        let still_inside =
            |lo: f64, hi: f64| (0..3).all(|k| moves[k] || (o[k] >= lo && o[k] <= hi));

        // Clip to the root (slab test); an axis the ray is parallel to must contain the origin.
        let (mut t0, mut t1) = (ray.tmin as f64, ray.tmax as f64);
        if !still_inside(0.0, n) {
            return None;
        }
        for k in 0..3 {
            if moves[k] {
                let (a, b) = (-oi[k], n * inv[k] - oi[k]);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        // Negated on purpose: NaN (from a NaN tmin or tmax) must mean a miss.
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !(t0 <= t1) {
            return None;
        }
        let ctx = RayCtx {
            o,
            d,
            inv,
            oi,
            moves,
            fwd,
            shear: RayShear::new(ray),
            boxes: BoxRay::new(ray),
            tmin: ray.tmin,
            cell_h: fwd.map(|f| {
                if f {
                    [0.0, 1.0, 1.0, 2.0]
                } else {
                    [1.0, 2.0, 0.0, 1.0]
                }
            }),
            cell_m: fwd.map(|f| {
                let m = CELL_MARGIN;
                if f { [-m, -m, m, m] } else { [m, m, -m, -m] }
            }),
            t0,
            t1,
        };
        Some(ctx)
    }

    /// Walks on from `w` through the top tree and the block `held` (if any) until the ray is
    /// answered or needs another block.
    #[inline(always)]
    fn walk_in<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &mut WalkState,
        held: Option<&Held<'_>>,
        k: &mut Counters,
    ) -> Result<Step, Corruption> {
        loop {
            // 1. Locate the leaf containing q, from the common ancestor down: in the block the
            // walk is in while the ancestor is inside it, else from the top tree, following a
            // link into a block.
            let mut culled = false;
            let in_block = match (w.cur, held) {
                (Some((b, rl)), Some(h)) => b == h.id && w.level >= rl,
                _ => false,
            };
            let (level, rec) = if in_block {
                self.descend_block(w, held, k)?
            } else {
                let (level, rec) =
                    self.top
                        .descend(w.level, &mut w.tpath, w.q, &mut k.nodes_visited)?;
                if rec.kind_bits() == KIND_LINK && !self.link_may_hit(r, w, level) {
                    // Its block holds nothing this ray can hit: cross its cell as if empty.
                    k.links_culled += 1;
                    w.cur = None;
                    culled = true;
                    (level, rec)
                } else if rec.kind_bits() == KIND_LINK {
                    let (b, root) = rec.link_bits();
                    w.cur = Some((b, level));
                    w.level = level;
                    w.bpath[(level & 31) as usize] = root as u64;
                    // The link itself was counted as a visit; its block's root is the same node.
                    k.nodes_visited -= 1;
                    match held {
                        Some(h) if h.id == b => self.descend_block(w, held, k)?,
                        _ => return Ok(Step::Need(b)),
                    }
                } else {
                    w.cur = None;
                    (level, rec)
                }
            };
            k.leaves_visited += 1;
            let (tris, refs) = match (w.cur, held) {
                (Some(_), Some(h)) => (h.tris, h.refs),
                _ => (&[][..], &[][..]),
            };
            let block = w.cur.map(|(b, _)| b);
            let bad = |what, level, index| Corruption {
                what,
                block,
                level,
                index,
            };

            // 2. Cross it: the box the ray leaves, and the triangles on the way.
            let q = w.q;
            let size = morton::cell_size(level);
            let cell_lo = q.map(|x| x & !(size - 1));
            let path_index = |w: &WalkState| {
                if block.is_some() {
                    w.bpath[(level & 31) as usize]
                } else {
                    w.tpath[(level & 31) as usize]
                }
            };
            let (lo, hi) = match rec.kind_bits() {
                _ if culled => (cell_lo, cell_lo.map(|x| x + size)),
                KIND_EMPTY => {
                    // Empty: its merged volume, rebuilt from the shape in the record (spec
                    // §4.2), jumped past whole.
                    k.volumes_crossed += 1;
                    let shape = rec.shape_bits();
                    if shape.level as u32 > level {
                        return Err(bad(
                            "merged volume smaller than its leaf",
                            level,
                            path_index(w),
                        ));
                    }
                    shape.box_around(q)
                }
                KIND_SOLID if block.is_some() => {
                    let (inline_count, b) = rec.solid_bits();
                    // The leaf's tight bounds (spec §4.2), widened by the cell margin: a ray that
                    // misses them over [tmin, best] cannot hit any of the leaf's triangles inside
                    // the cell, so their references and records are not even loaded.
                    let s16 = size as f64 / 16.0;
                    let q4 = |shift: u32| ((b >> shift) & 15) as f64;
                    let blo: [f64; 3] = std::array::from_fn(|a| {
                        cell_lo[a] as f64 + q4(4 * a as u32) * s16 - CELL_MARGIN
                    });
                    let bhi: [f64; 3] = std::array::from_fn(|a| {
                        cell_lo[a] as f64 + (q4(12 + 4 * a as u32) + 1.0) * s16 + CELL_MARGIN
                    });
                    if box_may_hit(r, w.s.t_best, blo, bhi) && self.clusters {
                        let Some(h) = held else {
                            return Err(bad("cluster outside a block", level, rec.payload as u64));
                        };
                        k.clusters_entered += 1;
                        let found = trace_cluster::<ANY, S>(
                            isa,
                            r,
                            &mut w.s,
                            h,
                            rec.payload,
                            k,
                            &mut Vec::new(),
                        )
                        .map_err(|what| bad(what, level, rec.payload as u64))?;
                        if ANY && found {
                            return Ok(Step::Done(w.s.best));
                        }
                        w.s.t_stop = r.t1.min(w.s.t_best as f64);
                    } else if box_may_hit(r, w.s.t_best, blo, bhi) {
                        let Some((leaf, _)) = leaf_refs(refs, rec.payload, inline_count) else {
                            return Err(bad(
                                "triangle references out of range",
                                level,
                                rec.payload as u64,
                            ));
                        };
                        k.triangles_tested += leaf.len() as u64;
                        // Four triangles at a time; a short last group repeats its first
                        // triangle (a repeated hit changes nothing: ties keep the first).
                        for group in leaf.chunks(4) {
                            let tri = |i: usize| tris.get(group[i.min(group.len() - 1)] as usize);
                            let (Some(r0), Some(r1), Some(r2), Some(r3)) =
                                (tri(0), tri(1), tri(2), tri(3))
                            else {
                                return Err(bad(
                                    "triangle index out of range",
                                    level,
                                    rec.payload as u64,
                                ));
                            };
                            let (mut mask, ts) = r.shear.intersect4(
                                [&r0.v, &r1.v, &r2.v, &r3.v],
                                r.tmin,
                                w.s.t_best,
                            );
                            while mask != 0 {
                                let l = mask.trailing_zeros() as usize;
                                mask &= mask - 1;
                                let (t, rec_l) = (ts[l], [r0, r1, r2, r3][l]);
                                let hit = HitInfo {
                                    t,
                                    prim: rec_l.prim,
                                    v: rec_l.v,
                                };
                                if ANY {
                                    return Ok(Step::Done(Some(hit)));
                                }
                                // Ties keep the first found, in the order of the leaf's
                                // references: the answers of format 3, which the paper's
                                // structure keeps (a cluster takes the smallest id instead).
                                if w.s.best.is_none() || t < w.s.t_best {
                                    w.s.t_best = t;
                                    w.s.best = Some(hit);
                                }
                            }
                        }
                        w.s.t_stop = r.t1.min(w.s.t_best as f64);
                    } else {
                        k.leaves_culled += 1;
                    }
                    (cell_lo, cell_lo.map(|x| x + size))
                }
                _ => {
                    return Err(bad(
                        if block.is_some() {
                            "invalid leaf record"
                        } else {
                            "invalid leaf record in the top tree"
                        },
                        level,
                        path_index(w),
                    ));
                }
            };

            // 3. Exit of the box (slab test on its far faces); stop where nothing closer remains.
            let te: [f64; 3] = std::array::from_fn(|a| {
                let face = if r.fwd[a] { hi[a] } else { lo[a] };
                face as f64 * r.inv[a] - r.oi[a]
            });
            // Branch-free: which axis is crossed first is unpredictable from ray to ray.
            let a01 = select_unpredictable(te[1] < te[0], 1usize, 0usize);
            let t01 = te[0].min(te[1]);
            let axis = select_unpredictable(te[2] < t01, 2usize, a01);
            let t_exit = t01.min(te[2]);
            // Negated on purpose: a NaN bound must stop the walk.
            #[allow(clippy::neg_cmp_op_on_partial_ord)]
            if !(t_exit < w.s.t_stop) {
                return Ok(Step::Done(w.s.best));
            }

            // 4. Step into the neighbour across the exit face: along the exit axis to `hi` or
            // `lo - 1`; along the others to the exit point's cell, forward only and inside the
            // box being left (so the walk never turns back; see the module documentation).
            let old = q;
            let mut next = [0u32; 3];
            for a in 0..3 {
                let p = r.o[a] + t_exit * r.d[a];
                let (lo_a, hi_a) = if r.fwd[a] {
                    (old[a], hi[a] - 1)
                } else {
                    (lo[a], old[a])
                };
                let lateral = select_unpredictable(r.moves[a], clamp_floor(p, lo_a, hi_a), old[a]);
                let across = select_unpredictable(r.fwd[a], hi[a], lo[a].wrapping_sub(1));
                next[a] = select_unpredictable(a == axis, across, lateral);
            }
            // Leaving the root: `hi` at the lattice's end, or `lo - 1` wrapping below 0.
            if next[axis] >= LATTICE_SIZE {
                return Ok(Step::Done(w.s.best));
            }
            w.q = next;
            if self.follow_ropes {
                // Spec §8.4: the rope of the exit face names the smallest node holding every
                // cell just across it, `next` among them; the walk descends from there.
                let face = 2 * axis + r.fwd[axis] as usize;
                let (map, ropes, at) = match (block, held) {
                    (Some(_), Some(h)) => (&h.map, h.ropes, w.bpath[(level & 31) as usize]),
                    _ => (&self.top, self.top_ropes, w.tpath[(level & 31) as usize]),
                };
                let rope = ropes
                    .get((map.node_start(level) + at) as usize)
                    .map(|r| r.across[face]);
                if let Some(rope) = rope
                    && self.take_rope(rope, level, block.is_some(), held, w)
                {
                    k.ropes_followed += 1;
                    continue;
                }
                // No rope (a block without them) or one that names no node: the root.
                w.level = 0;
                w.cur = None;
                continue;
            }
            w.level = level.min(morton::common_level(old, next));
        }
    }

    /// Moves the walk to the node `rope` names (spec §8.4), from a leaf at `level`
    /// (`in_block`: of the block `held`): its level is found from its record index, at or
    /// above `level`. `false` if the rope names no node of the unit it must be in (bytes that
    /// break the format: the walk then starts again from the root, and stays bounded either
    /// way, since every box is built around the walk's cell whatever node it starts from).
    #[inline(always)]
    fn take_rope(
        &self,
        rope: u32,
        level: u32,
        in_block: bool,
        held: Option<&Held<'_>>,
        w: &mut WalkState,
    ) -> bool {
        let (map, index) = if rope & ROPE_TOP != 0 {
            (&self.top, (rope & !ROPE_TOP) as u64)
        } else if in_block && let Some(h) = held {
            (&h.map, rope as u64)
        } else {
            return false;
        };
        let base = map.base();
        let mut l = level.min(base + map.level_count().saturating_sub(1));
        while l > base && map.node_start(l) > index {
            l -= 1;
        }
        let Some(e) = map.levels().get((l - base) as usize) else {
            return false;
        };
        let local = index.wrapping_sub(e.node_start);
        if index < e.node_start || local >= e.node_count {
            return false;
        }
        if rope & ROPE_TOP != 0 {
            w.cur = None;
            w.tpath[(l & 31) as usize] = local;
        } else {
            w.bpath[(l & 31) as usize] = local;
        }
        w.level = l;
        true
    }

    /// The top-down traversal of a file of clusters: the octree taken as a tree of 8-wide nodes
    /// whose children's boxes are their cells (widened by the cell margin), visited nearest
    /// first with a stack, as a BVH is; empty leaves are skipped by their kind, links and solid
    /// leaves culled by their bounds, clusters traversed where the ray meets them. The walk of
    /// the OAVM paper (neighbour steps through merged volumes, [`Self::walk`]) is what files of
    /// leaf lists use.
    ///
    /// Bounded whatever the bytes: children are on the next level (at most 22 levels), and
    /// distinct internal nodes have distinct children (their ranks differ), so the nodes
    /// reached form a tree, each visited at most once. One block is held at a time: a block's
    /// nodes are all above the top-tree nodes on the stack, and are done with before them.
    #[inline(always)]
    fn descend_all<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, TraceError> {
        c.rays += 1;
        let Some(r) = self.ray_ctx(ray) else {
            return Ok(None);
        };
        let mut w = Best {
            best: None,
            t_best: ray.tmax,
            t_stop: r.t1,
        };
        let result = self.descend_in::<ANY, S>(isa, &r, &mut w, c);
        result.map(|()| w.best)
    }

    #[inline(always)]
    fn descend_in<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &mut Best,
        k: &mut Counters,
    ) -> Result<(), TraceError> {
        let Some(root) = self.root_entry(r, w.t_best, k)? else {
            return Ok(());
        };
        let mut stacks = STACKS.take();
        let stack = &mut stacks.octree;
        stack.clear();
        stack.push(root);
        let result = self.descend_stack::<ANY, S>(isa, r, w, k, stack, &mut stacks.cluster);
        STACKS.set(stacks);
        result
    }

    /// The first entry of a top-down walk: the root, internal, a link to a block (a tree small
    /// enough to be one block), or empty (a file without triangles: `None`, as for a ray that
    /// misses the root's box).
    #[inline(always)]
    fn root_entry(
        &self,
        r: &RayCtx,
        t_best: f32,
        k: &mut Counters,
    ) -> Result<Option<Entry>, TraceError> {
        const NONE: u32 = u32::MAX;
        let root = self.top.node(0, 0)?;
        let (kind, block, index) = match root.kind_bits() {
            KIND_INTERNAL => {
                if !self.top_node_may_hit(r, t_best, 0) {
                    k.top_nodes_culled += 1;
                    return Ok(None);
                }
                (EntryKind::Internal, NONE, 0)
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

    /// Whether block `b` is resident now (a hint: it may be evicted the next moment).
    pub(super) fn resident(&self, b: u32) -> bool {
        self.blocks.resident(b)
    }

    /// The blocks in the file's directory.
    pub(super) fn block_count(&self) -> usize {
        self.directory.len()
    }

    /// Admits block `b` (reads, checks and decodes it through the pager, as a walk's first
    /// need of it would) and lets it go: [`super::stream`]'s readers.
    pub(super) fn admit(&self, b: u32, c: &mut PageCounters) -> Result<(), TraceError> {
        self.fetch(b, c).map(|_| ())
    }

    /// Closest hit (any hit with `ANY`) of `ray`, walked directly.
    pub(super) fn answer<const ANY: bool>(
        &self,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, TraceError> {
        self.dispatch::<ANY>(ray, c)
    }

    /// Whether solid leaves are clusters: the top-down walk, which [`super::stream`] parks
    /// between blocks (files of leaf lists are walked by neighbour steps, one ray at a time).
    /// Whether rays are walked top-down (what streamed batches and frames need).
    pub(super) fn walks_top_down(&self) -> bool {
        self.top_down
    }

    /// Starts `ray`'s top-down walk for [`super::stream`]: counts the ray, and gives its
    /// context and best hit so far with its root pushed on `stack` (cleared first); `None` if
    /// the ray needs no node (invalid, missing the root cube or the mesh's box): its answer is
    /// no hit. Exactly what [`Self::descend_all`] does before its first step.
    pub(super) fn begin(
        &self,
        ray: &Ray,
        stack: &mut Vec<Entry>,
        k: &mut Counters,
    ) -> Result<Option<(RayCtx, Best)>, TraceError> {
        k.rays += 1;
        stack.clear();
        let Some(r) = self.ray_ctx(ray) else {
            return Ok(None);
        };
        let w = Best {
            best: None,
            t_best: ray.tmax,
            t_stop: r.t1,
        };
        let Some(root) = self.root_entry(&r, w.t_best, k)? else {
            return Ok(None);
        };
        stack.push(root);
        Ok(Some((r, w)))
    }

    /// The context of a ray whose walk [`Self::begin`] started (the same, recomputed: a parked
    /// walk does not keep it).
    pub(super) fn context(&self, ray: &Ray) -> Option<RayCtx> {
        self.ray_ctx(ray)
    }

    /// [`Self::run_held`] for [`super::stream`], compiled for the CPU's best instruction set.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn resume<const ANY: bool>(
        &self,
        r: &RayCtx,
        w: &mut Best,
        k: &mut Counters,
        stack: &mut Vec<Entry>,
        cluster_stack: &mut Vec<(u32, f32, u8)>,
        view: Option<&Held<'_>>,
    ) -> Result<Option<u32>, TraceError> {
        struct Job<'t, 'a, 'r, 'v, const ANY: bool> {
            tree: &'t Tree<'a>,
            r: &'r RayCtx,
            w: &'r mut Best,
            k: &'r mut Counters,
            stack: &'r mut Vec<Entry>,
            cluster_stack: &'r mut Vec<(u32, f32, u8)>,
            view: Option<&'r Held<'v>>,
        }
        impl<const ANY: bool> WithAvx2 for Job<'_, '_, '_, '_, ANY> {
            type Output = Result<Option<u32>, TraceError>;
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                self.tree.run_held::<ANY, Avx2>(
                    isa,
                    self.r,
                    self.w,
                    self.k,
                    self.stack,
                    self.cluster_stack,
                    self.view,
                )
            }
        }
        match self.avx2 {
            Some(isa) => isa.vectorize(Job::<ANY> {
                tree: self,
                r,
                w,
                k,
                stack,
                cluster_stack,
                view,
            }),
            None => self.run_held::<ANY, _>(baseline(), r, w, k, stack, cluster_stack, view),
        }
    }

    /// [`Self::descend_in`] with its stacks (kept per thread, so that a ray costs no
    /// allocation and no initialised array).
    #[inline(always)]
    fn descend_stack<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &mut Best,
        k: &mut Counters,
        stack: &mut Vec<Entry>,
        cluster_stack: &mut Vec<(u32, f32, u8)>,
    ) -> Result<(), TraceError> {
        // Each turn holds one block (none at first) and its view, made once: it pops nodes of
        // the top tree and of that block until one needs another block, which the next turn
        // fetches after this turn's is let go.
        let mut need: Option<u32> = None;
        loop {
            let fetched = match need.take() {
                None => None,
                Some(b) => Some(self.fetch(b, &mut k.page)?),
            };
            let view = fetched
                .as_ref()
                .map(|(b, bytes, ready)| Held::new(*b, ready, bytes));
            need = self.run_held::<ANY, S>(isa, r, w, k, stack, cluster_stack, view.as_ref())?;
            if need.is_none() {
                return Ok(());
            }
        }
    }

    /// Pops the nodes of `stack` (of the top tree and of the block `view`, if any) until the
    /// ray is answered (`None`: its answer is in `w`) or the next node is in another block
    /// (`Some(block)`, that node left on top of the stack). What a walk is between two blocks
    /// is exactly `(r, w, stack)`: [`super::stream`] parks it there and resumes it later with
    /// the same result as if it had waited.
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
        const NONE: u32 = u32::MAX;
        const STACK: usize = 7 * (MAX_LEVEL as usize + 1) + 1;
        while let Some(e) = stack.pop() {
            if e.t > w.t_stop {
                continue;
            }
            let held = if e.block == NONE {
                None
            } else {
                match view {
                    Some(h) if h.id == e.block => Some(h),
                    _ => {
                        stack.push(e);
                        return Ok(Some(e.block));
                    }
                }
            };
            let bad = |what: &'static str| {
                TraceError::Corrupt(Corruption {
                    what,
                    block: (e.block != NONE).then_some(e.block),
                    level: e.level as u32,
                    index: e.index as u64,
                })
            };
            let level = e.level as u32;
            let mut kind = e.kind;
            if kind == EntryKind::Root {
                // A block's root, at its link's place: internal, a cluster, or (never written)
                // empty.
                let h = held.ok_or_else(|| bad("block not held"))?;
                if h.root_level != level {
                    return Err(bad("block roots are not at the level of their link"));
                }
                if e.index >= h.root_count {
                    return Err(bad("link to a root the block does not have"));
                }
                let rec = h
                    .map
                    .node(level, e.index as u64)
                    .map_err(|_| bad("block root out of range"))?;
                kind = match rec.kind_bits() {
                    _ if rec.is_internal() => EntryKind::Internal,
                    KIND_SOLID => EntryKind::Solid,
                    KIND_EMPTY => continue,
                    _ => return Err(bad("invalid leaf record")),
                };
            }
            if kind == EntryKind::Solid {
                let h = held
                    .as_ref()
                    .ok_or_else(|| bad("cluster outside a block"))?;
                let rec = h
                    .map
                    .node(level, e.index as u64)
                    .map_err(|_| bad("node record out of range"))?;
                let (inline, _) = rec.solid_bits();
                if rec.kind_bits() != KIND_SOLID || inline != 0 {
                    return Err(bad("invalid leaf record"));
                }
                k.leaves_visited += 1;
                k.clusters_entered += 1;
                let found = trace_cluster::<ANY, S>(isa, r, w, h, rec.payload, k, cluster_stack)
                    .map_err(bad)?;
                if ANY && found {
                    return Ok(None);
                }
                w.t_stop = r.t1.min(w.t_best as f64);
                continue;
            }
            // An internal node: its children's cells, nearest first.
            k.nodes_visited += 1;
            // Its occluders first (spec §8.5): an any hit may stop here.
            if ANY
                && self.occluders
                && let Some(h) = held
            {
                let tris = h.occluders_of(h.map.node_start(level) + e.index as u64);
                for tri in tris {
                    k.promoted_tested += 1;
                    k.triangles_tested += 1;
                    if let Some(t) = r.shear.intersect(&tri.v, r.tmin, w.t_best) {
                        w.best = Some(HitInfo {
                            t,
                            prim: tri.prim,
                            v: tri.v,
                        });
                        return Ok(None);
                    }
                }
            }
            let map = match held {
                Some(h) => &h.map,
                None => &self.top,
            };
            if level >= MAX_LEVEL {
                return Err(bad("internal node on the deepest level"));
            }
            let (first, internal, recs) = map
                .children(level, e.index as u64)
                .ok_or_else(|| bad("rank directory points past the next level"))?;
            let size = morton::cell_size(level);
            let half = size / 2;
            let m = CELL_MARGIN;
            // Per axis, where the ray enters and leaves the low and the high half (a half an
            // axis the ray does not move along does not hold the origin in: entered at +inf).
            let mut enter_at = [[0f64; 2]; 3];
            let mut leave_at = [[0f64; 2]; 3];
            for a in 0..3 {
                let lo = e.lo[a] as f64;
                if r.moves[a] {
                    // The planes (exact: integers below 2^23) by the ray's direction.
                    let (h, c) = (&r.cell_h[a], &r.cell_m[a]);
                    let t: [f64; 4] = std::array::from_fn(|i| {
                        (lo + h[i] * half as f64 + c[i]) * r.inv[a] - r.oi[a]
                    });
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
            // The eight children at once; then only those met are looked at.
            let (met, enters) = isa.cell_hits(&enter_at, &leave_at, r.tmin as f64, w.t_stop);
            let mut mask = 0u32;
            let mut scan = met;
            while scan != 0 {
                let o = scan.trailing_zeros();
                scan &= scan - 1;
                let live = (internal >> o) & 1 == 1 || recs[o as usize].kind_bits() != KIND_EMPTY;
                mask |= (live as u32) << o;
            }
            let mut hits: [(f64, u8, f64); 8] = [(0.0, 0, 0.0); 8];
            let mut n = 0usize;
            let sato = ANY && self.sato;
            while mask != 0 {
                let o = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                // The order key: the entry `t`, or (SATO) minus the child's surface area.
                let key = if sato {
                    -self.sato_area(
                        &e,
                        level,
                        first + o as u64,
                        recs[o],
                        (internal >> o) & 1 == 1,
                        half,
                    )
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
            for &(t, o, _) in &hits[..n] {
                let o = o as usize;
                let rec = recs[o];
                let child = first + o as u64;
                let lo = [
                    e.lo[0] + half * (o as u32 & 1),
                    e.lo[1] + half * ((o as u32 >> 1) & 1),
                    e.lo[2] + half * ((o as u32 >> 2) & 1),
                ];
                let is_internal = (internal >> o) & 1 == 1;
                let (kind, block, index) = if is_internal {
                    if e.block == NONE {
                        let at = self.top.node_start(level + 1) + child;
                        if !self.top_node_may_hit(r, w.t_best, at) {
                            k.top_nodes_culled += 1;
                            continue;
                        }
                    }
                    (EntryKind::Internal, e.block, child)
                } else {
                    match rec.kind_bits() {
                        KIND_SOLID if e.block != NONE => {
                            let (_, b) = rec.solid_bits();
                            if !leaf_may_hit(r, w.t_best, lo, half, b) {
                                k.leaves_culled += 1;
                                continue;
                            }
                            (EntryKind::Solid, e.block, child)
                        }
                        KIND_LINK if e.block == NONE => {
                            let at = self.top.node_start(level + 1) + child;
                            if !self.top_node_may_hit(r, w.t_best, at) {
                                k.links_culled += 1;
                                continue;
                            }
                            let (b, root) = rec.link_bits();
                            self.check_link(b, level + 1, child)?;
                            (EntryKind::Root, b, root as u64)
                        }
                        _ => return Err(bad("invalid leaf record")),
                    }
                };
                if stack.len() >= STACK {
                    return Err(bad("traversal deeper than the lattice"));
                }
                stack.push(Entry {
                    t,
                    lo,
                    index: index as u32,
                    level: (level + 1) as u8,
                    block,
                    kind,
                });
            }
        }
        Ok(None)
    }

    /// The surface area (lattice units) of the box the walk culls child `child` of the node
    /// of `e` (at `level`) by, for the SATO order ([`Self::sato`]).
    #[inline(always)]
    fn sato_area(
        &self,
        e: &Entry,
        level: u32,
        child: u64,
        rec: NodeRecord,
        internal: bool,
        half: u32,
    ) -> f64 {
        let area = |d: [f64; 3]| 2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0]);
        if e.block == u32::MAX {
            let at = self.top.node_start(level + 1) + child;
            return match usize::try_from(at).ok().and_then(|i| self.top_boxes.get(i)) {
                Some((lo, hi)) => area(std::array::from_fn(|a| (hi[a] - lo[a]).max(0.0))),
                None => area([half as f64; 3]),
            };
        }
        if !internal && rec.kind_bits() == KIND_SOLID {
            let (_, b) = rec.solid_bits();
            let q4 = |shift: u32| ((b >> shift) & 15) as f64;
            let s16 = half as f64 / 16.0;
            return area(std::array::from_fn(|a| {
                (q4(12 + 4 * a as u32) + 1.0 - q4(4 * a as u32)) * s16
            }));
        }
        area([half as f64; 3])
    }

    /// Whether the ray may hit anything below top-tree node record `at` over `[tmin, t_best]`:
    /// its box (`top_bounds`): a link's bounds widened by the margin, an internal node's union
    /// of the link boxes below it. A record without a box lets the ray in.
    #[inline(always)]
    fn top_node_may_hit(&self, r: &RayCtx, t_best: f32, at: u64) -> bool {
        match usize::try_from(at).ok().and_then(|i| self.top_boxes.get(i)) {
            Some((lo, hi)) => box_may_hit(r, t_best, *lo, *hi),
            None => true,
        }
    }

    /// A link (at `level`, node `index` of the top tree) to block `b`: `b` must be in the
    /// directory (which also keeps it from `u32::MAX`, the stack's mark for the top tree).
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

    /// Whether the ray may hit anything below the link at `level` on the walk's path: its
    /// bounds (spec §8.1), widened by the cell margin (its box in `top_bounds`), met over
    /// `[tmin, closest hit so far]`.
    /// A ray that misses them would cull every solid leaf below the link by the same test (each
    /// leaf's widened bounds lie inside the link's), so skipping the block changes no answer.
    /// Bounds past the section (which open rules out) let the walk in.
    #[inline(always)]
    fn link_may_hit(&self, r: &RayCtx, w: &WalkState, level: u32) -> bool {
        let at = self.top.node_start(level) + w.tpath[(level & 31) as usize];
        self.top_node_may_hit(r, w.s.t_best, at)
    }

    /// Descends inside the held block from `w.level` to the leaf containing `w.q`; checks, when
    /// starting from a root, that the root exists and the block is the link's.
    #[inline(always)]
    fn descend_block(
        &self,
        w: &mut WalkState,
        held: Option<&Held<'_>>,
        k: &mut Counters,
    ) -> Result<(u32, NodeRecord), Corruption> {
        let (Some((b, rl)), Some(h)) = (w.cur, held) else {
            return Err(Corruption {
                what: "walk inside a block it does not hold",
                block: w.cur.map(|c| c.0),
                level: w.level,
                index: 0,
            });
        };
        let bad = |what| Corruption {
            what,
            block: Some(b),
            level: rl,
            index: w.bpath[(rl & 31) as usize],
        };
        if w.level == rl {
            if h.root_level != rl {
                return Err(bad("block roots are not at the level of their link"));
            }
            if w.bpath[(rl & 31) as usize] >= h.root_count as u64 {
                return Err(bad("link to a root the block does not have"));
            }
        }
        h.map
            .descend(w.level, &mut w.bpath, w.q, &mut k.nodes_visited)
            .map_err(|mut e| {
                e.block = Some(b);
                e
            })
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

/// What a stack entry of [`Tree::descend_in`] is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) enum EntryKind {
    #[default]
    Internal,
    /// A solid leaf whose bounds the ray meets.
    Solid,
    /// A block's root, at the place of its link (index: the root's).
    Root,
}

/// A node waiting on the stack of [`Tree::descend_in`]: where the ray enters its cell, the
/// cell, and the node's place.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Entry {
    t: f64,
    lo: [u32; 3],
    index: u32,
    level: u8,
    /// The block it is in (`u32::MAX`: the top tree).
    block: u32,
    kind: EntryKind,
}

/// Whether the ray may hit the solid leaf with cell `lo` (edge `size`) and tight bounds `b`
/// (spec §4.2, widened by the margin) over `[tmin, t_best]`.
#[inline(always)]
fn leaf_may_hit(r: &RayCtx, t_best: f32, lo: [u32; 3], size: u32, b: u32) -> bool {
    let s16 = size as f64 / 16.0;
    let q4 = |shift: u32| ((b >> shift) & 15) as f64;
    let blo: [f64; 3] =
        std::array::from_fn(|a| lo[a] as f64 + q4(4 * a as u32) * s16 - CELL_MARGIN);
    let bhi: [f64; 3] =
        std::array::from_fn(|a| lo[a] as f64 + (q4(12 + 4 * a as u32) + 1.0) * s16 + CELL_MARGIN);
    box_may_hit(r, t_best, blo, bhi)
}

/// Slab test of the ray over `[tmin, t_best]` against the box `[blo, bhi]` (lattice units). An
/// axis the ray does not move along must hold the origin.
#[inline(always)]
fn box_may_hit(r: &RayCtx, t_best: f32, blo: [f64; 3], bhi: [f64; 3]) -> bool {
    let (mut tn, mut tf) = (r.tmin as f64, t_best as f64);
    let mut inside = true;
    // Plain comparisons (one `maxsd`/`minsd` each), not `f64::max`/`min`, whose NaN rules cost
    // three instructions each. The operands are ordered so that a NaN (which finite planes
    // and a moving axis never give) leaves `tn` and `tf` as they were: never a cull.
    let fmax = |a: f64, b: f64| if a > b { a } else { b };
    let fmin = |a: f64, b: f64| if a < b { a } else { b };
    // One index over several per-axis arrays.
    #[allow(clippy::needless_range_loop)]
    for a in 0..3 {
        if r.moves[a] {
            let (x, y) = (blo[a] * r.inv[a] - r.oi[a], bhi[a] * r.inv[a] - r.oi[a]);
            tn = fmax(fmin(x, y), tn);
            tf = fmin(fmax(x, y), tf);
        } else {
            inside &= r.o[a] >= blo[a] && r.o[a] <= bhi[a];
        }
    }
    inside && tn <= tf
}

/// `floor(p)` clamped to `[lo, hi]`, without branches (`max` and `min` give the other operand
/// for NaN, so NaN gives `lo`; truncation is floor for the non-negative clamped value).
#[inline(always)]
fn clamp_floor(p: f64, lo: u32, hi: u32) -> u32 {
    p.max(lo as f64).min(hi as f64) as u32
}

/// Traverses the cluster whose root is node `root` of the held block (spec §7.1), updating the
/// walk's closest hit (ties to the smallest primitive id); with `ANY`, stops at the first hit
/// and returns true. Bounded whatever the bytes: a tree visits each node at most once, so a
/// walk that visits more nodes than the block has, or goes deeper than
/// [`MAX_CLUSTER_DEPTH`], is reading something that is not a tree.
#[inline(always)]
fn trace_cluster<const ANY: bool, S: Simd8>(
    isa: S,
    r: &RayCtx,
    w: &mut Best,
    h: &Held<'_>,
    root: u32,
    k: &mut Counters,
    stack: &mut Vec<(u32, f32, u8)>,
) -> Result<bool, &'static str> {
    const STACK: usize = (CLUSTER_WIDTH - 1) * MAX_CLUSTER_DEPTH + 1;
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
            return Err("cluster node index out of range");
        };
        visits += 1;
        if visits > h.cluster_nodes.len() {
            return Err("cluster nodes do not form a tree");
        }
        k.cluster_nodes_visited += 1;
        let count = (n.child_count as usize).min(CLUSTER_WIDTH);
        k.boxes_tested += count as u64;
        let (mut mask, near) = r.boxes.node_hits_with(isa, n.view(), r.tmin, w.t_best);
        let inner = n.inner_count as u32;
        // Leaves first, nearest-first is not needed for them: all are tested now.
        let mut leaf_mask = mask & !((1u32 << inner.min(8)) - 1);
        mask &= (1u32 << inner.min(8)) - 1;
        while leaf_mask != 0 {
            let i = leaf_mask.trailing_zeros();
            leaf_mask &= leaf_mask - 1;
            let gi = n.group_base as u64 + (i - inner) as u64;
            let Some(g) = h.groups.get(gi as usize) else {
                return Err("triangle group index out of range");
            };
            k.groups_tested += 1;
            k.triangles_tested += g.count.min(8) as u64;
            let (mut hits, ts) = r
                .shear
                .intersect_group_with(isa, g.view(), r.tmin, w.t_best);
            while hits != 0 {
                let l = hits.trailing_zeros() as usize;
                hits &= hits - 1;
                let (t, prim) = (ts[l], g.prim[l]);
                if ANY {
                    w.best = Some(HitInfo {
                        t,
                        prim,
                        v: g.triangle(l),
                    });
                    return Ok(true);
                }
                let better = match &w.best {
                    None => true,
                    Some(b) => (t, prim) < (b.t, b.prim),
                };
                if better {
                    w.t_best = t;
                    w.best = Some(HitInfo {
                        t,
                        prim,
                        v: g.triangle(l),
                    });
                }
            }
        }
        if mask == 0 {
            continue;
        }
        if depth as usize + 1 >= MAX_CLUSTER_DEPTH {
            return Err("cluster deeper than the format allows");
        }
        // Inner children, nearest popped first.
        let mut kids: [(f32, u32); CLUSTER_WIDTH] = [(0.0, 0); CLUSTER_WIDTH];
        let mut nk = 0;
        while mask != 0 {
            let i = mask.trailing_zeros();
            mask &= mask - 1;
            kids[nk] = (near[i as usize], n.node_base.wrapping_add(i));
            nk += 1;
        }
        kids[..nk].sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
        for &(t, c) in &kids[..nk] {
            if stack.len() >= STACK {
                return Err("cluster deeper than the format allows");
            }
            stack.push((c, t, depth + 1));
        }
    }
    Ok(false)
}

/// The instruction set the build targets: SSE4.1 (the portable x86-64-v2 build), else eight
/// scalars.
#[inline(always)]
fn baseline() -> impl Simd8 {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
    return crate::os::Sse41::new();
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
    return crate::os::Portable;
}
