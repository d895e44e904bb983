//! Checks a ray tracer's answers against an independent brute force in f64, ray by ray, on a mesh
//! too big to brute-force naively (hundreds of millions of triangles), on a strided subset of the
//! rays.
//!
//! ```text
//! cargo run --release --features tools --example brute_big -- MESH.ply --rays RAYS (--hits HITS | --occluded OCCL)
//!     [--brute N] [--chunk TRIANGLES] [--no-cull] [--json]
//! ```
//!
//! `RAYS`, `HITS` and `OCCL` are the batch files of `../shared/RAYS.md` (record `i` answers ray
//! `i`), read with `oavm::rays::read_*`. Every `k`-th ray is checked, `k = max(1, floor(rays /
//! N))` (`--brute`, default 2000), as `tools/check.rs` does, with its agreement rule: a closest
//! hit agrees when both miss, or both hit with `|t1 - t2| <= 1e-4 * L` (`Hit::agrees`), `L` the
//! diagonal of the bounding box of all the mesh's vertices; an any-hit answer when both give the
//! same answer. A disagreement on a ray that grazes an edge or a corner of a triangle
//! (`reference::grazes` over all the mesh's triangles, where a watertight f32 test and the f64
//! one may both be right) is counted apart as `grazing` and does not fail. That excuse grows
//! with the scene: `grazes` looks at every triangle along the whole ray, with a tolerance of
//! `1e-6` of the largest coordinate beside `1e-5` of the edge, so on 150 copies of the dragon 50
//! of the 305 random rays that hit graze some edge somewhere. The JSON output's `grazing_rays`
//! counts the checked rays that would be excused.
//!
//! The reference shares no code with OAVM's tracer: the answer of a ray is that of
//! `oavm::geom::reference::closest` (the smallest `t` of `reference::hit_t` over all triangles,
//! ties to the lowest primitive id) or `reference::occluded` over the whole mesh, computed in one
//! streamed pass over the file, and the PLY is read by the plain reader below, not by
//! `oavm::mesh`. All vertex positions are read into memory (12 bytes a vertex: 3 GB for 250
//! million), then the faces are read in chunks of `--chunk` triangles (default 2^20) by a reader
//! thread while the previous chunk is traced. A chunk's triangles are sorted by the Morton code of
//! their centroids (their ids kept), cut into leaves of [`LEAF`] triangles and groups of
//! [`GROUP`] leaves, each with its f64 bounding box; each checked ray (in parallel, rayon) tests
//! the boxes its segment meets (a slab test in f64 on the box widened by a margin, see
//! [`Probe::new`]) and, in the leaves it meets, every triangle with `reference::hit_t`, and
//! `reference::grazes` until one grazes. A closest-hit ray's segment for `hit_t` ends at its best
//! hit so far: a triangle beyond it cannot change the answer. An any-hit ray stops testing
//! `hit_t` at its first hit. This culling is exact: a triangle it skips is one whose `hit_t`
//! (and `grazes`) cannot be true or cannot change the answer, except for a ray within about
//! 1e-10 radians of a triangle's plane, where f64 Möller–Trumbore's own `t` is off by more than
//! the margin (and such a ray grazes the triangle, in all likelihood). The answers do not depend
//! on `--chunk`; only the time does, and `--no-cull` (every triangle against every ray: rays x
//! triangles tests) checks on a smaller mesh that the culling changes nothing. The PLY written by
//! `tools/make_copies.rs` stores copy after copy, so chunks are spatially compact and most rays
//! skip most of them: 2,000 random rays on 20 copies of the dragon (17 million triangles) take
//! 1.9 s on 2 busy cores, on 150 copies 13 s and 0.9 GB, so 575 copies (500 million triangles,
//! 9.5 GB) should take about a minute and 3.1 GB: the time goes to reading and sorting the
//! chunks, not to the rays.
//!
//! The PLY may be `binary_little_endian` or `ascii`, with a `vertex` element whose properties are
//! scalars among which `x`, `y`, `z` (`float` or `double`, the latter rounded to f32 as `oavm`
//! reads it), and a `face` element with one list property `vertex_indices` (or `vertex_index`) of
//! `int` or `uint` indices, any integer count type, beside scalar properties; every face a
//! triangle (primitive id = face index). Other elements must have scalar properties only (they are
//! skipped), and `vertex` must come before `face`. Anything else is an error that names the file
//! and what is not supported, as is a non-finite coordinate, an index out of range, a binary file
//! whose size is not what its header says, or trailing data; input never makes it panic.
//!
//! Output: one line per run (rays in the file, rays checked, hits or occluded among them per the
//! reference and per the file, agree, grazing, disagree, seconds) and the first 5 disagreements
//! (the ray and both answers), or one JSON object (`--json`). Progress goes to stderr. Exit
//! status 0 when no ray disagrees off grazing ones, 1 if some does, 2 on an error (bad arguments,
//! bad input).

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{SyncSender, sync_channel};
use std::time::Instant;

use clap::Parser;
use oavm::Error;
use oavm::geom::{AGREEMENT_TOLERANCE, Hit, Ray, reference};
use oavm::rays::{read_hits, read_occlusion, read_rays};
use rayon::prelude::*;
use serde_json::{Value, json};

#[path = "../src/bin/cli/mod.rs"]
mod cli;

use cli::main_with;

/// Triangles in a leaf, the smallest set with its own box.
const LEAF: usize = 32;
/// Leaves in a group (the level above leaves).
const GROUP: usize = 32;
/// Disagreements printed.
const EXAMPLES: usize = 5;
/// The largest RAYS file read (all of it is held in memory: 32 bytes a ray).
const MAX_RAYS: u64 = 100_000_000;
/// The largest PLY header.
const MAX_HEADER: u64 = 1 << 20;
/// Binary records read at once.
const BATCH: usize = 1 << 16;

