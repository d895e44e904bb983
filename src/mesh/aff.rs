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
//!   segments, as BART's reference code computes them; see [`super::kb`] for the maths. `k`
//!   blocks may come before or after the `x` they animate, in any file; when a name has several
//!   `k` blocks the last one read counts (BART's list lookup finds the newest). An object is
//!   visible until its first visibility key, then as the latest key at or before the time says;
//!   the triangles of invisible subtrees are left out, the others keep their file order.
//!
//! Scene statements: `v` (a block of `from x y z`, `at x y z`, `up x y z`, `angle deg`,
//! `hither d`, `resolution w h`, all six required, in any order) gives [`AffView`]; `a start end
//! frames` gives the animation range (the default time is `start`, or 0 without `a`); `i level
//! file` includes `file` (relative to the including file's directory) when `level` is at most the
//! detail level (0, or as set by `d level`). Read and skipped, with their operands checked as
//! numbers: `b r g b`, `am r g b`, `l x y z [r g b]` (only the position is kept, in
//! [`AffScene::lights`]), `f r g b Kd Ks shine T ior` (8 numbers),
//! `fm` (12 numbers: ambient, diffuse, specular colours, shine, transmittance, index of
//! refraction). A `k camera` block (BART's camera path) is read like any other and not used: the
//! camera is the `v` block.
//!
//! An unknown keyword is an error, as in BART's reference parser (which stops on an unknown
//! code): the scenes use no other keyword, and skipping would misread the operands that follow.
//!
//! # Counts
//!
//! [`AffCounts::polygons`] counts the polygon statements (`p`, `pp`, `tt`, `ttp`, and each row
//! of a mesh's `triangles` block) before fan triangulation: the "polygons" of the BART scene
//! headers and of the OAVM paper. Animated triangles, cones and spheres are counted apart.
//! Measured (`tests/mesh_aff.rs`): the kitchen has 110,561 polygons (all triangles; 63,706
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
//! multiple of that.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::rc::Rc;

use super::kb::{self, MIN_KEYS, Quat, RotKey, VecKey};
use super::{Fan, Mesh, MeshError, Place};

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
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_owned(),
        source,
    })?;
    parse_aff_with(&bytes, path, time, &mut |p| std::fs::read(p))
}

/// Parses the AFF scene held in `bytes`, named `name` in errors; includes are read from the file
/// system, relative to `name`'s directory.
pub fn parse_aff(bytes: &[u8], name: &str, time: Option<f64>) -> Result<AffScene, MeshError> {
    parse_aff_with(bytes, Path::new(name), time, &mut |p| std::fs::read(p))
}

/// Parses the AFF scene held in `bytes`, whose path is `path` (for errors and for resolving
/// includes), reading included files with `read`.
pub fn parse_aff_with(
    bytes: &[u8],
    path: &Path,
    time: Option<f64>,
    read: &mut dyn FnMut(&Path) -> std::io::Result<Vec<u8>>,
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
    let mut p = Parser::new(read);
    let top = normalize(path);
    p.stack.push(top);
    p.parsed = bytes.len() as u64;
    check_budget(p.parsed, &name)?;
    p.parse_file(bytes, &name, path)?;
    let time = time.unwrap_or(p.animation.map_or(0.0, |a| a.0));
    let (mesh, lights) = p.pose(time)?;
    super::check_sizes(&mesh, &name)?;
    let camera_path = match (&p.view, p.animations.get(&b"camera"[..])) {
        (Some(v), Some(a)) => {
            let m = a.matrix(time);
            let from = apply(&m, [0.0; 3]);
            let at = apply(&m, [0.0, 0.0, -1.0]);
            let up_point = apply(&m, [0.0, 1.0, 0.0]);
            Some(AffView {
                from,
                at,
                up: std::array::from_fn(|k| up_point[k] - from[k]),
                ..*v
            })
        }
        _ => None,
    };
    Ok(AffScene {
        mesh,
        camera_path,
        view: p.view,
        animation: p.animation,
        time,
        lights,
        counts: p.counts,
    })
}

