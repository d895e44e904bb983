//! OBJ reader, through `tobj::load_obj_buf`.
//!
//! `tobj` reads the faces: `f` lines, relative (negative) indices, and the split into models at
//! `o`, `g` and `usemtl`. We read the `v` lines ourselves, in [`Lines`], the `BufRead` that feeds
//! `tobj`. What `tobj` 4.0 does, read from its source, and what we do about it:
//!
//! - It splits the file into models at `o` and `g` lines and at `usemtl` lines that change the
//!   material, each time only if faces were read since the last split, and returns the models
//!   in file order with each model's faces in file order. Concatenating the models therefore
//!   keeps the order of the `f` lines, which is the id order RAYS.md asks for.
//! - Its triangulation is a fan from the first corner, the same as ours, but it fails on an
//!   `f` line with no corner. We load with `triangulate: false` and fan-triangulate from
//!   `face_arities` with [`Fan`], the one triangulation both readers share. `ignore_points` and
//!   `ignore_lines` drop faces of one and two corners, which give no triangle anyway.
//! - It reads `l` (polyline) statements as faces, which would turn a 3-point polyline into a
//!   triangle and shift the ids of the faces after it. [`Lines`] hides `l` lines from it, and
//!   also `vt` and `vn` lines: we need positions only, and without them `tobj` never does the
//!   texcoord and normal index arithmetic that overflows (a panic with overflow checks on) on
//!   an index of 0 or a huge one.
//! - Per model it keeps only the vertices the model's faces use, in order of first use, so
//!   unused vertices vanish and shared ones are duplicated, and it does not say which `v` line
//!   a vertex came from. To keep the file's vertices, in file order, [`Lines`] parses each `v`
//!   line itself and hands `tobj` the line's 0-based number instead, as `v lo hi 0` with
//!   `lo + 65536 * hi` (both exact in `f32`); the positions `tobj` returns are then those
//!   numbers ([`vertex_number`]). So `Mesh::positions[i]` is the `i+1`-th `v` line, as in
//!   the file's own indices.
//! - Out-of-range vertex indices (0, too large, relative beyond the first vertex) give
//!   `FaceVertexOutOfBounds` when the model ends, without a line; we then find the face
//!   ourselves ([`locate_bad_index`]). Other `tobj` errors are reported at the line `tobj` was
//!   reading, which [`Lines`] counts.
//! - Material libraries are not opened (`mtllib` gets an error that `tobj` keeps to itself).
//!
//! A `v` line is `v x y z`, optionally followed by `w` (the position is divided by it, as
//! `tobj` does) or by three colour values (ignored); coordinates parse as `f32`, as in `tobj`.

use std::io::{BufRead, Read};

use super::{Fan, Mesh, MeshError, Place};

/// Parses an OBJ file held in `bytes`; `name` is the file name used in errors.
///
/// Triangle ids follow the `f` lines across all objects and groups (RAYS.md); vertex `i` is the
/// `i+1`-th `v` line (OBJ counts from 1).
pub fn parse_obj(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    // The rest stays default so that this compiles whether or not some other crate enables
    // tobj's `merging` and `reordering` features, which add fields.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let mut lines = Lines::new(bytes, name);
    let loaded = tobj::load_obj_buf(&mut lines, &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    });
    if let Some(error) = lines.error.take() {
        return Err(error);
    }
    let models = match loaded {
        Ok((models, _materials)) => models,
        Err(tobj::LoadError::FaceVertexOutOfBounds) => {
            return Err(match locate_bad_index(bytes, lines.line) {
                Some(bad) => MeshError::IndexOutOfRange {
                    file: name.to_owned(),
                    at: Place::Line(bad.line),
                    face: bad.face,
                    index: bad.index,
                    vertices: bad.vertices,
                },
                None => MeshError::Obj {
                    file: name.to_owned(),
                    line: lines.line,
                    detail: "a face of the object ending here refers to a missing vertex"
                        .to_owned(),
                },
            });
        }
        Err(e) => {
            return Err(MeshError::Obj {
                file: name.to_owned(),
                line: lines.line,
                detail: e.to_string(),
            });
        }
    };

    let mut mesh = Mesh {
        geometries: Vec::new(),
        positions: lines.positions,
        triangles: Vec::new(),
    };
    for model in &models {
        append_model(&mut mesh, &model.mesh, name, lines.line)?;
    }
    super::check_sizes(&mesh, name)?;
    Ok(mesh)
}

/// The `v` line number (0-based) that [`Lines`] encoded into a position it gave `tobj`.
fn vertex_number(p: &[f32]) -> Option<u32> {
    let [lo, hi, 0.0] = *p else {
        return None;
    };
    let integral = |c: f32| (0.0..65536.0).contains(&c) && c.fract() == 0.0;
    if !integral(lo) || !integral(hi) {
        return None;
    }
    Some(lo as u32 + ((hi as u32) << 16))
}

