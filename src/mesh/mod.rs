//! Mesh input: PLY (ascii, binary little- and big-endian), OBJ (through `tobj`), STL (binary
//! and ASCII), OFF and BART AFF scenes (posed at one time of their animation, see [`aff`]).
//!
//! Everything read here is untrusted: any bytes give a [`Mesh`] or a [`MeshError`] naming the
//! file and the place, never a panic, and no count read from a file makes us allocate more than
//! the file's own size can back. A file is read whole only up to a size limit ([`LoadLimits`],
//! checked before reading), and must not change while it is read ([`MeshError::Changed`]). The
//! parsers work on `&[u8]`, so they run the same over a `Vec` and over a memory-mapped file.
//!
//! Primitive ids follow `../shared/RAYS.md`: triangle `i` of [`Mesh::triangles`] is the `i`-th
//! triangle of the file after fan triangulation, in file order. `positions[i]` is the file's
//! vertex `i` (PLY vertex record `i`, OBJ `v` line `i + 1`), used or not.

pub mod aff;
mod gltf;
mod obj;
mod off;
mod ply;
mod read;
mod stl;
pub mod stream;

use std::path::Path;

pub use crate::error::{MeshError, Place};
pub use aff::{AffCounts, AffScene, AffView, load_aff, parse_aff, parse_aff_with};
pub use gltf::parse_gltf;
pub use obj::parse_obj;
pub use off::parse_off;
pub use ply::parse_ply;
pub use stl::parse_stl;

/// A triangle mesh as read from a file. `triangles[i]` has primitive id `i`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    /// The meshes it was made of, when it was made of several (a glTF scene's placed meshes,
    /// a list given to `oavm.pack`): runs of primitive ids that cover `triangles` in order,
    /// stored in the file as its geometry table (format-spec §8.8). Empty: one mesh, no table.
    pub geometries: Vec<Geometry>,
}

/// One of the meshes a [`Mesh`] or a file was made of (format-spec §8.8): primitive ids
/// `first_primitive .. first_primitive + primitive_count`, named, placed by `transform`
/// (row-major 3x4, applied to its vertices before they were stored; the identity when none).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Geometry {
    pub name: String,
    pub first_primitive: u64,
    pub primitive_count: u64,
    pub transform: [[f64; 4]; 3],
}

impl Geometry {
    /// The identity transform.
    pub const IDENTITY: [[f64; 4]; 3] = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];

    /// The primitive ids it holds.
    pub fn primitives(&self) -> std::ops::Range<u64> {
        self.first_primitive..self.first_primitive + self.primitive_count
    }
}

/// Which of `geometries` (a table that covers the primitive ids in order) holds primitive
/// `prim`, and the primitive's index within it; `None` past the last.
pub fn locate_primitive(geometries: &[Geometry], prim: u64) -> Option<(u32, u64)> {
    let g = geometries.partition_point(|g| g.first_primitive + g.primitive_count <= prim);
    let geo = geometries.get(g)?;
    geo.primitives()
        .contains(&prim)
        .then(|| (g as u32, prim - geo.first_primitive))
}

/// Whether `geometries` cover primitive ids `0..primitives` one after another, in order (an
/// error says where not): what a geometry table must be.
pub fn check_geometries(geometries: &[Geometry], primitives: u64) -> Result<(), String> {
    let mut next = 0u64;
    for (i, g) in geometries.iter().enumerate() {
        if g.first_primitive != next {
            return Err(format!(
                "geometry {i} ({:?}) starts at primitive {}, the one before it ends at {next}",
                g.name, g.first_primitive
            ));
        }
        if g.transform.iter().flatten().any(|x| !x.is_finite()) {
            return Err(format!(
                "geometry {i} ({:?}) has a non-finite transform",
                g.name
            ));
        }
        next = next
            .checked_add(g.primitive_count)
            .ok_or_else(|| format!("geometry {i} ({:?}): its primitive count overflows", g.name))?;
    }
    if !geometries.is_empty() && next != primitives {
        return Err(format!(
            "the geometries hold {next} primitives, the mesh {primitives}"
        ));
    }
    Ok(())
}

impl Mesh {
    /// The corners of every triangle, by primitive id (what `geom::reference` takes).
    pub fn corners(&self) -> Vec<[[f32; 3]; 3]> {
        (0..self.triangles.len())
            .map(|i| self.triangle(i))
            .collect()
    }

