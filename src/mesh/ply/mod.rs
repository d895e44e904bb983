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
//! Reading is in two steps: [`header`] turns the header into a `Header`, [`plan`](mod@plan) turns that
//! into one `Plan` per element (what to do with each property), then the body is read element
//! after element by [`ascii`] or [`binary`].
//!
//! The binary reader hands what it reads to a [`Sink`] ([`sink`]): [`parse_ply`]'s sink builds
//! the whole [`Mesh`]; the streaming reader ([`super::stream`]) reads a mapped file in passes,
//! one sink per pass ([`BinaryPly`] is its way in). One parser, so one set of checks and error
//! messages for both; the checks that need the whole body (vertex indices against the vertex
//! count, [`IndexCheck`]; the sizes of `check_sizes`) are made by each sink at its end.
//!
//! Before reading an element we check that the bytes left can hold its declared records at their
//! smallest (binary: the sum of scalar sizes and list-length sizes; ascii: two bytes per value,
//! a digit and a separator), and every allocation is sized from counts that passed that check.
//! An element with no properties occupies no bytes and is skipped without looping over its
//! declared count.

mod ascii;
mod binary;
mod header;
mod plan;
mod sink;

use super::{Mesh, MeshError};
use header::{Format, parse_header};
use plan::{Body, Plan, Role, plan};
use sink::Builder;

pub(crate) use sink::{IndexCheck, Sink, check_vertex};

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
        Format::Ascii => ascii::read_ascii(&body, header.body_start, header.body_line, &mut out)?,
        Format::BinaryLittleEndian => {
            binary::read_binary::<false, _>(&body, header.body_start, &mut out)?;
        }
        Format::BinaryBigEndian => {
            binary::read_binary::<true, _>(&body, header.body_start, &mut out)?;
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
            binary::read_binary::<true, S>(&body, self.body_start, out)
        } else {
            binary::read_binary::<false, S>(&body, self.body_start, out)
        }
    }
}
