//! The OAVM paper's walk (§2.4–2.5), from leaf to neighbouring leaf: the walk of files of leaf
//! lists, and on request ([`super::Walk::Neighbours`], [`super::Walk::Ropes`]) of files of
//! clusters.
//!
//! A ray is mapped into the lattice ([`super::ray`]) and enters the root; from then on it is
//! always *in* one lattice cell `q`:
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
//!    (see [`crate::mapping::morton`]). With ropes the next leaf is found from the node the
//!    exit face's rope names instead ([`super::ropes`]).
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

use std::hint::select_unpredictable;

use super::cluster::{ClusterFail, trace_cluster};
use super::ray::{Best, RayCtx, box_may_hit};
use super::{Counters, Held, HitInfo, Tree, baseline};
use crate::geom::Ray;
use crate::mapping::Corruption;
use crate::mapping::morton::{self, LATTICE_SIZE};
use crate::os::Simd8;
use crate::physical::format::{
    CELL_MARGIN, KIND_EMPTY, KIND_LINK, KIND_SOLID, LeafBounds, NodeRecord, TriRecord, leaf_refs,
};

/// Where a walk is: its cell, the ancestors of its leaf, the block it is in, its best hit.
pub(super) struct WalkState {
    pub(super) q: [u32; 3],
    /// Level of the lowest common ancestor of `q` and the previous leaf.
    pub(super) level: u32,
    /// Ancestors of the current leaf in the top tree, by absolute level (up to the link).
    pub(super) tpath: [u64; 32],
    /// Ancestors of the current leaf inside its block, by absolute level (from the root).
    pub(super) bpath: [u64; 32],
    /// The block of the current leaf and its roots' level, if it is in a block.
    pub(super) cur: Option<(u32, u32)>,
    pub(super) s: Best,
}

/// What a walk through the blocks it holds ends with.
enum Step {
    Done(Option<HitInfo>),
    /// It must move into this block.
    Need(u32),
}

/// The leaf a walk stands in (step 1).
pub(super) struct Leaf {
    pub(super) level: u32,
    rec: NodeRecord,
    /// A link whose bounds the ray misses: its cell is crossed as if it were empty.
    culled: bool,
    /// The block it is in, if any.
    pub(super) block: Option<u32>,
}

impl Leaf {
    /// Bytes that break the format, at `index` of this leaf's level.
    fn bad(&self, what: &'static str, index: u64) -> Corruption {
        Corruption {
            what,
            block: self.block,
            level: self.level,
            index,
        }
    }

    /// The index of this leaf on its level, in the block or the top tree.
    fn index(&self, w: &WalkState) -> u64 {
        let path = if self.block.is_some() {
            &w.bpath
        } else {
            &w.tpath
        };
        path[(self.level & 31) as usize]
    }
}

/// What locating gives (step 1): the leaf, or the block the walk must move into first.
enum Located {
    Leaf(Leaf),
    Need(u32),
}

/// What crossing a leaf gives: the box the ray leaves, or a final answer.
enum Crossed {
    Box([u32; 3], [u32; 3]),
    Done(Option<HitInfo>),
}

