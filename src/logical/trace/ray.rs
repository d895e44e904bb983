//! The ray as every walk sees it: mapped once into the lattice (`2^21` cells per axis over the
//! root cube, in f64, where cell faces are integers) with what the walks derive from it
//! ([`RayCtx`]), the closest hit so far ([`Best`]), and the slab tests the walks share.

use super::{HitInfo, Tree};
use crate::geom::triangle::RayShear;
use crate::geom::{BoxRay, Ray};
use crate::mapping::morton::LATTICE_SIZE;
use crate::physical::format::{CELL_MARGIN, LeafBounds};

/// The ray in lattice space, and what the walk derives from it once.
pub(in crate::logical) struct RayCtx {
    pub(super) o: [f64; 3],
    pub(super) d: [f64; 3],
    pub(super) inv: [f64; 3],
    pub(super) oi: [f64; 3],
    pub(super) moves: [bool; 3],
    pub(super) fwd: [bool; 3],
    pub(super) shear: RayShear,
    /// The ray in world units, for cluster boxes.
    pub(super) boxes: BoxRay,
    pub(super) tmin: f32,
    /// Per axis, the planes by which the ray enters the low and the high half of a cell and
    /// leaves them, in that order, as offsets from the cell's low face: `half * cell_h +
    /// cell_m` (the halves widened by the cell margin).
    pub(super) cell_h: [[f64; 4]; 3],
    pub(super) cell_m: [[f64; 4]; 3],
    /// Where the ray enters and leaves the root cube.
    pub(super) t0: f64,
    pub(super) t1: f64,
}

/// A walk's closest hit so far, and where it stops looking.
#[derive(Clone, Copy)]
pub(in crate::logical) struct Best {
    pub(in crate::logical) best: Option<HitInfo>,
    pub(in crate::logical) t_best: f32,
    /// `min(t1, t_best)`: no cell entered at or past it can hold a closer hit.
    pub(in crate::logical) t_stop: f64,
}

impl Best {
    /// No hit yet: looking up to `tmax`, stopping where the ray leaves the root (`r.t1`).
    #[inline(always)]
    pub(super) fn new(ray: &Ray, r: &RayCtx) -> Best {
        Best {
            best: None,
            t_best: ray.tmax,
            t_stop: r.t1,
        }
    }
}

impl Tree<'_> {
    /// The ray in lattice space, clipped to the root cube; `None` for a ray that cannot hit
    /// anything (invalid, or missing the root cube).
    #[inline(always)]
    pub(super) fn ray_ctx(&self, ray: &Ray) -> Option<RayCtx> {
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
}

/// Whether the ray may hit the solid leaf with cell `lo` (edge `size`) and tight bounds `b`
/// (the bits of spec §4.2, widened by the margin) over `[tmin, t_best]`: a ray that misses them
/// cannot hit any of the leaf's triangles inside the cell.
#[inline(always)]
pub(super) fn leaf_may_hit(r: &RayCtx, t_best: f32, lo: [u32; 3], size: u32, b: u32) -> bool {
    let (blo, bhi) = LeafBounds::unpack(b).lattice_box(lo, size, CELL_MARGIN);
    box_may_hit(r, t_best, blo, bhi)
}

/// Slab test of the ray over `[tmin, t_best]` against the box `[blo, bhi]` (lattice units). An
/// axis the ray does not move along must hold the origin.
#[inline(always)]
pub(super) fn box_may_hit(r: &RayCtx, t_best: f32, blo: [f64; 3], bhi: [f64; 3]) -> bool {
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
