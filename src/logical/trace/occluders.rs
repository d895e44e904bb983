//! What shadow rays (any hit) add to the top-down walk, from the multi-index tree of Liang and
//! Huang (2019): the occluders an internal node of a block holds (spec §8.5), tested before its
//! children ([`Tree::occluders`]), and the SATO order of a node's children (Nah and Manocha
//! 2014: larger surface area first, [`Tree::sato`]). Neither changes an answer.

use super::ray::{Best, RayCtx};
use super::topdown::{Children, Entry, TOP};
use super::{Counters, Held, HitInfo, Tree};
use crate::physical::format::{KIND_SOLID, LeafBounds};

impl Tree<'_> {
    /// Tests the occluders of the internal node of `e` in the block `h`; true (the hit in `w`)
    /// at the first one hit.
    #[inline(always)]
    pub(super) fn occluder_hit(
        &self,
        r: &RayCtx,
        w: &mut Best,
        k: &mut Counters,
        h: &Held<'_>,
        e: &Entry,
    ) -> bool {
        for tri in h.occluders_of(h.map.node_start(e.level as u32) + e.index as u64) {
            k.promoted_tested += 1;
            k.triangles_tested += 1;
            if let Some(t) = r.shear.intersect(&tri.v, r.tmin, w.t_best) {
                w.best = Some(HitInfo {
                    t,
                    prim: tri.prim,
                    v: tri.v,
                });
                return true;
            }
        }
        false
    }

    /// The surface area (lattice units) of the box the walk culls child `o` of the node of `e`
    /// by, for the SATO order: a top-tree node's or link's box, a solid leaf's tight bounds, an
    /// internal node of a block its whole cell.
    #[inline(always)]
    pub(super) fn sato_area(&self, e: &Entry, kids: &Children<'_>, o: usize) -> f64 {
        let area = |d: [f64; 3]| 2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0]);
        let half = kids.half;
        if e.block == TOP {
            let at = self.top.node_start(kids.level + 1) + kids.first + o as u64;
            return match usize::try_from(at).ok().and_then(|i| self.top_boxes.get(i)) {
                Some((lo, hi)) => area(std::array::from_fn(|a| (hi[a] - lo[a]).max(0.0))),
                None => area([half as f64; 3]),
            };
        }
        let rec = kids.recs[o];
        if (kids.internal >> o) & 1 == 0 && rec.kind_bits() == KIND_SOLID {
            let (_, b) = rec.solid_bits();
            return area(LeafBounds::unpack(b).extent(half));
        }
        area([half as f64; 3])
    }
}
