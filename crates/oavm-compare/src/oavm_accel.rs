//! OAVM itself behind the comparison's interface: the bytes a file holds, made in memory.

use super::{Accelerator, StructureStats};
use crate::error::Error;
use crate::geom::{Hit, Ray};
use crate::logical::{Counters, Scene, SceneOptions, Walk};
use crate::mesh::Mesh;
use crate::pack::BuildOptions;
use crate::physical::format::SectionKind;
use crate::physical::{AlignedBytes, OavmFile};

/// OAVM packed in memory (the same bytes a file holds), behind the common interface.
pub struct OavmAccel {
    scene: Scene<AlignedBytes>,
    stats: StructureStats,
}

impl OavmAccel {
    pub fn build(mesh: &Mesh, opts: &BuildOptions) -> Result<OavmAccel, Error> {
        Self::build_walk(mesh, opts, Walk::Auto)
    }

    /// OAVM walked by `walk`; [`Walk::Ropes`] adds ropes to the file (their time counts in
    /// the build, their six pointers per leaf and link in the pointers).
    pub fn build_walk(mesh: &Mesh, opts: &BuildOptions, walk: Walk) -> Result<OavmAccel, Error> {
        let t = std::time::Instant::now();
        let (parts, s) = crate::pack::build(mesh, opts, &crate::pack::Quiet)?;
        let mut bytes = crate::pack::encode(&parts)?;
        let mut pointers = s.pointers.total;
        if walk == Walk::Ropes {
            let plain = OavmFile::open(bytes).map_err(|e| Error::format("memory", e))?;
            let (roped, _, report) = crate::pack::ropes::add_ropes(&plain, Vec::new())?;
            bytes = AlignedBytes::from_slice(&roped);
            pointers += report.ropes;
        }
        let build_seconds = t.elapsed().as_secs_f64();
        let scene = Scene::from_bytes_with(
            bytes,
            "memory",
            &SceneOptions {
                walk,
                ..SceneOptions::default()
            },
        )?;
        let stats = StructureStats {
            name: match walk {
                Walk::Neighbours => "oavm:morton",
                Walk::Ropes => "oavm:ropes",
                Walk::TopDown | Walk::Auto => "oavm",
            },
            build_seconds,
            nodes: s.nodes,
            pointers,
            bytes: scene.file().bytes().len() as u64,
        };
        Ok(OavmAccel { scene, stats })
    }

    pub fn scene(&self) -> &Scene<AlignedBytes> {
        &self.scene
    }

    /// Another scene over a copy of the same bytes, walked top-down.
    pub fn clone_scene(&self) -> Result<OavmAccel, Error> {
        let scene = Scene::from_bytes_with(
            AlignedBytes::from_slice(self.scene.file().bytes()),
            "memory",
            &SceneOptions {
                walk: Walk::TopDown,
                ..SceneOptions::default()
            },
        )?;
        Ok(OavmAccel {
            scene,
            stats: self.stats.clone(),
        })
    }

    /// The same file with ropes added (spec §8.4), and what adding them cost: the pass's
    /// seconds and the bytes added.
    pub fn with_ropes(&self) -> Result<(OavmAccel, f64, u64), Error> {
        let t = std::time::Instant::now();
        let (roped, _, report) = crate::pack::ropes::add_ropes(self.scene.file(), Vec::new())?;
        let seconds = t.elapsed().as_secs_f64();
        let added = (roped.len() as u64).saturating_sub(self.scene.file().bytes().len() as u64);
        let scene = Scene::from_bytes_with(
            AlignedBytes::from_slice(&roped),
            "memory",
            &SceneOptions {
                walk: Walk::Ropes,
                ..SceneOptions::default()
            },
        )?;
        let stats = StructureStats {
            name: "oavm:ropes",
            build_seconds: self.stats.build_seconds + seconds,
            pointers: self.stats.pointers + report.ropes,
            bytes: scene.file().bytes().len() as u64,
            ..self.stats.clone()
        };
        Ok((OavmAccel { scene, stats }, seconds, added))
    }

    /// The same file with occluders added (spec §8.5) as `params` choose them, and what the
    /// pass reported.
    pub fn with_occluders(
        &self,
        params: &crate::pack::occluders::ShadowParams,
    ) -> Result<(OavmAccel, crate::pack::occluders::OccluderReport), Error> {
        let (bytes, _, report) =
            crate::pack::occluders::add_occluders(self.scene.file(), params, Vec::new())?;
        let scene = Scene::from_bytes_with(
            AlignedBytes::from_slice(&bytes),
            "memory",
            &SceneOptions {
                walk: Walk::TopDown,
                ..SceneOptions::default()
            },
        )?;
        let stats = StructureStats {
            build_seconds: self.stats.build_seconds + report.seconds,
            bytes: scene.file().bytes().len() as u64,
            ..self.stats.clone()
        };
        Ok((OavmAccel { scene, stats }, report))
    }

    /// Any hit by `walk` (a leaf-to-leaf walk by ropes needs a file with them: [`Self::with_ropes`]),
    /// the top-down walk taking children in the SATO order if `sato` ([`crate::logical::Tree::sato`])
    /// and testing the occluders of the nodes it enters if `occluders` (and the file has them,
    /// [`crate::logical::Tree::occluders`]).
    pub fn occluded_walk(
        &self,
        ray: &Ray,
        walk: Walk,
        sato: bool,
        occluders: bool,
        c: &mut Counters,
    ) -> bool {
        let ropes = self.scene.file().records(SectionKind::Ropes);
        let tree = self
            .scene
            .tree()
            .walking(walk, ropes)
            .sato(sato)
            .occluders(occluders);
        let before = self.count_start(c);
        let hit = tree.occluded(ray, c);
        self.count_end(c, before);
        matches!(hit, Ok(true))
    }

    fn count_start(&self, c: &Counters) -> (u64, u64) {
        (c.rays, c.cluster_nodes_visited)
    }

    /// The batch counts the rays; nodes include the clusters' (see [`Accelerator`] below).
    fn count_end(&self, c: &mut Counters, (rays, before): (u64, u64)) {
        c.rays = rays;
        c.nodes_visited += c.cluster_nodes_visited - before;
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
        let before = self.count_start(c);
        let hit = self.scene.tree().occluded(ray, c);
        self.count_end(c, before);
        matches!(hit, Ok(true))
    }
}