fn check_budget(parsed: u64, file: &str) -> Result<(), MeshError> {
    if parsed > MAX_PARSED_BYTES {
        return Err(MeshError::TooLarge {
            file: file.to_owned(),
            detail: format!(
                "the includes expand to more than {MAX_PARSED_BYTES} bytes of AFF (counting a \
                 file once per inclusion)"
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

// ---------------------------------------------------------------------------------------------
// Tokens

struct Tokens<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: u64,
    /// The line of the last token returned (1 before any): where a truncation is reported.
    last: u64,
}

impl<'a> Tokens<'a> {
    fn new(bytes: &'a [u8]) -> Tokens<'a> {
        Tokens {
            bytes,
            pos: 0,
            line: 1,
            last: 1,
        }
    }

    /// The next token and its line.
    fn next(&mut self) -> Option<(&'a [u8], u64)> {
        let b = self.bytes;
        loop {
            while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
                if b[self.pos] == b'\n' {
                    self.line += 1;
                }
                self.pos += 1;
            }
            if self.pos >= b.len() {
                return None;
            }
            if b[self.pos] == b'#' || b[self.pos] == b'%' {
                while self.pos < b.len() && b[self.pos] != b'\n' {
                    self.pos += 1;
                }
                continue;
            }
            let start = self.pos;
            if b[start] == b'{' || b[start] == b'}' {
                self.pos += 1;
            } else {
                while self.pos < b.len()
                    && !b[self.pos].is_ascii_whitespace()
                    && b[self.pos] != b'{'
                    && b[self.pos] != b'}'
                {
                    self.pos += 1;
                }
            }
            self.last = self.line;
            return Some((&b[start..self.pos], self.line));
        }
    }

    fn peek(&self) -> Option<&'a [u8]> {
        let mut t = Tokens { ..*self };
        t.next().map(|(tok, _)| tok)
    }
}

fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(tok);
    if s.chars().count() > 40 {
        format!("{}…", s.chars().take(40).collect::<String>())
    } else {
        s.into_owned()
    }
}

fn parse_number(tok: &[u8]) -> Option<f64> {
    let s = std::str::from_utf8(tok).ok()?;
    // Rust also reads "inf" and "nan"; those are rejected by the finiteness check.
    s.parse::<f64>().ok()
}

fn looks_like_number(tok: &[u8]) -> bool {
    parse_number(tok).is_some()
}

/// One file being read: its tokens and its name for errors.
struct Src<'a> {
    tok: Tokens<'a>,
    file: &'a str,
}

impl<'a> Src<'a> {
    fn aff(&self, line: u64, detail: String) -> MeshError {
        MeshError::Aff {
            file: self.file.to_owned(),
            line,
            detail,
        }
    }

    fn token(&mut self, what: &dyn Fn() -> String) -> Result<(&'a [u8], u64), MeshError> {
        self.tok.next().ok_or_else(|| MeshError::Truncated {
            file: self.file.to_owned(),
            at: Place::Line(self.tok.last),
            detail: format!("the file ends where {} should be", what()),
        })
    }

    fn number(&mut self, what: &dyn Fn() -> String) -> Result<f64, MeshError> {
        let (tok, line) = self.token(what)?;
        match parse_number(tok) {
            Some(x) if x.is_finite() => Ok(x),
            Some(_) => Err(MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!("`{}` for {}: not a finite number", show(tok), what()),
            }),
            None => Err(MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!("expected {}, found `{}`", what(), show(tok)),
            }),
        }
    }

    fn vec3(&mut self, what: &dyn Fn() -> String) -> Result<[f64; 3], MeshError> {
        Ok([
            self.number(&|| format!("the x of {}", what()))?,
            self.number(&|| format!("the y of {}", what()))?,
            self.number(&|| format!("the z of {}", what()))?,
        ])
    }

    fn skip_numbers(&mut self, n: usize, what: &str) -> Result<(), MeshError> {
        for i in 0..n {
            self.number(&|| format!("value {} of {what}", i + 1))?;
        }
        Ok(())
    }

    /// A non-negative integer (counts, detail levels are read with [`Self::integer`]).
    fn count(&mut self, what: &dyn Fn() -> String) -> Result<u64, MeshError> {
        let (tok, line) = self.token(what)?;
        std::str::from_utf8(tok)
            .ok()
            .and_then(|s| s.parse::<u64>().ok())
            .ok_or_else(|| MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!(
                    "expected {} (a non-negative integer), found `{}`",
                    what(),
                    show(tok)
                ),
            })
    }

    fn integer(&mut self, what: &dyn Fn() -> String) -> Result<(i64, u64), MeshError> {
        let (tok, line) = self.token(what)?;
        std::str::from_utf8(tok)
            .ok()
            .and_then(|s| s.parse::<i64>().ok())
            .map(|v| (v, line))
            .ok_or_else(|| MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!("expected {} (an integer), found `{}`", what(), show(tok)),
            })
    }

    /// An index into a block of `len` items.
    fn index(&mut self, len: u64, what: &dyn Fn() -> String) -> Result<u64, MeshError> {
        let (v, line) = self.integer(what)?;
        if v < 0 || v as u64 >= len {
            return Err(self.aff(
                line,
                format!("{} is {v}, but the mesh has {len} of them", what()),
            ));
        }
        Ok(v as u64)
    }

    fn expect(&mut self, word: &[u8], what: &dyn Fn() -> String) -> Result<u64, MeshError> {
        let (tok, line) = self.token(&|| format!("`{}` {}", show(word), what()))?;
        if tok != word {
            return Err(self.aff(
                line,
                format!(
                    "expected `{}` {}, found `{}`",
                    show(word),
                    what(),
                    show(tok)
                ),
            ));
        }
        Ok(line)
    }
}

// ---------------------------------------------------------------------------------------------
// Scene

/// An affine map: rows of `[R | t]`.
type Affine = [[f64; 4]; 3];

const IDENTITY: Affine = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
];

/// `T R S`.
fn trs(t: [f64; 3], r: [[f64; 3]; 3], s: [f64; 3]) -> Affine {
    std::array::from_fn(|i| [r[i][0] * s[0], r[i][1] * s[1], r[i][2] * s[2], t[i]])
}

