//! The tracer (OAVM paper §2.4–2.5): closest hit and any hit through the mapped tree.
//!
//! A [`Tree`] is a read-only view of a file's tree: the top tree (always resident) and the
//! blocks, reached through the pager. It answers a ray by one of its walks, each in a room of
//! its own around the ray's context ([`ray`]: the ray in lattice space, the closest hit so far,
//! the slab tests every walk shares):
//!
//! - [`neighbours`]: the OAVM paper's walk, from leaf to neighbouring leaf across merged empty
//!   volumes, each next leaf found from Morton arithmetic ([`Walk::Neighbours`]; the walk of
//!   files of leaf lists);
//! - [`ropes`]: the same walk, each next leaf found from the rope of the exit face (spec §8.4,
//!   [`Walk::Ropes`]);
//! - [`topdown`]: the octree as a tree of 8-wide nodes, nearest child first with a stack, as a
//!   BVH is walked ([`Walk::TopDown`]; the walk of files of clusters);
//! - [`occluders`]: what shadow rays add to the top-down walk: the SATO order and the
//!   occluders of inner nodes (the multi-index tree of Liang and Huang);
//! - [`cluster`]: a solid leaf's wide BVH over triangle groups, which both walks enter;
//! - [`resume`]: the top-down walk cut at block boundaries, parked and resumed by
//!   [`super::stream`].
//!
//! Each walk is compiled for the best instruction set the CPU has ([`Tree::dispatch`]).

mod closest;
mod cluster;
mod deferred;
mod neighbours;
mod occluders;
mod ray;
mod resume;
mod ropes;
mod topdown;
mod wide;

/// The triangle groups the wide walk tests, recorded per thread (the `group-trace` feature, for
/// research tools only: a push per group tested).
#[cfg(feature = "group-trace")]
pub mod group_trace {
    use std::cell::RefCell;

    thread_local! {
        static SEEN: RefCell<Vec<(u32, u32)>> = const { RefCell::new(Vec::new()) };
    }

    /// Group `group` of block `block` was tested.
    #[inline]
    pub(super) fn record(block: u32, group: u32) {
        SEEN.with(|s| s.borrow_mut().push((block, group)));
    }

    /// The groups this thread's walks tested since the last call, in the order tested.
    pub fn take() -> Vec<(u32, u32)> {
        SEEN.with(|s| std::mem::take(&mut *s.borrow_mut()))
    }
}

use std::sync::OnceLock;

use serde::Serialize;

use super::held::{Held, ReadyMap};
use super::pager::chunks::{ChunkCache, ChunkGuard};
use super::pager::{BlockBytes, BlockSource, PageCounters, PageError};
use super::top_bounds::LatticeBox;
use crate::geom::Ray;
use crate::mapping::morton::LATTICE_SIZE;
use crate::mapping::{Corruption, TreeMap};
use crate::os::{Avx2, Simd8, WithAvx2};
use crate::physical::format::{
    BlockEntry, ClusterNode, FLAG_CLUSTERS, FLAG_OCCLUDERS, Header, RopeRecord, WideLink,
};
pub use closest::{Nearest, closest_on_triangle};
pub(in crate::logical) use deferred::Deferred;
pub(in crate::logical) use ray::{Best, RayCtx};
pub(in crate::logical) use topdown::Entry;
pub(in crate::logical) use wide::WideEnd;

