//! Distance queries over a file ([`Scene::closest_points`], [`Scene::occupancy`]): the closest
//! point of the surface to each query point (a best-first descent of the wide nodes,
//! [`Tree::closest_point`]), and whether each point is inside, by a vote of rays.
//!
//! **The sign.** A point is inside when most of [`VOTE_DIRECTIONS`]'s three rays from it cross
//! the surface an odd number of times, each crossing counted exactly once
//! ([`Tree::all_hits`]: a ray through a shared edge or corner meets one triangle). On a closed
//! mesh every ray agrees, whatever edges it passes through; on a mesh with holes or cracks a ray
//! that leaves through a hole miscounts, and the vote outweighs one such ray. A vote over rays
//! rather than a generalised winding number (Barill et al. 2018): it needs nothing stored beyond
//! what the tracer reads (the fast winding number needs per-node expansions the format does not
//! hold yet), it pages like any ray, and the exact crossing counts make it exact on closed
//! meshes; the winding number is smoother on badly broken meshes, where three rays may not be.

use serde::Serialize;

use super::batch::{CHUNK, in_order};
use super::pager::BlockSource;
use super::trace::{Counters, HitInfo, TraceError, Tree};
use super::{Order, Scene};
use crate::error::Error;
use crate::geom::Ray;

/// The directions of the rays that vote on inside and outside: far from the axes and from each
/// other, so that no two run along the same faces of an axis-aligned mesh.
pub const VOTE_DIRECTIONS: [[f32; 3]; 3] = [
    [0.439_506_45, 0.617_598_6, 0.652_231_6],
    [-0.577_350_26, 0.612_372_4, -0.540_061_1],
    [0.280_056_02, -0.840_168_05, -0.464_095_14],
];

/// The closest point of the surface to a query point.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Serialize, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ClosestPoint {
    /// The point on the surface; NaN for none (no triangle within the distance asked, or a
    /// query point that is not finite).
    pub point: [f32; 3],
    /// Its distance from the query point; `inf` for none.
    pub distance: f32,
    /// The triangle's primitive id; `0xFFFFFFFF` for none.
    pub prim: u32,
    /// Barycentric coordinates of the point in the triangle, `(1 - u - v) v0 + u v1 + v v2`.
    pub u: f32,
    pub v: f32,
    /// The triangle's unit geometric normal `(v1 - v0) x (v2 - v0)` (NaN for none or a
    /// degenerate triangle).
    pub normal: [f32; 3],
}

impl ClosestPoint {
    pub const NONE: ClosestPoint = ClosestPoint {
        point: [f32::NAN; 3],
        distance: f32::INFINITY,
        prim: u32::MAX,
        u: f32::NAN,
        v: f32::NAN,
        normal: [f32::NAN; 3],
    };
}

impl<D: AsRef<[u8]> + BlockSource> Scene<D> {
    /// The closest point of the surface to each of `points` within `max_distance` of it, into
    /// `out` (same length), in parallel, the points in Morton order when the file is larger than
    /// the budget. Files of clusters; a file of leaf lists is refused.
    pub fn closest_points(
        &self,
        points: &[[f32; 3]],
        max_distance: f32,
        out: &mut [ClosestPoint],
    ) -> Result<Counters, Error> {
        let tree = self.tree();
        if !tree.has_clusters() {
            return Err(Error::Invalid(format!(
                "{}: closest points need a file of clusters (the default leaf); this one holds \
                 leaf lists: pack it again without --leaf list",
                self.path().display()
            )));
        }
        let md = max_distance as f64;
        let max_d2 = if md.is_nan() { f64::INFINITY } else { md * md };
        self.per_point(points, out, ClosestPoint::NONE, |p, c| {
            Ok(tree
                .closest_point(*p, max_d2, c)?
                .map_or(ClosestPoint::NONE, |n| {
                    let normal = unit_normal(&n.tri);
                    ClosestPoint {
                        point: n.point.map(|x| x as f32),
                        distance: n.d2.sqrt() as f32,
                        prim: n.prim,
                        u: n.u as f32,
                        v: n.v as f32,
                        normal,
                    }
                }))
        })
    }

