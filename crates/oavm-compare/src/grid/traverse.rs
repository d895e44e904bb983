//! The grid's traversal: the incremental 3D-DDA of Amanatides and Woo ("A Fast Voxel Traversal
//! Algorithm for Ray Tracing", Eurographics 1987).
//!
//! The ray is clipped to the grid's box, the cell holding the entry point is found, and from
//! then on the ray steps into the face neighbour across whichever of the three next cell faces
//! it meets first. The `t` of the next face on each axis is recomputed from the cell index
//! (`(lo + (i + 1) * size - o) / d`) instead of being accumulated, so it cannot drift over long
//! walks; the walk is in f64. Every non-empty cell's triangles go to the leaf test (no
//! mailboxing: a triangle in several cells is tested once per cell, and `triangles_tested`
//! counts every test).
//!
//! - closest hit: the walk stops as soon as the closest hit so far has `t <=` the current cell's
//!   exit `t` (no later cell can hold anything closer: the binning margin puts a triangle on a
//!   face into both cells), or the ray's range ends;
//! - any hit: the walk stops at the first hit.

use super::UniformGrid;
use crate::Counters;
use crate::StructureStats;
use crate::aabb::clip_ray;
use crate::leaf::{Soup, Walk};
use oavm::geom::Ray;

impl Walk for UniformGrid {
    type Leaf = [u32];

    fn soup(&self) -> &Soup {
        &self.soup
    }

    fn structure_stats(&self) -> &StructureStats {
        &self.stats
    }

    #[inline]
    fn walk(
        &self,
        ray: &Ray,
        c: &mut Counters,
        mut leaf: impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        if self.brute {
            return false;
        }
        let Some((t0, t1)) = clip_ray(ray, self.lo, self.hi) else {
            return true;
        };
        let o = ray.origin.map(|x| x as f64);
        let d = ray.dir.map(|x| x as f64);
        let res = self.res.map(|r| r as i64);
        let mut cell = [0i64; 3];
        let mut next = [f64::INFINITY; 3];
        for k in 0..3 {
            cell[k] = self.cell_coord(k, o[k] + t0 * d[k]) as i64;
        }
        let face_t = |k: usize, i: i64| {
            let face = if d[k] > 0.0 { i + 1 } else { i };
            (self.lo[k] + face as f64 * self.cell[k] - o[k]) / d[k]
        };
        for k in 0..3 {
            if d[k] != 0.0 {
                next[k] = face_t(k, cell[k]);
            }
        }
        // Each step moves one index by one cell in the ray's direction, so the walk leaves the
        // grid after at most res_x + res_y + res_z steps.
        loop {
            let exit = next[0].min(next[1]).min(next[2]).min(t1);
            c.nodes_visited += 1;
            let idx = ((cell[2] * res[1] + cell[1]) * res[0] + cell[0]) as usize;
            let list = self.cells.list(idx);
            if !list.is_empty() {
                c.leaves_visited += 1;
                // The closest hit so far (or STOP) within this cell: nothing later is closer.
                if leaf(list, c) as f64 <= exit {
                    return true;
                }
            }
            if exit >= t1 {
                return true;
            }
            let k = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            cell[k] += if d[k] > 0.0 { 1 } else { -1 };
            if cell[k] < 0 || cell[k] >= res[k] {
                return true;
            }
            next[k] = face_t(k, cell[k]);
        }
    }
}
