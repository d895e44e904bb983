//! The classic octree of the OAVM paper's comparison: exactly OAVM's subdivision, stored as a
//! pointer octree and traversed with the parametric algorithm of Revelles, Ureña and Lastra,
//! "An efficient parametric algorithm for octree traversal" (WSCG 2000).
//!
//! **Build.** The same tree as OAVM's, so that the comparison isolates what OAVM adds (merged
//! empty volumes, pointer-free Morton layout, neighbour stepping): the same root cube
//! ([`crate::build::root_cube`] of the triangles' bounds), the same mapping of the triangles
//! into the `2^21` lattice (in f64, as `prepare` in [`crate::build`] does), and the same
//! subdivision ([`crate::build::subdivide::subdivide`], with OAVM's `K` and `D` from
//! [`BuildOptions`]): a node is split while it holds more than `K` triangles, a triangle goes to
//! every child it overlaps by the exact triangle–box test, with the cell grown by
//! [`CELL_MARGIN`]. No merging. The levels are then stored as a pointer octree: every internal
//! node holds the indices of its 8 children, every solid leaf the offset and length of its
//! triangle list (a run of the reference array), every empty leaf nothing.
//!
//! Triangles with a non-finite coordinate are left out (OAVM's builder refuses such meshes; no
//! ray hits them). Without triangles the structure misses everything. If the tree needs more
//! than 32-bit node or reference indices, it is not kept and every ray tests every triangle
//! (correct, slow; far beyond any mesh the comparison uses).
//!
//! **Traversal** (Revelles et al. 2000), top-down and recursive, in lattice space (f64, where
//! cell faces are integers; `t` is unchanged by the affine map):
//!
//! - per node, the ray's entry and exit `t` per axis (`t0`, `t1`) come from the parent; the
//!   node is entered if `max t0 <= min t1` and that interval meets `[tmin, tmax]` (`tmax`
//!   shrinks to the closest hit so far);
//! - negative direction components are handled by mirroring: with the bitmask `a` (bit `k` set
//!   where `dir[k] < 0`), the children are enumerated in the mirrored frame, where the ray runs
//!   toward `+` on every axis, and child `i` of the mirrored frame is child `i ^ a` of the tree;
//! - the first child is found from the mid-plane parameters `tm` against the node's entry
//!   `t` (Revelles' `first_node`, here against `max(entry, tmin)` so a ray starting inside the
//!   node starts in the child holding its origin), and each next child from the axis of the
//!   current child's exit (`new_node`): children come front to back, and the walk leaves the
//!   node when the exit axis already has its bit set;
//! - a zero direction component (either sign of zero) never crosses a plane: its slab is
//!   `(-inf, +inf)` if the origin is inside (else the ray misses the root), and its mid-plane
//!   parameter is `-inf` if the origin is on the upper side (the upper child is entered from
//!   the start) and `+inf` if not. These are set explicitly, so `0 * inf` never makes a NaN;
//!   every other parameter is finite, since f32 inputs scaled into f64 neither overflow nor
//!   vanish;
//! - in a solid leaf the triangles are tested four at a time with the shared watertight test
//!   ([`RayShear::intersect4`]). A leaf references every triangle overlapping its cell grown by
//!   `CELL_MARGIN` (2 lattice units, far more than the f64 rounding of the slab parameters), so
//!   a hit at `t` no later than the leaf's exit is final: no later leaf can hold a closer one,
//!   and the closest-hit query stops there. The any-hit query stops at the first hit.
//!
//! **Counting conventions** (as `format-spec.md` §9 and [`crate::build::PointerCounts`]):
//!
//! - `nodes` = every octree node, internal or leaf, empty or solid: equal to OAVM's node count
//!   for the same options (OAVM keeps every node too, as a record);
//! - `pointers` = 8 child pointers per internal node + 1 triangle-list pointer per solid leaf:
//!   equal to OAVM's `pointer_octree_total`;
//! - `bytes` = the node array ([`std::mem::size_of`] of a node, which holds the 8 child
//!   pointers or the leaf's list) + the reference array (4 bytes a reference) + the triangles
//!   (36 bytes each) and their primitive ids (4 bytes each);
//! - `nodes_visited` = nodes whose slab interval was computed (entered or rejected);
//!   `leaves_visited` = leaves entered (empty or solid); `triangles_tested` = ray–triangle
//!   tests (a four-lane test of three triangles counts three).
//!
//! [`CELL_MARGIN`]: crate::physical::format::CELL_MARGIN

