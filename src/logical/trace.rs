//! The tracer (OAVM paper §2.4–2.5): closest hit and any hit through the mapped tree.
//!
//! A ray is mapped into the lattice (`2^21` cells per axis over the root cube) in f64, where
//! cell faces are integers. It enters the root, and from then on is always *in* one lattice cell
//! `q`:
//!
//! 1. **Locate** the leaf containing `q`, descending by rank (the mapping layer) from the lowest
//!    common ancestor of `q` and the previous leaf, found from the coordinates
//!    ([`morton::common_level`]); the ancestors' indices are kept in `path`.
//! 2. **Cross** the leaf. An empty leaf's whole merged volume is clipped with the slab
//!    (Liang–Barsky) test and jumped past; a solid leaf's triangles are tested with the
//!    watertight test, keeping the closest hit so far.
//! 3. **Stop** when the exit `t` of that box reaches the closest hit (no later cell can hold a
//!    closer one) or `tmax`, or when the ray leaves the root.
//! 4. **Step** to the neighbour across the exit face: the face neighbour query on integer
//!    coordinates (the neighbour's lattice cell is `hi` or `lo - 1` along the exit axis, the
//!    exit point's cell along the others). This is the paper's neighbour step, on coordinates
//!    rather than on the interleaved code, so it is right across parent boundaries
//!    (see [`crate::mapping::morton`]).
//!
//! **No cracks.** `q` only ever moves forward along each axis (in the ray's direction), and
//! along the exit axis by at least one cell, so no cell is entered twice and a walk takes at
//! most `3 * 2^depth` steps, which is also the bound enforced against corrupt files. Rounding in
//! the exit point can only move `q` to a cell the ray passes within about `2^-31` cells of,
//! and the builder references every triangle in every cell within [`CELL_MARGIN`] of it, so a
//! triangle is never missed for being just across a face.
//!
//! [`CELL_MARGIN`]: crate::build::subdivide::CELL_MARGIN

use serde::Serialize;

use crate::build::subdivide::CELL_MARGIN;
use crate::geom::Ray;
use crate::geom::triangle::RayShear;
use crate::mapping::morton::{self, LATTICE_SIZE, MAX_LEVEL};
use crate::mapping::{Corruption, Step, TreeMap};
use crate::physical::file::OavmFile;
use crate::physical::format::{NodeKind, SectionKind, TriRecord, VolumeRecord, leaf_refs};

/// Work counters of a batch of rays (summed over its rays).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counters {
    pub rays: u64,
    /// Node records read: the internal nodes of every descent and the leaves reached.
    pub nodes_visited: u64,
    /// Leaves entered (solid and empty).
    pub leaves_visited: u64,
    /// Merged empty volumes clipped and jumped past.
    pub volumes_crossed: u64,
    /// Solid leaves whose tight bounds the ray missed: their triangles were not tested.
    pub leaves_culled: u64,
    /// Ray–triangle tests.
    pub triangles_tested: u64,
}

impl std::ops::AddAssign for Counters {
    fn add_assign(&mut self, o: Counters) {
        self.rays += o.rays;
        self.nodes_visited += o.nodes_visited;
        self.leaves_visited += o.leaves_visited;
        self.volumes_crossed += o.volumes_crossed;
        self.leaves_culled += o.leaves_culled;
        self.triangles_tested += o.triangles_tested;
    }
}

impl std::ops::Add for Counters {
    type Output = Counters;
    fn add(mut self, o: Counters) -> Counters {
        self += o;
        self
    }
}

/// A closest hit, with the index of the triangle record hit (for shading).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitInfo {
    pub t: f32,
    pub prim: u32,
    /// Index of the triangle in the file's triangles section.
    pub tri: u32,
}

/// A read-only view of a file's tree, ready for tracing. Cheap to make (no allocation, no scan).
#[derive(Clone, Copy)]
pub struct Tree<'a> {
    map: TreeMap<'a>,
    volumes: &'a [VolumeRecord],
    refs: &'a [u32],
    tris: &'a [TriRecord],
    root_min: [f64; 3],
    /// Lattice cells per world unit.
    scale: f64,
    /// Bound on the steps of one walk: `3 * 2^depth + 1`.
    max_steps: u64,
}

