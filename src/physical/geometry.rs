//! The geometry table (spec §8.8): the meshes a file was made of, by runs of primitive ids.
//! Small (one record per input mesh), so it is read whole and checked when a scene opens.

use super::OavmFile;
use super::format::{FLAG_GEOMETRIES, GEOMETRY_NAME_LEN, GeometryRecord, SectionKind};
use crate::error::FormatError;
use crate::mesh::{Geometry, check_geometries};

/// The records of `geometries`, their names cut to [`GEOMETRY_NAME_LEN`] bytes at a character
/// boundary.
pub fn geometry_records(geometries: &[Geometry]) -> Vec<GeometryRecord> {
    geometries
        .iter()
        .map(|g| {
            let mut end = g.name.len().min(GEOMETRY_NAME_LEN);
            while !g.name.is_char_boundary(end) {
                end -= 1;
            }
            let mut name = [0u8; GEOMETRY_NAME_LEN];
            name[..end].copy_from_slice(&g.name.as_bytes()[..end]);
            GeometryRecord {
                first_primitive: g.first_primitive,
                primitive_count: g.primitive_count,
                transform: g.transform,
                name,
            }
        })
        .collect()
}

/// The file's geometry table (empty without [`FLAG_GEOMETRIES`]), checked: its checksum, that
/// it covers the primitive ids `0..input_triangles` in order, finite transforms, names UTF-8
/// padded with zeros.
pub fn read_geometries<D: AsRef<[u8]>>(file: &OavmFile<D>) -> Result<Vec<Geometry>, FormatError> {
    if file.header().flags & FLAG_GEOMETRIES == 0 {
        return Ok(Vec::new());
    }
    let section = "geometry table";
    let err = |what: String| FormatError::Section { section, what };
    let entry = file.section(SectionKind::Geometries);
    let computed = xxhash_rust::xxh3::xxh3_64(file.section_bytes(SectionKind::Geometries));
    if computed != entry.checksum {
        return Err(FormatError::Checksum {
            section,
            stored: entry.checksum,
            computed,
        });
    }
    let records: &[GeometryRecord] = file.records(SectionKind::Geometries);
    if records.len() as u64 != entry.count || records.is_empty() {
        return Err(err(format!(
            "{} records readable of {} (a table has at least one)",
            records.len(),
            entry.count
        )));
    }
    let geometries = records
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let used = r.name.iter().rposition(|&b| b != 0).map_or(0, |p| p + 1);
            let name = std::str::from_utf8(&r.name[..used])
                .ok()
                .filter(|n| !n.contains('\0'))
                .ok_or_else(|| {
                    err(format!(
                        "geometry {i}: its name is not UTF-8 padded with zeros"
                    ))
                })?;
            Ok(Geometry {
                name: name.to_owned(),
                first_primitive: r.first_primitive,
                primitive_count: r.primitive_count,
                transform: r.transform,
            })
        })
        .collect::<Result<Vec<_>, FormatError>>()?;
    check_geometries(&geometries, file.header().input_triangles).map_err(err)?;
    Ok(geometries)
}