use rayon::prelude::*;

use crate::build::BuildOptions;
use crate::build::subdivide::{self, BuildNode, LatticeTri, SubdivideParams};
use crate::compare::{Accelerator, StructureStats, Triangles};
use crate::geom::triangle::RayShear;
use crate::geom::{Hit, Ray};
use crate::logical::Counters;
use crate::mapping::morton::LATTICE_SIZE;

/// A node of the pointer octree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Node {
    /// Indices of the 8 children, in octant order (bit 0: x, bit 1: y, bit 2: z; a set bit is
    /// the upper half).
    Internal([u32; 8]),
    /// A leaf: `count` references from `first` in the reference array (`count == 0`: empty).
    Leaf { first: u32, count: u32 },
}

/// The classic pointer octree over OAVM's subdivision.
pub struct ClassicOctree {
    nodes: Vec<Node>,
    /// Triangle lists of the solid leaves: indices into `tris`.
    refs: Vec<u32>,
    tris: Vec<[[f32; 3]; 3]>,
    prim: Vec<u32>,
    root_min: [f64; 3],
    /// Lattice cells per world unit.
    scale: f64,
    /// No tree (indices beyond 32 bits): every ray tests every triangle.
    linear: bool,
    internal_nodes: u64,
    solid_leaves: u64,
    stats: StructureStats,
}

/// Per-ray state of a traversal.
struct Walk {
    shear: RayShear,
    /// The ray in lattice space.
    o: [f64; 3],
    d: [f64; 3],
    inv: [f64; 3],
    /// Mirroring mask: bit `k` set where `d[k] < 0`.
    a: usize,
    tmin: f32,
    tmax: f32,
    best: Hit,
}

impl Walk {
    /// The far end of the interval still searched: the closest hit so far, or `tmax`.
    fn limit(&self) -> f32 {
        if self.best.is_hit() {
            self.best.t
        } else {
            self.tmax
        }
    }
}

impl ClassicOctree {
    /// Builds the octree over `tris` with OAVM's subdivision parameters from `opts` (see the
    /// module documentation). Never panics.
    pub fn build(tris: &Triangles, opts: &BuildOptions) -> ClassicOctree {
        let t0 = std::time::Instant::now();
        let mut tree = Self::build_tree(tris, opts);
        let node_bytes = tree.nodes.len() * std::mem::size_of::<Node>();
        tree.stats = StructureStats {
            name: "octree",
            build_seconds: t0.elapsed().as_secs_f64(),
            nodes: tree.nodes.len() as u64,
            pointers: 8 * tree.internal_nodes + tree.solid_leaves,
            bytes: (node_bytes
                + tree.refs.len() * 4
                + tree.tris.len() * std::mem::size_of::<[[f32; 3]; 3]>()
                + tree.prim.len() * 4) as u64,
        };
        tree
    }

