//! A binary PLY read through a memory map in passes, never held whole: the input of the
//! bounded-memory pack (`oavm-pack --mem-budget`).
//!
//! [`PlyStream::read_positions`] is the first pass: the vertex positions, 12 bytes each, the only
//! memory proportional to the mesh. [`PlyStream::for_each_triangle_batch`] is a pass over the
//! triangles in primitive-id order, handed to the caller in batches of corner positions; it may
//! be run as often as the caller needs. Neither allocates anything proportional to the faces.
//!
//! Both passes run the body reader of [`parse_ply`](super::parse_ply) (the same code, through
//! its `Sink` interface), so a file gives the same positions, the same triangles with the same
//! primitive ids, and the same error for the same defect as `parse_ply` does on its bytes, with
//! the file named by its path as [`load`](super::load) names it. The two exceptions:
//!
//! - an ascii file is an error at [`PlyStream::open`] (ascii is read by `parse_ply` only);
//! - a file holding more vertices than `u32` indices can name (a file of more than 48 GiB) is
//!   an error at [`PlyStream::read_positions`], before the pass (`parse_ply` reports it after
//!   reading the whole body, so it reports any other defect of the body first).
//!
//! Mapped pages count in the process's memory (and in the page cache of its cgroup), so each
//! pass gives back the pages behind it as it goes ([`MappedFile::release`]), every *window*
//! of bytes ([`RELEASE_EVERY`] unless [`PlyStream::with_window`] sets another), and asks for two
//! windows ahead: a pass over a file of any size holds at most three windows of the map.

use std::path::Path;

use memmap2::Advice;

use super::ply::{BinaryPly, IndexCheck, Sink, check_vertex};
use super::{Fan, MeshError, Place};
use crate::error::Error;
use crate::os::{MappedFile, page_size};

/// How far a pass reads between two releases of the pages behind it (and two progress calls),
/// unless [`PlyStream::with_window`] sets another window.
pub const RELEASE_EVERY: usize = 16 << 20;

/// The smallest window: smaller ones would release and advise too often to read at speed.
pub const MIN_WINDOW: usize = 1 << 20;

/// The largest triangle count: primitive ids are `u32` below `0xFFFFFFFF` (RAYS.md uses it for
/// a miss), as [`parse_ply`](super::parse_ply) checks.
const MAX_TRIANGLES: u64 = u32::MAX as u64 - 1;

/// One triangle of a pass: its primitive id and its corners.
pub type StreamTriangle = (u32, [[f32; 3]; 3]);

/// A binary PLY file, mapped, its header read and checked. See the module documentation.
pub struct PlyStream {
    map: MappedFile,
    /// Bytes read between two releases of the map behind a pass.
    window: usize,
    /// The file, as given.
    path: std::path::PathBuf,
    ply: BinaryPly,
    /// The file's name in errors: its path, as [`load`](super::load) gives it.
    name: String,
}

impl PlyStream {
    /// Maps `path` and parses its header (as [`parse_ply`](super::parse_ply) does); the body
    /// is not read. An ascii PLY is an error: the streaming path reads binary PLY.
    pub fn open(path: &Path) -> Result<PlyStream, MeshError> {
        let map = MappedFile::open(path).map_err(|source| MeshError::Io {
            path: path.to_owned(),
            source,
        })?;
        let name = path.display().to_string();
        let ply = BinaryPly::new(
            map.as_ref(),
            &name,
            "the file is ascii PLY, and the streaming pack (`--mem-budget`) reads binary PLY \
             only: pack it without `--mem-budget` (which reads ascii PLY, in memory), or convert \
             it to binary_little_endian",
        )?;
        map.advise(Advice::Sequential);
        Ok(PlyStream {
            map,
            window: RELEASE_EVERY,
            path: path.to_owned(),
            ply,
            name,
        })
    }

    /// The window of the passes (see the module documentation), at least [`MIN_WINDOW`]: a
    /// pass holds at most three windows of the map.
    pub fn with_window(mut self, bytes: usize) -> PlyStream {
        self.window = bytes.max(MIN_WINDOW);
        self
    }

    /// Records declared by the `vertex` element.
    pub fn vertex_count(&self) -> u64 {
        self.ply.vertices()
    }

    /// Records declared by the `face` element: polygons, before fan triangulation.
    pub fn face_count(&self) -> u64 {
        self.ply.faces()
    }

    /// The file's size in bytes (what `progress` counts toward).
    pub fn file_len(&self) -> u64 {
        self.map.as_ref().len() as u64
    }