    /// One mesh of several (format-spec §8.8: each becomes a geometry, in order, named as
    /// given, its primitives numbered after the previous ones'). A part that has geometries of
    /// its own (a glTF scene) keeps them, their names prefixed with its name and `/`.
    pub fn join(parts: Vec<(String, Mesh)>) -> Result<Mesh, String> {
        let mut out = Mesh::default();
        for (name, part) in parts {
            let base = out.positions.len();
            if base + part.positions.len() > 1 << 32 {
                return Err(format!("{name}: more than 2^32 vertices in all"));
            }
            let n = part.positions.len() as u64;
            if let Some(i) = part
                .triangles
                .iter()
                .position(|t| t.iter().any(|&v| v as u64 >= n))
            {
                return Err(format!(
                    "{name}: triangle {i} holds a vertex index past its {n} vertices"
                ));
            }
            let first = out.triangles.len() as u64;
            out.positions.extend_from_slice(&part.positions);
            out.triangles
                .extend(part.triangles.iter().map(|t| t.map(|v| v + base as u32)));
            match part.geometries.is_empty() {
                true => out.geometries.push(Geometry {
                    name,
                    first_primitive: first,
                    primitive_count: part.triangles.len() as u64,
                    transform: Geometry::IDENTITY,
                }),
                false => out
                    .geometries
                    .extend(part.geometries.into_iter().map(|g| Geometry {
                        name: format!("{name}/{}", g.name),
                        first_primitive: first + g.first_primitive,
                        ..g
                    })),
            }
        }
        Ok(out)
    }

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

/// How much of a file [`load_with`] may read whole into memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoadLimits {
    /// The largest PLY or OBJ file read: a larger one is an error
    /// ([`MeshError::FileTooLarge`]) before a byte of it is read. For an AFF scene, the budget
    /// of all its files together ([`aff::MAX_PARSED_BYTES`]) is lowered to this when it is
    /// smaller.
    pub max_file_bytes: u64,
}

impl LoadLimits {
    /// The limit of [`load`] and [`load_at`]: 64 GiB, a bound on what one file may make us
    /// allocate, not a fit to any machine. The tools pass a tighter one, from the memory they
    /// may use; a mesh beyond it is for the streaming pack (`oavm-pack --mem-budget`).
    pub const DEFAULT_MAX_FILE_BYTES: u64 = 64 << 30;
}

impl Default for LoadLimits {
    fn default() -> LoadLimits {
        LoadLimits {
            max_file_bytes: LoadLimits::DEFAULT_MAX_FILE_BYTES,
        }
    }
}

/// Reads the mesh in `path`. The format is PLY if the file starts with the PLY magic line,
/// else a BART AFF scene if the extension is `.aff` (posed at its default time, see
/// [`load_aff`]), else STL if the extension is `.stl` or the file is a binary STL by its length,
/// else OFF if the extension is `.off` or it starts with an OFF header, else ASCII STL if it
/// starts with `solid`, else OBJ if the extension is `.obj` or the first statements are OBJ
/// statements.
/// The file may hold up to [`LoadLimits::DEFAULT_MAX_FILE_BYTES`] (see [`load_with`]).
pub fn load(path: &Path) -> Result<Mesh, MeshError> {
    load_at(path, None)
}

/// Like [`load`], posing an AFF scene at `time` (`None`: its default time). A time for a file
/// that is not AFF is an error ([`MeshError::NotAnimated`]).
pub fn load_at(path: &Path, time: Option<f64>) -> Result<Mesh, MeshError> {
    load_with(path, time, &LoadLimits::default())
}

/// Like [`load_at`], reading at most `limits.max_file_bytes` of the file. The file must not
/// change while it is read ([`MeshError::Changed`]).
pub fn load_with(path: &Path, time: Option<f64>, limits: &LoadLimits) -> Result<Mesh, MeshError> {
    if is_aff(path) {
        let budget = limits.max_file_bytes.min(aff::MAX_PARSED_BYTES);
        return aff::load_aff_within(path, time, budget).map(|scene| scene.mesh);
    }
    if time.is_some() {
        return Err(MeshError::NotAnimated {
            file: path.display().to_string(),
        });
    }
    let name = path.display().to_string();
    let bytes = read::read_file(path, limits.max_file_bytes).map_err(|e| match e {
        read::ReadError::Io(source) => MeshError::Io {
            path: path.to_owned(),
            source,
        },
        read::ReadError::TooLarge { bytes } => MeshError::FileTooLarge {
            file: name.clone(),
            bytes,
            limit: limits.max_file_bytes,
        },
        read::ReadError::Changed => MeshError::Changed {
            path: path.to_owned(),
        },
    })?;
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    if ply::has_magic(&bytes) {
        return parse_ply(&bytes, &name);
    }
    if matches!(extension.as_deref(), Some("gltf" | "glb")) || gltf::is_glb(&bytes) {
        let dir = path.parent().unwrap_or(Path::new("."));
        return parse_gltf(&bytes, &name, Some(dir), limits.max_file_bytes);
    }
    if extension.as_deref() == Some("stl") || stl::is_binary(&bytes) {
        return parse_stl(&bytes, &name);
    }
    if extension.as_deref() == Some("off") || off::looks_like_off(&bytes) {
        return parse_off(&bytes, &name);
    }
    if stl::looks_like_ascii(&bytes) {
        return parse_stl(&bytes, &name);
    }
    if extension.as_deref() == Some("obj") || obj::looks_like_obj(&bytes) {
        return parse_obj(&bytes, &name);
    }
    let detail = if extension.as_deref() == Some("ply") {
        "the file is named .ply but does not start with the PLY magic line `ply`".to_owned()
    } else {
        "it starts with neither the PLY magic line `ply`, nor `OFF`, nor `solid` (ASCII STL), \
         nor OBJ statements, is not a binary STL file (84 + 50 bytes a facet) nor a GLB \
         (magic `glTF`; a glTF JSON file is read by its extension, .gltf)"
            .to_owned()
    };
    Err(MeshError::UnknownFormat { file: name, detail })
}

