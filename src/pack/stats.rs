//! What the builder made: node, leaf, volume and pointer counts (counting conventions in
//! `format-spec.md` §9), for `oavm-pack`'s report.

use serde::Serialize;

use crate::physical::writer::UnitRef;

/// Stored pointers and offsets, against what a classic pointer octree over the same subdivision
/// stores (counting conventions in `format-spec.md` §9).
#[derive(Clone, Debug, Default, Serialize)]
pub struct PointerCounts {
    /// Child pointers stored: none, children are found by rank.
    pub child_pointers: u64,
    /// Rank directory entries (one per 64 nodes of a level).
    pub rank_entries: u64,
    /// Offsets from leaves into other sections: first reference of each solid leaf, volume index
    /// of each empty leaf.
    pub leaf_offsets: u64,
    pub total: u64,
    /// A pointer octree: 8 child pointers per internal node.
    pub pointer_octree_child_pointers: u64,
    /// A pointer octree: one triangle-list pointer per solid leaf.
    pub pointer_octree_leaf_offsets: u64,
    pub pointer_octree_total: u64,
}

/// What the builder made, for `oavm-pack`'s report.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BuildStats {
    pub input_triangles: u64,
    /// Triangles stored (the input minus degenerate ones, which no ray can hit).
    pub triangles: u64,
    pub degenerate_triangles: u64,
    pub depth: u32,
    pub nodes_per_level: Vec<u64>,
    pub nodes: u64,
    pub internal_nodes: u64,
    pub empty_leaves: u64,
    pub solid_leaves: u64,
    pub volumes: u64,
    /// Empty leaves per volume (1 without merging).
    pub empty_leaves_per_volume: f64,
    pub refs: u64,
    pub refs_per_triangle: f64,
    pub pointers: PointerCounts,
    pub build_seconds: f64,
    pub merge_seconds: f64,
    pub layout_seconds: f64,
}

/// Counts over a tree, or over the pieces the streaming builder makes and the top above them.
#[derive(Clone, Debug, Default)]
pub struct TreeCounts {
    /// Nodes per absolute level.
    pub nodes_per_level: Vec<u64>,
    pub internal: u64,
    pub empty: u64,
    pub solid: u64,
    pub volumes: u64,
    pub refs: u64,
    pub rank_entries: u64,
}

impl TreeCounts {
    /// Adds a unit whose level 0 is absolute level `base`, with its leaf counts.
    pub fn add(&mut self, unit: UnitRef<'_>, base: u32, empty: u64, solid: u64) {
        for (i, lv) in unit.levels.iter().enumerate() {
            let l = base as usize + i;
            if self.nodes_per_level.len() <= l {
                self.nodes_per_level.resize(l + 1, 0);
            }
            self.nodes_per_level[l] += lv.node_count;
            self.internal += lv.internal_count;
        }
        self.empty += empty;
        self.solid += solid;
        self.volumes += unit.volumes.len() as u64;
        self.refs += unit.refs.len() as u64;
        self.rank_entries += unit.ranks.len() as u64;
    }

    /// Adds another's counts.
    pub fn add_counts(&mut self, other: &TreeCounts) {
        if self.nodes_per_level.len() < other.nodes_per_level.len() {
            self.nodes_per_level.resize(other.nodes_per_level.len(), 0);
        }
        for (a, b) in self.nodes_per_level.iter_mut().zip(&other.nodes_per_level) {
            *a += b;
        }
        self.internal += other.internal;
        self.empty += other.empty;
        self.solid += other.solid;
        self.volumes += other.volumes;
        self.refs += other.refs;
        self.rank_entries += other.rank_entries;
    }
}

/// Seconds of the build's phases.
#[derive(Clone, Copy, Debug, Default)]
pub struct PhaseSeconds {
    pub build: f64,
    pub merge: f64,
    pub layout: f64,
}

impl BuildStats {
    /// The statistics of a tree of `counts` built from `input` triangles of which `stored`
    /// were kept.
    pub fn new(counts: &TreeCounts, input: u64, stored: u64, seconds: PhaseSeconds) -> BuildStats {
        let c = counts;
        let leaf_offsets = c.empty + c.solid;
        let pointers = PointerCounts {
            child_pointers: 0,
            rank_entries: c.rank_entries,
            leaf_offsets,
            total: c.rank_entries + leaf_offsets,
            pointer_octree_child_pointers: 8 * c.internal,
            pointer_octree_leaf_offsets: c.solid,
            pointer_octree_total: 8 * c.internal + c.solid,
        };
        BuildStats {
            input_triangles: input,
            triangles: stored,
            degenerate_triangles: input - stored,
            depth: (c.nodes_per_level.len() as u32).saturating_sub(1),
            nodes_per_level: c.nodes_per_level.clone(),
            nodes: c.nodes_per_level.iter().sum(),
            internal_nodes: c.internal,
            empty_leaves: c.empty,
            solid_leaves: c.solid,
            volumes: c.volumes,
            empty_leaves_per_volume: if c.volumes == 0 {
                0.0
            } else {
                c.empty as f64 / c.volumes as f64
            },
            refs: c.refs,
            refs_per_triangle: if stored == 0 {
                0.0
            } else {
                c.refs as f64 / stored as f64
            },
            pointers,
            build_seconds: seconds.build,
            merge_seconds: seconds.merge,
            layout_seconds: seconds.layout,
        }
    }
}