#[derive(Parser, Debug)]
#[command(
    about = "Checks closest-hit or any-hit answers on a large mesh against an f64 brute force",
    group(clap::ArgGroup::new("answers").required(true).args(["hits", "occluded"]))
)]
struct Args {
    /// The mesh: a binary little-endian (or ascii) PLY of triangles.
    mesh: PathBuf,
    /// The rays (a RAYS file).
    #[arg(long, value_name = "RAYS")]
    rays: PathBuf,
    /// Closest-hit answers to check (a HITS file, one record a ray).
    #[arg(long, value_name = "HITS")]
    hits: Option<PathBuf>,
    /// Any-hit answers to check (an OCCL file, one record a ray).
    #[arg(long, value_name = "OCCL")]
    occluded: Option<PathBuf>,
    /// Check every k-th ray, k = max(1, floor(rays / N)): at least N rays (all if fewer).
    #[arg(long, value_name = "N", default_value_t = 2000,
          value_parser = clap::value_parser!(u64).range(1..))]
    brute: u64,
    /// Triangles read and traced at a time (memory: about 100 bytes each). The answers do not
    /// depend on it.
    #[arg(long, value_name = "TRIANGLES", default_value_t = 1 << 20,
          value_parser = clap::value_parser!(u64).range(1..=(1 << 26)))]
    chunk: u64,
    /// Test every triangle against every checked ray, without culling (slow: rays x triangles;
    /// for checking on a small mesh that the culling changes no answer).
    #[arg(long)]
    no_cull: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let mut passed = None;
    let _ = main_with("brute_big", || {
        let result = run(&args);
        if result.is_err() && PROGRESS_LINE.load(Ordering::Relaxed) {
            // End the progress line, so that the error starts a line.
            eprintln!();
        }
        passed = Some(result?);
        Ok(())
    });
    match passed {
        Some(true) => ExitCode::SUCCESS,
        Some(false) => ExitCode::from(1),
        // main_with printed the error.
        None => ExitCode::from(2),
    }
}

/// An error about the contents of `path`.
fn bad(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("{}: {what}", path.display()))
}

// ---------------------------------------------------------------------------------------------
// PLY
// ---------------------------------------------------------------------------------------------

/// A scalar type of PLY.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Option<Ty> {
        Some(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return None,
        })
    }

    /// The PLY name.
    fn name(self) -> &'static str {
        match self {
            Ty::I8 => "char",
            Ty::U8 => "uchar",
            Ty::I16 => "short",
            Ty::U16 => "ushort",
            Ty::I32 => "int",
            Ty::U32 => "uint",
            Ty::F32 => "float",
            Ty::F64 => "double",
        }
    }

    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Ty::F32 | Ty::F64)
    }

    /// The integer at the start of `b` (little-endian; `b` holds at least `size()` bytes).
    fn int_le(self, b: &[u8]) -> i64 {
        match self {
            Ty::I8 => b[0] as i8 as i64,
            Ty::U8 => b[0] as i64,
            Ty::I16 => i16::from_le_bytes([b[0], b[1]]) as i64,
            Ty::U16 => u16::from_le_bytes([b[0], b[1]]) as i64,
            Ty::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as i64,
            Ty::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as i64,
            // Not integers: never asked (the layout checks count and index types).
            Ty::F32 | Ty::F64 => 0,
        }
    }

    /// A coordinate at the start of `b`, as f32 (a double rounded, as `oavm` reads it).
    fn coord_le(self, b: &[u8]) -> f32 {
        match self {
            Ty::F64 => f64::from_le_bytes(b[..8].try_into().unwrap_or_default()) as f32,
            _ => f32::from_le_bytes(b[..4].try_into().unwrap_or_default()),
        }
    }
}

#[derive(Debug)]
enum Prop {
    Scalar { ty: Ty, name: String },
    List { count: Ty, item: Ty, name: String },
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Prop>,
}

impl Element {
    /// Bytes of a record, if all its properties are scalars.
    fn scalar_size(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p {
                Prop::Scalar { ty, .. } => Some(ty.size()),
                Prop::List { .. } => None,
            })
            .sum()
    }
}

/// Reads the header; `r` is left at the first byte of the body.
fn read_header(r: &mut BufReader<File>, path: &Path) -> Result<(bool, u64, Vec<Element>), Error> {
    let mut len = 0u64;
    let mut ascii = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line = Vec::new();
    for n in 1.. {
        line.clear();
        let got = (&mut *r)
            .take(MAX_HEADER + 1 - len)
            .read_until(b'\n', &mut line)
            .map_err(|e| Error::io(path, e))?;
        len += got as u64;
        if len > MAX_HEADER {
            return Err(bad(
                path,
                format!("no end_header in the first {MAX_HEADER} bytes"),
            ));
        }
        if got == 0 || line.last() != Some(&b'\n') {
            return Err(bad(path, "the file ends inside the PLY header"));
        }
        let text = std::str::from_utf8(&line)
            .map_err(|_| bad(path, format!("header line {n} is not text")))?
            .trim_end_matches(['\n', '\r']);
        if n == 1 {
            if text != "ply" {
                return Err(bad(path, "not a PLY file (the first line is not `ply`)"));
            }
            continue;
        }
        let at = |what: String| bad(path, format!("header line {n} (`{text}`): {what}"));
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", format, "1.0"] => {
                ascii = Some(match *format {
                    "binary_little_endian" => false,
                    "ascii" => true,
                    "binary_big_endian" => {
                        return Err(at(
                            "big-endian PLY is not supported; convert it to binary_little_endian"
                                .into(),
                        ));
                    }
                    other => return Err(at(format!("unknown format {other}"))),
                });
            }
            ["format", ..] => return Err(at("unsupported format line".into())),
            ["element", name, count] => {
                let count = count
                    .parse()
                    .map_err(|_| at(format!("count {count} is not a non-negative integer")))?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            ["property", "list", count, item, name] => {
                let (Some(count), Some(item)) = (Ty::parse(count), Ty::parse(item)) else {
                    return Err(at("unknown property type".into()));
                };
                let e = elements
                    .last_mut()
                    .ok_or_else(|| at("a property before any element".into()))?;
                e.props.push(Prop::List {
                    count,
                    item,
                    name: name.to_string(),
                });
            }
            ["property", ty, name] => {
                let ty = Ty::parse(ty).ok_or_else(|| at(format!("unknown property type {ty}")))?;
                let e = elements
                    .last_mut()
                    .ok_or_else(|| at("a property before any element".into()))?;
                e.props.push(Prop::Scalar {
                    ty,
                    name: name.to_string(),
                });
            }
            ["end_header"] => break,
            _ => return Err(at("not a header line this reader knows".into())),
        }
    }
    let ascii = ascii.ok_or_else(|| bad(path, "the PLY header has no format line"))?;
    Ok((ascii, len, elements))
}