/// Which walk traces a scene's rays. Every walk gives the same answers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Walk {
    /// The fastest for the file: [`Walk::Wide`] for a file of clusters, else
    /// [`Walk::Neighbours`].
    #[default]
    Auto,
    /// One loop over the 8-wide nodes from the root to the triangle groups (format-spec §8.7;
    /// files of clusters).
    Wide,
    /// Top-down, nearest child first with a stack, as a BVH is walked (files of clusters).
    TopDown,
    /// The OAVM paper's walk: leaf to leaf across merged volumes, each next leaf found from the
    /// lowest common ancestor of its cell and the last one (the computed Morton neighbour).
    Neighbours,
    /// The same walk, each next leaf found from the node the rope of the exit face names
    /// (format-spec §8.4; a file packed with `--ropes`).
    Ropes,
}

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
    /// Groups whose tests were put off until their chunks were read (batches traced chunk by
    /// chunk, spec §8.3); each is tested later or passed over, and counted again if tested.
    pub groups_deferred: u64,
    /// Ropes followed by the leaf-to-leaf walk of [`Walk::Ropes`] (spec §8.4).
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
    /// Streamed batches: walks answered wide as they started, every block they needed being
    /// resident (never parked).
    pub walks_unparked: u64,
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
        self.ropes_followed += o.ropes_followed;
        self.promoted_tested += o.promoted_tested;
        self.cluster_nodes_visited += o.cluster_nodes_visited;
        self.boxes_tested += o.boxes_tested;
        self.groups_tested += o.groups_tested;
        self.groups_deferred += o.groups_deferred;
        self.page += o.page;
        self.walks_parked += o.walks_parked;
        self.blocks_served += o.blocks_served;
        self.peak_parked_bytes = self.peak_parked_bytes.max(o.peak_parked_bytes);
        self.walks_unparked += o.walks_unparked;
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
pub(in crate::logical) enum Fetched<'a> {
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
    /// leaf ([`neighbours`]).
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
    /// Rays are walked by [`wide`] (clusters, [`Walk::Auto`] or [`Walk::Wide`]).
    wide: bool,
    /// The top tree's wide nodes and links (spec §8.7; empty in a file of lists).
    wide_top: &'a [ClusterNode],
    wide_links: &'a [WideLink],
    /// A bound on the magnitude of every coordinate a wide node holds (twice the root cube's
    /// farthest corner from 0), for the node test's eligibility (spec §8.7).
    coord_bound: f32,
    /// Where the groups are when `blocks` gives blocks' heads (spec §8.3): read chunk by chunk.
    chunks: Option<ChunkCtx<'a>>,
}

/// The chunks of a block of which only the head is held (spec §8.3), and the cache they are
/// read into.
#[derive(Clone, Copy)]
pub(crate) struct Chunked<'v> {
    pub cache: &'v ChunkCache,
    pub src: &'v dyn BlockSource,
    /// The block's entry (its real one, not its head's) and decoded head.
    pub entry: &'v BlockEntry,
    pub head: &'v [u8],
}

impl<'v> Chunked<'v> {
    /// The chunk holding group `g` of block `block`, and the group's index in it.
    #[inline(never)]
    pub fn group(
        &self,
        block: u32,
        g: u64,
        c: &mut PageCounters,
    ) -> Result<(ChunkGuard<'v>, usize), PageError> {
        let per = self.cache.chunk_groups() as u64;
        let chunk = u32::try_from(g / per).map_err(|_| PageError {
            block,
            what: "triangle group index out of range".into(),
        })?;
        let guard = self
            .cache
            .get(self.src, block, self.entry, self.head, chunk, c)?;
        Ok((guard, (g % per) as usize))
    }
}