fn compose(a: &Affine, b: &Affine) -> Affine {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            let mut v = (0..3).map(|k| a[i][k] * b[k][j]).sum::<f64>();
            if j == 3 {
                v += a[i][3];
            }
            v
        })
    })
}

fn apply(m: &Affine, p: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3])
}

enum NodeKind {
    Root,
    Static(Affine),
    Animated(Vec<u8>),
}

struct Node {
    parent: usize,
    kind: NodeKind,
}

#[derive(Default)]
struct Animation {
    transl: Option<Vec<VecKey>>,
    rot: Option<Vec<RotKey>>,
    scale: Option<Vec<VecKey>>,
    visibility: Vec<(f64, bool)>,
}

impl Animation {
    fn matrix(&self, t: f64) -> Affine {
        let tr = self
            .transl
            .as_deref()
            .map_or([0.0; 3], |k| kb::interpolate_vec(k, t));
        let rot = self
            .rot
            .as_deref()
            .map_or(Quat::IDENTITY, |k| kb::interpolate_rot(k, t));
        let sc = self
            .scale
            .as_deref()
            .map_or([1.0; 3], |k| kb::interpolate_vec(k, t));
        trs(tr, rot.matrix(), sc)
    }

    fn visible(&self, t: f64) -> bool {
        let mut v = true;
        for &(time, flag) in &self.visibility {
            if time <= t {
                v = flag;
            }
        }
        v
    }
}

/// The vertices from `first` to the next run's `first` belong to one statement, under `node`.
struct Run {
    first: u32,
    node: usize,
    file: usize,
    line: u64,
}

struct AnimTri {
    /// First of the three vertex slots reserved for it.
    slot: u32,
    keys: Vec<(f64, [[f64; 3]; 3])>,
}

struct Parser<'r> {
    read: &'r mut dyn FnMut(&Path) -> std::io::Result<Vec<u8>>,
    cache: HashMap<PathBuf, Rc<Vec<u8>>>,
    /// Include stack, normalised paths, top file first.
    stack: Vec<PathBuf>,
    parsed: u64,
    detail: i64,
    files: Vec<String>,
    file_ids: HashMap<String, usize>,

    nodes: Vec<Node>,
    current: usize,
    positions: Vec<[f64; 3]>,
    triangles: Vec<[u32; 3]>,
    runs: Vec<Run>,
    anim_tris: Vec<AnimTri>,
    /// Point lights: node and local position.
    lights: Vec<(usize, [f64; 3])>,
    animations: HashMap<Vec<u8>, Animation>,
    view: Option<AffView>,
    animation: Option<(f64, f64, u64)>,
    counts: AffCounts,
}

