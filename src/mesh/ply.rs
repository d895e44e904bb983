//! PLY reader: `format ascii 1.0`, `binary_little_endian 1.0` and `binary_big_endian 1.0`.
//!
//! The format is Greg Turk's (the `ply.c` of the Stanford 3D Scanning Repository, described at
//! paulbourke.net/dataformats/ply). What we take from a file:
//!
//! - element `vertex`: the scalar properties `x`, `y`, `z` of type `float`/`float32` or
//!   `double`/`float64`; every other property (any scalar type, or a list) is skipped;
//! - element `face`: the list property `vertex_indices` (or `vertex_index`) with integer count
//!   and item types; every other property is skipped; polygons are fan-triangulated
//!   ([`Fan`](super::Fan));
//! - every other element is skipped, wherever it stands; `face` may come before `vertex`.
//!
//! Reading is in two steps: [`parse_header`] turns the header into [`Header`], [`plan`] turns
//! that into one [`Plan`] per element (what to do with each property), then the body is read
//! element after element by [`read_ascii`] or [`read_binary`]. Ascii records are one per line as
//! in `ply.c` (blank lines between records are allowed); an ascii line with too few or too many
//! values is an error, not something to realign.
//!
//! The binary reader hands what it reads to a [`Sink`]: [`parse_ply`]'s sink builds the whole
//! [`Mesh`]; the streaming reader ([`super::stream`]) reads a mapped file in passes, one sink
//! per pass ([`BinaryPly`] is its way in). One parser, so one set of checks and error messages
//! for both; the checks that need the whole body (vertex indices against the vertex count,
//! [`IndexCheck`]; the sizes of `check_sizes`) are made by each sink at its end.
//!
//! Before reading an element we check that the bytes left can hold its declared records at their
//! smallest (binary: the sum of scalar sizes and list-length sizes; ascii: two bytes per value,
//! a digit and a separator), and every allocation is sized from counts that passed that check.
//! An element with no properties occupies no bytes and is skipped without looping over its
//! declared count.

use super::{Fan, Mesh, MeshError, Place};

/// The first header line, with either line ending.
pub(crate) fn has_magic(bytes: &[u8]) -> bool {
    bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n")
}

/// Parses a PLY file held in `bytes`; `name` is the file name used in errors.
pub fn parse_ply(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    let header = parse_header(bytes, name)?;
    let plans = plan(&header, name)?;
    let mut out = Builder::default();
    let body = Body {
        bytes,
        file: name,
        plans: &plans,
    };
    match header.format {
        Format::Ascii => read_ascii(&body, header.body_start, header.body_line, &mut out)?,
        Format::BinaryLittleEndian => {
            read_binary::<false, _>(&body, header.body_start, &mut out)?;
        }
        Format::BinaryBigEndian => {
            read_binary::<true, _>(&body, header.body_start, &mut out)?;
        }
    }
    out.finish(name)
}

/// A binary PLY's header, checked and planned: what the streaming reader (`super::stream`)
/// needs to read the body in several passes, each into its own [`Sink`].
#[derive(Debug)]
pub(crate) struct BinaryPly {
    plans: Vec<Plan>,
    big_endian: bool,
    body_start: usize,
    vertices: u64,
    faces: u64,
}

impl BinaryPly {
    /// Parses and plans the header of `bytes` (only the header is read), exactly as
    /// [`parse_ply`] does; an ascii file is an error (at its `format` line) whose message
    /// begins with `ascii_detail`.
    pub(crate) fn new(bytes: &[u8], file: &str, ascii_detail: &str) -> Result<Self, MeshError> {
        let header = parse_header(bytes, file)?;
        let plans = plan(&header, file)?;
        let big_endian = match header.format {
            Format::Ascii => {
                return Err(MeshError::Header {
                    file: file.to_owned(),
                    line: header.format_line,
                    detail: ascii_detail.to_owned(),
                });
            }
            Format::BinaryLittleEndian => false,
            Format::BinaryBigEndian => true,
        };
        let count = |role| {
            plans
                .iter()
                .find(|p: &&Plan| p.role == role)
                .map_or(0, |p| p.count)
        };
        Ok(BinaryPly {
            vertices: count(Role::Vertex),
            faces: count(Role::Face),
            plans,
            big_endian,
            body_start: header.body_start,
        })
    }

    /// Records declared by the `vertex` element.
    pub(crate) fn vertices(&self) -> u64 {
        self.vertices
    }

    /// Records declared by the `face` element (polygons, before triangulation).
    pub(crate) fn faces(&self) -> u64 {
        self.faces
    }

