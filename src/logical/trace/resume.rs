//! The top-down walk as [`crate::logical::stream`] runs it: started without a block, run until
//! it needs a block other than the one being served, parked there as `(ray, best hit, stack)`
//! and resumed when that block is served, with the same answer as a walk that waited
//! ([`Tree::run_held`]).

use super::ray::{Best, RayCtx};
use super::topdown::Entry;
use super::{Counters, Held, TraceError, Tree, baseline};
use crate::geom::Ray;
use crate::logical::pager::PageCounters;
use crate::os::{Avx2, WithAvx2};

impl Tree<'_> {
    /// Whether block `b` is resident now (a hint: it may be evicted the next moment).
    pub(in crate::logical) fn resident(&self, b: u32) -> bool {
        self.blocks.resident(b)
    }

    /// The blocks in the file's directory.
    pub(in crate::logical) fn block_count(&self) -> usize {
        self.directory.len()
    }

    /// Admits block `b` (reads, checks and decodes it through the pager, as a walk's first
    /// need of it would) and lets it go: the stream's readers.
    pub(in crate::logical) fn admit(&self, b: u32, c: &mut PageCounters) -> Result<(), TraceError> {
        self.fetch(b, c).map(|_| ())
    }

    /// Whether rays are walked top-down (what streamed batches and frames need; files of leaf
    /// lists are walked by neighbour steps, one ray at a time).
    pub(in crate::logical) fn walks_top_down(&self) -> bool {
        self.top_down
    }

    /// Starts `ray`'s top-down walk: counts the ray, and gives its context and best hit so far
    /// with its root pushed on `stack` (cleared first); `None` if the ray needs no node
    /// (invalid, missing the root cube or the mesh's box): its answer is no hit. Exactly what
    /// the direct walk does before its first step.
    pub(in crate::logical) fn begin(
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
        let w = Best::new(ray, &r);
        let Some(root) = self.root_entry(&r, w.t_best, k)? else {
            return Ok(None);
        };
        stack.push(root);
        Ok(Some((r, w)))
    }

    /// The context of a ray whose walk [`Self::begin`] started (the same, recomputed: a parked
    /// walk does not keep it).
    pub(in crate::logical) fn context(&self, ray: &Ray) -> Option<RayCtx> {
        self.ray_ctx(ray)
    }

    /// [`Self::run_held`] for the stream, compiled for the CPU's best instruction set: runs
    /// the walk of `stack` through the top tree and the block `view` until it is answered
    /// (`None`) or needs another block (`Some(block)`).
    #[allow(clippy::too_many_arguments)]
    pub(in crate::logical) fn resume<const ANY: bool>(
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
}
