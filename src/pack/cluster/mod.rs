//! Building one cluster (format 4, spec §7.1–7.2): the compact wide BVH a solid octree leaf
//! carries inside its block, over the triangles referenced by the leaf.
//!
//! **What a cluster must do.** The tracer walks the octree; at a solid leaf it traverses the
//! leaf's cluster, testing the boxes of a node's eight children at once and the triangles of a
//! group eight lanes at once. A ray only needs a cluster to find hits inside the leaf's cell
//! widened by `CELL_MARGIN` (the `clip` box given to [`build_cluster`]): hits outside it belong
//! to another leaf, which references the triangle too. So a child box need not contain its
//! triangles, only their parts inside `clip`: each triangle's box is that of its polygon clipped
//! to `clip` ([`triangle_box`]), which keeps the boxes of a leaf's large triangles (a floor
//! crossing many cells) as small as the cell.
//!
//! **Records** ([`ClusterNode`], 80 bytes, and [`TriGroup`], 160 bytes, in
//! `physical::format`). A node has up to eight children: slots `0..inner_count` are nodes
//! `node_base + i`, the others are groups `group_base + (i - inner_count)`. Child boxes are
//! quantised to 8 bits per face on a per-node, per-axis grid `origin + q * 2^exp`, rounded
//! outward, as Ylitie, Karras and Laine store them ("Efficient Incoherent Ray Traversal on GPUs
//! Through Compressed Wide BVHs", HPG 2017, §3.1), which is what makes a node of eight
//! children 80 bytes instead of 8 × 24. Deviation: we keep a full f32 origin and an exponent per
//! axis (as they do) but require the origin to be a multiple of `2^exp` with few enough
//! significant bits that every face is an exact f32, so the tracer's dequantised box is exactly
//! the box the builder meant, and containment checks ([`check_cluster`]) need no tolerance. A
//! group holds up to eight triangles with at most eight distinct corners, so the kernel loads
//! one row of eight corners per coordinate and permutes them into lanes.
//!
//! **Layout.** Nodes in breadth-first order from the root (`nodes[0]`): the inner children of a
//! node are consecutive and come after every node of its level, so every child's index is
//! greater than its parent's (a traversal never loops, and a checker walks forward); the groups
//! of a node's leaf children are consecutive, in the same breadth-first order.
//!
//! **Build.** Five steps, each O(n log n) in the cluster's triangles with small constants:
//!
//! 1. *Windows.* A binary tree over the triangles by binned SAH (Wald, "On fast Construction
//!    of SAH-based Bounding Volume Hierarchies", IEEE RT 2007, §3: centroids of the triangles'
//!    clipped boxes into up to [`BINS`] equal bins, on all three axes, priced
//!    `A_l n_l + A_r n_r`), top-down, until a node's triangles fit one group (at most eight,
//!    with at most eight distinct corners) or number at most the window size ([`WINDOW`]).
//!    Where binning cannot separate the triangles (equal centroids), and below binary depth
//!    [`SAH_MAX_DEPTH`], a node is split at its median along the longest centroid axis (ties
//!    in input order), so the build always ends and stays O(n log n) on any input.
//! 2. *Groups.* Each window's triangles are formed into groups greedily, by shared corners
//!    ([`group`]); a window that fits is one group.
//! 3. *Tree.* A binary tree over the groups' boxes, by the same binned SAH, down to single
//!    groups.
//! 4. *Wide.* Collapsed to 8-wide: a node takes its binary children and opens the one with the
//!    largest surface area until it has eight (Embree's `BVHBuilderBinnedSAH`, "find best child
//!    with largest bounding box area"). Then groups among its children that together still fit
//!    one group are merged (the pair with the smallest joint box first), and the freed slots are
//!    filled by opening more.
//! 5. Written breadth-first, each node's boxes quantised.
//!
//! **The window size trades bytes for tests.** With a window of 1 this is the plain build
//! (SAH until the triangles fit one group, then merging): the tightest boxes. Larger windows
//! let the greedy grouping pack connected triangles (up to 6 of a mesh's triangles share 8
//! corners) where SAH splits would have cut them apart: fuller groups, fewer bytes, but groups
//! shaped by connectivity overlap more, so a ray meets more of them. On the dragon's octree
//! leaves (`K = 512`, 166 triangles each on average; `tools/cluster_stats.rs` prints these):
//!
//! | window | lanes per group | bytes per triangle | node visits, group tests per ray |
//! |-------:|----------------:|-------------------:|--------------------------------:|
//! |      1 |            4.85 |               37.7 |                      1.91, 1.14 |
//! |      8 |            5.10 |               36.0 |                      1.90, 1.20 |
//! |     32 |            5.55 |               32.8 |                      1.88, 1.35 |
//! |     64 |            5.77 |               31.6 |                      1.91, 1.37 |
//!
//! (Visits and tests: the SAH's expectation for a ray that meets the cluster's root box.) The
//! default, 8, takes the fill the greedy grouping gets for nodes SAH would split below one
//! group's worth; [`ClusterBuilder::with_window`] picks another point.
//!
//! **Depth.** The tracer's stack is bounded by [`MAX_CLUSTER_DEPTH`]. A collapsed SAH tree is
//! far shallower for any real cluster, but not provably so; if it were deeper, step 3 is redone
//! with median splits only, and step 4 opens the *tallest* child first. Each wide node then
//! removes at least three binary levels (its 8 slots hold every binary node within three levels
//! of it that is not a leaf), and median splits over `g` groups make a tree `ceil(log2 g)`
//! levels deep, so any cluster of fewer than `2^32` triangles is at most 11 wide levels deep.
//!
//! **Corners** are told apart by the bit patterns of their three coordinates: `-0.0` and `0.0`
//! are different corners (nothing is normalised, so every lane's triangle is bit for bit the
//! input triangle, corners in the input order: the watertight test's winding is unchanged).