    /// `Err(Error::Changed)` if the file changed since it was mapped (truncated or written in
    /// place by another program): what the passes read from it cannot be trusted. Call it
    /// after each pass.
    pub fn check_unchanged(&self) -> Result<(), Error> {
        self.map.check_unchanged().map_err(|source| Error::Changed {
            path: self.path.clone(),
            source,
        })
    }

    /// Pass 1: the vertex positions, `positions[i]` being vertex record `i` (exactly those of
    /// [`parse_ply`](super::parse_ply)). Reads the body up to the end of the vertex element
    /// (what follows is checked by the triangle passes). `progress` gets the offset reached in
    /// the file, every [`RELEASE_EVERY`] bytes and at the end.
    pub fn read_positions(&self, progress: &dyn Fn(u64)) -> Result<Vec<[f32; 3]>, MeshError> {
        let vertices = self.vertex_count();
        // Only if the file can hold them (x, y, z take at least 12 bytes): otherwise the pass
        // reports the truncation, as `parse_ply` does.
        if vertices > u64::from(u32::MAX) + 1 && vertices.saturating_mul(12) <= self.file_len() {
            // The message of `check_sizes`, which `parse_ply` gives for such a file.
            return Err(MeshError::TooLarge {
                file: self.name.clone(),
                detail: format!("{vertices} vertices; vertex indices are u32"),
            });
        }
        let mut sink = Positions {
            positions: Vec::new(),
            indices: IndexCheck::default(),
            behind: Behind::new(&self.map, progress, self.window),
        };
        let end = self.ply.read(self.map.as_ref(), &self.name, &mut sink)?;
        sink.behind.finish(end);
        Ok(sink.positions)
    }

    /// A pass over the triangles in primitive-id order: `f` gets them in batches of at most
    /// `batch` (at least 1), each triangle as its primitive id and its corners looked up in
    /// `positions` (which must be [`read_positions`](Self::read_positions)'s). Returns the
    /// number of triangles. The whole body is read and checked: an error (the file's, `f`'s,
    /// or `positions` of the wrong length) ends the pass, and after an error of the file `f`
    /// may already have had some triangles. `progress` is as in `read_positions`.
    ///
    /// The checks `parse_ply` makes after reading the body are made after the pass: a vertex
    /// index beyond the vertex count (once one is seen, `f` is not called again, and the pass
    /// reads on to report the largest index, as `parse_ply` does), no triangles, too many.
    pub fn for_each_triangle_batch(
        &self,
        positions: &[[f32; 3]],
        batch: usize,
        progress: &dyn Fn(u64),
        f: &mut dyn FnMut(&[StreamTriangle]) -> Result<(), Error>,
    ) -> Result<u64, Error> {
        if positions.len() as u64 != self.vertex_count() {
            return Err(Error::Invalid(format!(
                "{}: {} positions given for the triangle pass, but the file has {} vertices",
                self.name,
                positions.len(),
                self.vertex_count()
            )));
        }
        let batch = batch.max(1);
        let mut sink = Triangles {
            positions,
            indices: IndexCheck::default(),
            corners: Vec::with_capacity(batch),
            batch: Vec::with_capacity(batch),
            limit: batch,
            triangles: 0,
            stopped: false,
            f,
            behind: Behind::new(&self.map, progress, self.window),
        };
        let end = self.ply.read(self.map.as_ref(), &self.name, &mut sink)?;
        sink.flush()?;
        sink.behind.finish(end);
        sink.indices.finish(positions.len() as u64, &self.name)?;
        // The checks of `check_sizes` that only the triangle count decides, in its order.
        if sink.triangles == 0 {
            return Err(MeshError::Empty {
                file: self.name.clone(),
            }
            .into());
        }
        if sink.triangles > MAX_TRIANGLES {
            return Err(MeshError::TooLarge {
                file: self.name.clone(),
                detail: format!(
                    "{} triangles; primitive ids are u32 below 0xFFFFFFFF",
                    sink.triangles
                ),
            }
            .into());
        }
        Ok(sink.triangles)
    }
}

/// Gives back the pages of the map behind a pass, and reports its progress.
struct Behind<'a> {
    map: &'a MappedFile,
    window: usize,
    progress: &'a dyn Fn(u64),
    /// Every page before this offset (a page boundary) has been released.
    released: usize,
    /// The offset at which to release again.
    next: usize,
}

impl<'a> Behind<'a> {
    fn new(map: &'a MappedFile, progress: &'a dyn Fn(u64), window: usize) -> Self {
        Behind {
            map,
            window,
            progress,
            released: 0,
            // The first record read starts the read-ahead.
            next: 0,
        }
    }

    /// The pass is at `pos` and will not read before it again.
    #[inline]
    fn reached(&mut self, pos: usize) {
        if pos >= self.next {
            self.release_to(pos);
        }
    }