    fn build_tree(tris: &Triangles, opts: &BuildOptions) -> ClassicOctree {
        let (v, prim): (Vec<[[f32; 3]; 3]>, Vec<u32>) = tris
            .v
            .iter()
            .zip(&tris.prim)
            .filter(|(v, _)| v.iter().flatten().all(|x| x.is_finite()))
            .map(|(v, &p)| (*v, p))
            .unzip();
        let mut tree = ClassicOctree {
            nodes: Vec::new(),
            refs: Vec::new(),
            tris: v,
            prim,
            root_min: [0.0; 3],
            scale: 1.0,
            linear: false,
            internal_nodes: 0,
            solid_leaves: 0,
            stats: StructureStats::default(),
        };
        if tree.tris.is_empty() {
            return tree;
        }
        if tree.tris.len() > u32::MAX as usize {
            tree.linear = true;
            return tree;
        }
        // Bounds of the (finite) triangles: `tris.min`/`tris.max` whenever all are finite.
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in tree.tris.iter().flatten() {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        // The root cube and lattice mapping of `build::prepare`, expression for expression.
        let (root_min, root_size) = crate::physical::format::root_cube(lo, hi);
        let scale = LATTICE_SIZE as f64 / root_size;
        tree.root_min = root_min;
        tree.scale = scale;
        let lattice: Vec<LatticeTri> = tree
            .tris
            .par_iter()
            .map(|v| {
                LatticeTri::new(std::array::from_fn(|i| {
                    std::array::from_fn(|k| (v[i][k] as f64 - root_min[k]) * scale)
                }))
            })
            .collect();
        let params = SubdivideParams {
            max_depth: opts.max_depth,
            // OAVM refuses K = 0 (`BuildOptions::validate`); here it means K = 1.
            leaf_size: opts.leaf_size.max(1),
        };
        let levels = subdivide::subdivide(&lattice, params, &|_, _| {});
        drop(lattice);

        // Pointer octree, level by level: the children of a level's internal nodes, 8 at a time
        // in order, are the next level's nodes (see `subdivide`).
        let total: usize = levels.iter().map(|l| l.nodes.len()).sum();
        let total_refs: usize = levels
            .iter()
            .flat_map(|l| &l.nodes)
            .map(|n| match n {
                BuildNode::Leaf(t) => t.len(),
                BuildNode::Internal => 0,
            })
            .sum();
        if u32::try_from(total).is_err() || u32::try_from(total_refs).is_err() {
            tree.linear = true;
            return tree;
        }
        let mut nodes = Vec::with_capacity(total);
        let mut refs = Vec::with_capacity(total_refs);
        let mut next_level_start = 0usize;
        for level in &levels {
            next_level_start += level.nodes.len();
            let mut internal = 0usize;
            for n in &level.nodes {
                match n {
                    BuildNode::Internal => {
                        let first = next_level_start + 8 * internal;
                        internal += 1;
                        tree.internal_nodes += 1;
                        // first + 7 < total <= u32::MAX (checked above)
                        nodes.push(Node::Internal(std::array::from_fn(|o| {
                            u32::try_from(first + o).unwrap_or(u32::MAX)
                        })));
                    }
                    BuildNode::Leaf(t) => {
                        if !t.is_empty() {
                            tree.solid_leaves += 1;
                        }
                        nodes.push(Node::Leaf {
                            first: u32::try_from(refs.len()).unwrap_or(u32::MAX),
                            count: u32::try_from(t.len()).unwrap_or(u32::MAX),
                        });
                        refs.extend_from_slice(t);
                    }
                }
            }
        }
        tree.nodes = nodes;
        tree.refs = refs;
        tree
    }

    /// Internal nodes and solid leaves (for tests and reports).
    pub fn counts(&self) -> (u64, u64) {
        (self.internal_nodes, self.solid_leaves)
    }

    fn trace<const ANY: bool>(&self, ray: &Ray, c: &mut Counters) -> Hit {
        if !ray.is_valid() || self.tris.is_empty() {
            return Hit::MISS;
        }
        let shear = RayShear::new(ray);
        if self.linear || self.nodes.is_empty() {
            let mut w = self.walk_state(ray, shear);
            let all: Vec<u32> = (0..self.tris.len() as u32).collect();
            self.test_leaf::<ANY>(&all, &mut w, c);
            return w.best;
        }
        let mut w = self.walk_state(ray, shear);
        let n = LATTICE_SIZE as f64;
        let mut t0 = [0f64; 3];
        let mut t1 = [0f64; 3];
        for k in 0..3 {
            if w.d[k] == 0.0 {
                if !(0.0..=n).contains(&w.o[k]) {
                    return Hit::MISS; // runs beside the root, never into it
                }
                t0[k] = f64::NEG_INFINITY;
                t1[k] = f64::INFINITY;
            } else {
                let (near, far) = if w.a >> k & 1 == 1 {
                    (n, 0.0)
                } else {
                    (0.0, n)
                };
                t0[k] = (near - w.o[k]) * w.inv[k];
                t1[k] = (far - w.o[k]) * w.inv[k];
            }
        }
        self.visit::<ANY>(0, [0.0; 3], n, t0, t1, &mut w, c);
        w.best
    }

    fn walk_state(&self, ray: &Ray, shear: RayShear) -> Walk {
        let o: [f64; 3] =
            std::array::from_fn(|k| (ray.origin[k] as f64 - self.root_min[k]) * self.scale);
        let d: [f64; 3] = std::array::from_fn(|k| ray.dir[k] as f64 * self.scale);
        let inv = std::array::from_fn(|k| if d[k] != 0.0 { 1.0 / d[k] } else { 0.0 });
        let a = (0..3).filter(|&k| d[k] < 0.0).map(|k| 1 << k).sum();
        Walk {
            shear,
            o,
            d,
            inv,
            a,
            tmin: ray.tmin,
            tmax: ray.tmax,
            best: Hit::MISS,
        }
    }

    /// Revelles' `proc_subtree`: enters node `idx` (cell with lowest corner `lo` and edge
    /// `size`, ray parameters `t0`/`t1` per axis, in the mirrored frame). Returns `true` when
    /// the walk is finished (a final hit was found).
    #[allow(clippy::too_many_arguments)]
    fn visit<const ANY: bool>(
        &self,
        idx: u32,
        lo: [f64; 3],
        size: f64,
        t0: [f64; 3],
        t1: [f64; 3],
        w: &mut Walk,
        c: &mut Counters,
    ) -> bool {
        c.nodes_visited += 1;
        let tin = t0[0].max(t0[1]).max(t0[2]);
        let tout = t1[0].min(t1[1]).min(t1[2]);
        if tin > tout || tout < w.tmin as f64 || tin > w.limit() as f64 {
            return false;
        }
        let Some(node) = self.nodes.get(idx as usize) else {
            return false; // never: indices are made by the build
        };
        match *node {
            Node::Leaf { first, count } => {
                c.leaves_visited += 1;
                if count == 0 {
                    return false;
                }
                let (first, count) = (first as usize, count as usize);
                let Some(list) = self.refs.get(first..first + count) else {
                    return false;
                };
                if self.test_leaf::<ANY>(list, w, c) {
                    return true;
                }
                // A hit no later than this leaf's exit is final.
                w.best.is_hit() && w.best.t as f64 <= tout
            }
            Node::Internal(children) => {
                let half = size * 0.5;
                let tm: [f64; 3] = std::array::from_fn(|k| {
                    let mid = lo[k] + half;
                    if w.d[k] != 0.0 {
                        (mid - w.o[k]) * w.inv[k]
                    } else if w.o[k] >= mid {
                        f64::NEG_INFINITY
                    } else {
                        f64::INFINITY
                    }
                });
                // first_node: past the mid-plane of axis k at the start => upper (mirrored) half.
                let start = tin.max(w.tmin as f64);
                let mut ch = (0..3)
                    .filter(|&k| tm[k] < start)
                    .map(|k| 1usize << k)
                    .sum::<usize>();
                loop {
                    let bit = |k: usize| ch >> k & 1 == 1;
                    let ct0: [f64; 3] = std::array::from_fn(|k| if bit(k) { tm[k] } else { t0[k] });
                    let ct1: [f64; 3] = std::array::from_fn(|k| if bit(k) { t1[k] } else { tm[k] });
                    let actual = ch ^ w.a;
                    let clo: [f64; 3] = std::array::from_fn(|k| {
                        if actual >> k & 1 == 1 {
                            lo[k] + half
                        } else {
                            lo[k]
                        }
                    });
                    if self.visit::<ANY>(children[actual], clo, half, ct0, ct1, w, c) {
                        return true;
                    }
                    // new_node: leave the child across its nearest exit plane.
                    let mut axis = 0;
                    for k in 1..3 {
                        if ct1[k] < ct1[axis] {
                            axis = k;
                        }
                    }
                    if bit(axis) {
                        return false; // that plane is the node's own exit
                    }
                    ch |= 1 << axis;
                }
            }
        }
    }

    /// Tests the triangles `list` (four at a time), keeping the closest hit in `w.best`.
    /// Returns `true` if `ANY` and a hit was found.
    fn test_leaf<const ANY: bool>(&self, list: &[u32], w: &mut Walk, c: &mut Counters) -> bool {
        c.triangles_tested += list.len() as u64;
        for chunk in list.chunks(4) {
            let tri = |l: usize| {
                let r = chunk[l.min(chunk.len() - 1)] as usize;
                self.tris.get(r).unwrap_or(&DEGENERATE)
            };
            let (mask, t) = w
                .shear
                .intersect4([tri(0), tri(1), tri(2), tri(3)], w.tmin, w.limit());
            if mask == 0 {
                continue;
            }
            for (l, &tl) in t.iter().enumerate().take(chunk.len()) {
                if mask >> l & 1 == 1 && (!w.best.is_hit() || tl < w.best.t) {
                    w.best = Hit {
                        t: tl,
                        prim: self
                            .prim
                            .get(chunk[l] as usize)
                            .copied()
                            .unwrap_or(u32::MAX),
                    };
                    if ANY {
                        return true;
                    }
                }
            }
        }
        false
    }
}

/// Never hit (no area); stands in for an index that cannot occur.
const DEGENERATE: [[f32; 3]; 3] = [[0.0; 3]; 3];

impl Accelerator for ClassicOctree {
    fn stats(&self) -> &StructureStats {
        &self.stats
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        self.trace::<false>(ray, c)
    }