/// What the reader needs of the header, checked.
struct Layout {
    ascii: bool,
    elements: Vec<Element>,
    /// Indices of the `vertex` and `face` elements in `elements`.
    vertex: usize,
    face: usize,
    vertices: u64,
    faces: u64,
    /// Per vertex property: which coordinate it is (0, 1, 2), if any, and its type.
    vprops: Vec<(Option<usize>, Ty)>,
    /// Binary: bytes of a vertex record, and offset and type of x, y, z in it.
    vsize: usize,
    xyz: [(usize, Ty); 3],
    /// Face: the scalar properties before and after the index list, its count and item types.
    fpre: Vec<Ty>,
    fpost: Vec<Ty>,
    count: Ty,
    item: Ty,
}

impl Layout {
    /// Binary: bytes of a face record (a triangle).
    fn fsize(&self) -> usize {
        let s = |v: &[Ty]| v.iter().map(|t| t.size()).sum::<usize>();
        s(&self.fpre) + self.count.size() + 3 * self.item.size() + s(&self.fpost)
    }
}

fn layout(
    path: &Path,
    ascii: bool,
    header_len: u64,
    elements: Vec<Element>,
    file_len: u64,
) -> Result<Layout, Error> {
    let find = |name: &str| -> Result<usize, Error> {
        let mut found = elements.iter().enumerate().filter(|(_, e)| e.name == name);
        match (found.next(), found.next()) {
            (Some((i, _)), None) => Ok(i),
            (None, _) => Err(bad(path, format!("no `{name}` element"))),
            (Some(_), Some(_)) => Err(bad(path, format!("more than one `{name}` element"))),
        }
    };
    let (vertex, face) = (find("vertex")?, find("face")?);
    if face < vertex {
        return Err(bad(
            path,
            "the `face` element comes before the `vertex` element: not supported (faces are \
             streamed after the vertices are read)",
        ));
    }
    for (i, e) in elements.iter().enumerate() {
        if i != face && e.scalar_size().is_none() {
            return Err(bad(
                path,
                format!("element `{}` has a list property: not supported", e.name),
            ));
        }
    }
    let ve = &elements[vertex];
    let mut vprops = Vec::new();
    let mut xyz = [None; 3];
    let mut offset = 0;
    for p in &ve.props {
        let Prop::Scalar { ty, name } = p else {
            return Err(bad(path, "the vertex element has a list property"));
        };
        let axis = ["x", "y", "z"].iter().position(|a| a == name);
        if let Some(k) = axis {
            if !matches!(ty, Ty::F32 | Ty::F64) {
                return Err(bad(
                    path,
                    format!(
                        "vertex property {name} is {}: only float and double are supported",
                        ty.name()
                    ),
                ));
            }
            if xyz[k].is_some() {
                return Err(bad(path, format!("vertex property {name} appears twice")));
            }
            xyz[k] = Some((offset, *ty));
        }
        vprops.push((axis, *ty));
        offset += ty.size();
    }
    let [Some(x), Some(y), Some(z)] = xyz else {
        return Err(bad(path, "the vertex element lacks one of x, y, z"));
    };
    let fe = &elements[face];
    let (mut fpre, mut fpost, mut list) = (Vec::new(), Vec::new(), None);
    for p in &fe.props {
        match p {
            Prop::Scalar { ty, .. } => {
                if list.is_none() {
                    fpre.push(*ty)
                } else {
                    fpost.push(*ty)
                }
            }
            Prop::List { count, item, name } => {
                if list.is_some() {
                    return Err(bad(path, "the face element has two list properties"));
                }
                if name != "vertex_indices" && name != "vertex_index" {
                    return Err(bad(
                        path,
                        format!("face list `{name}`: expected vertex_indices"),
                    ));
                }
                if !count.is_int() || !matches!(item, Ty::I32 | Ty::U32) {
                    return Err(bad(
                        path,
                        format!(
                            "face list of {} counts and {} indices: supported are integer \
                             counts and int or uint indices (e.g. list uchar int)",
                            count.name(),
                            item.name()
                        ),
                    ));
                }
                list = Some((*count, *item));
            }
        }
    }
    let (count, item) = list.ok_or_else(|| bad(path, "the face element has no index list"))?;
    let l = Layout {
        ascii,
        vertex,
        face,
        vertices: ve.count,
        faces: fe.count,
        vsize: offset,
        vprops,
        xyz: [x, y, z],
        fpre,
        fpost,
        count,
        item,
        elements,
    };
    if l.faces == 0 {
        return Err(bad(path, "no faces"));
    }
    if l.faces > u64::from(u32::MAX) - 1 {
        return Err(bad(
            path,
            format!("{} faces: primitive ids are u32 below 0xFFFFFFFF", l.faces),
        ));
    }
    if l.vertices > u64::from(u32::MAX) + 1 {
        return Err(bad(
            path,
            format!("{} vertices: more than 32-bit indices can name", l.vertices),
        ));
    }
    if ascii {
        // At least a digit and a separator per value: no count of a small file makes us
        // allocate much.
        if l.vertices.saturating_mul(2 * l.vprops.len() as u64) > file_len {
            return Err(bad(
                path,
                format!("{} vertices cannot fit in {file_len} bytes", l.vertices),
            ));
        }
    } else {
        let mut need = Some(header_len);
        for (i, e) in l.elements.iter().enumerate() {
            let size = if i == face {
                l.fsize()
            } else {
                e.scalar_size().unwrap_or(0)
            };
            need = need.and_then(|n| {
                e.count
                    .checked_mul(size as u64)
                    .and_then(|b| n.checked_add(b))
            });
        }
        if need != Some(file_len) {
            return Err(bad(
                path,
                format!(
                    "the file has {file_len} bytes, but its header ({header_len} bytes) and \
                     elements need {} if every face is a triangle: it is truncated, has trailing \
                     data, or has faces that are not triangles (only triangles are supported)",
                    need.map_or("more than 2^64".into(), |n| n.to_string())
                ),
            ));
        }
    }
    Ok(l)
}