/// The chunk cache of a tree whose pager holds blocks' heads, the file, and its real block
/// directory (the tree's `directory` is then the heads').
#[derive(Clone, Copy)]
pub(crate) struct ChunkCtx<'a> {
    pub cache: &'a ChunkCache,
    pub src: &'a dyn BlockSource,
    pub directory: &'a [BlockEntry],
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
            wide: clusters,
            wide_top: &[],
            wide_links: &[],
            coord_bound: {
                let far = (0..3)
                    .map(|k| {
                        header.root_min[k]
                            .abs()
                            .max((header.root_min[k] + header.root_size).abs())
                    })
                    .fold(0.0, f64::max);
                (2.0 * far) as f32
            },
            chunks: None,
        }
    }

    /// The same tree with the top tree's wide nodes and links (spec §8.7), as the file holds
    /// them.
    pub(crate) fn with_wide(mut self, nodes: &'a [ClusterNode], links: &'a [WideLink]) -> Tree<'a> {
        self.wide_top = nodes;
        self.wide_links = links;
        self
    }

    /// The same tree, walked by `walk` ([`Walk::Ropes`] follows `top_ropes` and the blocks'
    /// ropes; the scene checked at open that the file has them).
    /// The same tree, whose pager gives blocks' heads and whose groups `chunks` reads.
    pub(crate) fn with_chunks(mut self, chunks: Option<ChunkCtx<'a>>) -> Tree<'a> {
        self.chunks = chunks;
        self
    }

    /// Where block `b`'s groups are when only its head `head` is held.
    #[inline]
    pub(in crate::logical) fn chunked<'v>(&self, b: u32, head: &'v [u8]) -> Option<Chunked<'v>>
    where
        'a: 'v,
    {
        let c = self.chunks?;
        Some(Chunked {
            cache: c.cache,
            src: c.src,
            entry: c.directory.get(b as usize)?,
            head,
        })
    }

    pub(crate) fn walking(mut self, walk: Walk, top_ropes: &'a [RopeRecord]) -> Tree<'a> {
        self.top_down = match walk {
            Walk::Auto | Walk::Wide => self.clusters,
            Walk::TopDown => true,
            Walk::Neighbours | Walk::Ropes => false,
        };
        self.wide = self.clusters && matches!(walk, Walk::Auto | Walk::Wide);
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

    /// The closest hits of `rays`, in order, into `out` (cleared first): the answers of
    /// [`Self::intersect`] ray by ray, with the instruction set and the walk chosen once for all
    /// of them. For a batch its caller has made (a wave of a render's rays); stops at the first
    /// ray whose walk fails.
    pub fn intersect_each(
        &self,
        rays: &[Ray],
        c: &mut Counters,
        out: &mut Vec<Option<HitInfo>>,
    ) -> Result<(), TraceError> {
        out.clear();
        out.reserve(rays.len());
        self.answer_each::<false>(rays.iter(), c, |_, _, h| out.push(h))
    }

    /// Whether each of `rays` is occluded, in order, into `out` (cleared first): the answers of
    /// [`Self::occluded`] ray by ray, as [`Self::intersect_each`].
    pub fn occluded_each(
        &self,
        rays: &[Ray],
        c: &mut Counters,
        out: &mut Vec<bool>,
    ) -> Result<(), TraceError> {
        out.clear();
        out.reserve(rays.len());
        self.answer_each::<true>(rays.iter(), c, |_, _, h| out.push(h.is_some()))
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
                if self.tree.wide {
                    self.tree.wide_all::<ANY, Avx2>(isa, self.ray, self.c)
                } else if self.tree.top_down {
                    self.tree.descend_all::<ANY, Avx2>(isa, self.ray, self.c)
                } else {
                    self.tree.walk::<ANY, Avx2>(isa, self.ray, self.c)
                }
            }
        }
        match self.avx2 {
            Some(isa) => isa.vectorize(Job::<ANY> { tree: self, ray, c }),
            None if self.wide => self.wide_all::<ANY, _>(baseline(), ray, c),
            None if self.top_down => self.descend_all::<ANY, _>(baseline(), ray, c),
            None => self.walk::<ANY, _>(baseline(), ray, c),
        }
    }

    /// The answers (closest hits; any hits with `ANY`) of `rays`, each given to `f` with the
    /// ray's index among them, in order; stops at the first walk that fails. The same answers as
    /// [`Self::dispatch`] ray by ray, with the choice of instruction set and walk made once for
    /// all of them (one entry into the AVX2-compiled code, one taking of the wide walk's stack),
    /// for the chunks of a batch.
    #[inline(always)]
    pub(in crate::logical) fn answer_each<'r, const ANY: bool>(
        &self,
        rays: impl Iterator<Item = &'r Ray>,
        c: &mut Counters,
        mut f: impl FnMut(usize, &'r Ray, Option<HitInfo>),
    ) -> Result<(), TraceError> {
        self.answer_each_with::<ANY>(rays, c, false, |i, ray, h, _| f(i, ray, h))
    }

    /// [`Self::answer_each`], and with `defer` the wide walk leaving the groups whose chunks are
    /// not resident in a list given to `f` with each ray's hit (`deferred`'s
    /// `answer_each_deferring`; empty otherwise).
    #[inline(always)]
    pub(super) fn answer_each_with<'r, const ANY: bool>(
        &self,
        rays: impl Iterator<Item = &'r Ray>,
        c: &mut Counters,
        defer: bool,
        f: impl FnMut(usize, &'r Ray, Option<HitInfo>, &mut Vec<Deferred>),
    ) -> Result<(), TraceError> {
        struct Job<'t, 'a, 'c, I, F, const ANY: bool> {
            tree: &'t Tree<'a>,
            rays: I,
            c: &'c mut Counters,
            defer: bool,
            f: F,
        }
        impl<'r, I, F, const ANY: bool> WithAvx2 for Job<'_, '_, '_, I, F, ANY>
        where
            I: Iterator<Item = &'r Ray>,
            F: FnMut(usize, &'r Ray, Option<HitInfo>, &mut Vec<Deferred>),
        {
            type Output = Result<(), TraceError>;
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                self.tree
                    .each::<ANY, Avx2>(isa, self.rays, self.c, self.defer, self.f)
            }
        }
        match self.avx2 {
            Some(isa) => isa.vectorize(Job::<_, _, ANY> {
                tree: self,
                rays,
                c,
                defer,
                f,
            }),
            None => self.each::<ANY, _>(baseline(), rays, c, defer, f),
        }
    }

    /// [`Self::answer_each`] with the instruction set `isa`: the walk chosen once, then each
    /// ray's (the wide walk's on the thread's stack, taken once).
    #[inline(always)]
    fn each<'r, const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        rays: impl Iterator<Item = &'r Ray>,
        c: &mut Counters,
        defer: bool,
        mut f: impl FnMut(usize, &'r Ray, Option<HitInfo>, &mut Vec<Deferred>),
    ) -> Result<(), TraceError> {
        // (Only the wide walk leaves groups for later; the others' lists stay empty.)
        let none = &mut Vec::new();
        if self.wide {
            self.each_wide::<ANY, S>(isa, rays, c, defer, f)
        } else if self.top_down {
            for (i, ray) in rays.enumerate() {
                f(i, ray, self.descend_all::<ANY, S>(isa, ray, c)?, none);
            }
            Ok(())
        } else {
            for (i, ray) in rays.enumerate() {
                f(i, ray, self.walk::<ANY, S>(isa, ray, c)?, none);
            }
            Ok(())
        }
    }

    /// Block `b`'s bytes and map: straight from the file if it was admitted and the pager never
    /// evicts, else from the pager (counted alike).
    #[inline(always)]
    pub(in crate::logical) fn fetch(
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
            c.resident_hit();
            return Ok((b, Fetched::Direct(bytes), ready));
        }
        let (bytes, ready) = self.blocks.fetch(b, c)?;
        Ok((b, Fetched::Paged(bytes), ready))
    }

    /// The view of a fetched block (see [`Self::fetch`]).
    #[inline(always)]
    fn held<'f>(&self, fetched: &'f Option<(u32, Fetched<'a>, &'a ReadyMap)>) -> Option<Held<'f>>
    where
        'a: 'f,
    {
        fetched
            .as_ref()
            .map(|(b, bytes, ready)| Held::new(*b, ready, bytes))
    }
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