impl<'r> Parser<'r> {
    fn new(read: &'r mut dyn FnMut(&Path) -> std::io::Result<Vec<u8>>) -> Parser<'r> {
        Parser {
            read,
            cache: HashMap::new(),
            stack: Vec::new(),
            parsed: 0,
            detail: 0,
            files: Vec::new(),
            file_ids: HashMap::new(),
            nodes: vec![Node {
                parent: 0,
                kind: NodeKind::Root,
            }],
            current: 0,
            positions: Vec::new(),
            triangles: Vec::new(),
            runs: Vec::new(),
            anim_tris: Vec::new(),
            lights: Vec::new(),
            animations: HashMap::new(),
            view: None,
            animation: None,
            counts: AffCounts::default(),
        }
    }

    fn file_id(&mut self, name: &str) -> usize {
        if let Some(&id) = self.file_ids.get(name) {
            return id;
        }
        let id = self.files.len();
        self.files.push(name.to_owned());
        self.file_ids.insert(name.to_owned(), id);
        id
    }

    /// Starts the vertices of a new statement.
    fn begin(&mut self, file: usize, line: u64) {
        self.runs.push(Run {
            first: self.positions.len() as u32,
            node: self.current,
            file,
            line,
        });
    }

    /// Adds a vertex, returning its index.
    fn vertex(&mut self, src: &Src, line: u64, p: [f64; 3]) -> Result<u32, MeshError> {
        let i = self.positions.len();
        if i >= u32::MAX as usize {
            return Err(MeshError::TooLarge {
                file: src.file.to_owned(),
                detail: format!("more than {} vertices at line {line}", u32::MAX),
            });
        }
        self.positions.push(p);
        Ok(i as u32)
    }

    fn parse_file(&mut self, bytes: &[u8], name: &str, path: &Path) -> Result<(), MeshError> {
        let mut src = Src {
            tok: Tokens::new(bytes),
            file: name,
        };
        let fid = self.file_id(name);
        // Lines of the `{` opened in this file and not yet closed.
        let mut open: Vec<u64> = Vec::new();
        while let Some((kw, line)) = src.tok.next() {
            match kw {
                b"v" => self.view = Some(parse_view(&mut src, line)?),
                b"b" => src.skip_numbers(3, "the background colour `b`")?,
                b"am" => src.skip_numbers(3, "the ambient light `am`")?,
                b"l" => {
                    let p = src.vec3(&|| "the position of the light `l`".into())?;
                    if src.tok.peek().is_some_and(looks_like_number) {
                        src.skip_numbers(3, "the light colour `l`")?;
                    }
                    self.lights.push((self.current, p));
                }
                b"f" => src.skip_numbers(8, "the material `f`")?,
                b"fm" => src.skip_numbers(12, "the material `fm`")?,
                b"p" | b"pp" => self.polygon(&mut src, fid, line, kw == b"pp")?,
                b"tt" | b"ttp" => self.textured_triangle(&mut src, fid, line, kw == b"ttp")?,
                b"tpa" => self.animated_triangle(&mut src, fid, line)?,
                b"m" => self.mesh(&mut src, fid, line)?,
                b"c" => self.cone(&mut src, fid, line)?,
                b"s" => self.sphere(&mut src, fid, line)?,
                b"xs" => {
                    let what =
                        |w: &'static str| move || format!("the {w} of the static transform `xs`");
                    let s = src.vec3(&what("scale"))?;
                    let axis = src.vec3(&what("rotation axis"))?;
                    let deg = src.number(&what("rotation angle"))?;
                    let t = src.vec3(&what("translation"))?;
                    src.expect(b"{", &|| "after the static transform `xs`".into())?;
                    let r = Quat::from_angle_axis(deg.to_radians(), axis).matrix();
                    self.push_node(NodeKind::Static(trs(t, r, s)));
                    open.push(line);
                }
                b"x" => {
                    let (name, _) = src.token(&|| "the name of the transform `x`".into())?;
                    let name = name.to_vec();
                    src.expect(b"{", &|| format!("after `x {}`", show(&name)))?;
                    self.push_node(NodeKind::Animated(name));
                    open.push(line);
                }
                b"{" => return Err(src.aff(line, "`{` without a transform before it".into())),
                b"}" => {
                    if open.pop().is_none() {
                        return Err(
                            src.aff(line, "`}` without a matching `{` in this file".to_owned())
                        );
                    }
                    self.current = self.nodes[self.current].parent;
                }
                b"a" => {
                    let start = src.number(&|| "the start time of `a`".into())?;
                    let end = src.number(&|| "the end time of `a`".into())?;
                    let frames = src.count(&|| "the number of frames of `a`".into())?;
                    self.animation = Some((start, end, frames));
                }
                b"k" => self.keyframes(&mut src, line)?,
                b"d" => self.detail = src.integer(&|| "the detail level of `d`".into())?.0,
                b"i" => self.include(&mut src, path, line)?,
                _ => {
                    return Err(src.aff(
                        line,
                        format!(
                            "unknown keyword `{}` (this reader knows v b am l f fm p pp tt ttp \
                             tpa m c s xs x k a d i and braces)",
                            show(kw)
                        ),
                    ));
                }
            }
        }
        if let Some(&line) = open.last() {
            return Err(src.aff(
                line,
                format!(
                    "the `{{` opened here is not closed by the end of the file ({} open)",
                    open.len()
                ),
            ));
        }
        Ok(())
    }

    fn push_node(&mut self, kind: NodeKind) {
        self.nodes.push(Node {
            parent: self.current,
            kind,
        });
        self.current = self.nodes.len() - 1;
    }

    fn polygon(
        &mut self,
        src: &mut Src,
        fid: usize,
        line: u64,
        patch: bool,
    ) -> Result<(), MeshError> {
        let kw = if patch { "pp" } else { "p" };
        let n = src.count(&|| format!("the vertex count of `{kw}`"))?;
        self.begin(fid, line);
        let mut fan = Fan::default();
        for i in 0..n {
            let p = src.vec3(&|| format!("vertex {i} of the `{kw}` at line {line}"))?;
            if patch {
                src.vec3(&|| format!("normal {i} of the `pp` at line {line}"))?;
            }
            let v = self.vertex(src, line, p)?;
            fan.push(v, &mut self.triangles);
        }
        self.counts.polygons += 1;
        Ok(())
    }

    fn textured_triangle(
        &mut self,
        src: &mut Src,
        fid: usize,
        line: u64,
        patch: bool,
    ) -> Result<(), MeshError> {
        let kw = if patch { "ttp" } else { "tt" };
        src.token(&|| format!("the texture name of `{kw}`"))?;
        self.begin(fid, line);
        let mut corners = [0u32; 3];
        for (i, c) in corners.iter_mut().enumerate() {
            let what = |w: &'static str| move || format!("{w} {i} of the `{kw}` at line {line}");
            let p = src.vec3(&what("vertex"))?;
            if patch {
                src.vec3(&what("normal"))?;
            }
            src.number(&what("the u coordinate of corner"))?;
            src.number(&what("the v coordinate of corner"))?;
            *c = self.vertex(src, line, p)?;
        }
        self.triangles.push(corners);
        self.counts.polygons += 1;
        Ok(())
    }

    fn animated_triangle(&mut self, src: &mut Src, fid: usize, line: u64) -> Result<(), MeshError> {
        let n = src.count(&|| "the number of keys of `tpa`".into())?;
        if n == 0 {
            return Err(src.aff(line, "`tpa` with no keys".into()));
        }
        let mut keys = Vec::new();
        for k in 0..n {
            let t = src.number(&|| format!("the time of key {k} of the `tpa` at line {line}"))?;
            let mut corners = [[0.0; 3]; 3];
            for (i, c) in corners.iter_mut().enumerate() {
                *c = src.vec3(&|| format!("vertex {i} of key {k} of the `tpa` at line {line}"))?;
                src.vec3(&|| format!("normal {i} of key {k} of the `tpa` at line {line}"))?;
            }
            keys.push((t, corners));
        }
        self.begin(fid, line);
        let a = self.vertex(src, line, [0.0; 3])?;
        let b = self.vertex(src, line, [0.0; 3])?;
        let c = self.vertex(src, line, [0.0; 3])?;
        self.triangles.push([a, b, c]);
        self.anim_tris.push(AnimTri { slot: a, keys });
        self.counts.animated_triangles += 1;
        Ok(())
    }

    fn mesh(&mut self, src: &mut Src, fid: usize, line: u64) -> Result<(), MeshError> {
        let at = format!("of the mesh `m` at line {line}");
        let at = at.as_str();
        src.expect(b"vertices", &|| {
            format!("to begin the mesh `m` at line {line}")
        })?;
        let nv = src.count(&|| format!("the vertex count {at}"))?;
        self.begin(fid, line);
        let base = self.positions.len() as u64;
        for i in 0..nv {
            let p = src.vec3(&|| format!("vertex {i} {at}"))?;
            self.vertex(src, line, p)?;
        }
        let (mut next, mut next_line) = src.token(&|| format!("`triangles` {at}"))?;
        let mut nn = 0;
        if next == b"normals" {
            nn = src.count(&|| format!("the normal count {at}"))?;
            for i in 0..nn {
                src.vec3(&|| format!("normal {i} {at}"))?;
            }
            (next, next_line) = src.token(&|| format!("`triangles` {at}"))?;
        }
        let mut nt = 0;
        if next == b"texturecoords" {
            nt = src.count(&|| format!("the texture coordinate count {at}"))?;
            src.token(&|| format!("the texture name {at}"))?;
            for i in 0..nt {
                src.number(&|| format!("u of texture coordinate {i} {at}"))?;
                src.number(&|| format!("v of texture coordinate {i} {at}"))?;
            }
            (next, next_line) = src.token(&|| format!("`triangles` {at}"))?;
        }
        if next != b"triangles" {
            return Err(src.aff(
                next_line,
                format!(
                    "expected `normals`, `texturecoords` or `triangles` {at}, found `{}`",
                    show(next)
                ),
            ));
        }
        let ntri = src.count(&|| format!("the triangle count {at}"))?;
        for q in 0..ntri {
            let mut tri = [0u32; 3];
            for (w, c) in tri.iter_mut().enumerate() {
                let v = src.index(nv, &|| format!("vertex index {w} of triangle {q} {at}"))?;
                *c = (base + v) as u32;
            }
            if nn > 0 {
                for w in 0..3 {
                    src.index(nn, &|| format!("normal index {w} of triangle {q} {at}"))?;
                }
            }
            if nt > 0 {
                for w in 0..3 {
                    src.index(nt, &|| {
                        format!("texture coordinate index {w} of triangle {q} {at}")
                    })?;
                }
            }
            self.triangles.push(tri);
            self.counts.polygons += 1;
        }
        Ok(())
    }

    fn cone(&mut self, src: &mut Src, fid: usize, line: u64) -> Result<(), MeshError> {
        let base = src.vec3(&|| "the base of the cone `c`".into())?;
        let r0 = src.number(&|| "the base radius of the cone `c`".into())?;
        let apex = src.vec3(&|| "the apex of the cone `c`".into())?;
        let r1 = src.number(&|| "the apex radius of the cone `c`".into())?;
        let axis = crate::rays::sub(apex, base);
        let len = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        if !(len > 0.0 && len.is_finite()) {
            return Err(src.aff(
                line,
                "the cone `c` has its base and apex at the same point".into(),
            ));
        }
        let d = axis.map(|c| c / len);
        let (u, v) = basis(d);
        self.begin(fid, line);
        let first = self.positions.len() as u32;
        let n = CONE_SEGMENTS;
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let (s, c) = a.sin_cos();
            let radial: [f64; 3] = std::array::from_fn(|k| c * u[k] + s * v[k]);
            self.vertex(src, line, std::array::from_fn(|k| base[k] + r0 * radial[k]))?;
            self.vertex(src, line, std::array::from_fn(|k| apex[k] + r1 * radial[k]))?;
        }
        for i in 0..n {
            let j = (i + 1) % n;
            let (b0, a0, b1, a1) = (
                first + 2 * i,
                first + 2 * i + 1,
                first + 2 * j,
                first + 2 * j + 1,
            );
            // Outward, counterclockwise seen from outside.
            self.triangles.push([b0, b1, a1]);
            self.triangles.push([b0, a1, a0]);
        }
        self.counts.cones += 1;
        Ok(())
    }

