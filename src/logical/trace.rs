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
//! **Bounded, whatever the bytes.** Every box a walk crosses contains `q` (a leaf's cell does;
//! a volume is rebuilt around `q` from its shape, whose level is checked to be no finer than the
//! leaf's), and its faces lie on the grid of a level no deeper than the tree's depth `D`. A step
//! moves `q` along the exit axis past such a face, and along the other axes only forward (in the
//! ray's direction) and within the box. So no box is entered twice, and since `q` moves forward
//! to a new line of the level-`D` grid along one axis at every step, a walk takes at most
//! `3 * 2^D + 1` steps, for any file: the loop needs no step counter. Rounding in
//! the exit point can only move `q` to a cell the ray passes within about `2^-31` cells of,
//! and the builder references every triangle in every cell within [`CELL_MARGIN`] of it, so a
//! triangle is never missed for being just across a face.
//!
//! [`CELL_MARGIN`]: crate::physical::format::CELL_MARGIN

use std::hint::select_unpredictable;

use serde::Serialize;

use crate::geom::Ray;
use crate::geom::triangle::RayShear;
use crate::mapping::morton::{self, LATTICE_SIZE};
use crate::mapping::{Corruption, TreeMap};
use crate::physical::file::OavmFile;
use crate::physical::format::{CELL_MARGIN, SectionKind, TriRecord, leaf_refs};

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
    refs: &'a [u32],
    tris: &'a [TriRecord],
    root_min: [f64; 3],
    /// Lattice cells per world unit.
    scale: f64,
}

