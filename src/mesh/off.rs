//! OFF (Geomview's Object File Format), line by line: a header line `OFF` (or `COFF`, `NOFF`,
//! `CNOFF`, `STOFF`, ...: per-vertex colours, normals and texture coordinates, which are not
//! read), its counts `vertices faces [edges]` (on the header line or the next), a line per
//! vertex whose first three values are its position, and a line per face `n i1 .. in` (any
//! colour after them is not read), fan-triangulated in file order as PLY faces are. `#` starts
//! a comment; blank lines are skipped. Vertex `i` is the `i`-th vertex line (from 0, as the
//! faces index them).

use super::{Fan, Mesh, MeshError, Place, check_sizes, shown, token};

/// Whether `bytes` begins (past blank lines and comments) with an OFF header.
pub(super) fn looks_like_off(bytes: &[u8]) -> bool {
    lines(bytes)
        .next()
        .and_then(|(_, l)| l.split(|b| b.is_ascii_whitespace()).find(|t| !t.is_empty()))
        .is_some_and(is_header)
}

/// `OFF` with the prefixes Geomview allows for extra per-vertex data (`ST`, `C`, `N`), not the
/// 4-D (`4OFF`) or any-dimension (`nOFF`) forms.
fn is_header(t: &[u8]) -> bool {
    let Some(prefix) = t.strip_suffix(b"OFF") else {
        return false;
    };
    let prefix = prefix.strip_prefix(b"ST").unwrap_or(prefix);
    let prefix = prefix.strip_prefix(b"C").unwrap_or(prefix);
    prefix.is_empty() || prefix == b"N"
}

/// The lines holding something, comments cut off, with their 1-based numbers.
fn lines(bytes: &[u8]) -> impl Iterator<Item = (u64, &[u8])> {
    bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .map(|(i, l)| {
            let l = l.split(|&b| b == b'#').next().unwrap_or(&[]);
            (i as u64 + 1, l.trim_ascii())
        })
        .filter(|(_, l)| !l.is_empty())
}

/// Reads `nf` face lines of a file of `nv` vertices into `mesh`, fan-triangulated; `last` is
/// the line last read (for an error at the file's end).
fn read_faces<'b>(
    it: &mut impl Iterator<Item = (u64, &'b [u8])>,
    (nf, nv): (u64, u64),
    last: &mut u64,
    mesh: &mut Mesh,
    file: &str,
) -> Result<(), MeshError> {
    let end = |line: u64, detail: String| MeshError::Truncated {
        file: file.to_owned(),
        at: Place::Line(line),
        detail,
    };
    for f in 0..nf {
        let Some((l, text)) = it.next() else {
            return Err(end(*last, format!("face {f} of {nf} is missing")));
        };
        *last = l;
        let w = words(text);
        let first = w.first().copied().unwrap_or(b"");
        let n: u64 = token(first, l, file, "a face's vertex count", "a count")?;
        // (A count near 2^64 must not overflow: the fuzz target found `n + 1` did.)
        if (w.len() as u64).saturating_sub(1) < n {
            return Err(MeshError::CountMismatch {
                file: file.to_owned(),
                at: Place::Line(l),
                detail: format!("face {f} declares {n} vertices but holds {}", w.len() - 1),
            });
        }
        let mut fan = Fan::default();
        for t in &w[1..=n as usize] {
            let index: i64 = token(t, l, file, &format!("face {f}"), "a vertex index")?;
            if index < 0 {
                return Err(MeshError::NegativeIndex {
                    file: file.to_owned(),
                    at: Place::Line(l),
                    face: f,
                    index,
                });
            }
            if index as u64 >= nv {
                return Err(MeshError::IndexOutOfRange {
                    file: file.to_owned(),
                    at: Place::Line(l),
                    face: f,
                    index,
                    vertices: nv,
                });
            }
            fan.push(index as u32, &mut mesh.triangles);
        }
    }
    Ok(())
}

/// A line's values.
fn words(l: &[u8]) -> Vec<&[u8]> {
    l.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
        .collect()
}

