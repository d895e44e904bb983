//! BART AFF scene reader: the animated scenes of BART (Lext, Assarsson, Möller, "BART: A
//! Benchmark for Animated Ray Tracing", IEEE CG&A 2001; technical report 2000), posed at one
//! time and flattened to a [`Mesh`].
//!
//! AFF is Eric Haines' NFF extended with triangle meshes, textures, transforms, keyframe
//! animation and includes. A file is a stream of whitespace-separated tokens; a statement is a
//! keyword and its operands, which may span lines. `#` or `%` at the start of a token starts a
//! comment to the end of the line (the files put `%` comments after statements too). `{` and `}`
//! are tokens of their own even when written against another token.
//!
//! # Statements
//!
//! Geometry (kept, in file order):
//!
//! - `p n` then `n` vertices `x y z`: a polygon, fan-triangulated as PLY and OBJ faces are
//!   (`v0 v1 v2`, `v0 v2 v3`, ...); `pp n`: the same with a normal after each vertex (normals are
//!   skipped);
//! - `tt texture` then three `x y z u v`; `ttp texture` then three `x y z nx ny nz u v`: a
//!   textured triangle (patch);
//! - `m`: a triangle mesh, `vertices n` then `n` × `x y z`, optionally `normals n` then `n` ×
//!   `x y z`, optionally `texturecoords n texture` then `n` × `u v`, then `triangles n` then `n`
//!   index rows `v0 v1 v2 [n0 n1 n2] [t0 t1 t2]` (normal indices when the mesh has normals, texture
//!   indices when it has texture coordinates, as in BART's `getTriangles`). Every index is
//!   checked against its block; all of the mesh's vertices are kept, used or not;
//! - `tpa n` then `n` times `time` and three `x y z nx ny nz`: an animated triangle; at time `t`
//!   its corners are the linear interpolation of the two keys around `t`, clamped to the first
//!   and last key (BART's `viGetAnimatedTriangle`);
//! - `c bx by bz br ax ay az ar`: a cone or cylinder (NFF), open as in NFF (no caps),
//!   tessellated into [`CONE_SEGMENTS`] quads around the axis, two triangles each;
//! - `s x y z r`: a sphere (NFF), tessellated as a UV sphere of [`SPHERE_SLICES`] slices around
//!   the y axis and [`SPHERE_STACKS`] stacks from pole to pole: `2 × slices × (stacks - 1)`
//!   triangles (960), with `|r|` as radius.
//!
//! Transforms, composed on a stack:
//!
//! - `xs sx sy sz  rx ry rz deg  tx ty tz {`: a static transform `T R S` (scale, then rotation
//!   by `deg` degrees about the axis, then translation) for everything up to the matching `}`;
//! - `x name {`: an animated transform, `T R S` from the keyframes of `k name` at the scene time
//!   (identity when no `k name` exists); `}` closes either kind. Braces must balance within each
//!   file;
//! - `k name { motion n  rows... }` with motions `transl` (rows `t x y z T C B`), `rot` (rows
//!   `t ax ay az deg T C B`), `scale` (rows `t sx sy sz T C B`), each with at least 4 rows, and
//!   `visibility` (rows `t flag`). Transforms follow Kochanek–Bartels splines (Kochanek, Bartels
//!   1984): positions and scales as cubic Hermite segments, rotations as quaternion `squad`
//!   segments, as BART's reference code computes them; see `kb.rs` for the maths. `k`
//!   blocks may come before or after the `x` they animate, in any file; when a name has several
//!   `k` blocks the last one read counts (BART's list lookup finds the newest). An object is
//!   visible until its first visibility key, then as the latest key at or before the time says;
//!   the triangles of invisible subtrees are left out, the others keep their file order.
//!
//! Scene statements: `v` (a block of `from x y z`, `at x y z`, `up x y z`, `angle deg`,
//! `hither d`, `resolution w h`, all six required, in any order) gives [`AffView`]; `a start end
//! frames` gives the animation range (the default time is `start`, or 0 without `a`); `i level
//! file` includes `file` (relative to the including file's directory) when `level` is at most the
//! detail level (0, or as set by `d level`). A `k camera` block (BART's camera path) is read like
//! any other and not used: the camera is the `v` block.
//!
//! Shading statements, kept for a renderer (every operand a number finite as an `f32`):
//!
//! - `f r g b Kd Ks shine T ior` (NFF): the fill material, as [`AffMaterial`] holds it:
//!   ambient and diffuse colour `Kd × (r, g, b)`, specular `Ks` in every channel, the Phong
//!   exponent `shine`, transmittance `T`, index of refraction `ior`;
//! - `fm ar ag ab  dr dg db  sr sg sb  shine T ior` (BART's extension of NFF): the ambient,
//!   diffuse and specular colours given apart, then the same three numbers. BART's scenes
//!   write `ior` 0 for opaque materials; the numbers are kept as written;
//! - as in NFF and BART's reference parser, a material is the current one for every primitive
//!   after it in reading order, until the next `f` or `fm`, whatever transforms or includes lie
//!   between (an include's material stays current after it). Primitives before any material
//!   take [`AffMaterial::DEFAULT`]. [`AffScene::materials`] lists the default first, then each
//!   distinct material in the order first read (materials equal in all twelve numbers share an
//!   entry); [`AffScene::material_of`] gives each triangle's entry, triangle by triangle as the
//!   mesh holds them (so by primitive id), invisible subtrees left out with their triangles;
//! - `l x y z [r g b]`: a point light, its position placed by the transforms around it
//!   ([`AffScene::lights`]), its colour white when none is given ([`AffScene::light_colours`]);
//! - `b r g b`: the background colour ([`AffScene::background`]; black without one);
//!   `am r g b`: the global ambient light ([`AffScene::ambient`]; white, `am 1 1 1`, without
//!   one). Both as BART's reference parser documents them; the last one read counts.
//!
//! An unknown keyword is an error, as in BART's reference parser (which stops on an unknown
//! code): the scenes use no other keyword, and skipping would misread the operands that follow.
//!
//! # Counts
//!
//! [`AffCounts::polygons`] counts the polygon statements (`p`, `pp`, `tt`, `ttp`, and each row
//! of a mesh's `triangles` block) before fan triangulation: the "polygons" of the BART scene
//! headers and of the OAVM paper. Animated triangles, cones and spheres are counted apart.
//! Measured (`tests/integration/mesh_aff.rs`): the kitchen has 110,561 polygons (all triangles; 63,706
//! vertices), the robots 71,708 (134,127 vertices), museum level 5 10,143 polygons (10,284
//! triangles) plus 1,024 animated triangles and 8 cones (256 triangles).
//!
//! # Untrusted input
//!
//! Every failure is a [`MeshError`] naming the file and line where it is; an error in an
//! included file is wrapped in [`MeshError::Included`] for each including statement, so the
//! message reads as the include chain from the top file down. No declared count sizes an
//! allocation: vectors grow with the values actually read. Includes are guarded against cycles
//! (by lexically normalised path), against nesting deeper than [`MAX_INCLUDE_DEPTH`], and against
//! exponential expansion: all include instances together may hold at most [`MAX_PARSED_BYTES`]
//! (each counting [`INCLUDE_COST`] more than its size), so the mesh made stays within a small
//! multiple of that. Files are read from the file system through `mesh::read`: an include whose
//! size is more than what is left of that budget is refused before it is read, no read takes
//! more than what is left, and a file that changes while it is read is an error
//! ([`MeshError::Changed`]).