/// The whitespace-separated tokens of an ascii PLY body.
struct Tokens {
    r: BufReader<File>,
    tok: Vec<u8>,
    /// Line of the last token (1 = the first line of the body).
    line: u64,
    newlines: u64,
}

impl Tokens {
    fn next(&mut self, path: &Path) -> Result<Option<&str>, Error> {
        self.tok.clear();
        loop {
            let buf = self.r.fill_buf().map_err(|e| Error::io(path, e))?;
            if buf.is_empty() {
                break;
            }
            let (mut used, mut done) = (0, false);
            for &b in buf {
                used += 1;
                if b.is_ascii_whitespace() {
                    if !self.tok.is_empty() {
                        done = true;
                    }
                    if b == b'\n' {
                        self.newlines += 1;
                    }
                    if done {
                        break;
                    }
                } else {
                    if self.tok.is_empty() {
                        self.line = self.newlines + 1;
                    }
                    self.tok.push(b);
                    if self.tok.len() > 100 {
                        return Err(bad(
                            path,
                            format!("body line {}: a value of over 100 characters", self.line),
                        ));
                    }
                }
            }
            self.r.consume(used);
            if done {
                break;
            }
        }
        if self.tok.is_empty() {
            return Ok(None);
        }
        std::str::from_utf8(&self.tok)
            .map(Some)
            .map_err(|_| bad(path, format!("body line {}: not text", self.line)))
    }

    /// The next value, parsed; `what` names it in errors.
    fn value<T: std::str::FromStr>(&mut self, path: &Path, what: &str) -> Result<T, Error> {
        let line = self.newlines + 1;
        let Some(tok) = self.next(path)? else {
            return Err(bad(
                path,
                format!("the file ends at body line {line}, before {what}"),
            ));
        };
        let parsed = tok.parse();
        parsed.map_err(|_| {
            bad(
                path,
                format!(
                    "body line {}: `{}` is not a valid {what}",
                    self.line,
                    tok_text(&self.tok)
                ),
            )
        })
    }
}

fn tok_text(t: &[u8]) -> String {
    String::from_utf8_lossy(t).into_owned()
}

/// The body of the file, positioned after what has been read.
enum Body {
    Binary(BufReader<File>),
    Ascii(Tokens),
}

impl Body {
    /// Skips the records of element `e` (scalar properties only).
    fn skip(&mut self, path: &Path, e: &Element) -> Result<(), Error> {
        match self {
            Body::Binary(r) => {
                let bytes = e.count * e.scalar_size().unwrap_or(0) as u64;
                let got = std::io::copy(&mut (&mut *r).take(bytes), &mut std::io::sink())
                    .map_err(|e| Error::io(path, e))?;
                if got != bytes {
                    return Err(bad(path, "the file is shorter than its header says"));
                }
            }
            Body::Ascii(t) => {
                let what = format!("a value of element `{}`", e.name);
                for _ in 0..e.count.saturating_mul(e.props.len() as u64) {
                    t.value::<f64>(path, &what)?;
                }
            }
        }
        Ok(())
    }
}

/// The bounding box of the vertices, as `oavm::rays::Bounds::of_points` computes it.
struct VertexBounds {
    min: [f32; 3],
    max: [f32; 3],
}