/// Reads an OFF file (see the module docs); `name` names it in errors.
pub fn parse_off(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    let file = name;
    let mut it = lines(bytes);
    let end = |line: u64, detail: String| MeshError::Truncated {
        file: file.to_owned(),
        at: Place::Line(line),
        detail,
    };
    let Some((line, header)) = it.next() else {
        return Err(end(1, "the file holds no OFF header".into()));
    };
    let mut head = words(header);
    if !head.first().is_some_and(|t| is_header(t)) {
        return Err(MeshError::Format {
            file: file.to_owned(),
            at: Place::Line(line),
            format: "OFF",
            detail: format!(
                "the first line must be `OFF` (or COFF, NOFF, STOFF, ...), not `{}`",
                shown(header)
            ),
        });
    }
    head.remove(0);
    let (counts, counts_line) = if head.is_empty() {
        match it.next() {
            Some((l, c)) => (words(c), l),
            None => return Err(end(line, "the file ends before its counts".into())),
        }
    } else {
        (head, line)
    };
    if counts.len() < 2 || counts.len() > 3 {
        return Err(MeshError::Format {
            file: file.to_owned(),
            at: Place::Line(counts_line),
            format: "OFF",
            detail: format!(
                "the counts line holds `vertices faces [edges]`, not {} values",
                counts.len()
            ),
        });
    }
    let nv: u64 = token(counts[0], counts_line, file, "the vertex count", "a count")?;
    let nf: u64 = token(counts[1], counts_line, file, "the face count", "a count")?;
    if nv > u64::from(u32::MAX) {
        return Err(MeshError::TooLarge {
            file: file.to_owned(),
            detail: format!("{nv} vertices; vertex indices are u32"),
        });
    }
    // A vertex line takes 6 bytes at least, a face line 2: no count reserves more than the
    // file's size can back.
    let cap = |n: u64, per: usize| (n as usize).min(bytes.len() / per);
    let mut mesh = Mesh {
        geometries: Vec::new(),
        positions: Vec::with_capacity(cap(nv, 6)),
        triangles: Vec::with_capacity(cap(nf, 2)),
    };
    let mut last = counts_line;
    for v in 0..nv {
        let Some((l, text)) = it.next() else {
            return Err(end(last, format!("vertex {v} of {nv} is missing")));
        };
        last = l;
        let w = words(text);
        if w.len() < 3 {
            return Err(MeshError::CountMismatch {
                file: file.to_owned(),
                at: Place::Line(l),
                detail: format!("vertex {v} holds {} values, not 3", w.len()),
            });
        }
        let mut xyz = [0f32; 3];
        for (c, t) in xyz.iter_mut().zip(&w) {
            *c = token::<f64>(t, l, file, "a vertex coordinate", "a number")? as f32;
        }
        if !xyz.iter().all(|c| c.is_finite()) {
            return Err(MeshError::NonFinite {
                file: file.to_owned(),
                at: Place::Line(l),
                vertex: v,
            });
        }
        mesh.positions.push(xyz);
    }
    read_faces(&mut it, (nf, nv), &mut last, &mut mesh, file)?;
    if let Some((l, text)) = it.next() {
        return Err(MeshError::TrailingData {
            file: file.to_owned(),
            at: Place::Line(l),
            detail: format!("`{}` after the {nf} faces", shown(text)),
        });
    }
    check_sizes(&mesh, name)?;
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    const CUBE_SIDE: &str = "OFF\n# a square and a triangle\n5 2 0\n0 0 0\n1 0 0\n1 1 0\n\n\
        0 1 0  # a comment\n0 0 1\n4 0 1 2 3\n3 0 1 4 255 0 0\n";

    #[test]
    fn faces_are_fanned_in_file_order() {
        let m = parse_off(CUBE_SIDE.as_bytes(), "a.off").unwrap();
        assert_eq!(m.positions.len(), 5);
        assert_eq!(m.positions[3], [0.0, 1.0, 0.0]);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]]);
        // Counts on the header line, a colour per vertex.
        let c = "COFF 3 1 0\n0 0 0 1 1 1 1\n1 0 0 1 1 1 1\n0 1 0 1 1 1 1\n3 2 1 0\n";
        let m = parse_off(c.as_bytes(), "c.off").unwrap();
        assert_eq!(m.triangles, vec![[2, 1, 0]]);
        assert!(looks_like_off(c.as_bytes()) && looks_like_off(CUBE_SIDE.as_bytes()));
        assert!(!looks_like_off(b"4OFF\n") && !looks_like_off(b"ply\n"));
    }

    /// Every prefix of a valid file, and each with one byte changed, gives a mesh or an error
    /// (never a panic).
    #[test]
    fn cut_and_changed_files_never_panic() {
        crate::mesh::survives_damage(CUBE_SIDE.as_bytes(), |b| parse_off(b, "a.off"));
    }

    #[test]
    fn malformed_files_are_errors_naming_the_place() {
        let cases: Vec<(String, &str)> = vec![
            (String::new(), "a.off: line 1: truncated"),
            (
                "OFFX\n".into(),
                "a.off: line 1: bad OFF: the first line must be",
            ),
            (
                "OFF\n".into(),
                "a.off: line 1: truncated: the file ends before its counts",
            ),
            ("OFF\n3\n".into(), "a.off: line 2: bad OFF: the counts line"),
            (
                "OFF\n-3 1 0\n".into(),
                "a.off: line 2: bad value: the vertex count",
            ),
            (
                "OFF\n99999999999 1 0\n".into(),
                "too large: 99999999999 vertices",
            ),
            (
                "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n18446744073709551615 0 1 2\n".into(),
                "a.off: line 6: data disagrees with the header: face 0 declares 18446744073709551615 vertices",
            ),
            (
                CUBE_SIDE.replace("1 1 0\n", "1 1\n"),
                "a.off: line 6: data disagrees with the header: vertex 2 holds 2 values",
            ),
            (
                CUBE_SIDE.replace("1 1 0\n", "1 z 0\n"),
                "a.off: line 6: bad value: a vertex coordinate: `z`",
            ),
            (
                CUBE_SIDE.replace("1 1 0\n", "1 1e99 0\n"),
                "a.off: line 6: vertex 2 has a non-finite",
            ),
            (
                CUBE_SIDE.replace("4 0 1 2 3", "4 0 1 2"),
                "a.off: line 10: data disagrees with the header: face 0 declares 4",
            ),
            (
                CUBE_SIDE.replace("4 0 1 2 3", "4 0 1 2 5"),
                "a.off: line 10: face 0 refers to vertex 5, but the file has 5",
            ),
            (
                CUBE_SIDE.replace("4 0 1 2 3", "4 0 -1 2 3"),
                "a.off: line 10: face 0 holds the negative vertex index -1",
            ),
            (
                CUBE_SIDE.replace("3 0 1 4 255 0 0\n", ""),
                "a.off: line 10: truncated: face 1 of 2 is missing",
            ),
            (
                format!("{CUBE_SIDE}3 0 1 2\n"),
                "a.off: line 12: data after the last element",
            ),
            ("OFF\n0 0 0\n".into(), "no triangles"),
        ];
        for (text, want) in cases {
            let e = parse_off(text.as_bytes(), "a.off").unwrap_err().to_string();
            assert!(e.contains(want), "{want:?} not in {e:?}");
        }
    }
}
