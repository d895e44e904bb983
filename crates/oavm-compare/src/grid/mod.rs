//! Uniform grid with 3D-DDA traversal: the oldest structure of the paper's comparison.
//!
//! - [`build`]: the resolution (Cleary and Wyvill 1988; about `λ` = 4 cells per triangle) and the
//!   binning of triangles into cells by the exact triangle–box test;
//! - [`node`]: the cells' triangle lists, stored CSR;
//! - [`traverse`]: the incremental 3D-DDA of Amanatides and Woo ("A Fast Voxel Traversal
//!   Algorithm for Ray Tracing", Eurographics 1987), in f64.
//!
//! **Storage and counting** (the paper's Table 2 sense): a *node* is a cell (`nodes` = all
//! cells, empty or not); the *pointers* are the cells' list pointers, one offset per cell into
//! the flattened reference list (`pointers` = cells; the CSR array has one extra closing entry,
//! counted in `bytes`). `bytes` counts the [`UniformGrid`] record itself, the offsets, the
//! references (`u32` each), the triangles (36 bytes) and their primitive ids (4 bytes). While
//! tracing, `nodes_visited` counts the cells the walk enters and `leaves_visited` the non-empty
//! ones among them.
//!
//! **Limits.** Triangles with a non-finite coordinate are not indexed (they cannot be hit).
//! Reference counts beyond `u32` make the build retry with fewer cells; an input too large even
//! for one cell (more than `u32::MAX` triangles) is traced by brute force rather than refused.

mod build;
mod node;
mod traverse;

#[cfg(test)]
mod tests;

pub use build::{LAMBDA, MARGIN_REL, MAX_CELLS, MAX_RES};

use super::StructureStats;
use super::leaf::Soup;
use node::Cells;

/// A uniform grid over the triangles' bounding box, cells stored CSR.
pub struct UniformGrid {
    /// The grid's box (the triangles' box, padded a little so no triangle lies on its faces).
    lo: [f64; 3],
    hi: [f64; 3],
    cell: [f64; 3],
    inv_cell: [f64; 3],
    res: [u32; 3],
    cells: Cells,
    soup: Soup,
    /// Too large to index with 32 bits: every ray tests every triangle.
    brute: bool,
    stats: StructureStats,
}

impl UniformGrid {
    /// Grid resolution (cells per axis).
    pub fn resolution(&self) -> [u32; 3] {
        self.res
    }

    /// Triangle references stored over all cells.
    pub fn references(&self) -> usize {
        self.cells.references()
    }

    /// The cell index along axis `k` holding coordinate `x`, clamped to the grid.
    #[inline]
    fn cell_coord(&self, k: usize, x: f64) -> usize {
        let i = ((x - self.lo[k]) * self.inv_cell[k]).floor();
        // NaN (never: finite inputs) maps to 0 through the saturating cast.
        (i.max(0.0) as usize).min(self.res[k] as usize - 1)
    }
}