impl VertexBounds {
    fn add(&mut self, p: [f32; 3]) {
        for (k, &c) in p.iter().enumerate() {
            self.min[k] = self.min[k].min(c);
            self.max[k] = self.max[k].max(c);
        }
    }
    fn diagonal(&self) -> f64 {
        (0..3)
            .map(|k| (self.max[k] as f64 - self.min[k] as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    }
    /// The largest absolute coordinate.
    fn max_abs(&self) -> f64 {
        (0..3).fold(0.0f64, |m, k| {
            m.max((self.min[k] as f64).abs())
                .max((self.max[k] as f64).abs())
        })
    }
}

/// Reads every vertex position.
fn read_vertices(
    body: &mut Body,
    path: &Path,
    l: &Layout,
    progress: &mut Progress,
) -> Result<(Vec<[f32; 3]>, VertexBounds), Error> {
    let n = l.vertices as usize;
    let mut positions: Vec<[f32; 3]> = Vec::new();
    positions.try_reserve_exact(n).map_err(|_| {
        bad(
            path,
            format!("cannot allocate {} bytes for {n} vertex positions", n * 12),
        )
    })?;
    let mut b = VertexBounds {
        min: [f32::INFINITY; 3],
        max: [f32::NEG_INFINITY; 3],
    };
    let finite = |p: [f32; 3], i: usize| -> Result<[f32; 3], Error> {
        if p.iter().all(|c| c.is_finite()) {
            Ok(p)
        } else {
            Err(bad(
                path,
                format!("vertex {i}: a coordinate is not finite (or overflows f32): {p:?}"),
            ))
        }
    };
    match body {
        Body::Binary(r) => {
            let mut buf = vec![0u8; BATCH * l.vsize];
            while positions.len() < n {
                let m = BATCH.min(n - positions.len());
                let bytes = &mut buf[..m * l.vsize];
                r.read_exact(bytes).map_err(|e| Error::io(path, e))?;
                for rec in bytes.chunks_exact(l.vsize) {
                    let p = l.xyz.map(|(off, ty)| ty.coord_le(&rec[off..]));
                    let p = finite(p, positions.len())?;
                    b.add(p);
                    positions.push(p);
                }
                progress.show("vertices", positions.len() as u64, l.vertices);
            }
        }
        Body::Ascii(t) => {
            for i in 0..n {
                let mut p = [0f32; 3];
                for &(axis, ty) in &l.vprops {
                    match (axis, ty) {
                        (Some(k), Ty::F32) => p[k] = t.value::<f32>(path, "vertex coordinate")?,
                        (Some(k), _) => p[k] = t.value::<f64>(path, "vertex coordinate")? as f32,
                        (None, _) => {
                            t.value::<f64>(path, "vertex property")?;
                        }
                    }
                }
                let p = finite(p, i)?;
                b.add(p);
                positions.push(p);
                if i % BATCH == 0 {
                    progress.show("vertices", i as u64, l.vertices);
                }
            }
        }
    }
    progress.done("vertices", l.vertices);
    Ok((positions, b))
}

/// A chunk of faces in file order: the id of the first, and vertex indices.
struct Chunk {
    first: u32,
    tris: Vec<[u32; 3]>,
}

/// Reads the faces (and what follows them) and sends them in chunks of `chunk`; stops at the
/// first error (sent) or when the receiver has gone.
fn read_faces(
    mut body: Body,
    path: &Path,
    l: &Layout,
    chunk: usize,
    tx: SyncSender<Result<Chunk, Error>>,
) {
    let result = (|| -> Result<(), Error> {
        let nv = l.vertices;
        let index = |i: i64, f: u64| -> Result<u32, Error> {
            if i < 0 {
                Err(bad(path, format!("face {f}: negative vertex index {i}")))
            } else if i as u64 >= nv {
                Err(bad(
                    path,
                    format!(
                        "face {f}: vertex index {i} is out of range: the file has {nv} vertices"
                    ),
                ))
            } else {
                Ok(i as u32)
            }
        };
        let triangle = |count: i64, f: u64| -> Result<(), Error> {
            if count == 3 {
                Ok(())
            } else {
                Err(bad(
                    path,
                    format!(
                        "face {f} has {count} vertices: only triangles are supported (convert \
                         polygons to triangles first)"
                    ),
                ))
            }
        };
        let mut f = 0u64;
        while f < l.faces {
            let m = (chunk as u64).min(l.faces - f) as usize;
            let mut tris = Vec::with_capacity(m);
            match &mut body {
                Body::Binary(r) => {
                    let size = l.fsize();
                    let pre: usize = l.fpre.iter().map(|t| t.size()).sum();
                    let at = pre + l.count.size();
                    let is = l.item.size();
                    let mut buf = vec![0u8; BATCH.min(m) * size];
                    while tris.len() < m {
                        let k = BATCH.min(m - tris.len());
                        let bytes = &mut buf[..k * size];
                        r.read_exact(bytes).map_err(|e| Error::io(path, e))?;
                        for rec in bytes.chunks_exact(size) {
                            let face = f + tris.len() as u64;
                            triangle(l.count.int_le(&rec[pre..]), face)?;
                            let c = |j: usize| index(l.item.int_le(&rec[at + j * is..]), face);
                            tris.push([c(0)?, c(1)?, c(2)?]);
                        }
                    }
                }
                Body::Ascii(t) => {
                    for _ in 0..m {
                        let face = f + tris.len() as u64;
                        for _ in &l.fpre {
                            t.value::<f64>(path, "face property")?;
                        }
                        triangle(t.value::<i64>(path, "face vertex count")?, face)?;
                        let mut c = [0u32; 3];
                        for v in &mut c {
                            let i = t.value::<i64>(path, "vertex index")?;
                            if (l.item == Ty::I32 && i > i32::MAX as i64) || i > u32::MAX as i64 {
                                return Err(bad(
                                    path,
                                    format!("face {face}: index {i} overflows {}", l.item.name()),
                                ));
                            }
                            *v = index(i, face)?;
                        }
                        for _ in &l.fpost {
                            t.value::<f64>(path, "face property")?;
                        }
                        tris.push(c);
                    }
                }
            }
            let first = f as u32;
            f += m as u64;
            if tx.send(Ok(Chunk { first, tris })).is_err() {
                return Ok(());
            }
        }
        for e in &l.elements[l.face + 1..] {
            body.skip(path, e)?;
        }
        match &mut body {
            Body::Binary(r) => {
                let mut one = [0u8; 1];
                if r.read(&mut one).map_err(|e| Error::io(path, e))? != 0 {
                    return Err(bad(path, "data after the last element (the file grew?)"));
                }
            }
            Body::Ascii(t) => {
                if t.next(path)?.is_some() {
                    return Err(bad(
                        path,
                        format!("body line {}: data after the last element", t.line),
                    ));
                }
            }
        }
        Ok(())
    })();
    if let Err(e) = result {
        let _ = tx.send(Err(e));
    }
}

// ---------------------------------------------------------------------------------------------
// Culling and the reference
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug)]
struct Aabb {
    min: [f64; 3],
    max: [f64; 3],
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };

    fn of(tris: &[[[f32; 3]; 3]]) -> Aabb {
        let mut b = Aabb::EMPTY;
        for p in tris.iter().flatten() {
            for (k, &c) in p.iter().enumerate() {
                b.min[k] = b.min[k].min(c as f64);
                b.max[k] = b.max[k].max(c as f64);
            }
        }
        b
    }

    fn union(self, o: &Aabb) -> Aabb {
        Aabb {
            min: std::array::from_fn(|k| self.min[k].min(o.min[k])),
            max: std::array::from_fn(|k| self.max[k].max(o.max[k])),
        }
    }
}