mod geometry;
mod kb;
mod keyframes;
mod material;
mod parser;
mod pose;
mod tessellate;
mod tokens;
mod transform;
mod view;
mod work;

use std::path::{Component, Path, PathBuf};

use glam::DVec3;

use super::read::{ReadError, read_file};
use super::{Mesh, MeshError};
use parser::Parser;
use transform::apply;

/// Quads around a cone or cylinder.
pub const CONE_SEGMENTS: u32 = 16;
/// Slices around a sphere's axis.
pub const SPHERE_SLICES: u32 = 32;
/// Stacks of a sphere from pole to pole.
pub const SPHERE_STACKS: u32 = 16;
/// Deepest include nesting (the top file is depth 0).
pub const MAX_INCLUDE_DEPTH: usize = 32;
/// Most bytes parsed over the top file and every include instance (a file included ten times
/// counts ten times, and each inclusion counts [`INCLUDE_COST`] bytes more): 256 MiB, over
/// twenty times what the largest BART scene reads (the robots: 11.2 MB in 836 files read,
/// 14.6 MB with the inclusion cost).
pub const MAX_PARSED_BYTES: u64 = 256 << 20;
/// What an inclusion costs against [`MAX_PARSED_BYTES`] beyond its bytes, so that many tiny
/// includes cannot make a great deal of work from a budget of bytes.
pub const INCLUDE_COST: u64 = 4096;