    /// Reads the body of `bytes` (the bytes the header was read from) into `out`, with every
    /// check of [`parse_ply`] but those of the sink's `finish` (index range, sizes); returns
    /// the offset where reading ended.
    pub(crate) fn read<S: Sink>(
        &self,
        bytes: &[u8],
        file: &str,
        out: &mut S,
    ) -> Result<usize, S::Error> {
        let body = Body {
            bytes,
            file,
            plans: &self.plans,
        };
        if self.big_endian {
            read_binary::<true, S>(&body, self.body_start, out)
        } else {
            read_binary::<false, S>(&body, self.body_start, out)
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Types

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum IntType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
}

impl IntType {
    fn size(self) -> usize {
        match self {
            IntType::I8 | IntType::U8 => 1,
            IntType::I16 | IntType::U16 => 2,
            IntType::I32 | IntType::U32 => 4,
        }
    }

    fn range(self) -> (i64, i64) {
        match self {
            IntType::I8 => (i8::MIN.into(), i8::MAX.into()),
            IntType::U8 => (0, u8::MAX.into()),
            IntType::I16 => (i16::MIN.into(), i16::MAX.into()),
            IntType::U16 => (0, u16::MAX.into()),
            IntType::I32 => (i32::MIN.into(), i32::MAX.into()),
            IntType::U32 => (0, u32::MAX.into()),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ScalarType {
    Int(IntType),
    F32,
    F64,
}

impl ScalarType {
    /// Both the `ply.c` names and the sized names.
    fn from_name(name: &[u8]) -> Option<ScalarType> {
        Some(match name {
            b"char" | b"int8" => ScalarType::Int(IntType::I8),
            b"uchar" | b"uint8" => ScalarType::Int(IntType::U8),
            b"short" | b"int16" => ScalarType::Int(IntType::I16),
            b"ushort" | b"uint16" => ScalarType::Int(IntType::U16),
            b"int" | b"int32" => ScalarType::Int(IntType::I32),
            b"uint" | b"uint32" => ScalarType::Int(IntType::U32),
            b"float" | b"float32" => ScalarType::F32,
            b"double" | b"float64" => ScalarType::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            ScalarType::Int(t) => t.size(),
            ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }
}

/// Floating-point types allowed for `x`, `y`, `z`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FloatType {
    F32,
    F64,
}

// ---------------------------------------------------------------------------------------------
// Header

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

#[derive(Clone, Copy, Debug)]
enum PropertyKind {
    Scalar(ScalarType),
    List { count: IntType, item: ScalarType },
}

#[derive(Debug)]
struct Property {
    name: Vec<u8>,
    kind: PropertyKind,
    line: u64,
}

#[derive(Debug)]
struct Element {
    name: Vec<u8>,
    count: u64,
    properties: Vec<Property>,
    line: u64,
}

#[derive(Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Offset of the first body byte, just past the `end_header` line's `\n`.
    body_start: usize,
    /// Line number of the first body line (for ascii).
    body_line: u64,
    /// Line number of the `format` line.
    format_line: u64,
}

fn show(name: &[u8]) -> String {
    String::from_utf8_lossy(name).into_owned()
}

fn parse_header(bytes: &[u8], file: &str) -> Result<Header, MeshError> {
    let error = |line: u64, detail: String| MeshError::Header {
        file: file.to_owned(),
        line,
        detail,
    };
    if !has_magic(bytes) {
        return Err(error(
            1,
            "the file does not start with the magic line `ply`".to_owned(),
        ));
    }
    let mut format = None;
    let mut format_line = 0;
    let mut elements: Vec<Element> = Vec::new();
    let mut pos = 0usize;
    let mut line = 0u64;
    loop {
        line += 1;
        let Some(newline) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            // The last line, whether or not it has text without a newline.
            let last = if pos == bytes.len() { line - 1 } else { line };
            return Err(error(
                last,
                "the file ends before the `end_header` line".to_owned(),
            ));
        };
        let text = &bytes[pos..pos + newline];
        pos += newline + 1;
        let mut words = text
            .split(|b| b.is_ascii_whitespace())
            .filter(|w| !w.is_empty());
        let keyword = words.next();
        let rest: Vec<&[u8]> = words.collect();
        match keyword {
            Some(b"ply") if line == 1 && rest.is_empty() => {}
            None | Some(b"comment" | b"obj_info") => {}
            Some(b"format") => {
                if format.is_some() {
                    return Err(error(line, "a second `format` line".to_owned()));
                }
                let kind = match rest.first().copied() {
                    Some(b"ascii") => Format::Ascii,
                    Some(b"binary_little_endian") => Format::BinaryLittleEndian,
                    Some(b"binary_big_endian") => Format::BinaryBigEndian,
                    other => {
                        return Err(error(
                            line,
                            format!(
                                "unknown format `{}` (expected ascii, binary_little_endian or binary_big_endian)",
                                show(other.unwrap_or_default())
                            ),
                        ));
                    }
                };
                if rest.len() != 2 || rest[1] != b"1.0" {
                    return Err(error(
                        line,
                        format!(
                            "unsupported format line `{}` (expected `format <kind> 1.0`)",
                            show(text.trim_ascii())
                        ),
                    ));
                }
                format = Some(kind);
                format_line = line;
            }
            Some(b"element") => {
                let [name, count] = rest[..] else {
                    return Err(error(
                        line,
                        format!(
                            "`{}` is not `element <name> <count>`",
                            show(text.trim_ascii())
                        ),
                    ));
                };
                let count = std::str::from_utf8(count)
                    .ok()
                    .and_then(|c| c.parse::<u64>().ok())
                    .ok_or_else(|| {
                        error(
                            line,
                            format!(
                                "element `{}` has the count `{}`, not a non-negative integer",
                                show(name),
                                show(count)
                            ),
                        )
                    })?;
                elements.push(Element {
                    name: name.to_vec(),
                    count,
                    properties: Vec::new(),
                    line,
                });
            }
            Some(b"property") => {
                let Some(element) = elements.last_mut() else {
                    return Err(error(
                        line,
                        "a `property` line before any `element` line".to_owned(),
                    ));
                };
                let scalar = |name: &[u8]| {
                    ScalarType::from_name(name)
                        .ok_or_else(|| error(line, format!("unknown type `{}`", show(name))))
                };
                let (kind, name) = match rest[..] {
                    [b"list", count, item, name] => {
                        let ScalarType::Int(count) = scalar(count)? else {
                            return Err(error(
                                line,
                                format!(
                                    "list `{}` has the length type `{}`; it must be an integer type",
                                    show(name),
                                    show(rest[1])
                                ),
                            ));
                        };
                        let item = scalar(item)?;
                        (PropertyKind::List { count, item }, name)
                    }
                    [ty, name] if ty != b"list" => (PropertyKind::Scalar(scalar(ty)?), name),
                    _ => {
                        return Err(error(
                            line,
                            format!(
                                "`{}` is not `property <type> <name>` or `property list <type> <type> <name>`",
                                show(text.trim_ascii())
                            ),
                        ));
                    }
                };
                element.properties.push(Property {
                    name: name.to_vec(),
                    kind,
                    line,
                });
            }
            Some(b"end_header") if rest.is_empty() => {
                let Some(format) = format else {
                    return Err(error(
                        line,
                        "no `format` line before `end_header`".to_owned(),
                    ));
                };
                return Ok(Header {
                    format,
                    elements,
                    body_start: pos,
                    body_line: line + 1,
                    format_line,
                });
            }
            Some(other) => {
                return Err(error(
                    line,
                    format!("unknown header line starting with `{}`", show(other)),
                ));
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Plan: what to do with each property

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Vertex,
    Face,
    Other,
}

#[derive(Clone, Copy, Debug)]
enum Field {
    /// A scalar we do not use.
    Skip(ScalarType),
    /// Coordinate `axis` (0, 1, 2 for x, y, z).
    Coord { axis: usize, ty: FloatType },
    /// A list we do not use.
    SkipList { count: IntType, item: ScalarType },
    /// The face's vertex indices.
    Indices { count: IntType, item: IntType },
}

impl Field {
    /// Bytes of the smallest binary encoding (an empty list is its length alone).
    fn min_binary_size(self) -> usize {
        match self {
            Field::Skip(ty) => ty.size(),
            Field::Coord {
                ty: FloatType::F32, ..
            } => 4,
            Field::Coord {
                ty: FloatType::F64, ..
            } => 8,
            Field::SkipList { count, .. } | Field::Indices { count, .. } => count.size(),
        }
    }
}

#[derive(Debug)]
struct Plan {
    /// The element's name, for messages.
    name: String,
    count: u64,
    role: Role,
    fields: Vec<Field>,
}

impl Plan {
    /// What a record is called in messages: `vertex 17`, `face 3`, `edge 0`.
    fn record(&self, index: u64) -> String {
        format!("{} {index}", self.name)
    }
}

fn plan(header: &Header, file: &str) -> Result<Vec<Plan>, MeshError> {
    let error = |line: u64, detail: String| MeshError::Header {
        file: file.to_owned(),
        line,
        detail,
    };
    let find = |name: &[u8]| -> Result<Option<&Element>, MeshError> {
        let mut found = header.elements.iter().filter(|e| e.name == name);
        let first = found.next();
        if let Some(second) = found.next() {
            return Err(error(
                second.line,
                format!("a second `{}` element", show(name)),
            ));
        }
        Ok(first)
    };
    let last_line = header.body_line - 1;
    let Some(vertex) = find(b"vertex")? else {
        return Err(error(last_line, "no `vertex` element".to_owned()));
    };
    let Some(face) = find(b"face")? else {
        return Err(error(
            last_line,
            "no `face` element (this reader wants polygons, not a point cloud)".to_owned(),
        ));
    };
    // vertex: exactly one x, y and z, each a float or double scalar.
    let mut axes: [Option<&Property>; 3] = [None; 3];
    for p in &vertex.properties {
        let axis = match &p.name[..] {
            b"x" => 0,
            b"y" => 1,
            b"z" => 2,
            _ => continue,
        };
        if axes[axis].is_some() {
            return Err(error(
                p.line,
                format!("a second vertex property `{}`", show(&p.name)),
            ));
        }
        match p.kind {
            PropertyKind::Scalar(ScalarType::F32 | ScalarType::F64) => axes[axis] = Some(p),
            _ => {
                return Err(error(
                    p.line,
                    format!(
                        "vertex property `{}` must be a float or double scalar",
                        show(&p.name)
                    ),
                ));
            }
        }
    }
    for (axis, name) in axes.iter().zip(["x", "y", "z"]) {
        if axis.is_none() {
            return Err(error(
                vertex.line,
                format!("the vertex element has no property `{name}`"),
            ));
        }
    }

    // face: exactly one integer list named vertex_indices or vertex_index.
    let mut indices = None;
    for p in &face.properties {
        if &p.name[..] != b"vertex_indices" && &p.name[..] != b"vertex_index" {
            continue;
        }
        if indices.is_some() {
            return Err(error(
                p.line,
                "a second vertex index list (`vertex_indices` or `vertex_index`)".to_owned(),
            ));
        }
        match p.kind {
            PropertyKind::List {
                item: ScalarType::Int(_),
                ..
            } => indices = Some(p),
            _ => {
                return Err(error(
                    p.line,
                    format!(
                        "face property `{}` must be a list of integers",
                        show(&p.name)
                    ),
                ));
            }
        }
    }
    if indices.is_none() {
        return Err(error(
            face.line,
            "the face element has no list property `vertex_indices` or `vertex_index`".to_owned(),
        ));
    }

    let plans = header
        .elements
        .iter()
        .map(|element| {
            let role = if std::ptr::eq(element, vertex) {
                Role::Vertex
            } else if std::ptr::eq(element, face) {
                Role::Face
            } else {
                Role::Other
            };
            let fields = element
                .properties
                .iter()
                .map(|p| {
                    let axis = axes
                        .iter()
                        .position(|a| a.is_some_and(|a| std::ptr::eq(a, p)));
                    let is_indices = indices.is_some_and(|i| std::ptr::eq(i, p));
                    match (p.kind, axis) {
                        (PropertyKind::Scalar(ScalarType::F32), Some(axis)) => Field::Coord {
                            axis,
                            ty: FloatType::F32,
                        },
                        (PropertyKind::Scalar(ScalarType::F64), Some(axis)) => Field::Coord {
                            axis,
                            ty: FloatType::F64,
                        },
                        (PropertyKind::Scalar(ty), _) => Field::Skip(ty),
                        (
                            PropertyKind::List {
                                count,
                                item: ScalarType::Int(item),
                            },
                            _,
                        ) if is_indices => Field::Indices { count, item },
                        (PropertyKind::List { count, item }, _) => Field::SkipList { count, item },
                    }
                })
                .collect();
            Plan {
                name: show(&element.name),
                count: element.count,
                role,
                fields,
            }
        })
        .collect();
    Ok(plans)
}

// ---------------------------------------------------------------------------------------------
// What the body reading builds

struct Body<'a> {
    bytes: &'a [u8],
    file: &'a str,
    plans: &'a [Plan],
}

/// Where the body reader puts what it reads. [`Builder`] collects a whole [`Mesh`]; the
/// streaming reader (`super::stream`) has one sink per pass over a mapped file, so that both
/// read the same bytes with the same code and the same errors.
///
/// The reader calls [`vertex`](Sink::vertex) for each vertex record and
/// [`corner`](Sink::corner) for each vertex index of each face record, in file order, and
/// [`reached`](Sink::reached) with the offset of each binary record before reading it (and of
/// the end of each element it skips whole), so a sink can follow its progress through the file.
pub(crate) trait Sink {
    /// Errors of the sink's own (e.g. a consumer's), beside the reader's [`MeshError`]s.
    type Error: From<MeshError>;
    /// Whether vertex records are decoded and passed to [`vertex`](Sink::vertex). When false,
    /// a vertex element of scalars only is skipped without reading its bytes (others are still
    /// walked, since their records' sizes vary).
    const VERTICES: bool = true;
    /// Whether binary reading stops just after the vertex element, not looking at what follows
    /// it (its elements, trailing bytes).
    const STOP_AFTER_VERTICES: bool = false;

    /// The vertex element declares `n` records (a count the bytes left can hold).
    fn reserve_vertices(&mut self, _n: usize) {}
    /// At least `n` triangles will follow (sized from the bytes left, see [`reservation`]).
    fn reserve_triangles(&mut self, _n: usize) {}
    /// Vertex record `vertex`, at `at`.
    fn vertex(
        &mut self,
        xyz: [f32; 3],
        vertex: u64,
        at: Place,
        file: &str,
    ) -> Result<(), Self::Error>;
    /// Vertex index `index`, as written, of face record `face` (at `at`); `fan` is the face's
    /// triangulation so far.
    fn corner(
        &mut self,
        index: i64,
        face: u64,
        at: Place,
        fan: &mut Fan,
        file: &str,
    ) -> Result<(), Self::Error>;
    /// The binary reader is at byte `pos` and will not read before it again.
    #[inline]
    fn reached(&mut self, _pos: usize) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// The largest vertex index seen, where; indices are checked against the vertex count once
/// the whole body is read, since `face` may come before `vertex`.
#[derive(Debug)]
struct MaxIndex {
    index: i64,
    face: u64,
    at: Place,
}

/// The checks of vertex indices, shared by every sink: a negative index is an error at once;
/// an index beyond the vertex count is reported by [`IndexCheck::finish`], after the whole body
/// (the largest index, at its first occurrence).
#[derive(Debug, Default)]
pub(crate) struct IndexCheck {
    max: Option<MaxIndex>,
}

impl IndexCheck {
    /// Checks `index` of face `face`; returns it as a `u32` (`u32::MAX` if it is beyond that,
    /// which is out of range for any vertex count we accept; `finish` reports it).
    #[inline]
    pub(crate) fn corner(
        &mut self,
        index: i64,
        face: u64,
        at: Place,
        file: &str,
    ) -> Result<u32, MeshError> {
        if index < 0 {
            return Err(MeshError::NegativeIndex {
                file: file.to_owned(),
                at,
                face,
                index,
            });
        }
        if self.max.as_ref().is_none_or(|m| index > m.index) {
            self.max = Some(MaxIndex { index, face, at });
        }
        Ok(u32::try_from(index).unwrap_or(u32::MAX))
    }

    /// The error for the largest index, if it is not below `vertices`.
    pub(crate) fn finish(&self, vertices: u64, file: &str) -> Result<(), MeshError> {
        match &self.max {
            Some(m) if m.index as u64 >= vertices => Err(MeshError::IndexOutOfRange {
                file: file.to_owned(),
                at: m.at,
                face: m.face,
                index: m.index,
                vertices,
            }),
            _ => Ok(()),
        }
    }
}

/// Checks a vertex's coordinates: all finite once rounded to `f32`.
#[inline]
pub(crate) fn check_vertex(
    xyz: [f32; 3],
    vertex: u64,
    at: Place,
    file: &str,
) -> Result<(), MeshError> {
    if xyz.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(MeshError::NonFinite {
            file: file.to_owned(),
            at,
            vertex,
        })
    }
}

/// The sink of [`parse_ply`]: the whole mesh in memory.
#[derive(Debug, Default)]
struct Builder {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    indices: IndexCheck,
}

impl Sink for Builder {
    type Error = MeshError;

    fn reserve_vertices(&mut self, n: usize) {
        self.positions.reserve(n);
    }

    fn reserve_triangles(&mut self, n: usize) {
        self.triangles.reserve(n);
    }

    #[inline]
    fn corner(
        &mut self,
        index: i64,
        face: u64,
        at: Place,
        fan: &mut Fan,
        file: &str,
    ) -> Result<(), MeshError> {
        let index = self.indices.corner(index, face, at, file)?;
        fan.push(index, &mut self.triangles);
        Ok(())
    }

    #[inline]
    fn vertex(
        &mut self,
        xyz: [f32; 3],
        vertex: u64,
        at: Place,
        file: &str,
    ) -> Result<(), MeshError> {
        check_vertex(xyz, vertex, at, file)?;
        self.positions.push(xyz);
        Ok(())
    }
}

impl Builder {
    fn finish(self, file: &str) -> Result<Mesh, MeshError> {
        self.indices.finish(self.positions.len() as u64, file)?;
        let mesh = Mesh {
            positions: self.positions,
            triangles: self.triangles,
        };
        super::check_sizes(&mesh, file)?;
        Ok(mesh)
    }
}

/// How many records to reserve room for: never more than the bytes left could hold.
fn reservation(count: u64, remaining: usize, min_record: usize) -> usize {
    let fit = remaining / min_record.max(1);
    usize::try_from(count).unwrap_or(usize::MAX).min(fit)
}

// ---------------------------------------------------------------------------------------------
// Ascii body

/// A cursor over ascii PLY text. Separators are space, tab, CR, VT and FF; records end at LF.
struct Text<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: u64,
}

/// Why a value is missing: the line ended, or the file did.
enum Missing {
    EndOfLine,
    EndOfFile,
}

#[inline]
fn is_separator(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | 0x0b | 0x0c)
}

impl<'a> Text<'a> {
    /// Skips separators and whole blank lines, to the first value of the next record.
    #[inline]
    fn skip_blank(&mut self) {
        while let Some(&b) = self.bytes.get(self.pos) {
            if b == b'\n' {
                self.line += 1;
            } else if !is_separator(b) {
                break;
            }
            self.pos += 1;
        }
    }

    #[inline]
    fn at_end(&self) -> bool {
        self.pos >= self.bytes.len()
    }

    /// The next value on the current line.
    #[inline]
    fn token(&mut self) -> Result<&'a [u8], Missing> {
        while let Some(&b) = self.bytes.get(self.pos) {
            if !is_separator(b) {
                break;
            }
            self.pos += 1;
        }
        let start = self.pos;
        while let Some(&b) = self.bytes.get(self.pos) {
            if b == b'\n' || is_separator(b) {
                break;
            }
            self.pos += 1;
        }
        if self.pos > start {
            Ok(&self.bytes[start..self.pos])
        } else if self.at_end() {
            Err(Missing::EndOfFile)
        } else {
            Err(Missing::EndOfLine)
        }
    }

    /// Ends a record: only separators may remain on the line. Returns false if a value remains.
    #[inline]
    fn end_record(&mut self) -> bool {
        while let Some(&b) = self.bytes.get(self.pos) {
            if b == b'\n' {
                self.pos += 1;
                self.line += 1;
                return true;
            }
            if !is_separator(b) {
                return false;
            }
            self.pos += 1;
        }
        true
    }
}

/// A decimal integer: optional sign, then ASCII digits.
#[inline]
fn parse_int(token: &[u8]) -> Option<i64> {
    let (negative, digits) = match token {
        [b'-', rest @ ..] => (true, rest),
        [b'+', rest @ ..] => (false, rest),
        _ => (false, token),
    };
    if digits.is_empty() {
        return None;
    }
    let mut value: i64 = 0;
    for &d in digits {
        let digit = d.wrapping_sub(b'0');
        if digit > 9 {
            return None;
        }
        value = value.checked_mul(10)?.checked_add(i64::from(digit))?;
    }
    Some(if negative { -value } else { value })
}

/// A list's length: an integer of the list's count type, not negative.
fn list_len(token: &[u8], count: IntType) -> Option<i64> {
    parse_typed_int(token, count).filter(|&n| n >= 0)
}

/// An integer of type `ty`, or `None` if the token is not one.
#[inline]
fn parse_typed_int(token: &[u8], ty: IntType) -> Option<i64> {
    let value = parse_int(token)?;
    let (min, max) = ty.range();
    (min..=max).contains(&value).then_some(value)
}

/// A coordinate: floats parse straight to `f32`, doubles to `f64` then round to `f32`.
#[inline]
fn parse_coord(token: &[u8], ty: FloatType) -> Option<f32> {
    let text = std::str::from_utf8(token).ok()?;
    match ty {
        FloatType::F32 => text.parse::<f32>().ok(),
        FloatType::F64 => text.parse::<f64>().ok().map(|v| v as f32),
    }
}

fn read_ascii(body: &Body, start: usize, line: u64, out: &mut Builder) -> Result<(), MeshError> {
    let mut text = Text {
        bytes: body.bytes,
        pos: start,
        line,
    };
    for plan in body.plans {
        read_ascii_element(body, plan, &mut text, out)?;
    }
    text.skip_blank();
    if !text.at_end() {
        let last = body.plans.last().map_or("header", |p| p.name.as_str());
        return Err(MeshError::TrailingData {
            file: body.file.to_owned(),
            at: Place::Line(text.line),
            detail: format!("values after the last record of the last element (`{last}`)"),
        });
    }
    Ok(())
}

fn read_ascii_element(
    body: &Body,
    plan: &Plan,
    text: &mut Text,
    out: &mut Builder,
) -> Result<(), MeshError> {
    let file = body.file;
    if plan.fields.is_empty() || plan.count == 0 {
        return Ok(());
    }
    // Each record holds at least one value per property, each value needs a character and a
    // separator; the very last record may lack its final newline.
    let remaining = text.bytes.len() - text.pos;
    let min_record = plan.fields.len() * 2;
    let needed = plan.count.checked_mul(min_record as u64).map(|n| n - 1);
    if needed.is_none_or(|n| n > remaining as u64) {
        return Err(MeshError::Truncated {
            file: file.to_owned(),
            at: Place::Line(text.line),
            detail: format!(
                "the header declares {} `{}` records of {} values, which need at least {} bytes, but {} bytes remain",
                plan.count,
                plan.name,
                plan.fields.len(),
                needed.map_or_else(|| "more than 2^64".to_owned(), |n| n.to_string()),
                remaining
            ),
        });
    }
    // A face record yielding a triangle holds at least three more values.
    match plan.role {
        Role::Vertex => out
            .positions
            .reserve(reservation(plan.count, remaining, min_record)),
        Role::Face => out
            .triangles
            .reserve(reservation(plan.count, remaining, min_record + 6)),
        Role::Other => {}
    }

    let missing = |why: Missing, record: u64, line: u64, field: usize| match why {
        Missing::EndOfFile => MeshError::Truncated {
            file: file.to_owned(),
            at: Place::Line(line),
            detail: format!(
                "the file ends inside {} (of {})",
                plan.record(record),
                plan.count
            ),
        },
        Missing::EndOfLine => MeshError::CountMismatch {
            file: file.to_owned(),
            at: Place::Line(line),
            detail: format!(
                "{} has fewer values than its properties declare (the line ends in property {} of {})",
                plan.record(record),
                field + 1,
                plan.fields.len()
            ),
        },
    };
    let bad = |record: u64, line: u64, token: &[u8], what: String| MeshError::BadValue {
        file: file.to_owned(),
        at: Place::Line(line),
        detail: format!("{}: `{}` is not {what}", plan.record(record), show(token)),
    };

    for record in 0..plan.count {
        text.skip_blank();
        if text.at_end() {
            return Err(MeshError::Truncated {
                file: file.to_owned(),
                at: Place::Line(text.line),
                detail: format!(
                    "the file ends before {} (of {})",
                    plan.record(record),
                    plan.count
                ),
            });
        }
        let line = text.line;
        let mut xyz = [0f32; 3];
        for (i, field) in plan.fields.iter().enumerate() {
            let token = text.token().map_err(|m| missing(m, record, line, i))?;
            match *field {
                Field::Skip(_) => {}
                Field::Coord { axis, ty } => {
                    xyz[axis] = parse_coord(token, ty)
                        .ok_or_else(|| bad(record, line, token, "a number".to_owned()))?;
                }
                Field::SkipList { count, .. } => {
                    let n = list_len(token, count).ok_or_else(|| {
                        bad(
                            record,
                            line,
                            token,
                            format!("a list length of type {count:?}"),
                        )
                    })?;
                    for _ in 0..n {
                        text.token().map_err(|m| missing(m, record, line, i))?;
                    }
                }
                Field::Indices { count, item } => {
                    let n = list_len(token, count).ok_or_else(|| {
                        bad(
                            record,
                            line,
                            token,
                            format!("a list length of type {count:?}"),
                        )
                    })?;
                    let mut fan = Fan::default();
                    for _ in 0..n {
                        let token = text.token().map_err(|m| missing(m, record, line, i))?;
                        let index = parse_typed_int(token, item).ok_or_else(|| {
                            bad(
                                record,
                                line,
                                token,
                                format!("a vertex index of type {item:?}"),
                            )
                        })?;
                        out.corner(index, record, Place::Line(line), &mut fan, file)?;
                    }
                }
            }
        }
        if !text.end_record() {
            return Err(MeshError::CountMismatch {
                file: file.to_owned(),
                at: Place::Line(line),
                detail: format!(
                    "{} has more values than its {} properties",
                    plan.record(record),
                    plan.fields.len()
                ),
            });
        }
        if plan.role == Role::Vertex {
            out.vertex(xyz, record, Place::Line(line), file)?;
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Binary body

/// Decodes an `N`-byte number in the file's byte order.
macro_rules! decode {
    ($ty:ty, $bytes:expr, $big:expr) => {{
        let array: [u8; size_of::<$ty>()] = $bytes;
        if $big {
            <$ty>::from_be_bytes(array)
        } else {
            <$ty>::from_le_bytes(array)
        }
    }};
}

/// The first `N` bytes of `bytes`, if there are that many.
#[inline]
fn take<const N: usize>(bytes: &[u8]) -> Option<[u8; N]> {
    bytes.get(..N)?.try_into().ok()
}

#[inline]
fn int_at<const BIG: bool>(bytes: &[u8], ty: IntType) -> Option<i64> {
    Some(match ty {
        IntType::I8 => decode!(i8, take(bytes)?, BIG).into(),
        IntType::U8 => decode!(u8, take(bytes)?, BIG).into(),
        IntType::I16 => decode!(i16, take(bytes)?, BIG).into(),
        IntType::U16 => decode!(u16, take(bytes)?, BIG).into(),
        IntType::I32 => decode!(i32, take(bytes)?, BIG).into(),
        IntType::U32 => decode!(u32, take(bytes)?, BIG).into(),
    })
}

#[inline]
fn coord_at<const BIG: bool>(bytes: &[u8], ty: FloatType) -> Option<f32> {
    Some(match ty {
        FloatType::F32 => decode!(f32, take(bytes)?, BIG),
        FloatType::F64 => decode!(f64, take(bytes)?, BIG) as f32,
    })
}

/// Reads the body from byte `start` into `out`; returns the offset where reading ended (the end
/// of the file, or of the vertex element for a sink that stops there).
fn read_binary<const BIG: bool, S: Sink>(
    body: &Body,
    start: usize,
    out: &mut S,
) -> Result<usize, S::Error> {
    let mut pos = start;
    for plan in body.plans {
        pos = read_binary_element::<BIG, S>(body, plan, pos, out)?;
        if S::STOP_AFTER_VERTICES && plan.role == Role::Vertex {
            return Ok(pos);
        }
    }
    out.reached(pos)?;
    if pos < body.bytes.len() {
        let last = body.plans.last().map_or("header", |p| p.name.as_str());
        return Err(MeshError::TrailingData {
            file: body.file.to_owned(),
            at: Place::Byte(pos as u64),
            detail: format!(
                "{} bytes after the last record of the last element (`{last}`)",
                body.bytes.len() - pos
            ),
        }
        .into());
    }
    Ok(pos)
}

/// Reads one element starting at byte `pos`; returns the offset just past it.
fn read_binary_element<const BIG: bool, S: Sink>(
    body: &Body,
    plan: &Plan,
    pos: usize,
    out: &mut S,
) -> Result<usize, S::Error> {
    let file = body.file;
    let bytes = body.bytes;
    let min_record: usize = plan.fields.iter().map(|f| f.min_binary_size()).sum();
    if min_record == 0 || plan.count == 0 {
        return Ok(pos);
    }
    let remaining = bytes.len() - pos;
    let fixed = plan
        .fields
        .iter()
        .all(|f| matches!(f, Field::Skip(_) | Field::Coord { .. }));
    let truncated = |at: usize, detail: String| MeshError::Truncated {
        file: file.to_owned(),
        at: Place::Byte(at as u64),
        detail,
    };
    let needed = plan.count.checked_mul(min_record as u64);
    if needed.is_none_or(|n| n > remaining as u64) {
        let whole = remaining / min_record;
        return Err(if fixed {
            truncated(
                pos + whole * min_record,
                format!(
                    "the file ends inside {} (of {}; {} bytes each)",
                    plan.record(whole as u64),
                    plan.count,
                    min_record
                ),
            )
        } else {
            truncated(
                pos,
                format!(
                    "the header declares {} `{}` records of at least {} bytes, but {} bytes remain",
                    plan.count, plan.name, min_record, remaining
                ),
            )
        }
        .into());
    }
    // `needed` fits in the file, so in usize.
    let count = plan.count as usize;

    if fixed {
        let end = pos + count * min_record;
        if plan.role == Role::Vertex && S::VERTICES {
            read_fixed_vertices::<BIG, S>(body, plan, pos, end, min_record, out)?;
        }
        out.reached(end)?;
        return Ok(end);
    }

    match plan.role {
        Role::Vertex => out.reserve_vertices(count),
        Role::Face => {
            // A face record yielding a triangle holds at least three indices.
            let corners: usize = plan
                .fields
                .iter()
                .map(|f| match f {
                    Field::Indices { item, .. } => 3 * item.size(),
                    _ => 0,
                })
                .sum();
            out.reserve_triangles(reservation(plan.count, remaining, min_record + corners));
        }
        Role::Other => {}
    }
    let mut pos = pos;
    for record in 0..plan.count {
        let record_start = pos;
        out.reached(record_start)?;
        let at = Place::Byte(record_start as u64);
        let ends = |_| {
            truncated(
                record_start,
                format!(
                    "the file ends inside {} (of {})",
                    plan.record(record),
                    plan.count
                ),
            )
        };
        let mut xyz = [0f32; 3];
        for field in &plan.fields {
            let rest = &bytes[pos..];
            match *field {
                Field::Skip(ty) => {
                    if rest.len() < ty.size() {
                        return Err(ends(()).into());
                    }
                    pos += ty.size();
                }
                Field::Coord { axis, ty } => {
                    xyz[axis] = coord_at::<BIG>(rest, ty).ok_or(()).map_err(ends)?;
                    pos += field.min_binary_size();
                }
                Field::SkipList { count, item } => {
                    let n = list_length::<BIG>(body, plan, record, pos, count)?;
                    pos += count.size();
                    let size = n
                        .checked_mul(item.size())
                        .filter(|&s| s <= bytes.len() - pos)
                        .ok_or(())
                        .map_err(ends)?;
                    pos += size;
                }
                Field::Indices { count, item } => {
                    let n = list_length::<BIG>(body, plan, record, pos, count)?;
                    pos += count.size();
                    let size = n
                        .checked_mul(item.size())
                        .filter(|&s| s <= bytes.len() - pos)
                        .ok_or(())
                        .map_err(ends)?;
                    let mut fan = Fan::default();
                    for corner in bytes[pos..pos + size].chunks_exact(item.size()) {
                        let index = int_at::<BIG>(corner, item).ok_or(()).map_err(ends)?;
                        out.corner(index, record, at, &mut fan, file)?;
                    }
                    pos += size;
                }
            }
        }
        if plan.role == Role::Vertex && S::VERTICES {
            out.vertex(xyz, record, at, file)?;
        }
    }
    Ok(pos)
}

/// A list's length at `pos`; negative lengths (signed length types) are errors.
fn list_length<const BIG: bool>(
    body: &Body,
    plan: &Plan,
    record: u64,
    pos: usize,
    ty: IntType,
) -> Result<usize, MeshError> {
    let Some(n) = int_at::<BIG>(&body.bytes[pos..], ty) else {
        return Err(MeshError::Truncated {
            file: body.file.to_owned(),
            at: Place::Byte(pos as u64),
            detail: format!(
                "the file ends inside {} (of {})",
                plan.record(record),
                plan.count
            ),
        });
    };
    usize::try_from(n).map_err(|_| MeshError::BadValue {
        file: body.file.to_owned(),
        at: Place::Byte(pos as u64),
        detail: format!("{}: negative list length {n}", plan.record(record)),
    })
}

/// The vertex element when every property is a scalar: records of `stride` bytes in
/// `bytes[start..end]`, whose length the caller checked.
fn read_fixed_vertices<const BIG: bool, S: Sink>(
    body: &Body,
    plan: &Plan,
    start: usize,
    end: usize,
    stride: usize,
    out: &mut S,
) -> Result<(), S::Error> {
    let mut offsets = [(0usize, FloatType::F32); 3];
    let mut offset = 0;
    for field in &plan.fields {
        if let Field::Coord { axis, ty } = *field {
            offsets[axis] = (offset, ty);
        }
        offset += field.min_binary_size();
    }
    out.reserve_vertices((end - start) / stride);
    for (record, bytes) in body.bytes[start..end].chunks_exact(stride).enumerate() {
        let at = start + record * stride;
        out.reached(at)?;
        let mut xyz = [0f32; 3];
        for (c, &(offset, ty)) in xyz.iter_mut().zip(&offsets) {
            // `offset + size <= stride` by construction, so this never fails.
            *c = coord_at::<BIG>(&bytes[offset..], ty).unwrap_or(f32::NAN);
        }
        out.vertex(xyz, record as u64, Place::Byte(at as u64), body.file)?;
    }
    Ok(())
}