/// A chunk ready to trace: its triangles in Morton order of their centroids, their primitive
/// ids, and the boxes of leaves, groups and the whole chunk.
struct Prepared {
    tris: Vec<[[f32; 3]; 3]>,
    ids: Vec<u32>,
    leaves: Vec<Aabb>,
    groups: Vec<Aabb>,
    bounds: Aabb,
}

/// Interleaves the low 10 bits of `x` with two zero bits between each.
fn spread(x: u32) -> u64 {
    let mut x = (x & 0x3ff) as u64;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    x = (x | (x << 2)) & 0x0924_9249;
    x
}

fn prepare(chunk: &Chunk, positions: &[[f32; 3]]) -> Prepared {
    // Indices were checked against the vertex count by the reader.
    let corners = |t: &[u32; 3]| t.map(|i| positions[i as usize]);
    let centroid = |t: &[u32; 3]| -> [f64; 3] {
        let c = corners(t);
        std::array::from_fn(|k| (c[0][k] as f64 + c[1][k] as f64 + c[2][k] as f64) / 3.0)
    };
    let (lo, hi) = chunk
        .tris
        .par_iter()
        .map(|t| {
            let c = centroid(t);
            (c, c)
        })
        .reduce(
            || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |a, b| {
                (
                    std::array::from_fn(|k| a.0[k].min(b.0[k])),
                    std::array::from_fn(|k| a.1[k].max(b.1[k])),
                )
            },
        );
    let scale: [f64; 3] = std::array::from_fn(|k| {
        let e = hi[k] - lo[k];
        if e > 0.0 { 1023.0 / e } else { 0.0 }
    });
    let mut keys: Vec<u64> = chunk
        .tris
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            let c = centroid(t);
            let q = |k: usize| ((c[k] - lo[k]) * scale[k]).clamp(0.0, 1023.0) as u32;
            let code = spread(q(0)) | spread(q(1)) << 1 | spread(q(2)) << 2;
            code << 32 | i as u64
        })
        .collect();
    keys.par_sort_unstable();
    let tris: Vec<[[f32; 3]; 3]> = keys
        .par_iter()
        .map(|&k| corners(&chunk.tris[k as u32 as usize]))
        .collect();
    let ids: Vec<u32> = keys.iter().map(|&k| chunk.first + k as u32).collect();
    let leaves: Vec<Aabb> = tris.par_chunks(LEAF).map(Aabb::of).collect();
    let groups: Vec<Aabb> = leaves
        .chunks(GROUP)
        .map(|g| g.iter().fold(Aabb::EMPTY, Aabb::union))
        .collect();
    let bounds = groups.iter().fold(Aabb::EMPTY, Aabb::union);
    Prepared {
        tris,
        ids,
        leaves,
        groups,
        bounds,
    }
}

/// A checked ray and what the pass has found for it so far.
struct Probe {
    /// The ray's index in the file.
    index: usize,
    ray: Ray,
    /// False for a ray that can hit nothing (invalid, or a range such as `[inf, inf]`):
    /// `hit_t` and `grazes` are false for it on every triangle.
    live: bool,
    o: [f64; 3],
    d: [f64; 3],
    inv: [f64; 3],
    /// How much each box is widened for this ray.
    w: f64,
    /// The ray's range `[tmin, tmax]`, widened.
    lo: f64,
    hi: f64,
    /// Closest hit so far: `t` and primitive id.
    best: Option<(f64, u32)>,
    occluded: bool,
    /// Whether the ray grazes a triangle seen so far (`reference::grazes`).
    grazes: bool,
    /// `--no-cull`: every box is met.
    no_cull: bool,
}

impl Probe {
    /// The margins make the culling conservative for both `reference` functions:
    ///
    /// - `grazes` is true for a triangle when the ray's point at some `t` in
    ///   `[tmin - s, tmax + s]`, `s = 1e-6 (1 + |tmin|)`, lies within
    ///   `1e-5 |edge| + 1e-6 max|a, b, o|` of an edge (`a`, `b`, the origin `o`): within
    ///   `1e-5 L + 1e-6 max(M, |o|)` of the triangle's box, `L` the diagonal and `M` the largest
    ///   coordinate of the mesh;
    /// - `hit_t`'s `t` and barycentrics are off from exact by about `1e-16 |o - a| / sin(angle
    ///   between ray and plane)` in position: within `1e-6 |o - a|` of the box unless the ray is
    ///   within about 1e-10 radians of the triangle's plane.
    ///
    /// Boxes are widened by twice the sum; ranges by `2 s`.
    fn new(index: usize, ray: Ray, diag: f64, max_abs: f64, no_cull: bool) -> Probe {
        let o = ray.origin.map(f64::from);
        let d = ray.dir.map(f64::from);
        let omax = o.iter().fold(0.0f64, |m, c| m.max(c.abs()));
        let (tmin, tmax) = (ray.tmin as f64, ray.tmax as f64);
        let slack = 2e-6 * (1.0 + tmin.abs());
        let (lo, hi) = (tmin - slack, tmax + slack + 2e-6 * tmax.abs());
        Probe {
            index,
            ray,
            // NaN ends (an infinite tmin) fail `lo <= hi`: `hit_t` and `grazes` are false.
            live: ray.is_valid() && lo <= hi,
            o,
            d,
            inv: d.map(|x| 1.0 / x),
            w: 2e-5 * diag + 1e-5 * max_abs.max(omax),
            lo,
            hi,
            best: None,
            occluded: false,
            grazes: false,
            no_cull,
        }
    }

    /// Whether a hit can still change the answer, and the end of the range where it can.
    fn hit_range(&self, any: bool) -> (bool, f64) {
        if any {
            (!self.occluded, self.hi)
        } else {
            match self.best {
                Some((t, _)) => (true, self.hi.min(t + 2e-6 * (1.0 + t.abs()))),
                None => (true, self.hi),
            }
        }
    }