/// The `v` block: the viewpoint. NFF's `angle` is read as the vertical field of view, as
/// BART's OpenGL viewer uses it (`gluPerspective`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffView {
    pub from: [f64; 3],
    pub at: [f64; 3],
    pub up: [f64; 3],
    pub angle_deg: f64,
    pub hither: f64,
    pub resolution: (u32, u32),
}

/// What the scene's statements held.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AffCounts {
    /// `p`, `pp`, `tt`, `ttp` statements and mesh triangles, before fan triangulation.
    pub polygons: u64,
    /// `tpa` statements.
    pub animated_triangles: u64,
    /// `c` statements.
    pub cones: u64,
    /// `s` statements.
    pub spheres: u64,
}

/// A surface material, from `f` or `fm` (see the [module documentation](self) for how each
/// fills it). The numbers are as written (finite); a renderer decides what to do with odd
/// ones (negative colours, `ior` 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffMaterial {
    /// Reflectance of the ambient light ([`AffScene::ambient`]).
    pub ambient: [f32; 3],
    /// Lambertian reflectance of the lights.
    pub diffuse: [f32; 3],
    /// Phong highlight and mirror reflectance.
    pub specular: [f32; 3],
    /// Phong exponent.
    pub shine: f32,
    /// Transmittance `T`: the fraction of light passed through.
    pub transmittance: f32,
    /// Index of refraction.
    pub ior: f32,
}

impl AffMaterial {
    /// The material of primitives before any `f` or `fm`: white, diffuse, as `f 1 1 1 0.8 0
    /// 0 0 1` would give.
    pub const DEFAULT: AffMaterial = AffMaterial {
        ambient: [0.8; 3],
        diffuse: [0.8; 3],
        specular: [0.0; 3],
        shine: 0.0,
        transmittance: 0.0,
        ior: 1.0,
    };
}

/// A scene posed at [`time`](AffScene::time).
#[derive(Clone, Debug)]
pub struct AffScene {
    pub mesh: Mesh,
    pub view: Option<AffView>,
    /// BART's animated camera (`k camera`) at the scene time, when the scene has one: the `v`
    /// block's field of view, hither and resolution, placed by the camera's transform `M` as
    /// BART's viewer places an OpenGL camera: `from = M (0,0,0)`, `at = M (0,0,-1)`, `up` = `M`'s
    /// rotation of `(0,1,0)`. It is the frame the animation renders at that time, inside the
    /// scene, where the `v` block may be a close-up (kitchen) or outside the scene (robots).
    pub camera_path: Option<AffView>,
    /// `a start end frames`.
    pub animation: Option<(f64, f64, u64)>,
    /// The time the scene is posed at.
    pub time: f64,
    /// The point lights (`l`), placed by the transforms around them.
    pub lights: Vec<[f64; 3]>,
    /// The colour of each light of [`lights`](AffScene::lights) (white when `l` gives none).
    pub light_colours: Vec<[f32; 3]>,
    /// The default material, then every distinct material of `f` and `fm`.
    pub materials: Vec<AffMaterial>,
    /// The index in [`materials`](AffScene::materials) of each triangle of `mesh`, in the order
    /// of `mesh.triangles` (by primitive id).
    pub material_of: Vec<u32>,
    /// The background colour (`b`; black without one).
    pub background: [f32; 3],
    /// The global ambient light (`am`; white without one).
    pub ambient: [f32; 3],
    pub counts: AffCounts,
}

