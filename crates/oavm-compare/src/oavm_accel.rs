//! OAVM itself behind the comparison's interface: the bytes a file holds, made in memory.

use super::{Accelerator, StructureStats};
use crate::Counters;
use oavm::error::Error;
use oavm::geom::{Hit, Ray};
use oavm::logical::{Scene, SceneOptions, Walk};
use oavm::mesh::Mesh;
use oavm::pack::BuildOptions;
use oavm::physical::{AlignedBytes, OavmFile};

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
        let (parts, s) = oavm::pack::build(mesh, opts, &oavm::pack::Quiet)?;
        let mut bytes = oavm::pack::encode(&parts)?;
        let mut pointers = s.pointers.total;
        if walk == Walk::Ropes {
            let plain = OavmFile::open(bytes).map_err(|e| Error::format("memory", e))?;
            let (roped, _, report) = oavm::pack::ropes::add_ropes(&plain, Vec::new())?;
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
                Walk::Wide => "oavm:wide",
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
        self.walked(Walk::TopDown)
    }

    /// Another scene over a copy of the same bytes, walked by `walk` (a scene's walk is chosen
    /// when it is opened: [`oavm::logical::SceneOptions::walk`]).
    pub fn walked(&self, walk: Walk) -> Result<OavmAccel, Error> {
        let scene = Scene::from_bytes_with(
            AlignedBytes::from_slice(self.scene.file().bytes()),
            "memory",
            &SceneOptions {
                walk,
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
        let (roped, _, report) = oavm::pack::ropes::add_ropes(self.scene.file(), Vec::new())?;
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
        params: &oavm::pack::occluders::ShadowParams,
    ) -> Result<(OavmAccel, oavm::pack::occluders::OccluderReport), Error> {
        let (bytes, _, report) =
            oavm::pack::occluders::add_occluders(self.scene.file(), params, Vec::new())?;
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

    /// Any hit by the scene's walk (another walk: [`Self::walked`]; a leaf-to-leaf walk by
    /// ropes needs a file with them: [`Self::with_ropes`]), the top-down walk taking children in
    /// the SATO order if `sato` ([`oavm::logical::Tree::sato`]) and testing the occluders of the
    /// nodes it enters if `occluders` (and the file has them, [`oavm::logical::Tree::occluders`]).
    pub fn occluded_walk(&self, ray: &Ray, sato: bool, occluders: bool, c: &mut Counters) -> bool {
        let tree = self.scene.tree().sato(sato).occluders(occluders);
        let mut walked = oavm::Counters::default();
        let hit = tree.occluded(ray, &mut walked);
        count(c, &walked);
        matches!(hit, Ok(true))
    }
}

/// Adds what OAVM's tracer counted for one ray to `c`: not the ray (the batch counts the rays);
/// its nodes with the clusters' (see [`Accelerator`] below).
fn count(c: &mut Counters, walked: &oavm::Counters) {
    *c += Counters {
        rays: 0,
        nodes_visited: walked.nodes_visited + walked.cluster_nodes_visited,
        ..Counters::from(walked)
    };
}

/// The comparison counts every node a structure's traversal visits: for a file of clusters,
/// the octree's nodes and the clusters' BVH nodes together (a BVH's inner nodes are what the
/// other structures' node counts are), so `nodes_visited` also takes `cluster_nodes_visited`.
impl Accelerator for OavmAccel {
    fn stats(&self) -> &StructureStats {
        &self.stats
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        let mut walked = oavm::Counters::default();
        let hit = self.scene.tree().intersect(ray, &mut walked);
        count(c, &walked);
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
        let mut walked = oavm::Counters::default();
        let hit = self.scene.tree().occluded(ray, &mut walked);
        count(c, &walked);
        matches!(hit, Ok(true))
    }
}
