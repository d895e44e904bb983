//! What the comparison structures share below their traversals: their triangles ([`Soup`]), the
//! test of a leaf's triangles against a ray ([`Query`]), and the plumbing from a traversal to
//! [`Accelerator`] ([`Walk`]).
//!
//! A structure's traversal ([`Walk::walk`]) knows nothing about triangles: it finds the leaves a
//! ray crosses, front to back, and hands each leaf's triangles ([`Ids`]) to a closure, which
//! answers with how far the walk still has to look (a *bound*: the `t` of the closest hit so far,
//! [`NO_HIT`] while there is none, [`STOP`] to end the walk). The closure is the same for every
//! structure: [`Query::closest`] for a closest hit, [`Query::any`] for an any hit, both with the
//! shared watertight kernel ([`RayShear`], Woop, Benthin and Wald 2013), four triangles at a time
//! ([`RayShear::intersect4`], bit for bit the scalar [`RayShear::intersect`], which a lone
//! triangle uses):
//!
//! - closest hit: triangles are tested over `[tmin, t of the closest hit so far]` and a hit is
//!   kept by [`closer`] (the smaller `t`, ties to the lower primitive id, the convention of
//!   [`oavm::geom::reference`]); which triangles a tie is decided among depends on where the
//!   traversal stops, so ties are only resolved alike among the triangles a structure tests;
//! - any hit: over the ray's whole `[tmin, tmax]`, stopping after the first test that hits;
//! - `triangles_tested` counts every triangle tested: a four-lane test of three triangles counts
//!   three, and an any-hit query stops counting with the test that found its hit.
//!
//! A traversal that cannot answer (a structure too large for its index widths builds no tree;
//! a stack that would overflow) returns `false`, and the ray is answered by testing every
//! triangle: slow, still correct.

use std::ops::Range;

use super::{Accelerator, StructureStats, Triangles};
use crate::Counters;
use oavm::geom::triangle::RayShear;
use oavm::geom::{Hit, Ray};

/// A triangle: three vertices.
pub(crate) type Tri = [[f32; 3]; 3];

/// The bound of a walk with no hit yet: every leaf the ray crosses is still visited.
pub(crate) const NO_HIT: f32 = f32::INFINITY;
/// The bound that ends a walk (an any-hit query found its hit).
pub(crate) const STOP: f32 = f32::NEG_INFINITY;

/// Never hit (no area); stands in for an index that cannot occur.
const DEGENERATE: Tri = [[0.0; 3]; 3];

/// A structure's own copy of its triangles and their primitive ids, index for index.
#[derive(Clone, Debug, Default)]
pub(crate) struct Soup {
    pub(crate) v: Vec<Tri>,
    pub(crate) prim: Vec<u32>,
}

impl Soup {
    /// The triangles of `tris` with finite coordinates (the others cannot be hit: the kernel
    /// answers NaN for them) and their primitive ids.
    pub(crate) fn finite(tris: &Triangles) -> Soup {
        let keep = |t: &Tri| t.iter().flatten().all(|c| c.is_finite());
        if tris.v.iter().all(keep) && tris.prim.len() == tris.v.len() {
            return Soup {
                v: tris.v.clone(),
                prim: tris.prim.clone(),
            };
        }
        let (v, prim) = tris
            .v
            .iter()
            .zip(&tris.prim)
            .filter(|(t, _)| keep(t))
            .map(|(t, &p)| (*t, p))
            .unzip();
        Soup { v, prim }
    }

    /// The triangles in the order `order` (indices into `self`).
    pub(crate) fn permuted(&self, order: &[usize]) -> Soup {
        Soup {
            v: order.iter().map(|&i| self.v[i]).collect(),
            prim: order.iter().map(|&i| self.prim[i]).collect(),
        }
    }

    pub(crate) fn len(&self) -> usize {
        self.v.len()
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.v.is_empty()
    }

    /// Bytes in memory: 36 per triangle, 4 per primitive id.
    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of::<Tri>() * self.v.len() + 4 * self.prim.len()
    }

    #[inline(always)]
    fn tri(&self, i: usize) -> &Tri {
        self.v.get(i).unwrap_or(&DEGENERATE)
    }

    #[inline(always)]
    fn prim(&self, i: usize) -> u32 {
        self.prim.get(i).copied().unwrap_or(u32::MAX)
    }
}

/// A leaf's triangles, as indices into a [`Soup`]: a list (`[u32]`: grid cells, KD-tree and
/// octree leaves) or a run (`Range<usize>`: BVH leaves, whose triangles are stored in leaf
/// order).
pub(crate) trait Ids {
    fn count(&self) -> usize;
    /// The `k`-th index, for `k < count()`.
    fn id(&self, k: usize) -> usize;
}

impl Ids for [u32] {
    #[inline(always)]
    fn count(&self) -> usize {
        self.len()
    }
    #[inline(always)]
    fn id(&self, k: usize) -> usize {
        self[k] as usize
    }
}

impl Ids for Range<usize> {
    #[inline(always)]
    fn count(&self) -> usize {
        self.len()
    }
    #[inline(always)]
    fn id(&self, k: usize) -> usize {
        self.start + k
    }
}

/// Replaces `best` by the hit (`t`, `prim`) if it is closer, or as close with a lower primitive
/// id (the convention of `geom::reference`, which keeps the lowest id among equal `t`). Returns
/// whether it did.
#[inline]
pub(crate) fn closer(best: &mut Hit, t: f32, prim: u32) -> bool {
    if !best.is_hit() || t < best.t || (t == best.t && prim < best.prim) {
        *best = Hit { t, prim };
        true
    } else {
        false
    }
}