    fn sphere(&mut self, src: &mut Src, fid: usize, line: u64) -> Result<(), MeshError> {
        let c = src.vec3(&|| "the centre of the sphere `s`".into())?;
        let r = src.number(&|| "the radius of the sphere `s`".into())?.abs();
        self.begin(fid, line);
        let (slices, stacks) = (SPHERE_SLICES, SPHERE_STACKS);
        let north = self.vertex(src, line, [c[0], c[1] + r, c[2]])?;
        for i in 1..stacks {
            let theta = std::f64::consts::PI * i as f64 / stacks as f64;
            let (st, ct) = theta.sin_cos();
            for j in 0..slices {
                let phi = std::f64::consts::TAU * j as f64 / slices as f64;
                let (sp, cp) = phi.sin_cos();
                self.vertex(
                    src,
                    line,
                    [c[0] + r * st * cp, c[1] + r * ct, c[2] - r * st * sp],
                )?;
            }
        }
        let south = self.vertex(src, line, [c[0], c[1] - r, c[2]])?;
        let ring = |i: u32, j: u32| north + 1 + (i - 1) * slices + j % slices;
        for j in 0..slices {
            self.triangles.push([north, ring(1, j), ring(1, j + 1)]);
        }
        for i in 1..stacks - 1 {
            for j in 0..slices {
                let (a, b, c2, d) = (
                    ring(i, j),
                    ring(i + 1, j),
                    ring(i + 1, j + 1),
                    ring(i, j + 1),
                );
                self.triangles.push([a, b, c2]);
                self.triangles.push([a, c2, d]);
            }
        }
        for j in 0..slices {
            self.triangles
                .push([south, ring(stacks - 1, j + 1), ring(stacks - 1, j)]);
        }
        self.counts.spheres += 1;
        Ok(())
    }

