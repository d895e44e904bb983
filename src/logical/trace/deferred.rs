//! The wide walk with its groups' tests put off where their chunks are not resident (spec §8.3).
//!
//! Out of core, the pager holds the blocks' heads (their wide nodes) and the groups are read
//! chunk by chunk. Reading a chunk the moment a ray reaches it makes each ray wait on the disk
//! alone, at a queue depth of one a thread. Instead the walk tests the groups whose chunks are
//! resident and leaves the others in a list ([`Deferred`]: the block, the group, the distance
//! at which the ray enters the group's box); a caller collects the chunks that many rays wait
//! for, reads them together, and [`Tree::resolve`] tests each ray's groups nearest first,
//! skipping those the ray enters past the closest hit found so far.
//!
//! **The same answers.** Every group the walk itself would test is either tested (now, or once
//! its chunk is read) or entered past the closest hit found, where the walk would have culled
//! it with the same comparison ([`grown_exit`]); the walk's other culls only lose work to the
//! hits it has not found yet, never a group. And the closest hit does not depend on the order
//! the groups are tested in: ties go to the smallest primitive id ([`test_group`]).

use super::cluster::test_group;
use super::wide::{WIDE_STACK, bad};
use super::{Counters, HitInfo, TraceError, Tree, baseline};
use crate::geom::Ray;
use crate::geom::triangle::RayShear;
use crate::geom::wide_box::grown_exit;
use crate::logical::pager::chunks::ChunkGuard;
use crate::logical::pager::{PageCounters, PageError};
use crate::os::{Avx2, Simd8, WithAvx2};

/// A triangle group a ray's walk reached but did not test, its chunk not being resident: its
/// block, its index among the block's groups, and the distance at which the ray enters its box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(in crate::logical) struct Deferred {
    pub block: u32,
    pub group: u32,
    pub t: f32,
}

impl<'a> Tree<'a> {
    /// Group `group` of block `block` and its index in its chunk, if the chunk is resident now.
    #[inline]
    pub(super) fn peek_group(
        &self,
        block: u32,
        group: u32,
        c: &mut PageCounters,
    ) -> Option<(ChunkGuard<'a>, usize)> {
        let cache = self.chunks?.cache;
        let per = cache.chunk_groups();
        Some((cache.peek(block, group / per, c)?, (group % per) as usize))
    }

    /// Group `group` of block `block` and its index in its chunk, the chunk read if it is not
    /// resident (the block's head fetched for its chunk table).
    pub(in crate::logical) fn read_group(
        &self,
        block: u32,
        group: u32,
        c: &mut PageCounters,
    ) -> Result<(ChunkGuard<'a>, usize), TraceError> {
        let out = || {
            bad(
                "a group left for later in a tree without chunks",
                Some(block),
            )
        };
        let ctx = self.chunks.ok_or_else(out)?;
        let entry = ctx.directory.get(block as usize).ok_or_else(out)?;
        let (b, head, _) = self.fetch(block, c)?;
        let per = ctx.cache.chunk_groups();
        let chunk = ctx.cache.get(ctx.src, b, entry, &head, group / per, c)?;
        Ok((chunk, (group % per) as usize))
    }

    /// Reads the chunks `keys` (each `block << 32 | chunk`) that are not resident, together:
    /// each block's head fetched (and let go) for where its chunks are, then all of them read
    /// from this thread, at most `depth` in flight ([`ChunkCache::read_many`]: where the cache
    /// has room, the others left for their rays to read).
    pub(in crate::logical) fn read_chunks(
        &self,
        keys: &[u64],
        depth: usize,
        c: &mut PageCounters,
    ) -> Result<(), TraceError> {
        let out = |block| bad("a chunk read in a tree without chunks", Some(block));
        let mut plans = Vec::with_capacity(keys.len());
        for &k in keys {
            let (block, chunk) = ((k >> 32) as u32, k as u32);
            let ctx = self.chunks.ok_or_else(|| out(block))?;
            let entry = ctx
                .directory
                .get(block as usize)
                .ok_or_else(|| out(block))?;
            let (_, head, _) = self.fetch(block, c)?;
            let plan = ctx.cache.plan(block, entry, &head, chunk);
            plans.push(plan.map_err(|what| PageError { block, what })?);
        }
        if let Some(ctx) = self.chunks {
            ctx.cache.read_many(ctx.src, &plans, depth, c)?;
        }
        Ok(())
    }

