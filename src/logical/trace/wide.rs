//! Format 6's walk ([`super::Walk::Wide`], spec §8.7): one loop from the top tree's wide
//! nodes through the links into the blocks' wide nodes (the octree's, then the clusters') down
//! to the triangle groups, with one stack of 8-byte entries (a reference and the distance at
//! which the ray enters it). No f64, no rank lookup, no per-level state: a node is an index
//! into the wide nodes of the unit it is in (the top tree's, or the held block's).
//!
//! **Units.** The stack holds the top tree's entries below the held block's: a block is entered
//! when a link is popped, and its own loop ([`Tree::walk_block`]) runs until the stack is back
//! at the place the link had (its floor); every entry it pushes is the block's. A popped link
//! to a block other than the one held ends the turn: the caller fetches that block (and lets
//! the other go) and runs the walk on, so one block is held at a time, as in the other walks.
//!
//! **Bounded whatever the bytes.** Each unit's nodes are visited at most as many times as the
//! unit has nodes plus the blocks entered have (a tree visits each once), and the stack is
//! capped by the depth the format allows; past either, the bytes are not a tree.

use super::cluster::{collect_group, test_group};
use super::deferred::Deferred;
use super::{Counters, Direct, Fetched, HitInfo, TraceError, Tree, baseline};
use crate::geom::Ray;
use crate::geom::triangle::RayShear;
use crate::geom::wide_box::{FmaRay, grown_exit};
use crate::logical::held::WideHeld;
use crate::logical::pager::chunks::ChunkGuard;
use crate::mapping::Corruption;
use crate::os::{Avx2, Simd8, WithAvx2};
use crate::physical::format::{CLUSTER_WIDTH, ClusterNode, MAX_CLUSTER_DEPTH};

/// A stack entry's reference: the index of a wide node of its unit, or with this bit a link
/// (an index into the top tree's wide links).
const LINK: u32 = 1 << 31;
/// The deepest stack a valid file needs: 7 entries left per level of the octree (22) and of a
/// cluster ([`MAX_CLUSTER_DEPTH`]), and the root.
const STACK: usize = (CLUSTER_WIDTH - 1) * (22 + MAX_CLUSTER_DEPTH) + 1;

/// A stack entry: a reference (a node of its unit, or a link) and the distance at which the ray
/// enters it.
type Entry = (u32, f32);

/// What a walk carries from one block to the next.
pub(in crate::logical) struct WideWalk<'s> {
    /// The stack, `sp` entries deep.
    st: &'s mut [Entry; STACK],
    sp: usize,
    /// Visits of the top tree's wide nodes left before the bytes are taken for something that
    /// is not a tree: never refilled, so the top tree's nodes push finitely many links (and
    /// each link entered visits at most its block's nodes, [`Tree::walk_block`]).
    budget: usize,
    pub(super) best: Option<HitInfo>,
    pub(super) t_best: f32,
    /// Where a walk that defers (spec §8.3: a block's head held, its chunks read later) leaves
    /// the groups whose chunks are not resident; `None`: such chunks are read as reached.
    defer: Option<&'s mut Vec<Deferred>>,
    /// Where a walk for every hit ([`Tree::all_hits`]) puts each hit it finds (its closest
    /// hit then stays `None`, and `t_best` the ray's `tmax`).
    all: Option<&'s mut Vec<HitInfo>>,
}

/// How a walk that may stop short of blocks that are not resident ended
/// ([`Tree::wide_if_resident`]).
pub(in crate::logical) enum WideEnd {
    /// The closest hit (any hit with `ANY`), if any.
    Answered(Option<HitInfo>),
    /// Stopped where it needed a block that was not resident.
    Stopped,
}

/// The ray's constants for the walk. The triangle test's are made when the ray first reaches
/// a group: most rays of a scene with open space (three in four of the dragon's primary rays)
/// never do. (In a `OnceCell`, whose first use is a cold call: made inline in the walk's
/// state instead, they cost the benchmark's any-hit rays 17-20 %, commit 772acea.)
pub(super) struct WideRay<'r> {
    pub(super) boxes: FmaRay,
    ray: &'r Ray,
    shear: std::cell::OnceCell<RayShear>,
    tmin: f32,
}