    fn keyframes(&mut self, src: &mut Src, line: u64) -> Result<(), MeshError> {
        let (name, _) = src.token(&|| "the name of the keyframes `k`".into())?;
        let name = name.to_vec();
        let at = format!("in `k {}` at line {line}", show(&name));
        let at = at.as_str();
        src.expect(b"{", &|| format!("after `k {}`", show(&name)))?;
        let mut anim = Animation::default();
        loop {
            let (motion, mline) = src.token(&|| format!("a motion or `}}` {at}"))?;
            if motion == b"}" {
                break;
            }
            let n = src.count(&|| format!("the key count of `{}` {at}", show(motion)))?;
            let few = |src: &Src| {
                src.aff(
                    mline,
                    format!(
                        "`{}` {at} has {n} keys; splines need at least {MIN_KEYS}",
                        show(motion)
                    ),
                )
            };
            match motion {
                b"transl" | b"scale" => {
                    if n < MIN_KEYS as u64 {
                        return Err(few(src));
                    }
                    let mut keys = Vec::new();
                    for i in 0..n {
                        let what = |w: &'static str| move || format!("{w} of key {i} {at}");
                        let t = src.number(&what("the time"))?;
                        let v = src.vec3(&what("the value"))?;
                        let tcb = src.vec3(&what("tension/continuity/bias"))?;
                        keys.push(VecKey { t, v, tcb });
                    }
                    if motion == b"transl" {
                        anim.transl = Some(keys);
                    } else {
                        anim.scale = Some(keys);
                    }
                }
                b"rot" => {
                    if n < MIN_KEYS as u64 {
                        return Err(few(src));
                    }
                    let mut keys = Vec::new();
                    for i in 0..n {
                        let what = |w: &'static str| move || format!("{w} of key {i} {at}");
                        let t = src.number(&what("the time"))?;
                        let axis = src.vec3(&what("the axis"))?;
                        let angle_deg = src.number(&what("the angle"))?;
                        let tcb = src.vec3(&what("tension/continuity/bias"))?;
                        keys.push(RotKey {
                            t,
                            axis,
                            angle_deg,
                            tcb,
                        });
                    }
                    anim.rot = Some(keys);
                }
                b"visibility" => {
                    let mut keys = Vec::new();
                    for i in 0..n {
                        let t = src.number(&|| format!("the time of visibility key {i} {at}"))?;
                        let (flag, _) =
                            src.integer(&|| format!("the flag of visibility key {i} {at}"))?;
                        keys.push((t, flag != 0));
                    }
                    anim.visibility = keys;
                }
                _ => {
                    return Err(src.aff(
                        mline,
                        format!(
                            "unknown motion `{}` {at} (expected transl, rot, scale or visibility)",
                            show(motion)
                        ),
                    ));
                }
            }
        }
        self.animations.insert(name, anim);
        Ok(())
    }

