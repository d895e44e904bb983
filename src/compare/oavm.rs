//! OAVM itself behind the comparison's interface: the bytes a file holds, made in memory.

use super::{Accelerator, StructureStats};
use crate::build::BuildOptions;
use crate::error::Error;
use crate::geom::{Hit, Ray};
use crate::logical::{Counters, Scene};
use crate::mesh::Mesh;
use crate::physical::AlignedBytes;

/// OAVM packed in memory (the same bytes a file holds), behind the common interface.
pub struct OavmAccel {
    scene: Scene<AlignedBytes>,
    stats: StructureStats,
}

impl OavmAccel {
    pub fn build(mesh: &Mesh, opts: &BuildOptions) -> Result<OavmAccel, Error> {
        let t = std::time::Instant::now();
        let (parts, s) = crate::build::build(mesh, opts, &crate::build::Quiet)?;
        let bytes = crate::build::encode(&parts)?;
        let build_seconds = t.elapsed().as_secs_f64();
        let scene = Scene::from_bytes(bytes, "memory")?;
        let stats = StructureStats {
            name: "oavm",
            build_seconds,
            nodes: s.nodes,
            pointers: s.pointers.total,
            bytes: scene.file().bytes().len() as u64,
        };
        Ok(OavmAccel { scene, stats })
    }

    pub fn scene(&self) -> &Scene<AlignedBytes> {
        &self.scene
    }
}

/// The comparison counts every node a structure's traversal visits: for a file of clusters,
/// the octree's nodes and the clusters' BVH nodes together (a BVH's inner nodes are what the
/// other structures' node counts are), so `nodes_visited` also takes `cluster_nodes_visited`.
impl Accelerator for OavmAccel {
    fn stats(&self) -> &StructureStats {
        &self.stats
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        let (rays, before) = (c.rays, c.cluster_nodes_visited); // the batch counts the rays
        let hit = self.scene.tree().intersect(ray, c);
        c.rays = rays;
        c.nodes_visited += c.cluster_nodes_visited - before;
        match hit {
            Ok(Some(h)) => Hit {
                t: h.t,
                prim: h.prim,
            },
            // The bytes were made in this process; a corruption here is a bug, reported as a miss
            // by the answer and loudly by the cross-checks of `oavm-bench`.
            _ => Hit::MISS,
        }
    }

    fn occluded(&self, ray: &Ray, c: &mut Counters) -> bool {
        let (rays, before) = (c.rays, c.cluster_nodes_visited);
        let hit = self.scene.tree().occluded(ray, c);
        c.rays = rays;
        c.nodes_visited += c.cluster_nodes_visited - before;
        matches!(hit, Ok(true))
    }
}

#[cfg(test)]
mod top_bounds_tests {
    use super::*;
    use crate::compare::Accelerator;
    use crate::compare::test_util::{check, tris_of, unit_rays, unit_soup};
    use crate::logical::{Counters, top_bounds};
    use crate::physical::format::{LATTICE_SIZE, SectionKind};

    /// A slab of triangles (the unit soup squashed to a tenth in y and z): the root cube is the
    /// slab's x extent on every axis, so the root's box must be about a tenth of it in y and z,
    /// hold every vertex, and the traversal that culls by the boxes must still find every hit
    /// brute force finds.
    #[test]
    fn boxes_hold_every_vertex_and_cull_nothing_they_should_not() {
        let slab: Vec<_> = unit_soup(5_000, 7)
            .into_iter()
            .map(|t| t.map(|v| [v[0], 0.45 + 0.1 * v[1], 0.45 + 0.1 * v[2]]))
            .collect();
        let (_, mesh) = tris_of(slab);
        let opts = BuildOptions {
            leaf_size: 8,
            ..BuildOptions::default()
        };
        let acc = OavmAccel::build(&mesh, &opts).unwrap();
        let scene = acc.scene();
        let h = scene.file().header();
        let tree = scene.tree();
        let top = tree.map();
        assert!(
            top.level_count() > 2,
            "the top tree must have internal nodes to test"
        );
        let boxes = top_bounds(top, scene.file().records(SectionKind::LinkBounds));
        let (lo, hi) = boxes[0];
        let scale = LATTICE_SIZE as f64 / h.root_size;
        for v in &mesh.positions {
            for k in 0..3 {
                let p = (v[k] as f64 - h.root_min[k]) * scale;
                assert!(
                    lo[k] <= p && p <= hi[k],
                    "vertex {v:?} outside the root's box"
                );
            }
        }
        let n = LATTICE_SIZE as f64;
        for k in 1..3 {
            assert!(hi[k] - lo[k] < 0.2 * n, "axis {k}: {lo:?} {hi:?}");
        }
        // Some internal node below the root is culled by its box for rays that pass beside
        // the slab, and none of the answers changes.
        let rays = unit_rays(8_000, 3);
        check(&acc as &dyn Accelerator, &mesh, &rays, 80);
        let mut c = Counters::default();
        for r in &rays {
            let _ = tree.intersect(r, &mut c);
        }
        assert!(c.top_nodes_culled > 0, "{c:?}");
    }
}