mod binary;
mod group;
mod wide;

#[cfg(test)]
mod tests;

pub use crate::geom::tribox::triangle_box;
use crate::geom::tribox::{corner_bounds, down, up};
use crate::physical::format::{ClusterNode, GROUP_LANES, MAX_CLUSTER_DEPTH, TriGroup};

/// Bins per axis of the binned SAH (Wald 2007 uses 16 to 32; clusters are small).
pub const BINS: usize = 16;
/// Triangles of a window, by default: step 1 splits the cluster down to windows of at most this
/// many triangles (or fewer that fit one group), step 2 forms each window's groups.
pub const WINDOW: usize = 8;
/// Binary depth from which only median splits are made (bounds the build's work on inputs
/// where SAH splits peel off a few primitives at a time).
pub const SAH_MAX_DEPTH: u32 = 32;

/// One triangle of a cluster: its corners (as the watertight test wants them) and primitive id.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClusterTri {
    pub v: [[f32; 3]; 3],
    pub prim: u32,
}

/// A built cluster: its nodes (the root first) and groups, with indices already absolute in
/// the block (see [`build_cluster`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClusterBuild {
    pub nodes: Vec<ClusterNode>,
    pub groups: Vec<TriGroup>,
}

/// Why a cluster cannot be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ClusterError {
    #[error("a cluster needs at least one triangle")]
    Empty,
    #[error("{0} triangles in one cluster: more than 32-bit indices can address")]
    TooMany(usize),
    #[error("triangle {index} (primitive {prim}) has a non-finite corner")]
    NonFinite { index: usize, prim: u32 },
    #[error("the clip box {lo:?}..{hi:?} is not a finite box with lo <= hi")]
    BadClip { lo: [f64; 3], hi: [f64; 3] },
    #[error(
        "the cluster's boxes span {lo:e}..{hi:e} along axis {axis}: beyond what an 8-bit grid \
         with exponents in CLUSTER_EXP_RANGE can hold (coordinates must stay below 2^86 in \
         magnitude, a node's extent below 2^70)"
    )]
    Range { axis: usize, lo: f32, hi: f32 },
    #[error("the cluster's node or group indices would pass 2^32")]
    IndexOverflow,
    #[error("no tree for this cluster is within depth {cap}")]
    TooDeep { cap: usize },
}