    fn include(&mut self, src: &mut Src, path: &Path, line: u64) -> Result<(), MeshError> {
        let (level, _) = src.integer(&|| "the detail level of the include `i`".into())?;
        let (name, _) = src.token(&|| "the file name of the include `i`".into())?;
        if level > self.detail {
            return Ok(());
        }
        let name = String::from_utf8_lossy(name).into_owned();
        let dir = path.parent().unwrap_or(Path::new(""));
        let target = dir.join(&name);
        let key = normalize(&target);
        if self.stack.contains(&key) {
            let chain: Vec<String> = self
                .stack
                .iter()
                .chain(std::iter::once(&key))
                .map(|p| p.display().to_string())
                .collect();
            return Err(src.aff(line, format!("include cycle: {}", chain.join(" includes "))));
        }
        if self.stack.len() > MAX_INCLUDE_DEPTH {
            return Err(src.aff(
                line,
                format!("includes nest deeper than {MAX_INCLUDE_DEPTH} files"),
            ));
        }
        let wrap = |e: MeshError| MeshError::Included {
            file: src.file.to_owned(),
            line,
            source: Box::new(e),
        };
        let bytes = match self.cache.get(&key) {
            Some(b) => Rc::clone(b),
            None => {
                let b = Rc::new((self.read)(&target).map_err(|source| {
                    wrap(MeshError::Io {
                        path: target.clone(),
                        source,
                    })
                })?);
                self.cache.insert(key.clone(), Rc::clone(&b));
                b
            }
        };
        let inner = target.display().to_string();
        self.parsed = self
            .parsed
            .saturating_add(bytes.len() as u64)
            .saturating_add(INCLUDE_COST);
        check_budget(self.parsed, &inner).map_err(wrap)?;
        self.stack.push(key);
        let result = self.parse_file(&bytes, &inner, &target);
        self.stack.pop();
        result.map_err(wrap)
    }

    /// Poses the scene at `time`: the mesh and the light positions.
    fn pose(&self, time: f64) -> Result<(Mesh, Vec<[f64; 3]>), MeshError> {
        let mut world = Vec::with_capacity(self.nodes.len());
        let mut visible = Vec::with_capacity(self.nodes.len());
        for (i, node) in self.nodes.iter().enumerate() {
            let (parent, pvis) = if i == 0 {
                (IDENTITY, true)
            } else {
                (world[node.parent], visible[node.parent])
            };
            let (local, vis) = match &node.kind {
                NodeKind::Root => (IDENTITY, true),
                NodeKind::Static(m) => (*m, true),
                NodeKind::Animated(name) => match self.animations.get(name) {
                    Some(a) => (a.matrix(time), a.visible(time)),
                    None => (IDENTITY, true),
                },
            };
            world.push(compose(&parent, &local));
            visible.push(pvis && vis);
        }

        let mut local = self.positions.clone();
        for a in &self.anim_tris {
            let corners = animated_corners(&a.keys, time);
            for (k, c) in corners.into_iter().enumerate() {
                local[a.slot as usize + k] = c;
            }
        }

        let mut positions = Vec::with_capacity(local.len());
        for (r, run) in self.runs.iter().enumerate() {
            let end = self
                .runs
                .get(r + 1)
                .map_or(local.len(), |n| n.first as usize);
            let m = &world[run.node];
            for (i, p) in local[run.first as usize..end].iter().enumerate() {
                let q = apply(m, *p).map(|c| c as f32);
                if !q.iter().all(|c| c.is_finite()) {
                    return Err(MeshError::NonFinite {
                        file: self.files[run.file].clone(),
                        at: Place::Line(run.line),
                        vertex: (run.first as usize + i) as u64,
                    });
                }
                positions.push(q);
            }
        }
        debug_assert_eq!(positions.len(), local.len());

        let triangles = if self.runs.iter().all(|r| visible[r.node]) {
            self.triangles.clone()
        } else {
            let firsts: Vec<u32> = self.runs.iter().map(|r| r.first).collect();
            self.triangles
                .iter()
                .filter(|t| {
                    let r = firsts.partition_point(|&f| f <= t[0]).saturating_sub(1);
                    visible[self.runs[r].node]
                })
                .copied()
                .collect()
        };
        let lights = self
            .lights
            .iter()
            .map(|&(node, p)| apply(&world[node], p))
            .collect();
        Ok((
            Mesh {
                positions,
                triangles,
            },
            lights,
        ))
    }
}

/// The corners of an animated triangle at `t`: linear between the keys around `t`, clamped.
fn animated_corners(keys: &[(f64, [[f64; 3]; 3])], t: f64) -> [[f64; 3]; 3] {
    let (first, last) = (keys[0], keys[keys.len() - 1]);
    if t <= first.0 {
        return first.1;
    }
    if t >= last.0 {
        return last.1;
    }
    for w in keys.windows(2) {
        let ((ta, a), (tb, b)) = (w[0], w[1]);
        if ta <= t && t <= tb {
            let s = if tb > ta { (t - ta) / (tb - ta) } else { 0.0 };
            return std::array::from_fn(|i| {
                std::array::from_fn(|k| a[i][k] + s * (b[i][k] - a[i][k]))
            });
        }
    }
    last.1
}