    /// Whether `b`, widened by `w`, meets the ray's line within `[lo, hi]`, and within
    /// `[lo, hit_hi]`.
    #[inline]
    fn reach(&self, b: &Aabb, hit_hi: f64) -> (bool, bool) {
        if self.no_cull {
            return (true, true);
        }
        let mut enter = f64::NEG_INFINITY;
        let mut exit = f64::INFINITY;
        for k in 0..3 {
            let lo = b.min[k] - self.w - self.o[k];
            let hi = b.max[k] + self.w - self.o[k];
            if self.d[k] == 0.0 {
                if lo > 0.0 || hi < 0.0 {
                    return (false, false);
                }
            } else {
                let (a, c) = (lo * self.inv[k], hi * self.inv[k]);
                enter = enter.max(a.min(c));
                exit = exit.min(a.max(c));
            }
        }
        if enter > exit || exit < self.lo {
            return (false, false);
        }
        (enter <= self.hi, enter <= hit_hi)
    }

    fn record(&mut self, t: f64, id: u32, any: bool) {
        if any {
            self.occluded = true;
        } else if self
            .best
            .is_none_or(|(bt, bi)| t < bt || (t == bt && id < bi))
        {
            // reference::closest: the smallest t, ties to the lowest id (it scans in id order).
            self.best = Some((t, id));
        }
    }

    /// Tests the triangles of `c` that may matter.
    fn visit(&mut self, c: &Prepared, any: bool) {
        if !self.live {
            return;
        }
        let (need_hit, hit_hi) = self.hit_range(any);
        let (full, hit) = self.reach(&c.bounds, hit_hi);
        if !((full && !self.grazes) || (hit && need_hit)) {
            return;
        }
        for (g, gb) in c.groups.iter().enumerate() {
            let (need_hit, hit_hi) = self.hit_range(any);
            if !need_hit && self.grazes {
                return;
            }
            let (full, hit) = self.reach(gb, hit_hi);
            if !((full && !self.grazes) || (hit && need_hit)) {
                continue;
            }
            for l in g * GROUP..((g + 1) * GROUP).min(c.leaves.len()) {
                let (need_hit, hit_hi) = self.hit_range(any);
                let (full, hit) = self.reach(&c.leaves[l], hit_hi);
                let test_hit = hit && need_hit;
                let test_graze = full && !self.grazes;
                if !test_hit && !test_graze {
                    continue;
                }
                for i in l * LEAF..((l + 1) * LEAF).min(c.tris.len()) {
                    let tri = &c.tris[i];
                    if test_hit
                        && !(any && self.occluded)
                        && let Some(t) = reference::hit_t(tri, &self.ray)
                    {
                        self.record(t, c.ids[i], any);
                    }
                    if test_graze
                        && !self.grazes
                        && reference::grazes(std::slice::from_ref(tri), &self.ray)
                    {
                        self.grazes = true;
                    }
                }
            }
        }
    }