/// Tuning knobs, for tests and experiments; [`ClusterBuilder::new`] uses the defaults.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Params {
    /// Most triangles of a window (`1..=group::MAX_WINDOW`).
    pub window: usize,
    /// Merge sibling groups that fit one.
    pub merge: bool,
    /// Deepest node allowed (the root is at depth 0).
    pub max_depth: usize,
    pub sah_max_depth: u32,
    /// Build in [`Mode::Shallow`] only.
    pub shallow_only: bool,
}

impl Default for Params {
    fn default() -> Params {
        Params {
            window: WINDOW,
            merge: true,
            max_depth: MAX_CLUSTER_DEPTH,
            sah_max_depth: SAH_MAX_DEPTH,
            shallow_only: false,
        }
    }
}

/// Builds clusters, keeping its scratch buffers from one cluster to the next (a pack builds
/// thousands per thread).
#[derive(Default)]
pub struct ClusterBuilder {
    params: Params,
    /// The triangles, then the groups, as primitives of a binary tree.
    refs: Vec<binary::PrimRef>,
    grefs: Vec<binary::PrimRef>,
    bin: Vec<binary::BinNode>,
    tasks: Vec<binary::Task>,
    drafts: Vec<group::Draft>,
    vertices: Vertices,
    local: group::Local,
    queue: Vec<(u32, u32)>,
}

impl ClusterBuilder {
    pub fn new() -> ClusterBuilder {
        ClusterBuilder::default()
    }

    /// A builder whose windows hold up to `window` triangles (clamped to `1..=64`; see the
    /// module documentation for what that trades).
    pub fn with_window(window: usize) -> ClusterBuilder {
        ClusterBuilder::with_params(Params {
            window: window.clamp(1, group::MAX_WINDOW),
            ..Params::default()
        })
    }

    pub(crate) fn with_params(params: Params) -> ClusterBuilder {
        ClusterBuilder {
            params,
            ..ClusterBuilder::default()
        }
    }

    /// [`build_cluster`] with this builder's scratch buffers.
    pub fn build(
        &mut self,
        tris: &[ClusterTri],
        clip: ([f64; 3], [f64; 3]),
        node_base: u32,
        group_base: u32,
    ) -> Result<ClusterBuild, ClusterError> {
        let mut out = ClusterBuild::default();
        self.build_at(
            tris,
            clip,
            node_base,
            group_base,
            &mut out.nodes,
            &mut out.groups,
        )?;
        Ok(out)
    }

    /// Builds the cluster over `tris` and appends it to a block's `nodes` and `groups`: its
    /// root is `nodes[len]` (the length before the call) and indices are positions in these
    /// vectors. On an error nothing is appended.
    pub fn build_into(
        &mut self,
        tris: &[ClusterTri],
        clip: ([f64; 3], [f64; 3]),
        nodes: &mut Vec<ClusterNode>,
        groups: &mut Vec<TriGroup>,
    ) -> Result<(), ClusterError> {
        let nb = u32::try_from(nodes.len()).map_err(|_| ClusterError::IndexOverflow)?;
        let gb = u32::try_from(groups.len()).map_err(|_| ClusterError::IndexOverflow)?;
        self.build_at(tris, clip, nb, gb, nodes, groups)
    }

