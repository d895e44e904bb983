//! The structures the OAVM paper compares against (its Table 2 and Figs. 7-8), built from the same
//! triangles and queried through the same interface as OAVM's tracer, so that one benchmark can
//! run the same rays through all of them (`oavm-bench`, this crate's binary).
//!
//! Research code beside the product: this crate depends on the library `oavm` (the store, its
//! builder and tracer), which knows nothing of it. A user of the store needs none of this.
//!
//! - [`grid`]: uniform grid, 3D-DDA traversal (Amanatides & Woo 1987);
//! - [`kdtree`]: the paper's "improved KD-tree": SAH splits with empty-space cut-off, stack
//!   traversal;
//! - [`octree`]: the classic octree: OAVM's subdivision, no merging, child pointers, ordinary
//!   traversal;
//! - [`bvh`]: a binned-SAH BVH, the modern reference (pbrt-v4's BVH is the bar for quality);
//! - [`OavmAccel`]: OAVM itself, packed in memory.
//!
//! Each of the four is a folder: `node.rs` (the records traversal reads), `build.rs`,
//! `traverse.rs` (which finds the leaves a ray crosses and knows nothing of triangles) and
//! `tests.rs`. Below their traversals they share [`leaf`]: the triangles, the test of a leaf's
//! triangles with the watertight kernel of [`oavm::geom`], and the [`Accelerator`] plumbing.
//! [`bench`] is the comparison itself, which `oavm-bench` runs. They live in memory; only OAVM
//! has a file format. Each reports its size with the counting conventions written in its module
//! docs, and its work in this crate's [`Counters`].

mod aabb;
pub mod bench;
pub mod bvh;
mod counters;
pub mod grid;
pub mod kdtree;
mod leaf;
mod oavm_accel;
pub mod octree;
pub mod shadow;
#[cfg(test)]
mod test_util;

pub use counters::Counters;
pub use oavm_accel::OavmAccel;

use rayon::prelude::*;
use serde::Serialize;

use oavm::error::Error;
use oavm::geom::triangle::is_degenerate;
use oavm::geom::{Hit, Ray};
use oavm::mesh::Mesh;
use oavm::pack::BuildOptions;

/// Size of a built structure. What a "node" and a "pointer" are for each structure is written in
/// its module documentation, matched to the paper's Table 2 where possible.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StructureStats {
    pub name: &'static str,
    pub build_seconds: f64,
    pub nodes: u64,
    /// Pointers and offsets stored (child pointers, primitive-list pointers).
    pub pointers: u64,
    /// Bytes of the structure in memory, including its triangle data and reference lists.
    pub bytes: u64,
}

/// What every structure answers. Implementations are read-only after build, so a batch runs on
/// rayon with `&self`. They count their work in `c` (nodes visited, leaves visited, triangles
/// tested, as their module docs define them) but not `c.rays`, which the batch counts.
pub trait Accelerator: Send + Sync {
    fn stats(&self) -> &StructureStats;
    /// Closest hit with `tmin <= t <= tmax` (`Hit::MISS` for none, and for invalid rays).
    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit;
    /// Whether any triangle is hit with `tmin <= t <= tmax`; stops at the first found.
    fn occluded(&self, ray: &Ray, c: &mut Counters) -> bool;
}

