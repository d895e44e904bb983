//! Mesh input: PLY (ascii, binary little- and big-endian) and OBJ (through `tobj`).
//!
//! Everything read here is untrusted. Primitive ids follow `../shared/RAYS.md`: triangle `i` of
//! [`Mesh::triangles`] is the `i`-th triangle of the file after fan triangulation, in file order.

use std::path::Path;

/// A triangle mesh as read from a file. `triangles[i]` has primitive id `i`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// The three corners of triangle `i`.
    pub fn triangle(&self, i: usize) -> [[f32; 3]; 3] {
        let [a, b, c] = self.triangles[i];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }
}

/// Placeholder until the mesh readers land.
#[derive(Debug, thiserror::Error)]
#[error("mesh readers are being written")]
pub struct MeshError;

pub fn load(_path: &Path) -> Result<Mesh, MeshError> {
    Err(MeshError)
}
