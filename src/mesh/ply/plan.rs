//! The plan of each element: what the body readers do with each of its properties (read a
//! coordinate, walk the face's index list, skip), checked once against what we need from a
//! file (see the [module documentation](super)).

use super::header::{Element, Header, IntType, Property, PropertyKind, ScalarType, show};
use crate::mesh::MeshError;

/// The body as the readers see it: its bytes, the file's name for errors, and the plan of each
/// element in file order.
pub(super) struct Body<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) file: &'a str,
    pub(super) plans: &'a [Plan],
}

/// Floating-point types allowed for `x`, `y`, `z`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FloatType {
    F32,
    F64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Role {
    Vertex,
    Face,
    Other,
}

#[derive(Clone, Copy, Debug)]
pub(super) enum Field {
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
    pub(super) fn min_binary_size(self) -> usize {
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
pub(super) struct Plan {
    /// The element's name, for messages.
    pub(super) name: String,
    pub(super) count: u64,
    pub(super) role: Role,
    pub(super) fields: Vec<Field>,
}

impl Plan {
    /// What a record is called in messages: `vertex 17`, `face 3`, `edge 0`.
    pub(super) fn record(&self, index: u64) -> String {
        format!("{} {index}", self.name)
    }
}

pub(super) fn plan(header: &Header, file: &str) -> Result<Vec<Plan>, MeshError> {
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
    let axes = coordinates(vertex, &error)?;
    let indices = index_list(face, &error)?;
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
                .map(|p| field(p, &axes, indices))
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

/// The vertex element's `x`, `y` and `z`: exactly one of each, each a float or double scalar.
fn coordinates<'h>(
    vertex: &'h Element,
    error: &dyn Fn(u64, String) -> MeshError,
) -> Result<[&'h Property; 3], MeshError> {
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
    let [Some(x), Some(y), Some(z)] = axes else {
        let name = ["x", "y", "z"][axes.iter().position(Option::is_none).unwrap_or(0)];
        return Err(error(
            vertex.line,
            format!("the vertex element has no property `{name}`"),
        ));
    };
    Ok([x, y, z])
}

/// The face element's index list: exactly one integer list named `vertex_indices` or
/// `vertex_index`.
fn index_list<'h>(
    face: &'h Element,
    error: &dyn Fn(u64, String) -> MeshError,
) -> Result<&'h Property, MeshError> {
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
    indices.ok_or_else(|| {
        error(
            face.line,
            "the face element has no list property `vertex_indices` or `vertex_index`".to_owned(),
        )
    })
}

/// What to do with property `p`, given the coordinates and the index list chosen above.
fn field(p: &Property, axes: &[&Property; 3], indices: &Property) -> Field {
    let axis = axes.iter().position(|&a| std::ptr::eq(a, p));
    let is_indices = std::ptr::eq(indices, p);
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
}