impl Tree<'_> {
    /// Closest hit (any hit with `ANY`) of `ray` by the leaf-to-leaf walk.
    #[inline(always)]
    pub(super) fn walk<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, super::TraceError> {
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
            let held = self.held(&fetched);
            match self.walk_in::<ANY, S>(isa, &ctx, &mut w, held.as_ref(), &mut k) {
                Ok(Step::Done(best)) => break Ok(best),
                Ok(Step::Need(b)) => need = Some(b),
                Err(e) => break Err(e.into()),
            }
        };
        *c += k;
        result
    }

    /// The first block `ray` needs (the block of the first link on its way whose bounds it
    /// meets), found in the top tree alone, without reading any block; `None` if it needs none
    /// (it misses the root cube, or passes every link by). [`crate::logical::Order::Blocks`]
    /// sorts rays by it.
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
            s: Best::new(ray, &ctx),
        };
        Some((ctx, w))
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
            // 1. Locate the leaf containing q.
            let leaf = match self.locate(r, w, held, k)? {
                Located::Leaf(leaf) => leaf,
                Located::Need(b) => return Ok(Step::Need(b)),
            };
            k.leaves_visited += 1;
            // 2. Cross it: the box the ray leaves, and the triangles on the way.
            let (lo, hi) = match self.cross::<ANY, S>(isa, r, w, held, &leaf, k)? {
                Crossed::Box(lo, hi) => (lo, hi),
                Crossed::Done(best) => return Ok(Step::Done(best)),
            };
            // 3. Exit of the box; stop where nothing closer remains.
            let Some((axis, t_exit)) = exit(r, &w.s, lo, hi) else {
                return Ok(Step::Done(w.s.best));
            };
            // 4. Step into the neighbour across the exit face.
            let old = w.q;
            let next = neighbour(r, old, lo, hi, axis, t_exit);
            // Leaving the root: `hi` at the lattice's end, or `lo - 1` wrapping below 0.
            if next[axis] >= LATTICE_SIZE {
                return Ok(Step::Done(w.s.best));
            }
            w.q = next;
            if self.follow_ropes {
                self.rope_step(r, w, held, &leaf, axis, k);
            } else {
                w.level = leaf.level.min(morton::common_level(old, next));
            }
        }
    }

    /// Step 1: the leaf containing `w.q`, from the common ancestor down: in the block the walk
    /// is in while the ancestor is inside it, else from the top tree, following a link into a
    /// block (or the block other than `held` the walk must move into first).
    #[inline(always)]
    fn locate(
        &self,
        r: &RayCtx,
        w: &mut WalkState,
        held: Option<&Held<'_>>,
        k: &mut Counters,
    ) -> Result<Located, Corruption> {
        let in_block = match (w.cur, held) {
            (Some((b, rl)), Some(h)) => b == h.id && w.level >= rl,
            _ => false,
        };
        let mut culled = false;
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
                    _ => return Ok(Located::Need(b)),
                }
            } else {
                w.cur = None;
                (level, rec)
            }
        };
        Ok(Located::Leaf(Leaf {
            level,
            rec,
            culled,
            block: w.cur.map(|(b, _)| b),
        }))
    }

    /// Step 2: crosses `leaf`: an empty leaf's merged volume (spec §4.2) is the box jumped
    /// past; a solid leaf's triangles on the way are tested (unless the ray misses its tight
    /// bounds) and its cell is the box.
    #[inline(always)]
    fn cross<const ANY: bool, S: Simd8>(
        &self,
        isa: S,
        r: &RayCtx,
        w: &mut WalkState,
        held: Option<&Held<'_>>,
        leaf: &Leaf,
        k: &mut Counters,
    ) -> Result<Crossed, Corruption> {
        let size = morton::cell_size(leaf.level);
        let cell_lo = w.q.map(|x| x & !(size - 1));
        let cell = Crossed::Box(cell_lo, cell_lo.map(|x| x + size));
        let rec = leaf.rec;
        match rec.kind_bits() {
            _ if leaf.culled => Ok(cell),
            KIND_EMPTY => {
                // Empty: its merged volume, rebuilt from the shape in the record, jumped past
                // whole.
                k.volumes_crossed += 1;
                let shape = rec.shape_bits();
                if shape.level as u32 > leaf.level {
                    return Err(leaf.bad("merged volume smaller than its leaf", leaf.index(w)));
                }
                let (lo, hi) = shape.box_around(w.q);
                Ok(Crossed::Box(lo, hi))
            }
            KIND_SOLID if leaf.block.is_some() => {
                let (inline_count, b) = rec.solid_bits();
                // The leaf's tight bounds, widened by the cell margin: a ray that misses them
                // over [tmin, best] cannot hit any of the leaf's triangles inside the cell, so
                // their references and records are not even loaded.
                let (blo, bhi) = LeafBounds::unpack(b).lattice_box(cell_lo, size, CELL_MARGIN);
                if !box_may_hit(r, w.s.t_best, blo, bhi) {
                    k.leaves_culled += 1;
                    return Ok(cell);
                }
                let bad = |what| leaf.bad(what, rec.payload as u64);
                // Never met: a leaf in a block is located only while the block is held.
                let h = held.ok_or_else(|| bad("leaf outside a block"))?;
                let found = if self.clusters {
                    k.clusters_entered += 1;
                    let stack = &mut Vec::new();
                    let found =
                        trace_cluster::<ANY, S>(isa, r, &mut w.s, (h, None), rec.payload, k, stack)
                            .map_err(|f| match f {
                                ClusterFail::Bad(what) => bad(what),
                                // (This walk is not given chunks: the scene holds whole blocks
                                // for it.)
                                ClusterFail::Page(_) => bad("a chunk of groups could not be read"),
                            })?;
                    if found { w.s.best } else { None }
                } else {
                    let (refs, _) = leaf_refs(h.refs, rec.payload, inline_count)
                        .ok_or_else(|| bad("triangle references out of range"))?;
                    test_list::<ANY>(r, &mut w.s, h.tris, refs, k)
                        .ok_or_else(|| bad("triangle index out of range"))?
                };
                if ANY && found.is_some() {
                    return Ok(Crossed::Done(found));
                }
                w.s.t_stop = r.t1.min(w.s.t_best as f64);
                Ok(cell)
            }
            _ => {
                let what = if leaf.block.is_some() {
                    "invalid leaf record"
                } else {
                    "invalid leaf record in the top tree"
                };
                Err(leaf.bad(what, leaf.index(w)))
            }
        }
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

/// A leaf list's triangles (spec §6), four at a time, keeping the first closest hit in the
/// order of the leaf's references (the answers of format 3, which the paper's structure keeps;
/// a cluster takes the smallest id instead). `Some(Some(hit))` for `ANY`'s first hit,
/// `Some(None)` when the walk goes on, `None` for a reference past the block's triangles.
#[inline(always)]
fn test_list<const ANY: bool>(
    r: &RayCtx,
    s: &mut Best,
    tris: &[TriRecord],
    refs: &[u32],
    k: &mut Counters,
) -> Option<Option<HitInfo>> {
    k.triangles_tested += refs.len() as u64;
    // A short last group repeats its first triangle (a repeated hit changes nothing: ties keep
    // the first).
    for group in refs.chunks(4) {
        let tri = |i: usize| tris.get(group[i.min(group.len() - 1)] as usize);
        let (r0, r1, r2, r3) = (tri(0)?, tri(1)?, tri(2)?, tri(3)?);
        let (mut mask, ts) = r
            .shear
            .intersect4([&r0.v, &r1.v, &r2.v, &r3.v], r.tmin, s.t_best);
        while mask != 0 {
            let l = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let (t, rec) = (ts[l], [r0, r1, r2, r3][l]);
            let hit = HitInfo {
                t,
                prim: rec.prim,
                v: rec.v,
            };
            if ANY {
                return Some(Some(hit));
            }
            if s.best.is_none() || t < s.t_best {
                s.t_best = t;
                s.best = Some(hit);
            }
        }
    }
    Some(None)
}

/// Step 3: the exit of the box `[lo, hi)` (slab test on its far faces): its axis and `t`, or
/// `None` where nothing closer remains (at or past `t_stop`).
#[inline(always)]
fn exit(r: &RayCtx, s: &Best, lo: [u32; 3], hi: [u32; 3]) -> Option<(usize, f64)> {
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
    if !(t_exit < s.t_stop) {
        return None;
    }
    Some((axis, t_exit))
}

/// Step 4: the cell across the exit face of the box `[lo, hi)` left from cell `old`: along the
/// exit axis `hi` or `lo - 1`; along the others the exit point's cell, forward only and inside
/// the box being left (so the walk never turns back; see the module documentation).
#[inline(always)]
fn neighbour(
    r: &RayCtx,
    old: [u32; 3],
    lo: [u32; 3],
    hi: [u32; 3],
    axis: usize,
    t_exit: f64,
) -> [u32; 3] {
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
    next
}

/// `floor(p)` clamped to `[lo, hi]`, without branches (`max` and `min` give the other operand
/// for NaN, so NaN gives `lo`; truncation is floor for the non-negative clamped value).
#[inline(always)]
fn clamp_floor(p: f64, lo: u32, hi: u32) -> u32 {
    p.max(lo as f64).min(hi as f64) as u32
}
