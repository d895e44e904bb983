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
