//! Preparing a mesh's triangles: validated, degenerate ones dropped, the root cube fitted, the
//! rest mapped into the lattice.

use rayon::prelude::*;

use super::subdivide::LatticeTri;
use crate::error::Error;
use crate::geom::triangle::is_degenerate;
use crate::mesh::Mesh;
use crate::physical::format::{LATTICE_SIZE, MAX_ROOT_SIZE, MIN_ROOT_SIZE, TriRecord, root_cube};

pub(super) struct Prepared {
    pub(super) records: Vec<TriRecord>,
    pub(super) lattice: Vec<LatticeTri>,
    pub(super) root_min: [f64; 3],
    pub(super) root_size: f64,
    pub(super) mesh_min: [f32; 3],
    pub(super) mesh_max: [f32; 3],
}

/// Validates the mesh, drops degenerate triangles, fits the root cube and maps the triangles
/// into the lattice; the root cube fitted to the union of the triangles' bounds and `room`
/// (`lo`, `hi`; room for the triangles to move into later, `oavm-pack --bounds`).
pub(super) fn prepare_within(
    mesh: &Mesh,
    room: Option<([f32; 3], [f32; 3])>,
) -> Result<Prepared, Error> {
    if mesh.triangles.is_empty() {
        return Err(Error::Invalid("the mesh has no triangles".into()));
    }
    if mesh.triangles.len() > u32::MAX as usize {
        return Err(Error::Invalid(format!(
            "{} triangles: primitive ids are 32-bit",
            mesh.triangles.len()
        )));
    }
    let n = mesh.positions.len();
    let mut records = Vec::with_capacity(mesh.triangles.len());
    for (i, tri) in mesh.triangles.iter().enumerate() {
        let mut v = [[0f32; 3]; 3];
        for (k, &ix) in tri.iter().enumerate() {
            let p = mesh.positions.get(ix as usize).ok_or_else(|| {
                Error::Invalid(format!(
                    "triangle {i} refers to vertex {ix}, the mesh has {n}"
                ))
            })?;
            if !p.iter().all(|c| c.is_finite()) {
                return Err(Error::Invalid(format!(
                    "vertex {ix} has non-finite coordinates {p:?}"
                )));
            }
            v[k] = *p;
        }
        if !is_degenerate(&v) {
            records.push(TriRecord { v, prim: i as u32 });
        }
    }

    // Bounds of the stored triangles (or of every vertex used, if all are degenerate).
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    let mut grow = |p: &[f32; 3]| {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    };
    if records.is_empty() {
        for tri in &mesh.triangles {
            tri.iter()
                .for_each(|&ix| grow(&mesh.positions[ix as usize]));
        }
    } else {
        records.iter().flat_map(|r| r.v.iter()).for_each(&mut grow);
    }

    let (root_min, root_size) = match room {
        Some((a, b)) => root_cube(
            std::array::from_fn(|k| lo[k].min(a[k])),
            std::array::from_fn(|k| hi[k].max(b[k])),
        ),
        None => root_cube(lo, hi),
    };
    check_scale(root_size)?;
    let scale = LATTICE_SIZE as f64 / root_size;

    let lattice = records
        .par_iter()
        .map(|r| {
            LatticeTri::new(std::array::from_fn(|i| {
                std::array::from_fn(|k| (r.v[i][k] as f64 - root_min[k]) * scale)
            }))
        })
        .collect();
    Ok(Prepared {
        records,
        lattice,
        root_min,
        root_size,
        mesh_min: lo,
        mesh_max: hi,
    })
}

/// Refuses a mesh whose extent (its root cube's edge) the f32 triangle test cannot trace
/// correctly (format-spec §2, [`MIN_ROOT_SIZE`]..=[`MAX_ROOT_SIZE`]): packed, it would
/// silently miss hits.
pub fn check_scale(root_size: f64) -> Result<(), Error> {
    if (MIN_ROOT_SIZE..=MAX_ROOT_SIZE).contains(&root_size) {
        return Ok(());
    }
    Err(Error::Invalid(format!(
        "the mesh's extent is {root_size:e} units; this version traces meshes whose extent is \
         between {MIN_ROOT_SIZE:e} and {MAX_ROOT_SIZE:e} units correctly (single-precision \
         triangle tests underflow or overflow outside): rescale the mesh"
    )))
}