    fn occluded(&self, ray: &Ray, c: &mut Counters) -> bool {
        self.trace::<true>(ray, c).is_hit()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compare::bvh::tests::{
        check_against_brute, flat_grid, rng_tri, test_rays, triangles,
    };
    use crate::mesh::Mesh;
    use crate::rays::SplitMix64;

    fn opts(leaf_size: u32, max_depth: u32) -> BuildOptions {
        BuildOptions {
            max_depth,
            leaf_size,
            merge: true,
        }
    }

    /// The mesh whose non-degenerate triangles are `t` (primitive ids renumbered).
    fn mesh_of(t: &Triangles) -> Mesh {
        Mesh {
            positions: t.v.iter().flatten().copied().collect(),
            triangles: (0..t.len() as u32)
                .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
                .collect(),
        }
    }

    /// Builds the octree, checks its node and pointer counts against OAVM's, and every answer
    /// for a few thousand rays against brute force.
    fn check(t: &Triangles, o: &BuildOptions) -> ClassicOctree {
        let oct = ClassicOctree::build(t, o);
        let (_, s) = crate::build::build(&mesh_of(t), o, &crate::build::Quiet).expect("OAVM build");
        assert_eq!(oct.stats().nodes, s.nodes, "nodes");
        assert_eq!(
            oct.stats().pointers,
            s.pointers.pointer_octree_total,
            "pointers"
        );
        assert_eq!(oct.counts(), (s.internal_nodes, s.solid_leaves));
        let hits = check_against_brute(&oct, t, &test_rays(t, 3000, 11));
        assert!(hits > 0, "the test rays should hit something");
        oct
    }

    fn soup(n: usize, scale: f32, seed: u64) -> Triangles {
        let mut rng = SplitMix64::new(seed);
        triangles((0..n).map(|_| rng_tri(&mut rng, scale)).collect())
    }

    #[test]
    fn empty_misses_everything() {
        for t in [
            triangles(vec![]),
            triangles(vec![[[0.0; 3], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]]),
            triangles(vec![[
                [f32::NAN, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
            ]]),
        ] {
            let oct = ClassicOctree::build(&t, &BuildOptions::default());
            let mut c = Counters::default();
            let r = Ray::new([0.1, 0.1, 5.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
            assert_eq!(oct.intersect(&r, &mut c), Hit::MISS);
            assert!(!oct.occluded(&r, &mut c));
            assert_eq!(oct.stats().nodes, 0);
        }
    }

    #[test]
    fn single_triangle_is_one_leaf() {
        let t = triangles(vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
        let oct = check(&t, &BuildOptions::default());
        assert_eq!(oct.stats().nodes, 1);
        assert_eq!(oct.stats().pointers, 1);
        let mut c = Counters::default();
        let r = Ray::new([0.25, 0.25, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(oct.intersect(&r, &mut c), Hit { t: 2.0, prim: 0 });
        assert_eq!(
            (c.nodes_visited, c.leaves_visited, c.triangles_tested),
            (1, 1, 1)
        );
    }

    #[test]
    fn random_soups_agree_with_brute_force_and_oavm_counts() {
        for (n, scale, seed, k, d) in [
            (10, 3.0, 1, 1, 16),
            (200, 2.0, 2, 4, 16),
            (2000, 1.0, 3, 8, 16),
            (2000, 1.0, 4, 32, 16),
            (2000, 1.0, 5, 2, 3),
        ] {
            let t = soup(n, scale, seed);
            let oct = check(&t, &opts(k, d));
            assert!(
                oct.counts().0 > 0,
                "{n} triangles, K = {k}: the tree should be split"
            );
        }
    }

    #[test]
    fn triangles_on_cell_faces() {
        // A flat grid in z = 0: the root cube is centred on it, so the mesh lies in the root's
        // mid-plane, and the grid lines fall on cell faces along x and y (20 cells a side, the
        // root's centre at 10). Rays along the plane, through grid lines and vertices.
        let t = flat_grid(20);
        let oct = check(&t, &opts(4, 16));
        let mut c = Counters::default();
        for i in 0..=40 {
            let x = i as f32 * 0.5;
            for r in [
                Ray::new([x, 10.0, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY),
                Ray::new([x, x, -1.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY),
                Ray::new([-1.0, x, 0.0], [1.0, 0.0, 0.0], 0.0, f32::INFINITY),
                Ray::new([x, 10.0, 0.0], [0.0, -1.0, 0.0], 0.0, f32::INFINITY),
                Ray::new([10.0, 10.0, 0.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY),
            ] {
                let want = crate::geom::brute::intersect(&mesh_of(&t), &r);
                let got = oct.intersect(&r, &mut c);
                assert_eq!(got.is_hit(), want.is_hit(), "{r:?}");
                assert_eq!(oct.occluded(&r, &mut c), want.is_hit(), "{r:?}");
            }
        }
        // Boxes of axis-aligned quads on the faces of cells of several levels: a cube made of
        // 12 triangles with corners on lattice planes of the root, nested.
        let mut v = Vec::new();
        for s in [8.0f32, 4.0, 2.0, 1.0] {
            let c = [[-s, -s, -s], [s, -s, -s], [s, s, -s], [-s, s, -s]];
            let top = c.map(|p| [p[0], p[1], s]);
            v.push([c[0], c[1], c[2]]);
            v.push([c[0], c[2], c[3]]);
            v.push([top[0], top[2], top[1]]);
            v.push([top[0], top[3], top[2]]);
            for e in 0..4 {
                let f = (e + 1) % 4;
                v.push([c[e], c[f], top[f]]);
                v.push([c[e], top[f], top[e]]);
            }
        }
        let t = triangles(v);
        check(&t, &opts(2, 8));
    }

    #[test]
    fn rays_starting_inside_and_axis_parallel() {
        let t = soup(1000, 1.5, 21);
        let oct = check(&t, &opts(4, 16));
        let mut rng = SplitMix64::new(3);
        let mut rays = Vec::new();
        for _ in 0..2000 {
            let o: [f32; 3] =
                std::array::from_fn(|k| t.min[k] + (t.max[k] - t.min[k]) * rng.next_f64() as f32);
            let mut d = [0f32; 3];
            let a = (rng.next_u64() % 3) as usize;
            d[a] = if rng.next_u64().is_multiple_of(2) {
                1.0
            } else {
                -1.0
            };
            if rng.next_u64().is_multiple_of(2) {
                d[(a + 1) % 3] = rng.next_f64() as f32 - 0.5;
            }
            rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
        }
        assert!(check_against_brute(&oct, &t, &rays) > 100);
    }

    #[test]
    fn closest_hit_stops_early() {
        // A stack of parallel planes: a ray straight through should not visit every leaf.
        let mut v = Vec::new();
        for z in 0..64 {
            let z = z as f32;
            v.push([[0.0, 0.0, z], [10.0, 0.0, z], [0.0, 10.0, z]]);
        }
        let t = triangles(v);
        let oct = check(&t, &opts(1, 10));
        let r = Ray::new([1.0, 1.0, -1.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY);
        let mut c = Counters::default();
        assert_eq!(oct.intersect(&r, &mut c), Hit { t: 1.0, prim: 0 });
        assert!(c.triangles_tested < 8, "{c:?}");
        let mut c2 = Counters::default();
        let r = Ray::new([1.0, 1.0, 70.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(oct.intersect(&r, &mut c2), Hit { t: 7.0, prim: 63 });
        assert!(c2.triangles_tested < 8, "{c2:?}");
    }
}