    fn build_at(
        &mut self,
        tris: &[ClusterTri],
        clip: ([f64; 3], [f64; 3]),
        node_base: u32,
        group_base: u32,
        nodes: &mut Vec<ClusterNode>,
        groups: &mut Vec<TriGroup>,
    ) -> Result<(), ClusterError> {
        if tris.is_empty() {
            return Err(ClusterError::Empty);
        }
        if tris.len() > (u32::MAX / 4) as usize {
            return Err(ClusterError::TooMany(tris.len()));
        }
        let (lo, hi) = clip;
        if !(0..3).all(|k| lo[k].is_finite() && hi[k].is_finite() && lo[k] <= hi[k]) {
            return Err(ClusterError::BadClip { lo, hi });
        }
        self.refs.clear();
        self.refs.reserve(tris.len());
        for (i, t) in tris.iter().enumerate() {
            if !t.v.iter().flatten().all(|c| c.is_finite()) {
                return Err(ClusterError::NonFinite {
                    index: i,
                    prim: t.prim,
                });
            }
            let (blo, bhi) = build_box(&t.v, &clip);
            for k in 0..3 {
                if !(blo[k].abs() <= MAX_COORD && bhi[k].abs() <= MAX_COORD) {
                    return Err(ClusterError::Range {
                        axis: k,
                        lo: blo[k],
                        hi: bhi[k],
                    });
                }
            }
            self.refs.push(binary::PrimRef::new(blo, bhi, i as u32));
        }
        // Steps 1 and 2: windows of neighbouring triangles, each formed into groups.
        self.vertices.number(tris);
        self.local.prepare(self.vertices.keys.len());
        let vid = &self.vertices.ids;
        self.bin.clear();
        let window = self.params.window.clamp(1, group::MAX_WINDOW);
        let sah = binary::Split::Sah {
            max_depth: self.params.sah_max_depth,
        };
        binary::build(
            &mut self.refs,
            window,
            sah,
            &mut self.bin,
            &mut self.tasks,
            |r| fits_group(vid, r.iter().map(|p| p.id)),
        );
        self.drafts.clear();
        for node in self.bin.iter().filter(|n| n.leaf) {
            let w = &self.refs[node.a as usize..(node.a + node.b) as usize];
            group::form(vid, w, &mut self.drafts, &mut self.local);
        }
        self.grefs.clear();
        self.grefs.extend(
            self.drafts
                .iter()
                .enumerate()
                .map(|(i, d)| binary::PrimRef::new(d.lo, d.hi, i as u32)),
        );
        // Steps 3 to 5: the groups' tree, collapsed and written; shallow if too deep.
        let (n0, g0) = (nodes.len(), groups.len());
        let mut result = Err(ClusterError::TooDeep { cap: 0 });
        let modes: &[Mode] = if self.params.shallow_only {
            &[Mode::Shallow]
        } else {
            &[Mode::Sah, Mode::Shallow]
        };
        for &mode in modes {
            self.bin.clear();
            let split = match mode {
                Mode::Sah => sah,
                Mode::Shallow => binary::Split::Median,
            };
            binary::build(
                &mut self.grefs,
                1,
                split,
                &mut self.bin,
                &mut self.tasks,
                |_| false,
            );
            result = wide::emit(
                &wide::Input {
                    bin: &self.bin,
                    refs: &self.grefs,
                    drafts: &self.drafts,
                    tris,
                    vid,
                    params: &self.params,
                    mode,
                    node_base,
                    group_base,
                },
                &mut self.queue,
                nodes,
                groups,
            );
            match result {
                Err(ClusterError::TooDeep { .. }) => {
                    nodes.truncate(n0);
                    groups.truncate(g0);
                }
                _ => break,
            }
        }
        if result.is_err() {
            nodes.truncate(n0);
            groups.truncate(g0);
        }
        result
    }
}

/// Largest coordinate magnitude a box may have: a grid with exponent up to 63 and an origin
/// below `2^24` steps reaches `2^87`; staying below `2^86` leaves room for a node's extent.
const MAX_COORD: f32 = (1u128 << 86) as f32;

/// How the binary tree is split and collapsed: [`Mode::Sah`] first; [`Mode::Shallow`] (median
/// splits, tallest child opened first) if that tree is too deep.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Mode {
    Sah,
    Shallow,
}

/// Builds the cluster over `tris` (at least one; finite corners) for the leaf whose widened
/// cell is `clip` (world units, `lo <= hi`). `node_base` and `group_base` are where the
/// cluster's first node and first group will sit in the block: the indices written into the
/// nodes are absolute, and the root is `nodes[0]`, i.e. block node `node_base`.
///
/// Every triangle is in exactly one lane of one group; each group has 1 to 8 lanes and at most
/// 8 distinct corners; every child box contains the part of each of its triangles inside
/// `clip` ([`triangle_box`]); the tree is at most [`MAX_CLUSTER_DEPTH`] deep. The result
/// depends on nothing but the arguments.
pub fn build_cluster(
    tris: &[ClusterTri],
    clip: ([f64; 3], [f64; 3]),
    node_base: u32,
    group_base: u32,
) -> Result<ClusterBuild, ClusterError> {
    ClusterBuilder::new().build(tris, clip, node_base, group_base)
}

