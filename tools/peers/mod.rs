//! Peer tracers: the `obvhs` and `bvh` crates (and, with the `embree` feature, Embree 4: see
//! `embree.rs`) wrapped behind oavm's own [`Ray`] and [`Hit`], so tools can compare oavm with
//! them ray by ray, in one process. Included by tools with
//! `#[path = "peers/mod.rs"] mod peers;` (tools are cargo examples, so they can use the
//! dev-dependencies).
//!
//! Every wrapper answers a ray exactly as `../shared/RAYS.md` asks:
//!
//! - the direction is used as given, never renormalised, so `t` is in units of the direction;
//! - a triangle hit at `t` counts when `tmin <= t <= tmax` (both ends inclusive, negative `tmin`
//!   included);
//! - a ray that is not [`Ray::is_valid`] is a miss (and never reaches a crate, some of which
//!   `debug_assert!` finiteness);
//! - `Hit::prim` is the index of the triangle in the `triangles` slice given to `build`.
//!
//! Neither crate does all of this out of the box; where a wrapper departs from a crate's own entry
//! point, the comment there says which line of the crate it works around. All scenes are read-only
//! after `build`, so `&self` calls are safe from many threads (the scene types are `Send + Sync`).

// Each tool uses a part of this module.
#![allow(dead_code)]

#[cfg(feature = "embree")]
pub mod embree;
#[cfg(feature = "embree")]
pub use embree::EmbreeScene;

// Scenes are shared by reference across rayon's threads.
const _: () = {
    const fn shareable<T: Send + Sync>() {}
    shareable::<ObvhsScene>();
    shareable::<BvhCrateScene>();
    #[cfg(feature = "embree")]
    shareable::<EmbreeScene>();
};

use std::cell::Cell;

/// What every peer answers, as `RAYS.md` asks: the closest hit and whether anything is hit.
/// Tools that run several peers the same way are generic over it.
pub trait Tracer: Sync {
    fn intersect(&self, ray: &Ray) -> Hit;
    fn occluded(&self, ray: &Ray) -> bool;
}

impl Tracer for ObvhsScene {
    fn intersect(&self, ray: &Ray) -> Hit {
        ObvhsScene::intersect(self, ray)
    }
    fn occluded(&self, ray: &Ray) -> bool {
        ObvhsScene::occluded(self, ray)
    }
}

impl Tracer for BvhCrateScene {
    fn intersect(&self, ray: &Ray) -> Hit {
        BvhCrateScene::intersect(self, ray)
    }
    fn occluded(&self, ray: &Ray) -> bool {
        BvhCrateScene::occluded(self, ray)
    }
}

#[cfg(feature = "embree")]
impl Tracer for EmbreeScene {
    fn intersect(&self, ray: &Ray) -> Hit {
        EmbreeScene::intersect(self, ray)
    }
    fn occluded(&self, ray: &Ray) -> bool {
        EmbreeScene::occluded(self, ray)
    }
}

use glam::{UVec2, Vec3A, Vec4};
use oavm::{Hit, Ray};

// ---------------------------------------------------------------------------------------------
// Möller–Trumbore, shared by the `bvh` wrapper and brute force.
// ---------------------------------------------------------------------------------------------