impl AffScene {
    /// Polygons before triangulation (see [`AffCounts::polygons`]).
    pub fn faces(&self) -> u64 {
        self.counts.polygons
    }
}

/// Reads the AFF scene `path` and its includes from the file system, posed at `time` (default:
/// the animation start, or 0).
pub fn load_aff(path: &Path, time: Option<f64>) -> Result<AffScene, MeshError> {
    load_aff_within(path, time, MAX_PARSED_BYTES)
}

/// [`load_aff`] with all files together bounded by `budget` bytes (at most
/// [`MAX_PARSED_BYTES`]) instead of [`MAX_PARSED_BYTES`].
pub(crate) fn load_aff_within(
    path: &Path,
    time: Option<f64>,
    budget: u64,
) -> Result<AffScene, MeshError> {
    let bytes = read_file(path, budget).map_err(|e| read_error(e, path, budget, budget))?;
    parse_within(&bytes, path, time, budget, &mut read_file)
}

/// Parses the AFF scene held in `bytes`, named `name` in errors; includes are read from the file
/// system, relative to `name`'s directory.
pub fn parse_aff(bytes: &[u8], name: &str, time: Option<f64>) -> Result<AffScene, MeshError> {
    parse_within(
        bytes,
        Path::new(name),
        time,
        MAX_PARSED_BYTES,
        &mut read_file,
    )
}

/// Parses the AFF scene held in `bytes`, whose path is `path` (for errors and for resolving
/// includes), reading included files with `read`. `read` is given no size limit: the budget
/// ([`MAX_PARSED_BYTES`]) is checked on what it returns.
pub fn parse_aff_with(
    bytes: &[u8],
    path: &Path,
    time: Option<f64>,
    read: &mut dyn FnMut(&Path) -> std::io::Result<Vec<u8>>,
) -> Result<AffScene, MeshError> {
    parse_within(bytes, path, time, MAX_PARSED_BYTES, &mut |p, _| {
        read(p).map_err(ReadError::Io)
    })
}

/// Reads an included file: its path and the most bytes it may hold.
type ReadInclude<'r> = dyn FnMut(&Path, u64) -> Result<Vec<u8>, ReadError> + 'r;

/// The [`MeshError`] of a failed read of `path`, when `left` bytes were left of `budget`.
fn read_error(e: ReadError, path: &Path, left: u64, budget: u64) -> MeshError {
    match e {
        ReadError::Io(source) => MeshError::Io {
            path: path.to_owned(),
            source,
        },
        ReadError::TooLarge { bytes } => MeshError::TooLarge {
            file: path.display().to_string(),
            detail: format!(
                "the file holds {bytes} bytes, more than the {left} bytes left of the {budget} \
                 bytes of AFF a scene may read (counting a file once per inclusion, and \
                 {INCLUDE_COST} bytes more for each)"
            ),
        },
        ReadError::Changed => MeshError::Changed {
            path: path.to_owned(),
        },
    }
}

fn parse_within(
    bytes: &[u8],
    path: &Path,
    time: Option<f64>,
    budget: u64,
    read: &mut ReadInclude,
) -> Result<AffScene, MeshError> {
    let name = path.display().to_string();
    if let Some(t) = time
        && !t.is_finite()
    {
        return Err(MeshError::BadTime {
            file: name,
            time: t,
        });
    }
    let mut p = Parser::new(read, budget);
    let top = normalize(path);
    p.stack.push(top);
    p.parsed = bytes.len() as u64;
    check_budget(p.parsed, budget, &name)?;
    p.parse_file(bytes, &name, path)?;
    p.sync_materials();
    let time = time.unwrap_or(p.animation.map_or(0.0, |a| a.0));
    let pose = p.pose(time)?;
    super::check_sizes(&pose.mesh, &name)?;
    let camera_path = match (&p.view, pose.camera) {
        (Some(v), Some(m)) => {
            let from = apply(&m, DVec3::ZERO);
            let at = apply(&m, DVec3::NEG_Z);
            let up_point = apply(&m, DVec3::Y);
            Some(AffView {
                from: from.to_array(),
                at: at.to_array(),
                up: (up_point - from).to_array(),
                ..*v
            })
        }
        _ => None,
    };
    Ok(AffScene {
        mesh: pose.mesh,
        camera_path,
        view: p.view,
        animation: p.animation,
        time,
        lights: pose.lights,
        light_colours: p.lights.iter().map(|l| l.2).collect(),
        material_of: pose.material_of,
        materials: p.materials.list,
        background: p.background,
        ambient: p.ambient,
        counts: p.counts,
    })
}

