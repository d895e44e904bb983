//! The ascii body: one record per line as in `ply.c` (blank lines between records allowed),
//! values separated by spaces or tabs; a line with too few or too many values is an error.

use super::header::IntType;
use super::header::show;
use super::plan::{Body, Field, FloatType, Plan, Role};
use super::sink::{Builder, Sink, reservation};
use crate::mesh::{Fan, MeshError, Place};

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

pub(super) fn read_ascii(
    body: &Body,
    start: usize,
    line: u64,
    out: &mut Builder,
) -> Result<(), MeshError> {
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
    if plan.fields.is_empty() || plan.count == 0 {
        return Ok(());
    }
    make_room(body, plan, text, out)?;
    for record in 0..plan.count {
        text.skip_blank();
        if text.at_end() {
            return Err(MeshError::Truncated {
                file: body.file.to_owned(),
                at: Place::Line(text.line),
                detail: format!(
                    "the file ends before {} (of {})",
                    plan.record(record),
                    plan.count
                ),
            });
        }
        read_ascii_record(body, plan, record, text, out)?;
    }
    Ok(())
}

/// Checks that the bytes left can hold the element's records at their smallest, and reserves
/// room for what they yield.
fn make_room(body: &Body, plan: &Plan, text: &Text, out: &mut Builder) -> Result<(), MeshError> {
    // Each record holds at least one value per property, each value needs a character and a
    // separator; the very last record may lack its final newline.
    let remaining = text.bytes.len() - text.pos;
    let min_record = plan.fields.len() * 2;
    let needed = plan.count.checked_mul(min_record as u64).map(|n| n - 1);
    if needed.is_none_or(|n| n > remaining as u64) {
        return Err(MeshError::Truncated {
            file: body.file.to_owned(),
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
    Ok(())
}

/// Reads record `record`, which starts at the text's current position, to the end of its line.
fn read_ascii_record(
    body: &Body,
    plan: &Plan,
    record: u64,
    text: &mut Text,
    out: &mut Builder,
) -> Result<(), MeshError> {
    let file = body.file;
    let line = text.line;
    let missing = |why: Missing, field: usize| match why {
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
    let bad = |token: &[u8], what: String| MeshError::BadValue {
        file: file.to_owned(),
        at: Place::Line(line),
        detail: format!("{}: `{}` is not {what}", plan.record(record), show(token)),
    };
    let mut xyz = [0f32; 3];
    for (i, field) in plan.fields.iter().enumerate() {
        let token = text.token().map_err(|m| missing(m, i))?;
        match *field {
            Field::Skip(_) => {}
            Field::Coord { axis, ty } => {
                xyz[axis] = parse_coord(token, ty).ok_or_else(|| bad(token, "a number".into()))?;
            }
            Field::SkipList { count, .. } => {
                let n = list_len(token, count)
                    .ok_or_else(|| bad(token, format!("a list length of type {count:?}")))?;
                for _ in 0..n {
                    text.token().map_err(|m| missing(m, i))?;
                }
            }
            Field::Indices { count, item } => {
                let n = list_len(token, count)
                    .ok_or_else(|| bad(token, format!("a list length of type {count:?}")))?;
                let mut fan = Fan::default();
                for _ in 0..n {
                    let token = text.token().map_err(|m| missing(m, i))?;
                    let index = parse_typed_int(token, item)
                        .ok_or_else(|| bad(token, format!("a vertex index of type {item:?}")))?;
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
    Ok(())
}
