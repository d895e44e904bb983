//! The binary body, in either byte order (`BIG`), read into any [`Sink`]: records whose
//! properties are all scalars are read at a fixed stride, others field by field.

use super::header::IntType;
use super::plan::{Body, Field, FloatType, Plan, Role};
use super::sink::{Sink, reservation};
use crate::mesh::{Fan, MeshError, Place};

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
pub(super) fn read_binary<const BIG: bool, S: Sink>(
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
        pos = read_binary_record::<BIG, S>(body, plan, record, pos, out)?;
    }
    Ok(pos)
}

/// Reads record `record` of an element whose records vary in size, from byte `pos`; returns
/// the offset just past it.
fn read_binary_record<const BIG: bool, S: Sink>(
    body: &Body,
    plan: &Plan,
    record: u64,
    start: usize,
    out: &mut S,
) -> Result<usize, S::Error> {
    let (file, bytes) = (body.file, body.bytes);
    out.reached(start)?;
    let at = Place::Byte(start as u64);
    let ends = |_| MeshError::Truncated {
        file: file.to_owned(),
        at,
        detail: format!(
            "the file ends inside {} (of {})",
            plan.record(record),
            plan.count
        ),
    };
    let mut pos = start;
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