/// The triangles every structure is built from: the mesh's non-degenerate triangles (as OAVM
/// stores them), with their primitive ids.
#[derive(Clone, Debug, Default)]
pub struct Triangles {
    pub v: Vec<[[f32; 3]; 3]>,
    pub prim: Vec<u32>,
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Triangles {
    pub fn from_mesh(mesh: &Mesh) -> Result<Triangles, Error> {
        let mut t = Triangles {
            min: [f32::INFINITY; 3],
            max: [f32::NEG_INFINITY; 3],
            ..Triangles::default()
        };
        for (i, tri) in mesh.triangles.iter().enumerate() {
            let mut v = [[0f32; 3]; 3];
            for (k, &ix) in tri.iter().enumerate() {
                v[k] = *mesh.positions.get(ix as usize).ok_or_else(|| {
                    Error::Invalid(format!(
                        "triangle {i} refers to vertex {ix}, the mesh has {}",
                        mesh.positions.len()
                    ))
                })?;
            }
            if is_degenerate(&v) {
                continue;
            }
            for p in &v {
                for (k, &c) in p.iter().enumerate() {
                    t.min[k] = t.min[k].min(c);
                    t.max[k] = t.max[k].max(c);
                }
            }
            t.v.push(v);
            t.prim.push(i as u32);
        }
        Ok(t)
    }

    pub fn len(&self) -> usize {
        self.v.len()
    }

    pub fn is_empty(&self) -> bool {
        self.v.is_empty()
    }
}

/// Closest hits of `rays` through `acc` into `out`, on the current rayon pool.
pub fn intersect_batch(acc: &dyn Accelerator, rays: &[Ray], out: &mut [Hit]) -> Counters {
    batch(rays, out, |r, c| acc.intersect(r, c))
}

/// Any-hit answers (1 or 0) of `rays` through `acc` into `out`, on the current rayon pool.
pub fn occluded_batch(acc: &dyn Accelerator, rays: &[Ray], out: &mut [u8]) -> Counters {
    batch(rays, out, |r, c| acc.occluded(r, c) as u8)
}

/// [`occluded_batch`], with the work counted apart for the rays found occluded (`[1]`) and
/// the rays found unoccluded (`[0]`): what the shadow-ray traversals of the multi-index tree
/// (Liang and Huang) are compared by, since an occluded ray may stop at its first hit and an
/// unoccluded one must cross the whole segment.
pub fn occluded_batch_split(acc: &dyn Accelerator, rays: &[Ray], out: &mut [u8]) -> [Counters; 2] {
    rays.par_chunks(256)
        .zip(out.par_chunks_mut(256))
        .map(|(rays, out)| {
            let mut split = [Counters::default(); 2];
            for (r, o) in rays.iter().zip(out) {
                let mut c = Counters {
                    rays: 1,
                    ..Counters::default()
                };
                *o = acc.occluded(r, &mut c) as u8;
                split[*o as usize] += c;
            }
            split
        })
        .reduce(
            || [Counters::default(); 2],
            |a, b| [a[0] + b[0], a[1] + b[1]],
        )
}

fn batch<T: Send>(
    rays: &[Ray],
    out: &mut [T],
    f: impl Fn(&Ray, &mut Counters) -> T + Sync,
) -> Counters {
    rays.par_chunks(256)
        .zip(out.par_chunks_mut(256))
        .map(|(rays, out)| {
            let mut c = Counters::default();
            for (r, o) in rays.iter().zip(out) {
                c.rays += 1;
                *o = f(r, &mut c);
            }
            c
        })
        .reduce(Counters::default, |a, b| a + b)
}

/// The structures `oavm-bench` knows, by name, in the order it reports them.
pub const STRUCTURES: [&str; 5] = ["grid", "kdtree", "octree", "bvh", "oavm"];

/// The KD-tree's traversal variants, by the names `oavm-bench` takes (`kdtree:stack` is the
/// plain `kdtree`; [`kdtree::KdTraversal`]). Not in `all`.
pub const KD_VARIANTS: [&str; 7] = [
    "kdtree:stack",
    "kdtree:restart",
    "kdtree:pushdown",
    "kdtree:shortstack",
    "kdtree:splitstack",
    "kdtree:ropes",
    "kdtree:popov",
];

/// OAVM's walks, by the names `oavm-bench` takes (the plain `oavm` walks files of clusters
/// top-down; [`oavm::logical::Walk`]): `oavm:morton` steps leaf to leaf finding each next
/// leaf from its Morton code (the paper's neighbour step), `oavm:ropes` by the rope of the face
/// it leaves (format-spec §8.4; the file is built with ropes). Not in `all`.
pub const OAVM_VARIANTS: [&str; 2] = ["oavm:morton", "oavm:ropes"];

/// The short stack's size in `kdtree:shortstack` (Horn et al. 2007 used 4 to 8 entries).
pub const SHORT_STACK: usize = 4;

/// Builds the structure called `name` (one of [`STRUCTURES`]) over `mesh` (OAVM and the classic
/// octree take `opts`, the subdivision they share; the others have their own heuristics).
pub fn build_structure(
    name: &str,
    mesh: &Mesh,
    tris: &Triangles,
    opts: &BuildOptions,
) -> Result<Box<dyn Accelerator>, Error> {
    match name {
        "grid" => Ok(Box::new(grid::UniformGrid::build(tris))),
        "kdtree" | "kdtree:stack" => Ok(Box::new(kdtree::KdTree::build(tris))),
        "kdtree:restart" => Ok(Box::new(
            kdtree::KdTree::build(tris).with_traversal(kdtree::KdTraversal::Restart),
        )),
        "kdtree:pushdown" => Ok(Box::new(
            kdtree::KdTree::build(tris).with_traversal(kdtree::KdTraversal::PushDown),
        )),
        "kdtree:ropes" => Ok(Box::new(
            kdtree::KdTree::build(tris).with_traversal(kdtree::KdTraversal::Ropes),
        )),
        "kdtree:splitstack" => Ok(Box::new(
            kdtree::KdTree::build(tris).with_traversal(kdtree::KdTraversal::SplitStack),
        )),
        "kdtree:popov" => Ok(Box::new(
            kdtree::KdTree::build(tris).with_traversal(kdtree::KdTraversal::Popov),
        )),
        "kdtree:shortstack" => Ok(Box::new(
            kdtree::KdTree::build(tris)
                .with_traversal(kdtree::KdTraversal::ShortStack(SHORT_STACK)),
        )),
        "octree" => Ok(Box::new(octree::ClassicOctree::build(tris, opts))),
        "bvh" => Ok(Box::new(bvh::Bvh::build(tris))),
        "oavm" => Ok(Box::new(OavmAccel::build(mesh, opts)?)),
        "oavm:morton" => Ok(Box::new(OavmAccel::build_walk(
            mesh,
            opts,
            oavm::logical::Walk::Neighbours,
        )?)),
        "oavm:ropes" => Ok(Box::new(OavmAccel::build_walk(
            mesh,
            opts,
            oavm::logical::Walk::Ropes,
        )?)),
        _ => Err(Error::Invalid(format!(
            "unknown structure {name:?}: expected one of {}, {}, {}",
            STRUCTURES.join(", "),
            KD_VARIANTS.join(", "),
            OAVM_VARIANTS.join(", ")
        ))),
    }
}