/// One ray's query over a soup: the ray's constants for the kernel and the closest hit so far.
pub(crate) struct Query<'a> {
    soup: &'a Soup,
    shear: RayShear,
    tmin: f32,
    tmax: f32,
    best: Hit,
}

impl<'a> Query<'a> {
    /// `None` when nothing can be hit: an invalid ray ([`Ray::is_valid`]) or no triangles.
    pub(crate) fn new(soup: &'a Soup, ray: &Ray) -> Option<Query<'a>> {
        (ray.is_valid() && !soup.is_empty()).then(|| Query {
            soup,
            shear: RayShear::new(ray),
            tmin: ray.tmin,
            tmax: ray.tmax,
            best: Hit::MISS,
        })
    }

    /// The closest hit found so far.
    pub(crate) fn best(&self) -> Hit {
        self.best
    }

    /// The far end of the range still searched: the closest hit so far, else `tmax`.
    #[inline(always)]
    fn limit(&self) -> f32 {
        if self.best.is_hit() {
            self.best.t
        } else {
            self.tmax
        }
    }

    /// Tests the triangles `ids` for a hit closer than the best so far; returns the walk's bound
    /// (the best hit's `t`, or [`NO_HIT`]).
    #[inline]
    pub(crate) fn closest<L: Ids + ?Sized>(&mut self, ids: &L, c: &mut Counters) -> f32 {
        let n = ids.count();
        let mut k = 0;
        while k < n {
            let m = (n - k).min(4);
            c.triangles_tested += m as u64;
            if m == 1 {
                let i = ids.id(k);
                if let Some(t) = self
                    .shear
                    .intersect(self.soup.tri(i), self.tmin, self.limit())
                {
                    closer(&mut self.best, t, self.soup.prim(i));
                }
            } else {
                let (mask, t) = self.test4(ids, k, m, self.limit());
                for (l, &tl) in t.iter().enumerate().take(m) {
                    if mask >> l & 1 == 1 {
                        closer(&mut self.best, tl, self.soup.prim(ids.id(k + l)));
                    }
                }
            }
            k += m;
        }
        if self.best.is_hit() {
            self.best.t
        } else {
            NO_HIT
        }
    }

    /// Whether any of the triangles `ids` is hit over the ray's whole range; stops at the first
    /// test that finds one.
    #[inline]
    pub(crate) fn any<L: Ids + ?Sized>(&self, ids: &L, c: &mut Counters) -> bool {
        let n = ids.count();
        let mut k = 0;
        while k < n {
            let m = (n - k).min(4);
            c.triangles_tested += m as u64;
            let hit = if m == 1 {
                let tri = self.soup.tri(ids.id(k));
                self.shear.intersect(tri, self.tmin, self.tmax).is_some()
            } else {
                self.test4(ids, k, m, self.tmax).0 != 0
            };
            if hit {
                return true;
            }
            k += m;
        }
        false
    }

    /// The four-lane test of `ids[k..k + m]` (`2 <= m <= 4`; short groups repeat their last
    /// triangle, whose lanes answer the same) over `[tmin, tmax]`.
    #[inline(always)]
    fn test4<L: Ids + ?Sized>(&self, ids: &L, k: usize, m: usize, tmax: f32) -> (u32, [f32; 4]) {
        let lane = |l: usize| self.soup.tri(ids.id(k + l.min(m - 1)));
        self.shear
            .intersect4([lane(0), lane(1), lane(2), lane(3)], self.tmin, tmax)
    }
}

/// A comparison structure's traversal; [`Accelerator`] follows from it (closest hit, any hit,
/// the invalid-ray and no-tree cases) for every implementor.
pub(crate) trait Walk: Send + Sync {
    /// How a leaf names its triangles.
    type Leaf: Ids + ?Sized;

    /// The triangles the leaves index.
    fn soup(&self) -> &Soup;

    fn structure_stats(&self) -> &StructureStats;

    /// Visits the leaves `ray` crosses, front to back, calling `leaf` with the triangles of each
    /// non-empty one; `leaf` returns the bound (module docs): no leaf entirely beyond it needs
    /// visiting, and [`STOP`] ends the walk. Returns `false` if the walk cannot answer (no tree,
    /// or a stack that would overflow). Only called with valid rays.
    fn walk(
        &self,
        ray: &Ray,
        c: &mut Counters,
        leaf: impl FnMut(&Self::Leaf, &mut Counters) -> f32,
    ) -> bool;
}

impl<T: Walk> Accelerator for T {
    fn stats(&self) -> &StructureStats {
        self.structure_stats()
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        let Some(mut q) = Query::new(self.soup(), ray) else {
            return Hit::MISS;
        };
        if self.walk(ray, c, |ids, c| q.closest(ids, c)) {
            return q.best();
        }
        q.best = Hit::MISS;
        q.closest(&(0..self.soup().len()), c);
        q.best()
    }

    fn occluded(&self, ray: &Ray, c: &mut Counters) -> bool {
        let Some(q) = Query::new(self.soup(), ray) else {
            return false;
        };
        let mut found = false;
        let complete = self.walk(ray, c, |ids, c| {
            found = q.any(ids, c);
            if found { STOP } else { NO_HIT }
        });
        if complete {
            found
        } else {
            q.any(&(0..self.soup().len()), c)
        }
    }
}