/// Appends the triangles of one `tobj` model, fan-triangulating its faces and checking what
/// `tobj` promises.
fn append_model(
    mesh: &mut Mesh,
    model: &tobj::Mesh,
    file: &str,
    last_line: u64,
) -> Result<(), MeshError> {
    let broken = |detail: &str| MeshError::Obj {
        file: file.to_owned(),
        line: last_line,
        detail: format!("tobj returned {detail}"),
    };
    // Model vertex -> file vertex.
    let numbers = model
        .positions
        .chunks(3)
        .map(|p| {
            vertex_number(p)
                .filter(|&n| (n as usize) < mesh.positions.len())
                .ok_or_else(|| broken("a vertex that is not one of the file's"))
        })
        .collect::<Result<Vec<u32>, MeshError>>()?;
    let corner = |i: u32| -> Result<u32, MeshError> {
        numbers
            .get(i as usize)
            .copied()
            .ok_or_else(|| broken("an index out of its model's range"))
    };
    // With `triangulate: false`, empty `face_arities` means every face is a triangle.
    let all_triangles;
    let arities: &[u32] = if model.face_arities.is_empty() {
        if !model.indices.len().is_multiple_of(3) {
            return Err(broken("a triangle index array that is not made of triples"));
        }
        all_triangles = vec![3; model.indices.len() / 3];
        &all_triangles
    } else {
        &model.face_arities
    };
    let mut rest = &model.indices[..];
    for &arity in arities {
        let Some((face, tail)) = rest.split_at_checked(arity as usize) else {
            return Err(broken("face arities longer than its indices"));
        };
        let mut fan = Fan::default();
        for &i in face {
            fan.push(corner(i)?, &mut mesh.triangles);
        }
        rest = tail;
    }
    if !rest.is_empty() {
        return Err(broken("indices beyond its face arities"));
    }
    Ok(())
}

/// The first words of OBJ statements, for recognising an OBJ file by its content.
const STATEMENTS: &[&str] = &[
    "v",
    "vt",
    "vn",
    "vp",
    "f",
    "l",
    "p",
    "o",
    "g",
    "s",
    "mg",
    "mtllib",
    "usemtl",
    "usemap",
    "maplib",
    "cstype",
    "deg",
    "bmat",
    "step",
    "curv",
    "curv2",
    "surf",
    "parm",
    "trim",
    "hole",
    "scrv",
    "sp",
    "end",
    "con",
    "lod",
    "shadow_obj",
    "trace_obj",
    "ctech",
    "stech",
    "bevel",
    "c_interp",
    "d_interp",
];

/// Whether `bytes` reads as OBJ: the first 100 statements (lines other than blank lines and
/// `#` comments) are OBJ statements, and there is at least one.
pub(crate) fn looks_like_obj(bytes: &[u8]) -> bool {
    let mut statements = 0;
    for line in bytes.split(|&b| b == b'\n') {
        let Ok(line) = std::str::from_utf8(line) else {
            return false;
        };
        let Some(first) = line.split_whitespace().next() else {
            continue;
        };
        if first.starts_with('#') {
            continue;
        }
        if !STATEMENTS.contains(&first) {
            return false;
        }
        statements += 1;
        if statements == 100 {
            break;
        }
    }
    statements > 0
}

/// The first whitespace-separated word of a line, split the way `tobj` splits it.
fn first_word(line: &[u8]) -> Option<&str> {
    std::str::from_utf8(line).ok()?.split_whitespace().next()
}

/// A `BufRead` over the file's bytes that hands `tobj` one line at a time. It counts lines (so
/// `tobj`'s errors get a line number), hides `l`, `vt` and `vn` lines, and reads each `v` line
/// itself, handing `tobj` the vertex's number in its place (see the module docs).
struct Lines<'a> {
    bytes: &'a [u8],
    file: &'a str,
    /// Start of the next line in `bytes`.
    next: usize,
    /// The line being handed out, and how much of it is consumed.
    current: Vec<u8>,
    consumed: usize,
    /// The 1-based number of the line being handed out (or of the last line, at the end).
    line: u64,
    /// The `v` lines read so far, in file order.
    positions: Vec<[f32; 3]>,
    /// The first bad `v` line; the file then ends, for `tobj`, just before it.
    error: Option<MeshError>,
}