/// Whether `path` names a BART AFF scene (by its extension, `.aff` in any case).
pub fn is_aff(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("aff"))
}

/// Fan triangulation, fed one polygon corner at a time (RAYS.md, "Primitive ids"): the polygon
/// `v0 v1 ... vk` becomes `(v0, v1, v2), (v0, v2, v3), ...`; fewer than three corners give no
/// triangle; degenerate triangles are kept. Streaming it means a polygon's declared length never
/// sizes an allocation.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Fan {
    first: u32,
    prev: u32,
    corners: u32,
}

impl Fan {
    #[inline]
    pub(crate) fn push(&mut self, corner: u32, out: &mut Vec<[u32; 3]>) {
        match self.corners {
            0 => self.first = corner,
            1 => {}
            _ => out.push([self.first, self.prev, corner]),
        }
        self.prev = corner;
        self.corners = self.corners.saturating_add(1);
    }
}

/// A token as an error message shows it: its first 40 bytes, lossy UTF-8.
pub(crate) fn shown(t: &[u8]) -> String {
    String::from_utf8_lossy(&t[..t.len().min(40)]).into_owned()
}

/// Token `t` (on line `line` of `file`) read as a `T`, or a [`MeshError::BadValue`] saying
/// `what: `t` is not a(n) noun`.
pub(crate) fn token<T: std::str::FromStr>(
    t: &[u8],
    line: u64,
    file: &str,
    what: &str,
    noun: &str,
) -> Result<T, MeshError> {
    std::str::from_utf8(t)
        .ok()
        .and_then(|s| s.parse::<T>().ok())
        .ok_or_else(|| MeshError::BadValue {
            file: file.to_owned(),
            at: Place::Line(line),
            detail: format!("{what}: `{}` is not {noun}", shown(t)),
        })
}

/// For the readers' tests: `parse` gives a mesh or an error (never panics) on every prefix of
/// `file` and on `file` with each of its bytes changed in turn.
#[cfg(test)]
pub(crate) fn survives_damage<T>(file: &[u8], parse: impl Fn(&[u8]) -> T) {
    for n in 0..=file.len() {
        parse(&file[..n]);
        let mut changed = file.to_vec();
        if let Some(b) = changed.get_mut(n) {
            *b = b.wrapping_mul(31).wrapping_add(7);
        }
        parse(&changed);
    }
}

/// Checks what both formats promise on success: some triangles, and few enough of them, and of
/// vertices, for `u32` ids (`0xFFFFFFFF` stays free: RAYS.md uses it for a miss).
fn check_sizes(mesh: &Mesh, file: &str) -> Result<(), MeshError> {
    if mesh.triangles.is_empty() {
        return Err(MeshError::Empty {
            file: file.to_owned(),
        });
    }
    if mesh.positions.len() > u32::MAX as usize + 1 {
        return Err(MeshError::TooLarge {
            file: file.to_owned(),
            detail: format!("{} vertices; vertex indices are u32", mesh.positions.len()),
        });
    }
    if mesh.triangles.len() >= u32::MAX as usize {
        return Err(MeshError::TooLarge {
            file: file.to_owned(),
            detail: format!(
                "{} triangles; primitive ids are u32 below 0xFFFFFFFF",
                mesh.triangles.len()
            ),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir).expect("src/mesh") {
            let path = entry.expect("src/mesh").path();
            if path.is_dir() {
                sources(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }

    /// Mesh input sits below the tracer: it uses glam for its vector maths and imports nothing
    /// from the tracer's `rays` module.
    #[test]
    fn mesh_input_does_not_import_the_rays_layer() {
        let mut files = Vec::new();
        sources(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("src/mesh"),
            &mut files,
        );
        assert!(files.len() > 10, "{files:?}");
        for file in files {
            let text = std::fs::read_to_string(&file).expect("a source file");
            assert!(
                !text.contains(concat!("crate::", "rays")),
                "{} imports the rays module",
                file.display()
            );
        }
    }
}