/// The box the builder gives triangle `v`: [`triangle_box`], or for a triangle with nothing
/// inside `clip` (bounding boxes of neighbours overlap, the triangles do not) its bounds
/// clamped into `clip`, a flat box on its face or edge (any box would do).
fn build_box(v: &[[f32; 3]; 3], clip: &([f64; 3], [f64; 3])) -> ([f32; 3], [f32; 3]) {
    triangle_box(v, clip).unwrap_or_else(|| {
        let (tlo, thi) = corner_bounds(v);
        let (lo, hi) = clip;
        let clamp = |x: f32, k: usize| x.clamp(down(lo[k]), up(hi[k]));
        (
            std::array::from_fn(|k| clamp(tlo[k], k)),
            std::array::from_fn(|k| clamp(thi[k], k)),
        )
    })
}

/// The bit patterns of a corner's coordinates: corners are the same iff these are.
#[inline]
fn corner_key(p: &[f32; 3]) -> [u32; 3] {
    p.map(f32::to_bits)
}

/// Numbers the distinct corners of a cluster's triangles (by [`corner_key`], in order of first
/// appearance): `ids[t][c]` is the number of corner `c` of triangle `t`. An open-addressing
/// table, so numbering is O(1) per corner and corners are compared as `u32` afterwards.
#[derive(Default)]
struct Vertices {
    /// Vertex number + 1 per slot, 0 for an empty slot.
    slots: Vec<u32>,
    keys: Vec<[u32; 3]>,
    ids: Vec<[u32; 3]>,
}

impl Vertices {
    fn number(&mut self, tris: &[ClusterTri]) {
        let size = (3 * tris.len()).next_power_of_two() * 2;
        self.slots.clear();
        self.slots.resize(size, 0);
        self.keys.clear();
        self.ids.clear();
        let mask = size - 1;
        for t in tris {
            let ids = t.v.map(|p| {
                let key = corner_key(&p);
                // A multiplicative hash of the three words (FxHash's constant).
                let h = key.iter().fold(0u64, |h, &w| {
                    (h.rotate_left(5) ^ w as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95)
                });
                let mut i = (h >> 32) as usize & mask;
                loop {
                    match self.slots[i] {
                        0 => {
                            self.keys.push(key);
                            self.slots[i] = self.keys.len() as u32;
                            break self.keys.len() as u32 - 1;
                        }
                        v if self.keys[v as usize - 1] == key => break v - 1,
                        _ => i = (i + 1) & mask,
                    }
                }
            });
            self.ids.push(ids);
        }
    }
}

/// Whether triangles `ids` fit one group: at most 8 of them, with at most 8 distinct corners
/// (`vid`: their corners' numbers, [`Vertices`]).
fn fits_group(vid: &[[u32; 3]], ids: impl Iterator<Item = u32> + Clone) -> bool {
    if ids.clone().count() > GROUP_LANES {
        return false;
    }
    let mut seen = [0u32; 8];
    let mut n = 0;
    for id in ids {
        for &v in &vid[id as usize] {
            if !seen[..n].contains(&v) {
                if n == 8 {
                    return false;
                }
                seen[n] = v;
                n += 1;
            }
        }
    }
    true
}

/// The group of triangles `ids` (which fit one group, [`fits_group`]): corners in slots by first
/// appearance, lanes in the order of `ids`, everything unused zero.
fn make_group(tris: &[ClusterTri], vid: &[[u32; 3]], ids: &[u32]) -> TriGroup {
    let mut g: TriGroup = bytemuck::Zeroable::zeroed();
    let mut seen = [0u32; 8];
    let mut n = 0;
    for (l, &id) in ids.iter().enumerate() {
        let t = &tris[id as usize];
        for (c, p) in t.v.iter().enumerate() {
            let v = vid[id as usize][c];
            let slot = match seen[..n].iter().position(|&s| s == v) {
                Some(s) => s,
                None => {
                    seen[n] = v;
                    for (row, &x) in g.corner.iter_mut().zip(p) {
                        row[n] = x;
                    }
                    n += 1;
                    n - 1
                }
            };
            g.tri[c][l] = slot as u8;
        }
        g.prim[l] = t.prim;
    }
    g.count = ids.len() as u32;
    g
}