/// Two unit vectors `u`, `v` with `u × v = d` for a unit `d`.
fn basis(d: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let helper = if d[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = crate::rays::normalize(crate::rays::cross(helper, d));
    let v = crate::rays::cross(d, u);
    (u, v)
}

fn parse_view(src: &mut Src, line: u64) -> Result<AffView, MeshError> {
    let mut from = None;
    let mut at = None;
    let mut up = None;
    let mut angle = None;
    let mut hither = None;
    let mut resolution = None;
    while let Some(word) = src.tok.peek() {
        let what = |w: &'static str| move || format!("`{w}` of the viewpoint `v`");
        match word {
            b"from" => {
                src.tok.next();
                from = Some(src.vec3(&what("from"))?);
            }
            b"at" => {
                src.tok.next();
                at = Some(src.vec3(&what("at"))?);
            }
            b"up" => {
                src.tok.next();
                up = Some(src.vec3(&what("up"))?);
            }
            b"angle" => {
                src.tok.next();
                angle = Some(src.number(&what("angle"))?);
            }
            b"hither" => {
                src.tok.next();
                hither = Some(src.number(&what("hither"))?);
            }
            b"resolution" => {
                src.tok.next();
                let mut dim = |w: &'static str| -> Result<u32, MeshError> {
                    let (v, l) = src.integer(&what(w))?;
                    u32::try_from(v).ok().filter(|&v| v > 0).ok_or_else(|| {
                        src.aff(l, format!("the {w} is {v}; it must be a positive integer"))
                    })
                };
                let w = dim("resolution width")?;
                let h = dim("resolution height")?;
                resolution = Some((w, h));
            }
            _ => break,
        }
    }
    let missing = |w: &str| src.aff(line, format!("the viewpoint `v` has no `{w}`"));
    Ok(AffView {
        from: from.ok_or_else(|| missing("from"))?,
        at: at.ok_or_else(|| missing("at"))?,
        up: up.ok_or_else(|| missing("up"))?,
        angle_deg: angle.ok_or_else(|| missing("angle"))?,
        hither: hither.ok_or_else(|| missing("hither"))?,
        resolution: resolution.ok_or_else(|| missing("resolution"))?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tokens(text: &str) -> Vec<(String, u64)> {
        let mut t = Tokens::new(text.as_bytes());
        std::iter::from_fn(|| t.next())
            .map(|(tok, line)| (String::from_utf8_lossy(tok).into_owned(), line))
            .collect()
    }

    #[test]
    fn tokens_split_braces_skip_comments_and_count_lines() {
        assert_eq!(
            tokens("xs 1 # c { }\r\n{p % x\n}}a"),
            vec![
                ("xs".into(), 1),
                ("1".into(), 1),
                ("{".into(), 2),
                ("p".into(), 2),
                ("}".into(), 3),
                ("}".into(), 3),
                ("a".into(), 3),
            ]
        );
        let mut t = Tokens::new(b"a\n\n b\n\n");
        assert_eq!(t.peek(), Some(&b"a"[..]));
        t.next();
        t.next();
        assert_eq!((t.next(), t.last), (None, 3));
    }

    #[test]
    fn paths_are_normalised_lexically() {
        assert_eq!(normalize(Path::new("a/./b/../c.aff")), Path::new("a/c.aff"));
        assert_eq!(normalize(Path::new("../x/../y")), Path::new("../y"));
        assert_eq!(normalize(Path::new("/r/./s")), Path::new("/r/s"));
    }

    #[test]
    fn animated_corners_interpolate_and_clamp() {
        let k = |t: f64, z: f64| (t, [[0.0, 0.0, z]; 3]);
        let keys = [k(0.0, 0.0), k(1.0, 2.0), k(1.0, 5.0), k(3.0, 9.0)];
        assert_eq!(animated_corners(&keys, -1.0)[0][2], 0.0);
        assert_eq!(animated_corners(&keys, 0.5)[0][2], 1.0);
        assert_eq!(animated_corners(&keys, 2.0)[0][2], 7.0);
        assert_eq!(animated_corners(&keys, 4.0)[0][2], 9.0);
    }

    #[test]
    fn trs_scales_then_rotates_then_translates() {
        let r = Quat::from_angle_axis(90f64.to_radians(), [0.0, 0.0, 1.0]).matrix();
        let m = trs([1.0, 2.0, 3.0], r, [2.0, 1.0, 1.0]);
        let p = apply(&m, [1.0, 0.0, 0.0]);
        let want = [1.0, 4.0, 3.0];
        assert!(
            p.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12),
            "{p:?}"
        );
        let twice = compose(&m, &m);
        let q = apply(&twice, [1.0, 0.0, 0.0]);
        let want = apply(&m, apply(&m, [1.0, 0.0, 0.0]));
        assert!(q.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12));
    }

    #[test]
    fn basis_is_right_handed_and_orthonormal() {
        for d in [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.6, -0.8]] {
            let (u, v) = basis(d);
            let w = crate::rays::cross(u, v);
            assert!(w.iter().zip(d).all(|(a, b)| (a - b).abs() < 1e-12));
            assert!(crate::rays::dot(u, d).abs() < 1e-12 && crate::rays::dot(v, d).abs() < 1e-12);
        }
    }
}