impl<'a> Tree<'a> {
    pub fn new<D: AsRef<[u8]>>(file: &'a OavmFile<D>) -> Tree<'a> {
        let h = file.header();
        let map = TreeMap::new(
            file.levels(),
            file.records(SectionKind::Nodes),
            file.records(SectionKind::Ranks),
        );
        let depth = h.level_count.saturating_sub(1).min(MAX_LEVEL);
        Tree {
            map,
            volumes: file.records(SectionKind::Volumes),
            refs: file.records(SectionKind::Refs),
            tris: file.records(SectionKind::Triangles),
            root_min: h.root_min,
            scale: LATTICE_SIZE as f64 / h.root_size,
            max_steps: 3 * (1u64 << depth) + 1,
        }
    }

    pub fn map(&self) -> &TreeMap<'a> {
        &self.map
    }

    /// The triangle record `tri` (as in [`HitInfo::tri`]).
    pub fn triangle(&self, tri: u32) -> Option<&'a TriRecord> {
        self.tris.get(tri as usize)
    }

    /// Closest hit of `ray` with `tmin <= t <= tmax`, or `None`.
    pub fn intersect(&self, ray: &Ray, c: &mut Counters) -> Result<Option<HitInfo>, Corruption> {
        self.walk::<false>(ray, c)
    }

    /// Whether any triangle is hit with `tmin <= t <= tmax`; stops at the first one found.
    pub fn occluded(&self, ray: &Ray, c: &mut Counters) -> Result<bool, Corruption> {
        Ok(self.walk::<true>(ray, c)?.is_some())
    }

    fn walk<const ANY: bool>(
        &self,
        ray: &Ray,
        c: &mut Counters,
    ) -> Result<Option<HitInfo>, Corruption> {
        c.rays += 1;
        if !ray.is_valid() {
            return Ok(None);
        }
        let n = LATTICE_SIZE as f64;
        // The ray in lattice space; `t` is unchanged by this affine map.
        let o: [f64; 3] =
            std::array::from_fn(|k| (ray.origin[k] as f64 - self.root_min[k]) * self.scale);
        let d: [f64; 3] = std::array::from_fn(|k| ray.dir[k] as f64 * self.scale);
        let inv: [f64; 3] = std::array::from_fn(|k| 1.0 / d[k]);

        // Clip to the root (slab test); an axis the ray is parallel to must contain the origin.
        let (mut t0, mut t1) = (ray.tmin as f64, ray.tmax as f64);
        for k in 0..3 {
            if d[k] == 0.0 {
                if !(o[k] >= 0.0 && o[k] <= n) {
                    return Ok(None);
                }
            } else {
                let (a, b) = (-o[k] * inv[k], (n - o[k]) * inv[k]);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if !(t0 <= t1) {
            return Ok(None);
        }
        let mut q: [u32; 3] =
            std::array::from_fn(|k| clamp_floor(o[k] + t0 * d[k], 0, LATTICE_SIZE - 1));

        let shear = RayShear::new(ray);
        // Per axis: does the ray move forward (+1), backward (-1) or not at all? The exit face
        // of a box is its `hi` face forward, its `lo` face backward; an axis the ray does not
        // move along never exits, which `exit_o = -inf` encodes: (face - (-inf)) * 1 = +inf.
        let fwd: [bool; 3] = std::array::from_fn(|k| d[k] > 0.0);
        let moves: [bool; 3] = std::array::from_fn(|k| d[k] != 0.0);
        let exit_o: [f64; 3] =
            std::array::from_fn(|k| if moves[k] { o[k] } else { f64::NEG_INFINITY });
        let exit_inv: [f64; 3] = std::array::from_fn(|k| if moves[k] { inv[k] } else { 1.0 });

        let mut best: Option<HitInfo> = None;
        let mut t_best = ray.tmax;
        let mut t_stop = t1.min(t_best as f64);
        // Indices of the current leaf's ancestors by level; 32 entries so `level & 31` indexes it
        // without a bounds check.
        let mut path = [0u64; 32];
        let mut level = 0u32;
        let mut steps = 0u64;
        loop {
            steps += 1;
            if steps > self.max_steps {
                return Err(Corruption {
                    what: "walk exceeds its step bound",
                    level,
                    index: 0,
                });
            }
            // 1. Locate the leaf containing q, from the common ancestor down.
            let kind = loop {
                let idx = path[(level & 31) as usize];
                c.nodes_visited += 1;
                match self.map.step(level, idx, q)? {
                    Step::Child(child) => {
                        level += 1;
                        path[(level & 31) as usize] = child;
                    }
                    Step::Leaf(rec) => match rec.kind() {
                        Some(NodeKind::Internal) | None => {
                            return Err(Corruption {
                                what: "invalid leaf record",
                                level,
                                index: idx,
                            });
                        }
                        Some(leaf) => break leaf,
                    },
                }
            };
            c.leaves_visited += 1;

            // 2. Cross it: the box the ray leaves, and the triangles on the way.
            let size = morton::cell_size(level);
            let cell_lo = q.map(|x| x & !(size - 1));
            let (lo, hi) = match kind {
                NodeKind::Empty { volume } => {
                    c.volumes_crossed += 1;
                    let bad = Corruption {
                        what: "merged volume missing or not containing its leaf",
                        level,
                        index: volume as u64,
                    };
                    let v = self.volumes.get(volume as usize).ok_or(bad)?;
                    let contains = (0..3).all(|k| {
                        v.lo[k] <= cell_lo[k]
                            && cell_lo[k] + size <= v.hi[k]
                            && v.hi[k] <= LATTICE_SIZE
                    });
                    if !contains {
                        return Err(bad);
                    }
                    (v.lo, v.hi)
                }
                NodeKind::Solid {
                    first,
                    inline_count,
                    bounds,
                } => {
                    let bad = |what| Corruption {
                        what,
                        level,
                        index: first as u64,
                    };
                    let (refs, _) = leaf_refs(self.refs, first, inline_count)
                        .ok_or(bad("triangle references out of range"))?;
                    // The leaf's tight bounds (spec §4.2), widened by the cell margin: a ray that
                    // misses them over [tmin, best] cannot hit any of the leaf's triangles inside
                    // the cell, so their references and records are not even loaded.
                    let s16 = size as f64 / 16.0;
                    let (mut tn, mut tf) = (ray.tmin as f64, t_best as f64);
                    for k in 0..3 {
                        let blo = cell_lo[k] as f64 + bounds.lo[k] as f64 * s16 - CELL_MARGIN;
                        let bhi =
                            cell_lo[k] as f64 + (bounds.hi[k] as f64 + 1.0) * s16 + CELL_MARGIN;
                        if moves[k] {
                            let (a, b) = ((blo - o[k]) * inv[k], (bhi - o[k]) * inv[k]);
                            tn = tn.max(a.min(b));
                            tf = tf.min(a.max(b));
                        } else if o[k] < blo || o[k] > bhi {
                            tn = f64::INFINITY;
                        }
                    }
                    if tn <= tf {
                        for &ti in refs {
                            let tri = self
                                .tris
                                .get(ti as usize)
                                .ok_or(bad("triangle index out of range"))?;
                            c.triangles_tested += 1;
                            if let Some(t) = shear.intersect(&tri.v, ray.tmin, t_best) {
                                let hit = HitInfo {
                                    t,
                                    prim: tri.prim,
                                    tri: ti,
                                };
                                if ANY {
                                    return Ok(Some(hit));
                                }
                                if best.is_none() || t < t_best {
                                    t_best = t;
                                    best = Some(hit);
                                }
                            }
                        }
                    } else {
                        c.leaves_culled += 1;
                    }
                    t_stop = t1.min(t_best as f64);
                    (cell_lo, cell_lo.map(|x| x + size))
                }
                NodeKind::Internal => {
                    return Err(Corruption {
                        what: "descent ended on an internal node",
                        level,
                        index: 0,
                    });
                }
            };

            // 3. Exit of the box (slab test on its far faces); stop where nothing closer remains.
            let face: [u32; 3] = std::array::from_fn(|k| if fwd[k] { hi[k] } else { lo[k] });
            let te: [f64; 3] = std::array::from_fn(|k| (face[k] as f64 - exit_o[k]) * exit_inv[k]);
            let axis = if te[0] <= te[1] && te[0] <= te[2] {
                0
            } else if te[1] <= te[2] {
                1
            } else {
                2
            };
            let t_exit = te[axis];
            if !(t_exit < t_stop) {
                break;
            }

            // 4. Step into the neighbour across the exit face.
            let old = q;
            if fwd[axis] {
                if hi[axis] >= LATTICE_SIZE {
                    break;
                }
                q[axis] = hi[axis];
            } else {
                if lo[axis] == 0 {
                    break;
                }
                q[axis] = lo[axis] - 1;
            }
            for k in 0..3 {
                if k != axis && moves[k] {
                    let p = o[k] + t_exit * d[k];
                    // Forward only, and inside the box being left.
                    q[k] = if fwd[k] {
                        clamp_floor(p, old[k], hi[k] - 1)
                    } else {
                        clamp_floor(p, lo[k], old[k])
                    };
                }
            }
            level = level.min(morton::common_level(old, q));
        }
        Ok(best)
    }
}

/// `floor(p)` clamped to `[lo, hi]` (NaN gives `lo`).
#[inline(always)]
fn clamp_floor(p: f64, lo: u32, hi: u32) -> u32 {
    if !(p > lo as f64) {
        lo
    } else if p >= hi as f64 {
        hi
    } else {
        p as u32
    }
}