    /// The reference's closest hit (as `reference::closest` gives it).
    fn hit(&self) -> Hit {
        self.best.map_or(Hit::MISS, |(t, id)| Hit {
            t: t as f32,
            prim: id,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// The run
// ---------------------------------------------------------------------------------------------

/// Whether stderr's last line is a progress line not ended yet.
static PROGRESS_LINE: AtomicBool = AtomicBool::new(false);

/// Progress on stderr, at most twice a second.
struct Progress {
    start: Instant,
    last: f64,
}

impl Progress {
    fn show(&mut self, what: &str, done: u64, total: u64) {
        let now = self.start.elapsed().as_secs_f64();
        if now - self.last >= 0.5 {
            self.last = now;
            eprint!(
                "\rbrute_big: {what} {done} / {total} ({:.1} %), {now:.0} s   ",
                100.0 * done as f64 / total.max(1) as f64
            );
            PROGRESS_LINE.store(true, Ordering::Relaxed);
        }
    }
    fn done(&mut self, what: &str, total: u64) {
        eprintln!(
            "\rbrute_big: {what} {total} / {total} (100.0 %), {:.1} s   ",
            self.start.elapsed().as_secs_f64()
        );
        PROGRESS_LINE.store(false, Ordering::Relaxed);
        self.last = self.start.elapsed().as_secs_f64();
    }
}

/// The answers being checked.
enum Answers {
    Closest(Vec<Hit>),
    Any(Vec<bool>),
}

fn number(x: f32) -> Value {
    if x.is_finite() {
        json!(x)
    } else {
        json!(x.to_string())
    }
}

fn hit_json(h: Hit) -> Value {
    if h.is_hit() {
        json!({ "t": number(h.t), "prim": h.prim })
    } else {
        json!("miss")
    }
}

fn text(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Object(o) => format!("t={} prim={}", text(&o["t"]), o["prim"]),
        other => other.to_string(),
    }
}

fn run(args: &Args) -> Result<bool, Error> {
    let start = Instant::now();
    let mut progress = Progress { start, last: -1.0 };
    let rays = read_rays(&args.rays, MAX_RAYS)?;
    let (answers, answers_path) = match (&args.hits, &args.occluded) {
        (Some(p), _) => (Answers::Closest(read_hits(p, MAX_RAYS)?), p),
        (None, Some(p)) => {
            let raw = read_occlusion(p, MAX_RAYS)?;
            if let Some(i) = raw.iter().position(|&b| b > 1) {
                return Err(bad(p, format!("record {i} is {}, not 0 or 1", raw[i])));
            }
            (Answers::Any(raw.iter().map(|&b| b == 1).collect()), p)
        }
        (None, None) => unreachable!("clap requires one"),
    };
    let answered = match &answers {
        Answers::Closest(h) => h.len(),
        Answers::Any(o) => o.len(),
    };
    if answered != rays.len() {
        return Err(bad(
            answers_path,
            format!(
                "{answered} answers for the {} rays of {}",
                rays.len(),
                args.rays.display()
            ),
        ));
    }
    let any = matches!(answers, Answers::Any(_));
    let stride = (rays.len() / args.brute as usize).max(1);
    let subset: Vec<usize> = (0..rays.len()).step_by(stride).collect();

    // The mesh: header, vertices.
    let path = args.mesh.as_path();
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut r = BufReader::with_capacity(1 << 22, file);
    let (ascii, header_len, elements) = read_header(&mut r, path)?;
    let l = layout(path, ascii, header_len, elements, file_len)?;
    let mut body = if l.ascii {
        Body::Ascii(Tokens {
            r,
            tok: Vec::new(),
            line: 0,
            newlines: 0,
        })
    } else {
        Body::Binary(r)
    };
    for e in &l.elements[..l.vertex] {
        body.skip(path, e)?;
    }
    let (positions, vb) = read_vertices(&mut body, path, &l, &mut progress)?;
    for e in &l.elements[l.vertex + 1..l.face] {
        body.skip(path, e)?;
    }
    let diag = vb.diagonal();
    let max_abs = vb.max_abs();
    eprintln!(
        "brute_big: {}: {} vertices, {} triangles, L = {diag}; checking {} of {} rays (every {})",
        path.display(),
        l.vertices,
        l.faces,
        subset.len(),
        rays.len(),
        stride
    );

    let mut probes: Vec<Probe> = subset
        .iter()
        .map(|&i| Probe::new(i, rays[i], diag, max_abs, args.no_cull))
        .collect();

    // The faces: read by a thread, traced here.
    let traced = Instant::now();
    std::thread::scope(|s| -> Result<(), Error> {
        let (tx, rx) = sync_channel(2);
        let l = &l;
        s.spawn(move || read_faces(body, path, l, args.chunk as usize, tx));
        let mut done = 0u64;
        for chunk in rx {
            let chunk = chunk?;
            let prepared = prepare(&chunk, &positions);
            probes.par_iter_mut().for_each(|p| p.visit(&prepared, any));
            done += chunk.tris.len() as u64;
            progress.show("triangles", done, l.faces);
        }
        if done != l.faces {
            return Err(bad(path, "the face pass ended early"));
        }
        progress.done("triangles", l.faces);
        Ok(())
    })?;
    let trace_seconds = traced.elapsed().as_secs_f64();

    // Compare.
    let (mut agree, mut grazing, mut disagree, mut both_hit, mut same_prim) = (0, 0, 0, 0, 0);
    let (mut ref_hits, mut file_hits) = (0, 0);
    let mut examples = Vec::new();
    for p in &probes {
        let (ok, theirs, ours) = match &answers {
            Answers::Closest(h) => {
                let (file, truth) = (h[p.index], p.hit());
                ref_hits += usize::from(truth.is_hit());
                file_hits += usize::from(file.is_hit());
                let ok = file.agrees(&truth, diag);
                if ok && file.is_hit() {
                    both_hit += 1;
                    same_prim += usize::from(file.prim == truth.prim);
                }
                (ok, hit_json(file), hit_json(truth))
            }
            Answers::Any(o) => {
                let (file, truth) = (o[p.index], p.occluded);
                ref_hits += usize::from(truth);
                file_hits += usize::from(file);
                let word = |b: bool| json!(if b { "occluded" } else { "clear" });
                (file == truth, word(file), word(truth))
            }
        };
        if ok {
            agree += 1;
        } else if p.grazes {
            grazing += 1;
        } else {
            disagree += 1;
            if examples.len() < EXAMPLES {
                let r = &p.ray;
                examples.push(json!({
                    "ray": p.index,
                    "origin": r.origin.map(number), "dir": r.dir.map(number),
                    "tmin": number(r.tmin), "tmax": number(r.tmax),
                    "file": theirs, "reference": ours,
                }));
            }
        }
    }
    let seconds = start.elapsed().as_secs_f64();
    let pass = disagree == 0;
    let query = if any { "any hit" } else { "closest hit" };
    let hit_word = if any { "occluded" } else { "hits" };
    if args.json {
        cli::print_json(&json!({
            "mesh": path.display().to_string(),
            "rays_file": args.rays.display().to_string(),
            "answers_file": answers_path.display().to_string(),
            "query": if any { "any" } else { "closest" },
            "vertices": l.vertices,
            "triangles": l.faces,
            "diagonal": diag,
            "tolerance": AGREEMENT_TOLERANCE * diag,
            "rays": rays.len(),
            "stride": stride,
            "checked": probes.len(),
            "reference_hits": ref_hits,
            "file_hits": file_hits,
            "agree": agree,
            "grazing": grazing,
            "grazing_rays": probes.iter().filter(|p| p.grazes).count(),
            "culled": !args.no_cull,
            "disagree": disagree,
            "both_hit": both_hit,
            "same_prim": same_prim,
            "examples": examples,
            "trace_seconds": trace_seconds,
            "seconds": seconds,
            "pass": pass,
        }))?;
    } else {
        let mut out = format!(
            "{query}: {} rays in {}, {} checked (every {stride}); {hit_word}: reference {ref_hits}, \
             file {file_hits}; agree {agree}, grazing {grazing}, disagree {disagree}; {:.1} s \
             ({} triangles, L = {diag:.6}){}\n",
            rays.len(),
            args.rays.display(),
            probes.len(),
            seconds,
            l.faces,
            if any {
                String::new()
            } else {
                format!("; both hit {both_hit}, same primitive {same_prim}")
            },
        );
        for e in &examples {
            out.push_str(&format!(
                "  disagreement: ray {}: origin {} dir {} t in [{}, {}]: file {}, reference {}\n",
                e["ray"],
                e["origin"],
                e["dir"],
                text(&e["tmin"]),
                text(&e["tmax"]),
                text(&e["file"]),
                text(&e["reference"]),
            ));
        }
        out.push_str(if pass { "PASS\n" } else { "FAIL\n" });
        cli::print_text(&out)?;
    }
    Ok(pass)
}