impl<'a> Lines<'a> {
    fn new(bytes: &'a [u8], file: &'a str) -> Lines<'a> {
        Lines {
            bytes,
            file,
            next: 0,
            current: Vec::new(),
            consumed: 0,
            line: 0,
            positions: Vec::new(),
            error: None,
        }
    }

    /// Moves to the next line `tobj` should see; leaves `current` empty at the end.
    fn next_line(&mut self) {
        self.current.clear();
        self.consumed = 0;
        while self.error.is_none() && self.next < self.bytes.len() {
            let rest = &self.bytes[self.next..];
            let len = rest
                .iter()
                .position(|&b| b == b'\n')
                .map_or(rest.len(), |n| n + 1);
            let text = &rest[..len];
            self.next += len;
            self.line += 1;
            match first_word(text) {
                Some("l" | "vt" | "vn") => continue,
                Some("v") => {
                    if let Err(error) = self.vertex(text) {
                        self.error = Some(error);
                        return;
                    }
                    let number = self.positions.len() - 1;
                    let line = format!("v {} {} 0\n", number & 0xffff, number >> 16);
                    self.current.extend_from_slice(line.as_bytes());
                }
                _ => self.current.extend_from_slice(text),
            }
            return;
        }
    }

    /// Reads a `v` line: `x y z`, then nothing, `w`, or `r g b`.
    fn vertex(&mut self, text: &[u8]) -> Result<(), MeshError> {
        let vertex = self.positions.len() as u64 + 1;
        let at = Place::Line(self.line);
        let bad = |detail: String| MeshError::Obj {
            file: self.file.to_owned(),
            line: self.line,
            detail: format!("vertex {vertex}: {detail}"),
        };
        if self.positions.len() > u32::MAX as usize {
            return Err(MeshError::TooLarge {
                file: self.file.to_owned(),
                detail: format!("more than 2^32 vertices at line {}", self.line),
            });
        }
        let text = std::str::from_utf8(text).map_err(|_| bad("not UTF-8".to_owned()))?;
        let words: Vec<&str> = text.split_whitespace().skip(1).collect();
        let number = |word: &str| {
            word.parse::<f32>()
                .map_err(|_| bad(format!("`{word}` is not a number")))
        };
        let mut xyz = [0f32; 3];
        match words[..] {
            [x, y, z] | [x, y, z, _, _, _] => xyz = [number(x)?, number(y)?, number(z)?],
            [x, y, z, w] => {
                let w = number(w)?;
                if w == 0.0 {
                    return Err(bad("the weight w is 0".to_owned()));
                }
                for (c, word) in xyz.iter_mut().zip([x, y, z]) {
                    *c = number(word)? / w;
                }
            }
            _ => {
                return Err(bad(format!(
                    "{} values; a `v` line holds x y z, then optionally w or r g b",
                    words.len()
                )));
            }
        }
        if !xyz.iter().all(|c| c.is_finite()) {
            return Err(MeshError::NonFinite {
                file: self.file.to_owned(),
                at,
                vertex,
            });
        }
        self.positions.push(xyz);
        Ok(())
    }
}

impl Read for Lines<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let available = self.fill_buf()?;
        let n = available.len().min(buf.len());
        buf[..n].copy_from_slice(&available[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl BufRead for Lines<'_> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.consumed >= self.current.len() {
            self.next_line();
        }
        Ok(&self.current[self.consumed..])
    }

    fn consume(&mut self, amount: usize) {
        self.consumed = self.consumed.saturating_add(amount).min(self.current.len());
    }
}

/// A face whose vertex index is out of range.
struct BadIndex {
    line: u64,
    face: u64,
    index: i64,
    vertices: u64,
}

/// Finds the face behind `tobj`'s `FaceVertexOutOfBounds`, raised when the model ending at
/// line `error_line` was exported: the first `f` line up to there with an index that is 0,
/// resolves (relative indices against the `v` lines before it) before the first vertex, or at
/// or beyond the vertices read by `error_line`.
fn locate_bad_index(bytes: &[u8], error_line: u64) -> Option<BadIndex> {
    let lines = || {
        bytes
            .split(|&b| b == b'\n')
            .take(usize::try_from(error_line).unwrap_or(usize::MAX))
            .zip(1u64..)
    };
    let vertices = lines()
        .filter(|(text, _)| first_word(text) == Some("v"))
        .count() as i64;
    let mut seen = 0i64;
    let mut face = 0u64;
    for (text, line) in lines() {
        let Ok(text) = std::str::from_utf8(text) else {
            continue;
        };
        let mut words = text.split_whitespace();
        match words.next() {
            Some("v") => seen += 1,
            Some("f") => {
                face += 1;
                for word in words {
                    let Some(Ok(index)) = word.split('/').next().map(str::parse::<i64>) else {
                        continue;
                    };
                    let resolved = if index < 0 {
                        seen.saturating_add(index)
                    } else {
                        index - 1
                    };
                    if !(0..vertices).contains(&resolved) {
                        return Some(BadIndex {
                            line,
                            face,
                            index,
                            vertices: vertices as u64,
                        });
                    }
                }
            }
            _ => {}
        }
    }
    None
}