    /// Whether each of `points` is inside the surface (1) or not (0), by the vote of three rays
    /// (see the module's docs), into `out`. Files of clusters.
    pub fn occupancy(&self, points: &[[f32; 3]], out: &mut [u8]) -> Result<Counters, Error> {
        let tree = self.tree();
        if !tree.has_clusters() {
            return Err(Error::Invalid(format!(
                "{}: occupancy needs a file of clusters (the default leaf): pack it again \
                 without --leaf list",
                self.path().display()
            )));
        }
        self.per_point(points, out, 0u8, |p, c| inside(&tree, *p, c).map(u8::from))
    }

    /// `answer` for each point of `points` into `out`, on the scene's threads, in Morton order
    /// when the file does not fit its budget.
    fn per_point<T: Send + Sync + Copy>(
        &self,
        points: &[[f32; 3]],
        out: &mut [T],
        fill: T,
        answer: impl Fn(&[f32; 3], &mut Counters) -> Result<T, TraceError> + Sync,
    ) -> Result<Counters, Error> {
        if points.len() != out.len() {
            let what = format!("{} points but room for {} answers", points.len(), out.len());
            return Err(Error::Invalid(what));
        }
        // The order of zero-length rays at the points is the points' Morton order.
        let order = match self.fits_in_budget() {
            true => None,
            false => {
                let rays: Vec<Ray> = points
                    .iter()
                    .map(|p| Ray::new(*p, [1.0, 0.0, 0.0], 0.0, 0.0))
                    .collect();
                self.permutation(&rays, Order::Morton)?
            }
        };
        let order = order.unwrap_or_else(|| (0..points.len() as u32).collect());
        let mut sorted = vec![fill; points.len()];
        let walked = in_order(
            &order,
            &mut sorted,
            CHUNK,
            self.threads(),
            |idx, out, c: &mut Counters| -> Result<(), TraceError> {
                for (o, &i) in out.iter_mut().zip(idx) {
                    *o = answer(&points[i as usize], c)?;
                }
                Ok(())
            },
        );
        let c = walked.map_err(|e| self.corrupt(e))?;
        for (&i, a) in order.iter().zip(&sorted) {
            out[i as usize] = *a;
        }
        self.check_unchanged()?;
        Ok(c)
    }
}

/// Whether `p` is inside: most of the vote's rays cross the surface an odd number of times.
fn inside(tree: &Tree<'_>, p: [f32; 3], c: &mut Counters) -> Result<bool, TraceError> {
    if p.iter().any(|x| !x.is_finite()) {
        return Ok(false);
    }
    thread_local! {
        /// The rays' hits, kept per thread: a point costs no allocation.
        static FOUND: std::cell::Cell<Vec<HitInfo>> = const { std::cell::Cell::new(Vec::new()) };
    }
    let mut found = FOUND.take();
    let mut odd = 0;
    let mut walked = Ok(());
    for d in VOTE_DIRECTIONS {
        let ray = Ray::new(p, d, 0.0, f32::INFINITY);
        walked = tree.all_hits(&ray, c, &mut found).map(drop);
        if walked.is_err() {
            break;
        }
        odd += found.len() % 2;
    }
    FOUND.set(found);
    walked.map(|()| odd >= 2)
}

/// The unit normal `(v1 - v0) x (v2 - v0)` of `t` (NaN if it has no area).
fn unit_normal(t: &[[f32; 3]; 3]) -> [f32; 3] {
    let [a, b, c] = t.map(|p| p.map(f64::from));
    let (e1, e2) = (
        [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
        [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
    );
    let n = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    n.map(|x| (x / len) as f32)
}