thread_local! {
    /// The walk's stack, kept per thread so that a ray costs no allocation: taken once per ray
    /// ([`Tree::wide_all`]) or once per chunk of a batch ([`Tree::answer_each`]).
    pub(super) static WIDE_STACK: std::cell::Cell<Vec<(u32, f32)>> = const { std::cell::Cell::new(Vec::new()) };
}

impl<'a> Tree<'a> {
    /// Closest hit (any hit with `ANY`) of `ray` by the wide walk, with the thread's stack
    /// ([`Self::wide_ray`]).
    #[inline(always)]
    pub(super) fn wide_all<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, TraceError> {
        let mut stack = WIDE_STACK.take();
        let result = self.wide_ray::<ANY, S>(isa, ray, c, (&mut stack, None), &mut None);
        WIDE_STACK.set(stack);
        result
    }

    /// The wide walk of `ray` if every block it needs is resident now: its closest hit (any
    /// hit with `ANY`), the same answer as [`Self::intersect`]'s (or [`Self::occluded`]'s);
    /// else [`WideEnd::Stopped`] where it needs a block that is not, before reading any, the
    /// ray not counted (the nodes it visited are). Also stopped: a tree that does not walk
    /// wide, and a ray the wide walk hands to the top-down walk. For a stream's walks, which
    /// need to park only when a block must be read.
    pub(in crate::logical) fn wide_if_resident<const ANY: bool>(
        &self,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<WideEnd, TraceError> {
        struct Job<'t, 'a, 'r, const ANY: bool> {
            tree: &'t Tree<'a>,
            ray: &'r Ray,
            c: &'r mut Counters,
        }
        impl<const ANY: bool> WithAvx2 for Job<'_, '_, '_, ANY> {
            type Output = Result<WideEnd, TraceError>;
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                self.tree.wide_stack::<ANY, Avx2>(isa, self.ray, self.c)
            }
        }
        if !self.wide {
            return Ok(WideEnd::Stopped);
        }
        match self.avx2 {
            Some(isa) => isa.vectorize(Job::<ANY> { tree: self, ray, c }),
            None => self.wide_stack::<ANY, _>(baseline(), ray, c),
        }
    }

    /// Every hit of `ray` with `tmin <= t <= tmax`, each triangle once, into `out` (cleared
    /// first), ordered by `t` then primitive id; a ray through an edge or a corner shared by
    /// several triangles meets one of them ([`RayShear::owns`]). The wide walk with the
    /// closest hit never closing in, so it enters every node the ray's segment meets; a
    /// triangle referenced by several leaves is found in each and kept once. `Ok(false)`, `out`
    /// empty, for a file of leaf lists (whatever walk its closest hits take, a file of clusters
    /// is walked wide for every hit) and for a ray the wide
    /// walk does not take (`tmin < 0`, a direction too small or too large for f32, spec §8.7).
    pub fn all_hits(
        &self,
        ray: &Ray,
        c: &mut Counters,
        out: &mut Vec<HitInfo>,
    ) -> Result<bool, TraceError> {
        struct Job<'t, 'a, 'r> {
            tree: &'t Tree<'a>,
            ray: &'r Ray,
            c: &'r mut Counters,
            out: &'r mut Vec<HitInfo>,
        }
        impl WithAvx2 for Job<'_, '_, '_> {
            type Output = Result<WideEnd, TraceError>;
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                self.tree.wide_hits(isa, self.ray, self.c, self.out)
            }
        }
        out.clear();
        if !self.clusters {
            return Ok(false);
        }
        let end = match self.avx2 {
            Some(isa) => isa.vectorize(Job {
                tree: self,
                ray,
                c,
                out: &mut *out,
            })?,
            None => self.wide_hits(baseline(), ray, c, out)?,
        };
        if matches!(end, WideEnd::Stopped) {
            out.clear();
            return Ok(false);
        }
        once_in_order(out);
        Ok(true)
    }

    /// [`Self::all_hits`] of each of `rays` in turn, each ray's hits (`None`: a ray the walk
    /// cannot take, as `all_hits` refuses it) handed to `f`: the instruction set chosen, the
    /// thread's stack taken and the last block entered kept once for them all, as the closest
    /// hits' batches do.
    pub fn all_hits_each<'r>(
        &self,
        rays: impl Iterator<Item = &'r Ray>,
        c: &mut Counters,
        out: &mut Vec<HitInfo>,
        f: impl FnMut(&'r Ray, Option<&[HitInfo]>),
    ) -> Result<(), TraceError> {
        struct Job<'t, 'a, 'o, I, F> {
            tree: &'t Tree<'a>,
            rays: I,
            c: &'o mut Counters,
            out: &'o mut Vec<HitInfo>,
            f: F,
        }
        impl<'r, I, F> WithAvx2 for Job<'_, '_, '_, I, F>
        where
            I: Iterator<Item = &'r Ray>,
            F: FnMut(&'r Ray, Option<&[HitInfo]>),
        {
            type Output = Result<(), TraceError>;
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                self.tree
                    .hits_each(isa, self.rays, self.c, self.out, self.f)
            }
        }
        if !self.clusters {
            rays.for_each({
                let mut f = f;
                move |r| f(r, None)
            });
            return Ok(());
        }
        match self.avx2 {
            Some(isa) => isa.vectorize(Job {
                tree: self,
                rays,
                c,
                out,
                f,
            }),
            None => self.hits_each(baseline(), rays, c, out, f),
        }
    }

    /// [`Self::all_hits_each`] with the instruction set `isa`.
    #[inline(always)]
    fn hits_each<'r, S: Simd8>(
        &self,
        isa: S,
        rays: impl Iterator<Item = &'r Ray>,
        c: &mut Counters,
        out: &mut Vec<HitInfo>,
        mut f: impl FnMut(&'r Ray, Option<&[HitInfo]>),
    ) -> Result<(), TraceError> {
        let mut stack = WIDE_STACK.take();
        let mut kept = None;
        let mut result = Ok(());
        for ray in rays {
            out.clear();
            let walked = (&mut stack, None);
            match self.wide_ray_until::<false, false, true, S>(
                isa,
                ray,
                c,
                walked,
                &mut kept,
                Some(&mut *out),
            ) {
                Ok(WideEnd::Stopped) => f(ray, None),
                Ok(WideEnd::Answered(_)) => {
                    once_in_order(out);
                    f(ray, Some(out));
                }
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        WIDE_STACK.set(stack);
        result
    }

    /// [`Self::all_hits`]'s walk with the instruction set `isa`, on the thread's stack.
    #[inline(always)]
    fn wide_hits<S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
        out: &mut Vec<HitInfo>,
    ) -> Result<WideEnd, TraceError> {
        let mut stack = WIDE_STACK.take();
        let walked = (&mut stack, None);
        let end =
            self.wide_ray_until::<false, false, true, S>(isa, ray, c, walked, &mut None, Some(out));
        WIDE_STACK.set(stack);
        end
    }

    /// [`Self::wide_if_resident`] with the instruction set `isa`, on the thread's stack.
    #[inline(always)]
    fn wide_stack<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<WideEnd, TraceError> {
        let mut stack = WIDE_STACK.take();
        let end = self.wide_ray_until::<ANY, true, false, S>(
            isa,
            ray,
            c,
            (&mut stack, None),
            &mut None,
            None,
        );
        WIDE_STACK.set(stack);
        end
    }

    /// Whether the tree's leaves are clusters (and so can be walked for every hit).
    pub(in crate::logical) fn has_clusters(&self) -> bool {
        self.clusters
    }

    /// Whether block `b` is resident now (a hint: admitted to a pager that never evicts, or
    /// the pager says so).
    #[inline]
    fn resident_now(&self, b: u32) -> bool {
        let admitted = |d: &Direct| d.ready.get(b as usize).is_some_and(|r| r.get().is_some());
        self.direct.as_ref().is_some_and(admitted) || self.blocks.resident(b)
    }

    /// Closest hit (any hit with `ANY`) of `ray` by the wide walk on `stack` (grown once to the
    /// deepest stack a valid file needs, and kept for the next ray); a ray the node test's bound
    /// does not cover (spec §8.7: `tmin < 0`, a direction too small or too large for f32) is
    /// walked top-down instead (the same answers).
    ///
    /// `kept` is the view of the last block entered straight from the file (admitted, and the
    /// pager never evicts, [`Self::fetch`]), kept for the next ray of a batch: rays traced one
    /// after the other mostly enter the same block, and entering it again then costs no
    /// directory lookup and no cast (counted as the fetch counts it). `defer`: where the groups
    /// whose chunks are not resident are left, untested ([`Deferred`]); the hit returned is
    /// then the closest among the groups tested.
    #[inline(always)]
    pub(super) fn wide_ray<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
        walked: (&mut Vec<(u32, f32)>, Option<&mut Vec<Deferred>>),
        kept: &mut Option<WideHeld<'a>>,
    ) -> Result<Option<HitInfo>, TraceError> {
        match self.wide_ray_until::<ANY, false, false, S>(isa, ray, c, walked, kept, None)? {
            WideEnd::Answered(h) => Ok(h),
            WideEnd::Stopped => Err(bad("a walk stopped that may not", None)),
        }
    }

    /// [`Self::wide_ray`], which with `STOP` does not read blocks: it stops
    /// ([`WideEnd::Stopped`], the ray not counted) where it needs a block that is not resident
    /// now, and for a ray the wide walk does not take.
    #[inline(always)]
    fn wide_ray_until<const ANY: bool, const STOP: bool, const ALL: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
        (stack, defer): (&mut Vec<(u32, f32)>, Option<&mut Vec<Deferred>>),
        kept: &mut Option<WideHeld<'a>>,
        all: Option<&mut Vec<HitInfo>>,
    ) -> Result<WideEnd, TraceError> {
        // Made in place (it is not small), before the checks that may send the ray elsewhere.
        let r = WideRay {
            boxes: FmaRay::new(ray, self.coord_bound),
            ray,
            shear: std::cell::OnceCell::new(),
            tmin: ray.tmin,
        };
        // The occluders and the SATO order are the top-down walk's (research variants).
        let research = ANY && (self.occluders || self.sato);
        if stack.len() < STACK {
            stack.resize(STACK, (0, 0.0));
        }
        // The stack is there (grown just above).
        let st = match stack.first_chunk_mut::<STACK>() {
            Some(st) if r.boxes.eligible() && ray.is_valid() && !research => st,
            _ if STOP || ALL => return Ok(WideEnd::Stopped),
            _ => {
                return self
                    .descend_all::<ANY, S>(isa, ray, c)
                    .map(WideEnd::Answered);
            }
        };
        c.rays += 1;
        if self.wide_top.is_empty() {
            return Ok(WideEnd::Answered(None));
        }
        st[0] = (0, ray.tmin);
        let mut w = WideWalk {
            st,
            sp: 1,
            budget: self.wide_top.len(),
            best: None,
            t_best: ray.tmax,
            defer,
            all,
        };
        let mut need: Option<u32> = None;
        loop {
            // A block from the pager, held for this turn only.
            let paged;
            let paged_view;
            let view = match need.take() {
                None => None,
                Some(b) if kept.as_ref().is_some_and(|h| h.id == b) => {
                    // Counted as `fetch` counts a block read from the map.
                    c.page.resident_hit();
                    kept.as_ref()
                }
                Some(b) if STOP && !self.resident_now(b) => {
                    c.rays -= 1;
                    return Ok(WideEnd::Stopped);
                }
                Some(b) => match self.fetch(b, &mut c.page)? {
                    (b, Fetched::Direct(raw), ready) => {
                        *kept = Some(ready.wide(b, raw));
                        kept.as_ref()
                    }
                    fetched => {
                        paged = fetched;
                        paged_view = paged.2.wide(paged.0, &paged.1);
                        Some(&paged_view)
                    }
                },
            };
            match self.run_wide::<ANY, ALL, S>(isa, &r, &mut w, c, view)? {
                Some(b) => need = Some(b),
                None => return Ok(WideEnd::Answered(w.best)),
            }
        }
    }

    /// Pops the top tree's entries until the ray is answered (`None`) or a link needs a block
    /// other than `view` (`Some(block)`, the link left on the stack); a link to `view` runs
    /// that block's walk.
    #[inline(always)]
    fn run_wide<const ANY: bool, const ALL: bool, S: Simd8>(
        &self,
        isa: S,
        r: &WideRay,
        w: &mut WideWalk,
        k: &mut Counters,
        view: Option<&WideHeld<'_>>,
    ) -> Result<Option<u32>, TraceError> {
        while w.sp > 0 {
            w.sp -= 1;
            let (at, t) = w.st[w.sp];
            // A child entered past the closest hit (grown as the node test grows exits).
            if t > grown_exit(w.t_best) {
                continue;
            }
            if at & LINK != 0 {
                let Some(link) = self.wide_links.get((at & !LINK) as usize) else {
                    return Err(bad("wide link index out of range", None));
                };
                match view {
                    Some(h) if h.id == link.block => {
                        if link.root >= h.root_count {
                            let what = "wide link to a root the block does not have";
                            return Err(bad(what, Some(h.id)));
                        }
                        if self.walk_block::<ANY, ALL, S>(isa, r, w, k, h, (link.root, t))? {
                            return Ok(None);
                        }
                        continue;
                    }
                    _ if link.block as usize >= self.directory.len() => {
                        return Err(TraceError::Corrupt(Corruption {
                            what: "wide link to a block the directory does not have",
                            block: Some(link.block),
                            level: 0,
                            index: (at & !LINK) as u64,
                        }));
                    }
                    _ => {
                        w.sp += 1;
                        return Ok(Some(link.block));
                    }
                }
            }
            let Some(n) = self.wide_top.get(at as usize) else {
                return Err(bad("wide node index out of range", None));
            };
            let Some(left) = w.budget.checked_sub(1) else {
                return Err(bad("wide nodes that do not form a tree", None));
            };
            w.budget = left;
            k.nodes_visited += 1;
            let (mask, near) = r.boxes.node_hits_with(isa, n.view(), r.tmin, w.t_best);
            // The top tree's children culled: its nodes, and links whose blocks the ray never
            // asks for.
            let inner_bits = inner_bits(n);
            let missed = ((1u32 << n.child_count.min(8)) - 1) & !mask;
            k.top_nodes_culled += (missed & inner_bits).count_ones() as u64;
            k.links_culled += (missed & !inner_bits).count_ones() as u64;
            // The top tree's leaves are links, pushed with its inner children, nearest first
            // for any hit too: the blocks it asks for are then those a closest hit asks for,
            // or fewer (it stops at the first block that holds a hit), which is what keeps
            // shadow rays from paging in blocks behind their first occluder.
            if mask != 0 {
                w.sp = push_children(w.st, w.sp, mask, &near, n, self.wide_top, true)
                    .map_err(|what| bad(what, None))?;
            }
        }
        Ok(None)
    }

    /// Walks block `h` from its root `root` (entered at `t`) on the stack above `w.sp` until
    /// the stack is back there; true if `ANY` found a hit. Its nodes are visited at most as
    /// many times as it has nodes (a tree visits each once).
    #[inline(always)]
    fn walk_block<const ANY: bool, const ALL: bool, S: Simd8>(
        &self,
        isa: S,
        r: &WideRay,
        w: &mut WideWalk,
        k: &mut Counters,
        h: &WideHeld<'_>,
        root: Entry,
    ) -> Result<bool, TraceError> {
        let floor = w.sp;
        let mut sp = floor;
        // In the place of the link just popped.
        w.st[sp] = root;
        sp += 1;
        let mut budget = h.nodes.len();
        let mut cull = grown_exit(w.t_best);
        while sp > floor {
            sp -= 1;
            let (at, t) = w.st[sp];
            if t > cull {
                continue;
            }
            let Some(n) = h.nodes.get(at as usize) else {
                return Err(bad("wide node index out of range", Some(h.id)));
            };
            let Some(left) = budget.checked_sub(1) else {
                return Err(bad("wide nodes that do not form a tree", Some(h.id)));
            };
            budget = left;
            k.nodes_visited += 1;
            let (mask, near) = r.boxes.node_hits_with(isa, n.view(), r.tmin, w.t_best);
            let kids = mask & inner_bits(n);
            let leaves = mask ^ kids;
            if leaves != 0 {
                if self.test_leaves::<ANY, ALL, S>(isa, r, w, k, (n, &near), leaves, h)? {
                    w.sp = sp;
                    return Ok(true);
                }
                cull = grown_exit(w.t_best);
            }
            if kids != 0 {
                // Any hit takes a block's children as they come.
                sp = push_children(w.st, sp, kids, &near, n, h.nodes, !ANY)
                    .map_err(|what| bad(what, Some(h.id)))?;
            }
        }
        w.sp = floor;
        Ok(false)
    }

    /// Tests the groups of `n`'s leaf slots in `leaves`; true if `ANY` found a hit.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn test_leaves<const ANY: bool, const ALL: bool, S: Simd8>(
        &self,
        isa: S,
        r: &WideRay,
        w: &mut WideWalk,
        k: &mut Counters,
        (n, near): (&ClusterNode, &[f32; CLUSTER_WIDTH]),
        mut leaves: u32,
        h: &WideHeld<'_>,
    ) -> Result<bool, TraceError> {
        let inner = n.inner_count as u32;
        // Every group's lines first, so that their loads overlap.
        let mut ahead = leaves;
        while ahead != 0 {
            let i = ahead.trailing_zeros();
            ahead &= ahead - 1;
            if let Some(g) = h.groups.get(n.group_base as usize + (i - inner) as usize) {
                crate::os::prefetch::<_, 3>(g);
            }
        }
        while leaves != 0 {
            let i = leaves.trailing_zeros();
            leaves &= leaves - 1;
            let gi = n.group_base as u64 + (i - inner) as u64;
            // A held head's groups are read chunk by chunk; the chunk is held for the test.
            let chunk;
            let g = match h.groups.get(gi as usize) {
                Some(g) => g,
                None => match self.chunk_group(w, k, h, gi, near[i as usize])? {
                    Some(c) => {
                        chunk = c;
                        let out = || bad("triangle group index out of range", Some(h.id));
                        chunk.0.groups().get(chunk.1).ok_or_else(out)?
                    }
                    None => continue,
                },
            };
            #[cfg(feature = "group-trace")]
            super::group_trace::record(h.id, gi as u32);
            let shear = r.shear.get_or_init(|| RayShear::new(r.ray));
            if ALL && let Some(out) = w.all.as_deref_mut() {
                collect_group(isa, (shear, r.tmin, w.t_best), g, out, k);
                continue;
            }
            if test_group::<ANY, S>(isa, (shear, r.tmin), &mut w.best, &mut w.t_best, g, k) {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// The chunk holding group `gi` of `h`, a block of which only the head is held (spec
    /// §8.3), and the group's index in it: read if it is not resident, or, for a walk that
    /// defers, `None` and the group (entered at `t`) left in its list.
    #[inline(never)]
    fn chunk_group<'v>(
        &self,
        w: &mut WideWalk,
        k: &mut Counters,
        h: &WideHeld<'v>,
        gi: u64,
        t: f32,
    ) -> Result<Option<(ChunkGuard<'v>, usize)>, TraceError>
    where
        'a: 'v,
    {
        let out = || bad("triangle group index out of range", Some(h.id));
        let ch = self.chunked(h.id, h.raw).ok_or_else(out)?;
        let Some(defer) = &mut w.defer else {
            return Ok(Some(ch.group(h.id, gi, &mut k.page)?));
        };
        let group = u32::try_from(gi).map_err(|_| out())?;
        match self.peek_group(h.id, group, &mut k.page) {
            Some(found) => Ok(Some(found)),
            None => {
                k.groups_deferred += 1;
                defer.push(Deferred {
                    block: h.id,
                    group,
                    t,
                });
                Ok(None)
            }
        }
    }
}

/// The slots of `n` that are wide nodes (the first `inner_count`).
#[inline(always)]
fn inner_bits(n: &ClusterNode) -> u32 {
    0xff >> (8 - (n.inner_count as u32).min(8))
}

/// Pushes the children of `n` in `mask` (entered at `near`) on `st` above `sp` and returns the
/// new depth: inner slots as wide nodes `node_base + i` of `nodes` (whose records it
/// prefetches, so that their loads overlap), the others (the top tree's links) as links
/// `group_base + i - inner`; so that the nearest is popped first where `sorted`, else as they
/// come.
#[inline(always)]
fn push_children(
    st: &mut [Entry; STACK],
    mut sp: usize,
    mut mask: u32,
    near: &[f32; CLUSTER_WIDTH],
    n: &ClusterNode,
    nodes: &[ClusterNode],
    sorted: bool,
) -> Result<usize, &'static str> {
    let inner = n.inner_count as u32;
    let refer = |i: u32| {
        if i < inner {
            let c = n.node_base.wrapping_add(i);
            if let Some(rec) = nodes.get(c as usize) {
                crate::os::prefetch::<_, 2>(rec);
            }
            c & !LINK
        } else {
            n.group_base.wrapping_add(i - inner) | LINK
        }
    };
    if sp + CLUSTER_WIDTH > STACK {
        return Err("wide nodes deeper than the format allows");
    }
    if !sorted || mask & (mask - 1) == 0 {
        while mask != 0 {
            let i = mask.trailing_zeros();
            mask &= mask - 1;
            st[sp] = (refer(i), near[i as usize]);
            sp += 1;
        }
        return Ok(sp);
    }
    let mut kids: [(f32, u32); CLUSTER_WIDTH] = [(0.0, 0); CLUSTER_WIDTH];
    let mut nk = 0;
    while mask != 0 {
        let i = mask.trailing_zeros();
        mask &= mask - 1;
        kids[nk] = (near[i as usize], refer(i));
        nk += 1;
    }
    if nk == 2 {
        if kids[0].0 < kids[1].0 {
            kids.swap(0, 1);
        }
    } else {
        // Insertion sort, farthest first.
        for a in 1..nk {
            let mut b = a;
            while b > 0 && kids[b - 1].0 < kids[b].0 {
                kids.swap(b - 1, b);
                b -= 1;
            }
        }
    }
    for &(t, c) in &kids[..nk] {
        st[sp] = (c, t);
        sp += 1;
    }
    Ok(sp)
}

/// Bytes that break the format at a wide node of block `block` (or of the top tree).
pub(super) fn bad(what: &'static str, block: Option<u32>) -> TraceError {
    TraceError::Corrupt(Corruption {
        what,
        block,
        level: 0,
        index: 0,
    })
}

/// A ray's hits each triangle once (found once per leaf that references it, at the same `t`:
/// the same test on the same corners), then in order along the ray.
#[inline(always)]
fn once_in_order(out: &mut Vec<HitInfo>) {
    if out.len() > 1 {
        out.sort_unstable_by(|a, b| a.prim.cmp(&b.prim).then(a.t.total_cmp(&b.t)));
        out.dedup_by_key(|h| h.prim);
        out.sort_unstable_by(|a, b| a.t.total_cmp(&b.t).then(a.prim.cmp(&b.prim)));
    }
}