    #[cold]
    fn release_to(&mut self, pos: usize) {
        if pos > self.released {
            self.map.release(self.released, pos - self.released);
            self.released = pos / page_size() * page_size();
        }
        self.next = pos.saturating_add(self.window);
        // Asks for the next two steps now, so that the disk reads them while we parse: the
        // map's sequential advice alone reads ahead too little to keep up.
        self.map
            .advise_range(Advice::WillNeed, pos, 2 * self.window);
        (self.progress)(pos as u64);
    }

    /// The pass ended at `end`: releases everything it read, reports `end`.
    fn finish(&mut self, end: usize) {
        self.release_to(end);
    }
}

/// Pass 1's sink: positions only. Faces before the vertex element are walked (their records'
/// sizes vary) and their indices checked for sign, as `parse_ply` does before it reaches the
/// vertices; their range is checked by the triangle pass.
struct Positions<'a> {
    positions: Vec<[f32; 3]>,
    indices: IndexCheck,
    behind: Behind<'a>,
}

impl Sink for Positions<'_> {
    type Error = MeshError;
    const STOP_AFTER_VERTICES: bool = true;

    fn reserve_vertices(&mut self, n: usize) {
        self.positions.reserve_exact(n);
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

    #[inline]
    fn corner(
        &mut self,
        index: i64,
        face: u64,
        at: Place,
        _fan: &mut Fan,
        file: &str,
    ) -> Result<(), MeshError> {
        self.indices.corner(index, face, at, file).map(drop)
    }

    #[inline]
    fn reached(&mut self, pos: usize) -> Result<(), MeshError> {
        self.behind.reached(pos);
        Ok(())
    }
}

/// The triangle pass's sink: fan-triangulates into `corners` (vertex indices), and hands each
/// full batch to `f` with its corners looked up.
struct Triangles<'a> {
    positions: &'a [[f32; 3]],
    indices: IndexCheck,
    /// Triangles (vertex indices) not yet handed to `f`; at most `limit`.
    corners: Vec<[u32; 3]>,
    /// The batch handed to `f`, reused.
    batch: Vec<StreamTriangle>,
    limit: usize,
    /// Triangles so far, those not yet handed to `f` included: the next primitive id.
    triangles: u64,
    /// An index beyond the vertex count, or more than [`MAX_TRIANGLES`] triangles, was seen:
    /// the pass will end in an error; `f` is not called again.
    stopped: bool,
    f: &'a mut dyn FnMut(&[StreamTriangle]) -> Result<(), Error>,
    behind: Behind<'a>,
}

impl Triangles<'_> {
    /// Hands the triangles in `corners` to `f` (unless the pass has stopped).
    fn flush(&mut self) -> Result<(), Error> {
        let first = self.triangles;
        self.triangles += self.corners.len() as u64;
        if self.triangles > MAX_TRIANGLES {
            self.stopped = true;
        }
        if self.stopped || self.corners.is_empty() {
            self.corners.clear();
            return Ok(());
        }
        self.batch.clear();
        for (prim, &[a, b, c]) in (first..).zip(&self.corners) {
            let corner = |i: u32| self.positions.get(i as usize).copied();
            // Indices were checked against the vertex count (`corner`) and ids against
            // MAX_TRIANGLES above, so neither fails.
            let (Some(a), Some(b), Some(c), Ok(prim)) =
                (corner(a), corner(b), corner(c), u32::try_from(prim))
            else {
                self.stopped = true;
                self.corners.clear();
                return Ok(());
            };
            self.batch.push((prim, [a, b, c]));
        }
        self.corners.clear();
        (self.f)(&self.batch)
    }
}

impl Sink for Triangles<'_> {
    type Error = Error;
    const VERTICES: bool = false;

    #[inline]
    fn vertex(&mut self, _: [f32; 3], _: u64, _: Place, _: &str) -> Result<(), Error> {
        Ok(())
    }

    #[inline]
    fn corner(
        &mut self,
        index: i64,
        face: u64,
        at: Place,
        fan: &mut Fan,
        file: &str,
    ) -> Result<(), Error> {
        let checked = self.indices.corner(index, face, at, file)?;
        // Not negative: `corner` checked.
        if index as u64 >= self.positions.len() as u64 {
            self.stopped = true;
        }
        fan.push(checked, &mut self.corners);
        if self.corners.len() >= self.limit {
            self.flush()?;
        }
        Ok(())
    }

    #[inline]
    fn reached(&mut self, pos: usize) -> Result<(), Error> {
        self.behind.reached(pos);
        Ok(())
    }
}
