//! Where the body readers put what they read: the [`Sink`] interface, the checks every sink
//! makes ([`IndexCheck`], [`check_vertex`]), and [`Builder`], the sink of
//! [`parse_ply`](super::parse_ply).

use crate::mesh::{Fan, Mesh, MeshError, Place};

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

/// The sink of [`parse_ply`](super::parse_ply): the whole mesh in memory.
#[derive(Debug, Default)]
pub(super) struct Builder {
    pub(super) positions: Vec<[f32; 3]>,
    pub(super) triangles: Vec<[u32; 3]>,
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
    pub(super) fn finish(self, file: &str) -> Result<Mesh, MeshError> {
        self.indices.finish(self.positions.len() as u64, file)?;
        let mesh = Mesh {
            geometries: Vec::new(),
            positions: self.positions,
            triangles: self.triangles,
        };
        crate::mesh::check_sizes(&mesh, file)?;
        Ok(mesh)
    }
}

/// How many records to reserve room for: never more than the bytes left could hold.
pub(super) fn reservation(count: u64, remaining: usize, min_record: usize) -> usize {
    let fit = remaining / min_record.max(1);
    usize::try_from(count).unwrap_or(usize::MAX).min(fit)
}