impl<'a> Tree<'a> {
    pub fn new<D: AsRef<[u8]>>(file: &'a OavmFile<D>) -> Tree<'a> {
        let h = file.header();
        let map = TreeMap::new(
            file.levels(),
            file.records(SectionKind::Nodes),
            file.records(SectionKind::Ranks),
        );
        Tree {
            map,
            refs: file.records(SectionKind::Refs),
            tris: file.records(SectionKind::Triangles),
            root_min: h.root_min,
            scale: LATTICE_SIZE as f64 / h.root_size,
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
        let moves: [bool; 3] = std::array::from_fn(|k| d[k] != 0.0);
        let fwd: [bool; 3] = std::array::from_fn(|k| d[k] > 0.0);
        // Plane crossings as `t = plane * inv - oi`. An axis the ray does not move along gets
        // `inv = 0`, `oi = -inf`: its planes are never crossed (`t = +inf`).
        let inv: [f64; 3] = std::array::from_fn(|k| if moves[k] { 1.0 / d[k] } else { 0.0 });
        let oi: [f64; 3] = std::array::from_fn(|k| {
            if moves[k] {
                o[k] * inv[k]
            } else {
                f64::NEG_INFINITY
            }
        });
        let still_inside =
            |lo: f64, hi: f64| (0..3).all(|k| moves[k] || (o[k] >= lo && o[k] <= hi));

        // Clip to the root (slab test); an axis the ray is parallel to must contain the origin.
        let (mut t0, mut t1) = (ray.tmin as f64, ray.tmax as f64);
        if !still_inside(0.0, n) {
            return Ok(None);
        }
        for k in 0..3 {
            if moves[k] {
                let (a, b) = (-oi[k], n * inv[k] - oi[k]);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        // Negated on purpose: NaN (from a NaN tmin or tmax) must mean a miss.
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !(t0 <= t1) {
            return Ok(None);
        }
        let mut q: [u32; 3] =
            std::array::from_fn(|k| clamp_floor(o[k] + t0 * d[k], 0, LATTICE_SIZE - 1));

        let shear = RayShear::new(ray);
        let tmin = ray.tmin;
        let mut best: Option<HitInfo> = None;
        let mut t_best = ray.tmax;
        let mut t_stop = t1;
        // Indices of the current leaf's ancestors by level (32 entries: `level & 31` needs no
        // bounds check).
        let mut path = [0u64; 32];
        let mut level = 0u32;
        let mut k = Counters::default();
        let result = loop {
            // 1. Locate the leaf containing q, from the common ancestor down.
            let rec;
            (level, rec) = match self.map.descend(level, &mut path, q, &mut k.nodes_visited) {
                Ok(found) => found,
                Err(e) => break Err(e),
            };
            k.leaves_visited += 1;

            // 2. Cross it: the box the ray leaves, and the triangles on the way.
            let size = morton::cell_size(level);
            let cell_lo = q.map(|x| x & !(size - 1));
            let (lo, hi) = match rec.kind_bits() {
                0 => {
                    // Empty: its merged volume, rebuilt from the shape in the record (spec
                    // §4.2), jumped past whole.
                    k.volumes_crossed += 1;
                    let shape = rec.shape_bits();
                    if shape.level as u32 > level {
                        break Err(Corruption {
                            what: "merged volume smaller than its leaf",
                            level,
                            index: path[(level & 31) as usize],
                        });
                    }
                    shape.box_around(q)
                }
                1 => {
                    let (inline_count, b) = rec.solid_bits();
                    // The leaf's tight bounds (spec §4.2), widened by the cell margin: a ray that
                    // misses them over [tmin, best] cannot hit any of the leaf's triangles inside
                    // the cell, so their references and records are not even loaded.
                    let s16 = size as f64 / 16.0;
                    let q4 = |shift: u32| ((b >> shift) & 15) as f64;
                    let (mut tn, mut tf) = (tmin as f64, t_best as f64);
                    let mut inside = true;
                    for a in 0..3 {
                        let blo = cell_lo[a] as f64 + q4(4 * a as u32) * s16 - CELL_MARGIN;
                        let bhi =
                            cell_lo[a] as f64 + (q4(12 + 4 * a as u32) + 1.0) * s16 + CELL_MARGIN;
                        if moves[a] {
                            let (x, y) = (blo * inv[a] - oi[a], bhi * inv[a] - oi[a]);
                            tn = tn.max(x.min(y));
                            tf = tf.min(x.max(y));
                        } else {
                            inside &= o[a] >= blo && o[a] <= bhi;
                        }
                    }
                    if inside && tn <= tf {
                        let Some((refs, _)) = leaf_refs(self.refs, rec.payload, inline_count)
                        else {
                            break Err(Corruption {
                                what: "triangle references out of range",
                                level,
                                index: rec.payload as u64,
                            });
                        };
                        k.triangles_tested += refs.len() as u64;
                        // Four triangles at a time; a short last group repeats its first
                        // triangle (a repeated hit changes nothing: ties keep the first).
                        for group in refs.chunks(4) {
                            let tri =
                                |i: usize| self.tris.get(group[i.min(group.len() - 1)] as usize);
                            let (Some(r0), Some(r1), Some(r2), Some(r3)) =
                                (tri(0), tri(1), tri(2), tri(3))
                            else {
                                return Err(Corruption {
                                    what: "triangle index out of range",
                                    level,
                                    index: rec.payload as u64,
                                });
                            };
                            let (mut mask, ts) =
                                shear.intersect4([&r0.v, &r1.v, &r2.v, &r3.v], tmin, t_best);
                            while mask != 0 {
                                let l = mask.trailing_zeros() as usize;
                                mask &= mask - 1;
                                let (t, rec_l) = (ts[l], [r0, r1, r2, r3][l]);
                                let hit = HitInfo {
                                    t,
                                    prim: rec_l.prim,
                                    tri: group[l.min(group.len() - 1)],
                                };
                                if ANY {
                                    *c += k;
                                    return Ok(Some(hit));
                                }
                                if best.is_none() || t < t_best {
                                    t_best = t;
                                    best = Some(hit);
                                }
                            }
                        }
                        t_stop = t1.min(t_best as f64);
                    } else {
                        k.leaves_culled += 1;
                    }
                    (cell_lo, cell_lo.map(|x| x + size))
                }
                _ => {
                    break Err(Corruption {
                        what: "invalid leaf record",
                        level,
                        index: path[(level & 31) as usize],
                    });
                }
            };

            // 3. Exit of the box (slab test on its far faces); stop where nothing closer remains.
            let te: [f64; 3] = std::array::from_fn(|a| {
                let face = if fwd[a] { hi[a] } else { lo[a] };
                face as f64 * inv[a] - oi[a]
            });
            // Branch-free: which axis is crossed first is unpredictable from ray to ray.
            let a01 = select_unpredictable(te[1] < te[0], 1usize, 0usize);
            let t01 = te[0].min(te[1]);
            let axis = select_unpredictable(te[2] < t01, 2usize, a01);
            let t_exit = t01.min(te[2]);
            // Negated on purpose: a NaN bound must stop the walk.
            #[allow(clippy::neg_cmp_op_on_partial_ord)]
            if !(t_exit < t_stop) {
                break Ok(best);
            }

            // 4. Step into the neighbour across the exit face: along the exit axis to `hi` or
            // `lo - 1`; along the others to the exit point's cell, forward only and inside the
            // box being left (so the walk never turns back; see the module documentation).
            let old = q;
            let mut next = [0u32; 3];
            for a in 0..3 {
                let p = o[a] + t_exit * d[a];
                let (lo_a, hi_a) = if fwd[a] {
                    (old[a], hi[a] - 1)
                } else {
                    (lo[a], old[a])
                };
                let lateral = select_unpredictable(moves[a], clamp_floor(p, lo_a, hi_a), old[a]);
                let across = select_unpredictable(fwd[a], hi[a], lo[a].wrapping_sub(1));
                next[a] = select_unpredictable(a == axis, across, lateral);
            }
            // Leaving the root: `hi` at the lattice's end, or `lo - 1` wrapping below 0.
            if next[axis] >= LATTICE_SIZE {
                break Ok(best);
            }
            q = next;
            level = level.min(morton::common_level(old, q));
        };
        *c += k;
        result
    }
}

/// `floor(p)` clamped to `[lo, hi]`, without branches (`max` and `min` give the other operand
/// for NaN, so NaN gives `lo`; truncation is floor for the non-negative clamped value).
#[inline(always)]
fn clamp_floor(p: f64, lo: u32, hi: u32) -> u32 {
    p.max(lo as f64).min(hi as f64) as u32
}