    /// [`Self::answer_each`] by the wide walk, leaving the groups whose chunks are not resident
    /// in a list: `f` is given each ray's closest hit (any hit with `ANY`) among the groups
    /// tested, and the list (to take; its order is the walk's). A tree that does not walk wide
    /// leaves nothing for later.
    pub(in crate::logical) fn answer_each_deferring<'r, const ANY: bool>(
        &self,
        rays: impl Iterator<Item = &'r Ray>,
        c: &mut Counters,
        f: impl FnMut(usize, &'r Ray, Option<HitInfo>, &mut Vec<Deferred>),
    ) -> Result<(), TraceError> {
        self.answer_each_with::<ANY>(rays, c, true, f)
    }

    /// Each ray's wide walk on the thread's stack (taken once), its hit given to `f` with the
    /// groups left for later (none unless `defer`).
    #[inline(always)]
    pub(super) fn each_wide<'r, const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        rays: impl Iterator<Item = &'r Ray>,
        c: &mut Counters,
        defer: bool,
        mut f: impl FnMut(usize, &'r Ray, Option<HitInfo>, &mut Vec<Deferred>),
    ) -> Result<(), TraceError> {
        let mut stack = WIDE_STACK.take();
        let mut deferred = Vec::new();
        let mut kept = None;
        let mut result = Ok(());
        for (i, ray) in rays.enumerate() {
            deferred.clear();
            let walked = (&mut stack, defer.then_some(&mut deferred));
            match self.wide_ray::<ANY, S>(isa, ray, c, walked, &mut kept) {
                Ok(h) => f(i, ray, h, &mut deferred),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        WIDE_STACK.set(stack);
        result
    }

    /// Tests `ray`'s groups left for later, `pending` (sorted by the distance at which the ray
    /// enters them), into `best` (the closest hit among the groups tested so far; with `ANY`,
    /// any hit), in order while their chunks are resident (the first's read if it is not and
    /// `read_first`), and passes over those the ray enters past the closest hit (all of them
    /// once `ANY` has a hit). Returns how many are done: the rest wait for the first's chunk.
    pub(in crate::logical) fn resolve<const ANY: bool>(
        &self,
        ray: &Ray,
        best: &mut Option<HitInfo>,
        pending: &[Deferred],
        read_first: bool,
        c: &mut Counters,
    ) -> Result<usize, TraceError> {
        struct Job<'t, 'a, 'r, const ANY: bool> {
            tree: &'t Tree<'a>,
            ray: &'r Ray,
            best: &'r mut Option<HitInfo>,
            pending: &'r [Deferred],
            read_first: bool,
            c: &'r mut Counters,
        }
        impl<const ANY: bool> WithAvx2 for Job<'_, '_, '_, ANY> {
            type Output = Result<usize, TraceError>;
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                let (ray, best, read_first) = (self.ray, self.best, self.read_first);
                self.tree.resolve_with::<ANY, Avx2>(
                    isa,
                    ray,
                    best,
                    self.pending,
                    read_first,
                    self.c,
                )
            }
        }
        match self.avx2 {
            Some(isa) => isa.vectorize(Job::<ANY> {
                tree: self,
                ray,
                best,
                pending,
                read_first,
                c,
            }),
            None => self.resolve_with::<ANY, _>(baseline(), ray, best, pending, read_first, c),
        }
    }

    #[inline(always)]
    fn resolve_with<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        best: &mut Option<HitInfo>,
        pending: &[Deferred],
        read_first: bool,
        c: &mut Counters,
    ) -> Result<usize, TraceError> {
        let shear = RayShear::new(ray);
        let mut t_best = best.map_or(ray.tmax, |h| h.t);
        for (i, d) in pending.iter().enumerate() {
            if (ANY && best.is_some()) || d.t > grown_exit(t_best) {
                break;
            }
            let (chunk, at) = match self.peek_group(d.block, d.group, &mut c.page) {
                Some(found) => found,
                None if i == 0 && read_first => self.read_group(d.block, d.group, &mut c.page)?,
                None => return Ok(i),
            };
            let Some(g) = chunk.groups().get(at) else {
                return Err(bad("triangle group index out of range", Some(d.block)));
            };
            test_group::<ANY, S>(isa, (&shear, ray.tmin), best, &mut t_best, g, c);
        }
        Ok(pending.len())
    }
}
