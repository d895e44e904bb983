//! The PLY header: the `ply` magic line, `format`, `element`, `property`, `comment` and
//! `obj_info` lines up to `end_header`, read into a [`Header`], and the scalar types of
//! `ply.c` with their sizes.

use crate::mesh::MeshError;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum IntType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
}

impl IntType {
    pub(super) fn size(self) -> usize {
        match self {
            IntType::I8 | IntType::U8 => 1,
            IntType::I16 | IntType::U16 => 2,
            IntType::I32 | IntType::U32 => 4,
        }
    }

    pub(super) fn range(self) -> (i64, i64) {
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
pub(super) enum ScalarType {
    Int(IntType),
    F32,
    F64,
}

impl ScalarType {
    /// Both the `ply.c` names and the sized names.
    pub(super) fn from_name(name: &[u8]) -> Option<ScalarType> {
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

    pub(super) fn size(self) -> usize {
        match self {
            ScalarType::Int(t) => t.size(),
            ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Format {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

#[derive(Clone, Copy, Debug)]
pub(super) enum PropertyKind {
    Scalar(ScalarType),
    List { count: IntType, item: ScalarType },
}

#[derive(Debug)]
pub(super) struct Property {
    pub(super) name: Vec<u8>,
    pub(super) kind: PropertyKind,
    pub(super) line: u64,
}

#[derive(Debug)]
pub(super) struct Element {
    pub(super) name: Vec<u8>,
    pub(super) count: u64,
    pub(super) properties: Vec<Property>,
    pub(super) line: u64,
}

#[derive(Debug)]
pub(super) struct Header {
    pub(super) format: Format,
    pub(super) elements: Vec<Element>,
    /// Offset of the first body byte, just past the `end_header` line's `\n`.
    pub(super) body_start: usize,
    /// Line number of the first body line (for ascii).
    pub(super) body_line: u64,
    /// Line number of the `format` line.
    pub(super) format_line: u64,
}

pub(super) fn show(name: &[u8]) -> String {
    String::from_utf8_lossy(name).into_owned()
}

/// One header line, split into words: its number, its text (for messages), the words after
/// the keyword.
struct Line<'a> {
    number: u64,
    text: &'a [u8],
    rest: Vec<&'a [u8]>,
}

impl Line<'_> {
    fn error(&self, file: &str, detail: String) -> MeshError {
        MeshError::Header {
            file: file.to_owned(),
            line: self.number,
            detail,
        }
    }
}

pub(super) fn parse_header(bytes: &[u8], file: &str) -> Result<Header, MeshError> {
    let error = |line: u64, detail: String| MeshError::Header {
        file: file.to_owned(),
        line,
        detail,
    };
    if !super::has_magic(bytes) {
        return Err(error(
            1,
            "the file does not start with the magic line `ply`".to_owned(),
        ));
    }
    let mut format = None;
    let mut format_line = 0;
    let mut elements: Vec<Element> = Vec::new();
    let mut pos = 0usize;
    let mut number = 0u64;
    loop {
        number += 1;
        let Some(newline) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            // The last line, whether or not it has text without a newline.
            let last = if pos == bytes.len() {
                number - 1
            } else {
                number
            };
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
        let line = Line {
            number,
            text,
            rest: words.collect(),
        };
        match keyword {
            Some(b"ply") if number == 1 && line.rest.is_empty() => {}
            None | Some(b"comment" | b"obj_info") => {}
            Some(b"format") => {
                if format.is_some() {
                    return Err(line.error(file, "a second `format` line".to_owned()));
                }
                format = Some(format_line_kind(&line, file)?);
                format_line = number;
            }
            Some(b"element") => elements.push(element_line(&line, file)?),
            Some(b"property") => {
                let Some(element) = elements.last_mut() else {
                    return Err(line.error(
                        file,
                        "a `property` line before any `element` line".to_owned(),
                    ));
                };
                element.properties.push(property_line(&line, file)?);
            }
            Some(b"end_header") if line.rest.is_empty() => {
                let Some(format) = format else {
                    return Err(line.error(file, "no `format` line before `end_header`".to_owned()));
                };
                return Ok(Header {
                    format,
                    elements,
                    body_start: pos,
                    body_line: number + 1,
                    format_line,
                });
            }
            Some(other) => {
                return Err(line.error(
                    file,
                    format!("unknown header line starting with `{}`", show(other)),
                ));
            }
        }
    }
}

/// `format <kind> 1.0`.
fn format_line_kind(line: &Line, file: &str) -> Result<Format, MeshError> {
    let rest = &line.rest;
    let kind = match rest.first().copied() {
        Some(b"ascii") => Format::Ascii,
        Some(b"binary_little_endian") => Format::BinaryLittleEndian,
        Some(b"binary_big_endian") => Format::BinaryBigEndian,
        other => {
            return Err(line.error(
                file,
                format!(
                    "unknown format `{}` (expected ascii, binary_little_endian or binary_big_endian)",
                    show(other.unwrap_or_default())
                ),
            ));
        }
    };
    if rest.len() != 2 || rest[1] != b"1.0" {
        return Err(line.error(
            file,
            format!(
                "unsupported format line `{}` (expected `format <kind> 1.0`)",
                show(line.text.trim_ascii())
            ),
        ));
    }
    Ok(kind)
}

/// `element <name> <count>`.
fn element_line(line: &Line, file: &str) -> Result<Element, MeshError> {
    let [name, count] = line.rest[..] else {
        return Err(line.error(
            file,
            format!(
                "`{}` is not `element <name> <count>`",
                show(line.text.trim_ascii())
            ),
        ));
    };
    let count = std::str::from_utf8(count)
        .ok()
        .and_then(|c| c.parse::<u64>().ok())
        .ok_or_else(|| {
            line.error(
                file,
                format!(
                    "element `{}` has the count `{}`, not a non-negative integer",
                    show(name),
                    show(count)
                ),
            )
        })?;
    Ok(Element {
        name: name.to_vec(),
        count,
        properties: Vec::new(),
        line: line.number,
    })
}

/// `property <type> <name>` or `property list <count type> <item type> <name>`.
fn property_line(line: &Line, file: &str) -> Result<Property, MeshError> {
    let rest = &line.rest;
    let scalar = |name: &[u8]| {
        ScalarType::from_name(name)
            .ok_or_else(|| line.error(file, format!("unknown type `{}`", show(name))))
    };
    let (kind, name) = match rest[..] {
        [b"list", count, item, name] => {
            let ScalarType::Int(count) = scalar(count)? else {
                return Err(line.error(
                    file,
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
            return Err(line.error(
                file,
                format!(
                    "`{}` is not `property <type> <name>` or `property list <type> <type> <name>`",
                    show(line.text.trim_ascii())
                ),
            ));
        }
    };
    Ok(Property {
        name: name.to_vec(),
        kind,
        line: line.number,
    })
}
