//! The one error type of mesh input.
//!
//! Every variant names the file (the path for [`load`](crate::mesh::load), the `name` given to
//! [`parse_ply`](crate::mesh::parse_ply) / [`parse_obj`](crate::mesh::parse_obj)) and, where the problem has
//! a place, the place: a line (1-based) for text, a byte offset from the start of the file for
//! binary PLY. Records are numbered the way the format numbers them in its own indices: from 0
//! in PLY (`vertex 0` is the first vertex record, `face 0` the first face record), from 1 in OBJ
//! (`vertex 1` is the first `v` line, `face 1` the first `f` line).

use std::fmt;
use std::path::PathBuf;

/// Where in a file a problem is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Place {
    /// A 1-based line of a text file (PLY header, ascii PLY body, OBJ).
    Line(u64),
    /// A byte offset from the start of the file (binary PLY body).
    Byte(u64),
    /// An item of a structured file, by kind and index (glTF: `accessor 3`, `node 7`).
    Item(&'static str, u64),
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Place::Line(line) => write!(f, "line {line}"),
            Place::Byte(byte) => write!(f, "byte {byte}"),
            Place::Item(what, index) => write!(f, "{what} {index}"),
        }
    }
}

/// Why a mesh could not be read. `Display` gives `file: place: what`, ready to print.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be opened or read.
    #[error("{}: cannot read the file: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },

    /// The bytes are neither PLY (no `ply` magic line) nor OBJ.
    #[error("{file}: unknown mesh format: {detail}")]
    UnknownFormat { file: String, detail: String },

    /// The PLY header is malformed or describes something this reader cannot use.
    #[error("{file}: line {line}: bad PLY header: {detail}")]
    Header {
        file: String,
        line: u64,
        detail: String,
    },

    /// The data ends before the records the header declares.
    #[error("{file}: {at}: truncated: {detail}")]
    Truncated {
        file: String,
        at: Place,
        detail: String,
    },

    /// An ascii record holds fewer or more values than its element's properties.
    #[error("{file}: {at}: data disagrees with the header: {detail}")]
    CountMismatch {
        file: String,
        at: Place,
        detail: String,
    },

    /// Something follows the last element the header declares.
    #[error("{file}: {at}: data after the last element: {detail}")]
    TrailingData {
        file: String,
        at: Place,
        detail: String,
    },

    /// A value that cannot be read as its declared type (not a number, out of the type's range,
    /// a negative list length).
    #[error("{file}: {at}: bad value: {detail}")]
    BadValue {
        file: String,
        at: Place,
        detail: String,
    },

    /// A face refers to a vertex that does not exist. `index` is as written in the file.
    #[error(
        "{file}: {at}: face {face} refers to vertex {index}, but the file has {vertices} vertices"
    )]
    IndexOutOfRange {
        file: String,
        at: Place,
        face: u64,
        index: i64,
        vertices: u64,
    },

    /// A PLY face holds a negative vertex index.
    #[error("{file}: {at}: face {face} holds the negative vertex index {index}")]
    NegativeIndex {
        file: String,
        at: Place,
        face: u64,
        index: i64,
    },

    /// A vertex coordinate is NaN or infinite once rounded to `f32`.
    #[error(
        "{file}: {at}: vertex {vertex} has a non-finite coordinate (NaN, infinite, or beyond the f32 range)"
    )]
    NonFinite {
        file: String,
        at: Place,
        vertex: u64,
    },

    /// A mesh handed over as arrays (not read from a file) that cannot be packed: a face
    /// refers to a vertex that does not exist, a corner is not finite, there are no faces. The
    /// message names the arrays and the face or vertex.
    #[error("{0}")]
    Arrays(String),

    /// A statement of a text format other than PLY, OBJ and AFF (ASCII STL, OFF) that does
    /// not follow its grammar.
    #[error("{file}: {at}: bad {format}: {detail}")]
    Format {
        file: String,
        at: Place,
        format: &'static str,
        detail: String,
    },

    /// The file is well formed but yields no triangle.
    #[error(
        "{file}: the mesh has no triangles (every face has fewer than three vertices, or there are no faces)"
    )]
    Empty { file: String },

    /// An OBJ statement `tobj` rejects.
    #[error("{file}: line {line}: bad OBJ: {detail}")]
    Obj {
        file: String,
        line: u64,
        detail: String,
    },

    /// More vertices or triangles than 32-bit ids can name (or, for AFF, more include
    /// expansion than the reader allows).
    #[error("{file}: too large: {detail}")]
    TooLarge { file: String, detail: String },

    /// A PLY or OBJ file larger than [`LoadLimits::max_file_bytes`](super::LoadLimits): it is
    /// refused before it is read.
    #[error(
        "{file}: the file holds {bytes} bytes, more than the {limit} bytes a mesh may have to be \
         read whole into memory; pack it with `oavm-pack --mem-budget`, which streams the mesh \
         instead (it reads binary PLY: convert other formats first)"
    )]
    FileTooLarge {
        file: String,
        bytes: u64,
        limit: u64,
    },

    /// The file's length, change time or inode differed after it was read from before: it was
    /// written while we read it, so its bytes may mix two versions.
    #[error("{}: the file changed while it was being read", path.display())]
    Changed { path: PathBuf },

    /// A BART AFF statement this reader cannot read: an unknown keyword, a missing `{`, an
    /// unbalanced `}`, a mesh index out of range, too few keyframes, an include cycle.
    #[error("{file}: line {line}: bad AFF: {detail}")]
    Aff {
        file: String,
        line: u64,
        detail: String,
    },

    /// An error in (or reading) the file an AFF `i` statement includes. `file` and `line` are
    /// the including statement's; `source` names the included file, so printing the error shows
    /// the include chain from the top file down.
    #[error("{file}: line {line}: in the file included here: {source}")]
    Included {
        file: String,
        line: u64,
        source: Box<MeshError>,
    },

    /// A scene time that is not a finite number.
    #[error("{file}: the animation time {time} is not a finite number")]
    BadTime { file: String, time: f64 },

    /// A time was asked for a file that is not an animated scene format.
    #[error(
        "{file}: a time was given, but only BART AFF scenes (.aff) are animated; this file is not one"
    )]
    NotAnimated { file: String },
}

impl MeshError {
    /// The error at the bottom of an AFF include chain (`self` when it is not [`Included`]).
    ///
    /// [`Included`]: MeshError::Included
    pub fn innermost(&self) -> &MeshError {
        let mut e = self;
        while let MeshError::Included { source, .. } = e {
            e = source;
        }
        e
    }
}
