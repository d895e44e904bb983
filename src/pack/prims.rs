//! The primitive table (format-spec §8.6): every input triangle's corners by primitive id, so
//! that an update finds which triangles changed and where they were without decoding a block.

use rayon::prelude::*;

use crate::mesh::Mesh;
use crate::physical::format::PrimRecord;

/// The table's records of `mesh`: one per triangle, in primitive-id order (degenerate
/// triangles too: an update that makes one non-degenerate finds it by its id).
pub fn prim_records(mesh: &Mesh) -> Vec<PrimRecord> {
    (0..mesh.triangles.len())
        .into_par_iter()
        .map(|i| PrimRecord {
            v: mesh.triangle(i),
        })
        .collect()
}
