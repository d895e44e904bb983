//! The work the comparison's walks count, summed over a batch of rays: the figures `oavm-bench`
//! reports per ray. The structures of this crate count into it directly; OAVM's tracer counts
//! into `oavm::Counters` (which has much more: culling, clusters, paging, streams), taken over
//! by [`From`] for [`crate::OavmAccel`].

use serde::Serialize;

/// Work counters of a batch of rays through a comparison structure (summed over its rays). The
/// field names are those of `oavm::Counters` for what both count.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counters {
    pub rays: u64,
    /// Nodes visited: what each structure's module docs call a node (for OAVM, the octree's
    /// node records and its clusters' BVH nodes together).
    pub nodes_visited: u64,
    /// Leaves (cells) entered.
    pub leaves_visited: u64,
    /// Ray–triangle tests.
    pub triangles_tested: u64,
    /// Walks begun again from a node above the last one (the KD-tree's kd-restart, push-down
    /// and short-stack traversals: each time the rest of the ray is walked down again; its rope
    /// walks count each rope taken here).
    pub restarts: u64,
    /// Ropes followed by OAVM's leaf-to-leaf walk by ropes, and links followed by the
    /// KD-tree's adjacency walk (the multi-index tree's shadow rays).
    pub ropes_followed: u64,
    /// Triangles tested at inner nodes by the shadow-ray walk of a primitive index (the
    /// multi-index tree of Liang and Huang, and OAVM's occluders; also counted in
    /// `triangles_tested`).
    pub promoted_tested: u64,
}

impl std::ops::AddAssign for Counters {
    fn add_assign(&mut self, o: Counters) {
        self.rays += o.rays;
        self.nodes_visited += o.nodes_visited;
        self.leaves_visited += o.leaves_visited;
        self.triangles_tested += o.triangles_tested;
        self.restarts += o.restarts;
        self.ropes_followed += o.ropes_followed;
        self.promoted_tested += o.promoted_tested;
    }
}

impl std::ops::Add for Counters {
    type Output = Counters;
    fn add(mut self, o: Counters) -> Counters {
        self += o;
        self
    }
}

/// What OAVM's tracer counted, field for field where both count the same thing. OAVM's walks
/// never begin again from above: `restarts` is 0. Its `nodes_visited` is the octree's alone;
/// [`crate::OavmAccel`] adds the clusters' nodes, as the comparison counts them.
impl From<&oavm::Counters> for Counters {
    fn from(c: &oavm::Counters) -> Counters {
        Counters {
            rays: c.rays,
            nodes_visited: c.nodes_visited,
            leaves_visited: c.leaves_visited,
            triangles_tested: c.triangles_tested,
            restarts: 0,
            ropes_followed: c.ropes_followed,
            promoted_tested: c.promoted_tested,
        }
    }
}