fn check_budget(parsed: u64, budget: u64, file: &str) -> Result<(), MeshError> {
    if parsed > budget {
        return Err(MeshError::TooLarge {
            file: file.to_owned(),
            detail: format!(
                "the includes expand to more than {budget} bytes of AFF (counting a file once \
                 per inclusion)"
            ),
        });
    }
    Ok(())
}

/// `path` with `.` removed and `..` folded where it follows a normal component.
fn normalize(path: &Path) -> PathBuf {
    let mut out: Vec<Component> = Vec::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.last(), Some(Component::Normal(_))) => {
                out.pop();
            }
            _ => out.push(c),
        }
    }
    out.iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_are_normalised_lexically() {
        assert_eq!(normalize(Path::new("a/./b/../c.aff")), Path::new("a/c.aff"));
        assert_eq!(normalize(Path::new("../x/../y")), Path::new("../y"));
        assert_eq!(normalize(Path::new("/r/./s")), Path::new("/r/s"));
    }

    /// A scene with one `k` block of `n` keys of each motion, `n` transforms `x` using it, and
    /// one animated triangle of `n` keys.
    fn keyed_scene(n: usize) -> String {
        let mut s = String::from("k a {\n");
        for motion in ["transl", "scale"] {
            s += &format!("{motion} {n}\n");
            for i in 0..n {
                s += &format!("{i} {} 1 {} 0 0 0\n", 1 + i % 3, i % 5);
            }
        }
        s += &format!("rot {n}\n");
        for i in 0..n {
            s += &format!("{i} 0 1 0 {} 0 0 0\n", (i * 37) % 360);
        }
        s += &format!("visibility {n}\n");
        for i in 0..n {
            s += &format!("{i} 1\n");
        }
        s += "}\n";
        for _ in 0..n {
            s += "x a { p 3 0 0 0 1 0 0 0 1 0 }\n";
        }
        s += &format!("tpa {n}\n");
        for i in 0..n {
            s += &format!("{i} 0 0 {i} 0 0 1 1 0 {i} 0 0 1 0 1 {i} 0 0 1\n");
        }
        s
    }

    /// The review's quadratic case: every `x` re-evaluated its animation's splines, each
    /// evaluation read all the keys, and key searches were linear. Posing must evaluate each
    /// animation once, and read each key a bounded number of times (once to prepare its
    /// spline) plus a logarithmic number of keys per evaluation.
    #[test]
    fn posing_reads_each_key_a_bounded_number_of_times() {
        let no_includes = &mut |_: &Path| -> std::io::Result<Vec<u8>> {
            Err(std::io::ErrorKind::NotFound.into())
        };
        for n in [16usize, 256, 2048] {
            let text = keyed_scene(n);
            for time in [-1.0, 0.3 * n as f64, n as f64 - 2.5, 2.0 * n as f64] {
                work::take();
                let s = parse_aff_with(
                    text.as_bytes(),
                    Path::new("work.aff"),
                    Some(time),
                    no_includes,
                )
                .unwrap_or_else(|e| panic!("{e}"));
                let (keys, evaluations) = work::take();
                assert_eq!(s.mesh.triangles.len(), n + 1);
                assert_eq!(
                    evaluations, 1,
                    "n = {n}, t = {time}: the one animation is evaluated once, not once per `x`"
                );
                // 5 key lists of n keys; a few reads per key, 64 per key search at most.
                let bound = 8 * 5 * n as u64 + 5 * 64;
                assert!(
                    keys <= bound,
                    "n = {n}, t = {time}: {keys} key reads, more than {bound}"
                );
            }
        }
    }
}