#[inline(always)]
fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Möller–Trumbore ("Fast, minimum storage ray/triangle intersection", 1997) in f32, both faces,
/// no epsilon: the `t` of the hit of `origin + t * dir` with triangle `(a, b, c)` if it lies in
/// `[tmin, tmax]`, in units of `dir` (which need not be normalised).
///
/// Points on an edge count (`u, v >= 0`, `u + v <= 1`); a triangle whose plane contains the ray
/// is never hit (`det == 0`, which includes every triangle with a repeated corner); every NaN
/// along the way fails a comparison and so is a miss.
#[inline(always)]
pub fn moller_trumbore(
    [a, b, c]: [[f32; 3]; 3],
    origin: [f32; 3],
    dir: [f32; 3],
    tmin: f32,
    tmax: f32,
) -> Option<f32> {
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let p = cross(dir, e2);
    let det = dot(e1, p);
    if det == 0.0 {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = sub(origin, a);
    let u = dot(s, p) * inv_det;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = cross(s, e1);
    let v = dot(dir, q) * inv_det;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = dot(e2, q) * inv_det;
    (t >= tmin && t <= tmax && t.is_finite()).then_some(t)
}

/// The corners of an indexed triangle.
#[inline(always)]
fn corners(positions: &[[f32; 3]], tri: [u32; 3]) -> [[f32; 3]; 3] {
    tri.map(|v| positions[v as usize])
}

/// Closest hit by testing every triangle (ties go to the lowest id). The reference for the peers.
pub fn brute_force_intersect(positions: &[[f32; 3]], triangles: &[[u32; 3]], ray: &Ray) -> Hit {
    if !ray.is_valid() {
        return Hit::MISS;
    }
    let mut best = Hit::MISS;
    for (i, &tri) in triangles.iter().enumerate() {
        if let Some(t) = moller_trumbore(
            corners(positions, tri),
            ray.origin,
            ray.dir,
            ray.tmin,
            ray.tmax,
        ) && t < best.t
        {
            best = Hit { t, prim: i as u32 };
        }
    }
    best
}

/// Any hit in `[tmin, tmax]`, by testing triangles until one is hit.
pub fn brute_force_occluded(positions: &[[f32; 3]], triangles: &[[u32; 3]], ray: &Ray) -> bool {
    ray.is_valid()
        && triangles.iter().any(|&tri| {
            moller_trumbore(
                corners(positions, tri),
                ray.origin,
                ray.dir,
                ray.tmin,
                ray.tmax,
            )
            .is_some()
        })
}

/// A reciprocal of the direction for slab tests that is finite and never NaN: a component smaller
/// than `2^-40` of the largest one (zero included) is replaced by that bound, with the sign of the
/// component and `+` for `±0`.
///
/// Slab tests then never see `0 * inf`; the ray they test strays from the true line by at most
/// `2^-40` of the distance travelled, far below f32 resolution. `-0.0` counts as positive so that
/// the sign of the reciprocal and the `dir < 0` tests that pick near/far planes agree (see
/// [`ObvhsScene`] for why that matters).
fn safe_reciprocal(dir: [f32; 3]) -> [f32; 3] {
    let largest = dir[0].abs().max(dir[1].abs()).max(dir[2].abs());
    // The floor keeps 1/floor finite (and far from overflow once scaled by node extents) for
    // absurdly short directions.
    let floor = (largest * (-40f32).exp2()).max(1e-30);
    dir.map(|d| {
        if d.abs() >= floor {
            1.0 / d
        } else if d < 0.0 {
            -1.0 / floor
        } else {
            1.0 / floor
        }
    })
}

/// The same direction with `-0.0` components made `+0.0` (the same line, exactly).
fn positive_zeros(dir: [f32; 3]) -> [f32; 3] {
    dir.map(|d| if d == 0.0 { 0.0 } else { d })
}

// ---------------------------------------------------------------------------------------------
// obvhs
// ---------------------------------------------------------------------------------------------

use obvhs::{BvhBuildParams, cwbvh::CwBvh, cwbvh::node::CwBvhNode, triangle::Triangle};

/// The obvhs build preset [`ObvhsScene::build`] uses, by name.
///
/// `very_slow_build` is obvhs's highest-quality preset (PLOC with spatial pre-splits, reinsertion
/// over the whole node set, 128-bit Morton sort). On the bunny it builds in about 0.12 s
/// single-threaded (obvhs's `parallel` feature is off) and visits the fewest nodes per ray,
/// though all presets but `fastest_build` trace within a few percent of each other there.
/// `peers_smoke --compare` prints build time, work per ray and speed of every preset.
pub const OBVHS_PRESET: &str = "very_slow_build";

/// Every obvhs build preset, by name, slowest build last.
pub fn obvhs_presets() -> [(&'static str, BvhBuildParams); 6] {
    [
        ("fastest_build", BvhBuildParams::fastest_build()),
        ("very_fast_build", BvhBuildParams::very_fast_build()),
        ("fast_build", BvhBuildParams::fast_build()),
        ("medium_build", BvhBuildParams::medium_build()),
        ("slow_build", BvhBuildParams::slow_build()),
        ("very_slow_build", BvhBuildParams::very_slow_build()),
    ]
}

/// A compressed wide BVH8 (Ylitie et al. 2017) built by obvhs, traced by obvhs's `traverse!`
/// macro with a node test of our own.
///
/// Why not `CwBvh::ray_traverse` with `obvhs::ray::Ray::new` (`intersect_stock` keeps that path
/// for comparison):
///
/// - the node test (`CwBvhNode::intersect_ray_simd`, `cwbvh/simd.rs`) clips boxes to
///   `[EPSILON = 1e-4, ray.tmax]`, not `[ray.tmin, ray.tmax]` (`//ray.tmin?` in the source), so
///   hits with `t < 1e-4` (in units of the direction) are lost even for `tmin = 0`, and so is
///   everything before the origin when `tmin < 0`;
/// - `ray_traverse` keeps a hit only if `t < traverse_ray.tmax` (`cwbvh/mod.rs`), so a hit at
///   exactly `t == tmax` is dropped although `Triangle::intersect` accepted it (`t <= ray.tmax`);
/// - `Ray::new` takes `safe_inverse` (`ray.rs`): `signum(-0.0) = -1` makes the reciprocal of a
///   `-0.0` component negative while the node test picks near/far planes by `direction < 0.0`,
///   which is false for `-0.0`: slabs come out inverted and such a ray misses every box it starts
///   in. It also treats any component below `f32::EPSILON` (absolute) as `±f32::EPSILON`, which
///   bends short directions visibly.
///
/// The node test here ([`intersect_node`]) is `intersect_ray_simd` with `[tmin, tmax]` and
/// [`safe_reciprocal`]. Triangles are tested with obvhs's own `Triangle::intersect` (Möller–Trumbore
/// in the form of madmann91's BVH tutorial; `t = n·(v0 - o) / n·d`, so `t` is in units of the
/// direction as given, and it accepts `ray.tmin <= t <= ray.tmax`), on the caller's ray unchanged.
pub struct ObvhsScene {
    bvh: CwBvh,
    /// Triangles in the order of `bvh.primitive_indices` (so leaves index them directly).
    tris: Vec<Triangle>,
    /// Mesh id of `tris[i]`.
    ids: Vec<u32>,
}

/// Work done by traversals: nodes whose children were tested, triangles tested.
#[derive(Clone, Copy, Debug, Default)]
pub struct TraceStats {
    pub nodes: u64,
    pub triangles: u64,
}

/// The ray as the node test sees it.
struct NodeRay {
    origin: Vec3A,
    inv_dir: Vec3A,
    /// `dir < 0` per axis, consistent with the sign of `inv_dir` and with the traversal octant.
    negative: [bool; 3],
    tmin: f32,
    tmax: f32,
}

impl NodeRay {
    fn new(ray: &Ray) -> (NodeRay, Vec3A) {
        let dir = positive_zeros(ray.dir);
        let node_ray = NodeRay {
            origin: ray.origin.into(),
            inv_dir: safe_reciprocal(dir).into(),
            negative: dir.map(|d| d < 0.0),
            tmin: ray.tmin,
            tmax: ray.tmax,
        };
        // The traversal direction only orders children (`ray_get_octant_inv4` tests `< 0.0`).
        (node_ray, dir.into())
    }
}

/// Which of a CWBVH node's 8 children the ray enters within `[tmin, tmax]`, as the hit mask the
/// `traverse!` macro expects: `CwBvhNode::intersect_ray_simd` (obvhs 0.4.0, `cwbvh/simd.rs`) with
/// `ray.tmin` where it has `EPSILON`, and our reciprocal; four children at a time through glam's
/// `Vec4` (SSE on x86-64, scalar elsewhere).
#[inline(always)]
fn intersect_node(node: &CwBvhNode, ray: &NodeRay, oct_inv4: u32) -> u32 {
    // Child boxes are quantised on a grid with origin `p` and cell size `extent`; transform the
    // ray into grid units rather than the boxes into world units.
    let scale = node.compute_extent() * ray.inv_dir;
    let offset = (Vec3A::from(node.p) - ray.origin) * ray.inv_dir;
    let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
    let tmin = Vec4::splat(ray.tmin);
    let tmax = Vec4::splat(ray.tmax);
    let mut hit_mask = 0u32;
    for half in 0..2 {
        let lanes = |q: &[u8; 8]| {
            let q = &q[half * 4..half * 4 + 4];
            Vec4::new(q[0] as f32, q[1] as f32, q[2] as f32, q[3] as f32)
        };
        let slab = |lo: &[u8; 8], hi: &[u8; 8], negative: bool, scale: f32, offset: f32| {
            let (near, far) = if negative {
                (lanes(hi), lanes(lo))
            } else {
                (lanes(lo), lanes(hi))
            };
            let (scale, offset) = (Vec4::splat(scale), Vec4::splat(offset));
            (near * scale + offset, far * scale + offset)
        };
        let (near_x, far_x) = slab(
            &node.child_min_x,
            &node.child_max_x,
            ray.negative[0],
            scale.x,
            offset.x,
        );
        let (near_y, far_y) = slab(
            &node.child_min_y,
            &node.child_max_y,
            ray.negative[1],
            scale.y,
            offset.y,
        );
        let (near_z, far_z) = slab(
            &node.child_min_z,
            &node.child_max_z,
            ray.negative[2],
            scale.z,
            offset.z,
        );
        let enter = near_x.max(near_y).max(near_z).max(tmin);
        let leave = far_x.min(far_y).min(far_z).min(tmax);
        let entered = enter.cmple(leave).bitmask();
        for lane in 0..4 {
            if entered & (1 << lane) != 0 {
                let child = half * 4 + lane;
                let child_bits = obvhs::cwbvh::node::extract_byte64(child_bits8, child);
                let bit_index = obvhs::cwbvh::node::extract_byte64(bit_index8, child);
                hit_mask |= child_bits << bit_index;
            }
        }
    }
    hit_mask
}

/// The depth of a CWBVH (root = 0), walking it without recursion.
fn cwbvh_depth(bvh: &CwBvh) -> usize {
    let mut deepest = 0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((node, depth)) = stack.pop() {
        if bvh.nodes.is_empty() {
            break;
        }
        deepest = deepest.max(depth);
        let node = &bvh.nodes[node];
        for child in 0..8 {
            if !node.is_child_empty(child) && !node.is_leaf(child) {
                stack.push((node.child_node_index(child) as usize, depth + 1));
            }
        }
    }
    deepest
}

/// obvhs's traversal stack (`TRAVERSAL_STACK_SIZE`, private in `cwbvh/mod.rs`) holds 32 entries
/// and overwrites its top entry when full; `CwBvh::validate` asserts the depth is below it.
const OBVHS_STACK: usize = 32;

impl ObvhsScene {
    /// Builds with the [`OBVHS_PRESET`] preset.
    pub fn build(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Self {
        Self::build_with(positions, triangles, BvhBuildParams::very_slow_build())
    }

    /// Builds with any obvhs preset (see [`obvhs_presets`]).
    ///
    /// # Panics
    /// If the tree is too deep for obvhs's fixed traversal stack (never seen on real meshes; the
    /// alternative is wrong answers).
    pub fn build_with(
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
        params: BvhBuildParams,
    ) -> Self {
        let mesh_tris: Vec<Triangle> = triangles
            .iter()
            .map(|&tri| {
                let [v0, v1, v2] = corners(positions, tri).map(Vec3A::from);
                Triangle { v0, v1, v2 }
            })
            .collect();
        if mesh_tris.is_empty() {
            // An empty CwBvh traverses to nothing (`new_traversal` starts with an empty group).
            return ObvhsScene {
                bvh: CwBvh::default(),
                tris: Vec::new(),
                ids: Vec::new(),
            };
        }
        let mut core_build_time = std::time::Duration::ZERO;
        let bvh =
            obvhs::cwbvh::builder::build_cwbvh_from_tris(&mesh_tris, params, &mut core_build_time);
        let depth = cwbvh_depth(&bvh);
        assert!(
            depth < OBVHS_STACK,
            "obvhs CWBVH depth {depth} overflows its traversal stack"
        );
        // With spatial splits a triangle may sit in several leaves, so `primitive_indices` can be
        // longer than the mesh; ids keep pointing at the mesh.
        let ids = bvh.primitive_indices.clone();
        let tris = ids.iter().map(|&i| mesh_tris[i as usize]).collect();
        ObvhsScene { bvh, tris, ids }
    }

    /// Closest hit in `[tmin, tmax]`; `prim` is the index into the `triangles` given to `build`.
    pub fn intersect(&self, ray: &Ray) -> Hit {
        self.closest::<false>(ray, &mut TraceStats::default())
    }

    /// [`ObvhsScene::intersect`], also counting the work done (slower; to compare builds).
    pub fn intersect_counting(&self, ray: &Ray, stats: &mut TraceStats) -> Hit {
        self.closest::<true>(ray, stats)
    }

    #[inline(always)]
    fn closest<const COUNT: bool>(&self, ray: &Ray, stats: &mut TraceStats) -> Hit {
        if !ray.is_valid() {
            return Hit::MISS;
        }
        let tri_ray = obvhs_ray(ray);
        let (mut node_ray, traversal_dir) = NodeRay::new(ray);
        let mut best = Hit::MISS;
        let mut state = self.bvh.new_traversal(traversal_dir);
        let mut node;
        obvhs::traverse!(
            self.bvh,
            node,
            state,
            {
                if COUNT {
                    stats.nodes += 1;
                }
                intersect_node(node, &node_ray, state.oct_inv4)
            },
            {
                if COUNT {
                    stats.triangles += 1;
                }
                let i = state.primitive_id as usize;
                // `Triangle::intersect` returns `f32::INFINITY` for a miss and accepts
                // `tmin <= t <= tmax` of the ray it is given: the caller's, whole.
                let t = self.tris[i].intersect(&tri_ray);
                if t < best.t {
                    best = Hit {
                        t,
                        prim: self.ids[i],
                    };
                    // Only boxes entered at or before the best hit can hold a closer one.
                    node_ray.tmax = t;
                }
            }
        );
        best
    }

    /// Is any triangle hit in `[tmin, tmax]`? Stops at the first hit found.
    pub fn occluded(&self, ray: &Ray) -> bool {
        if !ray.is_valid() {
            return false;
        }
        let tri_ray = obvhs_ray(ray);
        let (node_ray, traversal_dir) = NodeRay::new(ray);
        let mut state = self.bvh.new_traversal(traversal_dir);
        let mut node;
        let mut hit = false;
        // `break` inside the macro's primitive block only leaves its inner loop; a labelled block
        // stops the whole traversal (as `CwBvh::ray_traverse_miss` does).
        'traversal: {
            obvhs::traverse!(
                self.bvh,
                node,
                state,
                intersect_node(node, &node_ray, state.oct_inv4),
                {
                    if self.tris[state.primitive_id as usize].intersect(&tri_ray) != f32::INFINITY {
                        hit = true;
                        break 'traversal;
                    }
                }
            );
        }
        hit
    }

    /// obvhs's own entry point, for comparison only: `CwBvh::ray_traverse` with `Ray::new` and
    /// `Triangle::intersect`, as its README does. Misses hits at `t < 1e-4`, before the origin and
    /// at exactly `tmax`, and rays with `-0.0` direction components (see [`ObvhsScene`]).
    pub fn intersect_stock(&self, ray: &Ray) -> Hit {
        if !ray.is_valid() {
            return Hit::MISS;
        }
        let ray = obvhs::ray::Ray::new(ray.origin.into(), ray.dir.into(), ray.tmin, ray.tmax);
        let mut hit = obvhs::ray::RayHit::none();
        if self
            .bvh
            .ray_traverse(ray, &mut hit, |r, i| self.tris[i].intersect(r))
        {
            Hit {
                t: hit.t,
                prim: self.ids[hit.primitive_id as usize],
            }
        } else {
            Hit::MISS
        }
    }

    /// Number of CWBVH nodes (each 80 bytes).
    pub fn node_count(&self) -> usize {
        self.bvh.nodes.len()
    }
}

/// The caller's ray for `Triangle::intersect`, which reads only origin, direction, tmin and
/// tmax; built field by field because `Ray::new` would compute (and `debug_assert!` on) a
/// reciprocal nobody reads here.
fn obvhs_ray(ray: &Ray) -> obvhs::ray::Ray {
    obvhs::ray::Ray {
        origin: ray.origin.into(),
        direction: ray.dir.into(),
        inv_direction: Vec3A::ZERO,
        tmin: ray.tmin,
        tmax: ray.tmax,
    }
}

// ---------------------------------------------------------------------------------------------
// bvh (svenstaro)
// ---------------------------------------------------------------------------------------------

use bvh::aabb::{Aabb, Bounded, IntersectsAabb};
use bvh::bounding_hierarchy::{BHShape, BoundingHierarchy};
use bvh::bvh::Bvh;
use bvh::flat_bvh::FlatBvh;

/// A triangle as the `bvh` crate stores it: bounds and its leaf's node index.
#[derive(Clone, Copy, Debug)]
struct BvhTri {
    corners: [[f32; 3]; 3],
    /// Mesh id (the crate hands shapes back by reference).
    id: u32,
    node_index: usize,
}

impl Bounded<f32, 3> for BvhTri {
    fn aabb(&self) -> Aabb<f32, 3> {
        let [a, b, c] = self.corners;
        let min = std::array::from_fn::<f32, 3, _>(|i| a[i].min(b[i]).min(c[i]));
        let max = std::array::from_fn::<f32, 3, _>(|i| a[i].max(b[i]).max(c[i]));
        Aabb::with_bounds(min.into(), max.into())
    }
}

impl BHShape<f32, 3> for BvhTri {
    fn set_bh_node_index(&mut self, index: usize) {
        self.node_index = index;
    }

    fn bh_node_index(&self) -> usize {
        self.node_index
    }
}

/// How [`BvhCrateScene`] walks the tree for a closest hit. The crate's traversals only return
/// candidate shapes; triangles are tested here with [`moller_trumbore`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BvhTraversal {
    /// `Bvh::traverse`: recursive, collects all candidates in a `Vec`, then tests them all.
    Recursive,
    /// `Bvh::traverse_iterator` with the crate's `Ray`: no allocation, tests every candidate.
    Iterator,
    /// `FlatBvh::traverse` (`Bvh::flatten`): stackless, collects all candidates, tests them all.
    Flat,
    /// `Bvh::nearest_traverse_iterator`: leaves in order of box entry (a binary heap), stopping
    /// once a leaf box starts beyond the best hit.
    Nearest,
    /// `Bvh::traverse_iterator` with a query of ours (the crate's `IntersectsAabb` trait) whose
    /// slab test clips to `[tmin, best t]`, so boxes behind the best hit are skipped.
    Clipped,
}

impl BvhTraversal {
    pub const ALL: [BvhTraversal; 5] = [
        BvhTraversal::Recursive,
        BvhTraversal::Iterator,
        BvhTraversal::Flat,
        BvhTraversal::Nearest,
        BvhTraversal::Clipped,
    ];
}

/// The `bvh` crate (0.13): binned-SAH binary BVH, one triangle per leaf, built in parallel with
/// `build_par` (rayon).
///
/// The crate's `Ray::new` normalises the direction (`ray/ray_impl.rs`: `let direction =
/// direction.normalize();`); its fields are public, so the wrapper builds the `Ray` field by field
/// from the caller's direction and every distance stays in the caller's units. Its slab test
/// (`ray/intersect_simd.rs`, `ray/intersect_default.rs`) knows no `tmin`/`tmax`: it accepts a
/// box when `tmax >= max(tmin, 0)`, i.e. anywhere ahead of the origin, and rejects a box whose
/// test produces a NaN (a ray lying in the plane of a box face).
///
/// The default traversal ([`BVH_TRAVERSAL`], `Clipped`) therefore walks the crate's tree with the
/// crate's `traverse_iterator` but a query of ours that clips boxes to `[tmin, best t]`. The
/// traversals that use the crate's `Ray` apply `tmin`/`tmax` in the triangle test only, and trace
/// a ray with `tmin < 0` twice, forwards and backwards (`-dir` negates `t` exactly), since the
/// crate's boxes never reach behind the origin. Triangles are tested with [`moller_trumbore`]
/// (the crate's `Ray::intersects_triangle` culls back faces and rejects `t <= f32::EPSILON`).
pub struct BvhCrateScene {
    bvh: Bvh<f32, 3>,
    flat: FlatBvh<f32, 3>,
    shapes: Vec<BvhTri>,
    /// Tree depth; the crate's iterators have a fixed stack of 32 and panic beyond it.
    depth: usize,
}

/// Deepest tree the crate's iterators (`bvh/iter.rs`, `stack: [usize; 32]`) can walk.
const BVH_ITER_STACK: usize = 32;

/// The traversal [`BvhCrateScene::intersect`] uses: the fastest on the bunny, about 1.3x the
/// crate's own best (`Recursive`/`Flat`); `peers_smoke --compare` times them all.
pub const BVH_TRAVERSAL: BvhTraversal = BvhTraversal::Clipped;

impl BvhCrateScene {
    pub fn build(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Self {
        let mut shapes: Vec<BvhTri> = triangles
            .iter()
            .enumerate()
            .map(|(id, &tri)| BvhTri {
                corners: corners(positions, tri),
                id: id as u32,
                node_index: 0,
            })
            .collect();
        let bvh = Bvh::build_par(&mut shapes);
        // `flatten` starts at `nodes[0]`, which an empty mesh does not have.
        let flat = if bvh.nodes.is_empty() {
            FlatBvh::new()
        } else {
            bvh.flatten()
        };
        let depth = bvh_depth(&bvh);
        BvhCrateScene {
            bvh,
            flat,
            shapes,
            depth,
        }
    }

    /// Closest hit in `[tmin, tmax]` with [`BVH_TRAVERSAL`].
    pub fn intersect(&self, ray: &Ray) -> Hit {
        self.intersect_with(ray, BVH_TRAVERSAL)
    }

    /// Closest hit in `[tmin, tmax]` with a chosen traversal (all give the same answers).
    pub fn intersect_with(&self, ray: &Ray, traversal: BvhTraversal) -> Hit {
        if !ray.is_valid() {
            return Hit::MISS;
        }
        // The iterators panic on trees deeper than their stack; the recursive walk has none.
        let traversal = match traversal {
            BvhTraversal::Iterator | BvhTraversal::Nearest | BvhTraversal::Clipped
                if self.depth >= BVH_ITER_STACK =>
            {
                BvhTraversal::Recursive
            }
            BvhTraversal::Nearest if ray.tmin < 0.0 => BvhTraversal::Iterator,
            t => t,
        };
        match traversal {
            BvhTraversal::Clipped => self.intersect_clipped(ray),
            BvhTraversal::Nearest => self.intersect_nearest(ray),
            _ => {
                let mut best = Hit::MISS;
                // Forwards: the crate's boxes cover `t >= 0`.
                if ray.tmax >= 0.0 {
                    let query = crate_ray(ray.origin, ray.dir);
                    self.for_candidates(&query, traversal, |i, tri| {
                        if let Some(t) =
                            moller_trumbore(tri, ray.origin, ray.dir, ray.tmin, ray.tmax)
                            && (t < best.t || (t == best.t && (i as u32) < best.prim))
                        {
                            best = Hit { t, prim: i as u32 };
                        }
                    });
                }
                // Backwards, for `t < 0`: along `-dir` every `t` is negated exactly.
                if ray.tmin < 0.0 {
                    let back = ray.dir.map(|d| -d);
                    let query = crate_ray(ray.origin, back);
                    self.for_candidates(&query, traversal, |i, tri| {
                        if let Some(t) =
                            moller_trumbore(tri, ray.origin, back, -ray.tmax, -ray.tmin)
                            && (-t < best.t || (-t == best.t && (i as u32) < best.prim))
                        {
                            best = Hit {
                                t: -t,
                                prim: i as u32,
                            };
                        }
                    });
                }
                best
            }
        }
    }

    /// Is any triangle hit in `[tmin, tmax]`? `traverse_iterator` (no allocation) with the
    /// clipped query, stopping at the first hit.
    pub fn occluded(&self, ray: &Ray) -> bool {
        if !ray.is_valid() {
            return false;
        }
        if self.depth >= BVH_ITER_STACK {
            return self.intersect_with(ray, BvhTraversal::Recursive).is_hit();
        }
        let query = ClippedQuery::new(ray);
        self.bvh
            .traverse_iterator(&query, &self.shapes)
            .any(|shape| {
                moller_trumbore(shape.corners, ray.origin, ray.dir, ray.tmin, ray.tmax).is_some()
            })
    }

    fn for_candidates(
        &self,
        query: &bvh::ray::Ray<f32, 3>,
        traversal: BvhTraversal,
        mut test: impl FnMut(usize, [[f32; 3]; 3]),
    ) {
        match traversal {
            BvhTraversal::Recursive => {
                for shape in self.bvh.traverse(query, &self.shapes) {
                    test(shape.id as usize, shape.corners);
                }
            }
            BvhTraversal::Flat => {
                for shape in self.flat.traverse(query, &self.shapes) {
                    test(shape.id as usize, shape.corners);
                }
            }
            _ => {
                for shape in self.bvh.traverse_iterator(query, &self.shapes) {
                    test(shape.id as usize, shape.corners);
                }
            }
        }
    }

    fn intersect_nearest(&self, ray: &Ray) -> Hit {
        // Only for `tmin >= 0` (the caller sends other rays elsewhere): leaves come nearest box
        // first, so once a leaf's box starts after the best hit, none later can beat it.
        let query = crate_ray(ray.origin, ray.dir);
        let mut best = Hit::MISS;
        for shape in self.bvh.nearest_traverse_iterator(&query, &self.shapes) {
            if best.is_hit() {
                match query.intersection_slice_for_aabb(&shape.aabb()) {
                    Some((enter, _)) if enter > best.t => break,
                    _ => {}
                }
            }
            let i = shape.id as usize;
            if let Some(t) = moller_trumbore(shape.corners, ray.origin, ray.dir, ray.tmin, ray.tmax)
                && (t < best.t || (t == best.t && (i as u32) < best.prim))
            {
                best = Hit { t, prim: i as u32 };
            }
        }
        best
    }

    fn intersect_clipped(&self, ray: &Ray) -> Hit {
        let query = ClippedQuery::new(ray);
        let mut best = Hit::MISS;
        for shape in self.bvh.traverse_iterator(&query, &self.shapes) {
            let i = shape.id as usize;
            if let Some(t) = moller_trumbore(shape.corners, ray.origin, ray.dir, ray.tmin, ray.tmax)
                && (t < best.t || (t == best.t && (i as u32) < best.prim))
            {
                best = Hit { t, prim: i as u32 };
                query.tmax.set(t);
            }
        }
        best
    }

    /// Depth of the binary tree (root = 0).
    pub fn depth(&self) -> usize {
        self.depth
    }
}

/// The crate's `Ray`, built field by field so the direction is not normalised (`Ray::new` would).
fn crate_ray(origin: [f32; 3], dir: [f32; 3]) -> bvh::ray::Ray<f32, 3> {
    bvh::ray::Ray {
        origin: origin.into(),
        direction: dir.into(),
        inv_direction: dir.map(|d| 1.0 / d).into(),
    }
}

fn bvh_depth(bvh: &Bvh<f32, 3>) -> usize {
    use bvh::bvh::BvhNode;
    let mut deepest = 0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((node, depth)) = stack.pop() {
        let Some(node) = bvh.nodes.get(node) else {
            break;
        };
        deepest = deepest.max(depth);
        if let BvhNode::Node {
            child_l_index,
            child_r_index,
            ..
        } = *node
        {
            stack.push((child_l_index, depth + 1));
            stack.push((child_r_index, depth + 1));
        }
    }
    deepest
}

/// A ray segment `[tmin, tmax]` for the `bvh` crate's traversals; `tmax` shrinks to the best hit
/// while the traversal runs (the crate passes the query by shared reference, hence the `Cell`).
struct ClippedQuery {
    origin: Vec3A,
    inv_dir: Vec3A,
    tmin: f32,
    tmax: Cell<f32>,
}

impl ClippedQuery {
    fn new(ray: &Ray) -> Self {
        ClippedQuery {
            origin: ray.origin.into(),
            inv_dir: safe_reciprocal(positive_zeros(ray.dir)).into(),
            tmin: ray.tmin,
            tmax: Cell::new(ray.tmax),
        }
    }
}

impl IntersectsAabb<f32, 3> for ClippedQuery {
    #[inline(always)]
    fn intersects_aabb(&self, aabb: &Aabb<f32, 3>) -> bool {
        let lo = (Vec3A::new(aabb.min.x, aabb.min.y, aabb.min.z) - self.origin) * self.inv_dir;
        let hi = (Vec3A::new(aabb.max.x, aabb.max.y, aabb.max.z) - self.origin) * self.inv_dir;
        let enter = lo.min(hi).max_element().max(self.tmin);
        let leave = lo.max(hi).min_element().min(self.tmax.get());
        enter <= leave
    }
}
