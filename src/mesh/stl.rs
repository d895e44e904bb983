//! STL, binary and ASCII: a list of facets, each its own three corners (the format shares no
//! vertex). Facet `i` is primitive `i`; its corners are positions `3i`, `3i + 1`, `3i + 2` (the
//! facets' normals are not read: the corners' order gives the triangle).
//!
//! Which one: a file whose length is exactly `84 + 50 n`, `n` the little-endian count at byte
//! 80, is binary (whatever its 80-byte header says: binary files often begin with `solid` too);
//! otherwise one that begins with the word `solid` (and has no NUL byte in its first 84) is ASCII. The ASCII grammar is read as tokens:
//! `solid [name]`, then facets `facet normal x y z`, `outer loop`, three `vertex x y z`,
//! `endloop`, `endfacet`, and `endsolid [name]`; several solids may follow each other.

use super::{Mesh, MeshError, Place, check_sizes, shown, token};

/// Whether `bytes` is a binary STL file (its length is what its facet count says).
pub(super) fn is_binary(bytes: &[u8]) -> bool {
    binary_count(bytes).is_some_and(|n| bytes.len() as u64 == 84 + 50 * n)
}

/// Whether `bytes` looks like an ASCII STL file: it begins with the word `solid`, and no NUL
/// byte is where a binary file's header and count would be (a count below 2^24 has one).
pub(super) fn looks_like_ascii(bytes: &[u8]) -> bool {
    let text = bytes.trim_ascii_start();
    text.strip_prefix(b"solid")
        .is_some_and(|rest| rest.first().is_none_or(u8::is_ascii_whitespace))
        && !bytes[..bytes.len().min(84)].contains(&0)
}

fn binary_count(bytes: &[u8]) -> Option<u64> {
    let count: [u8; 4] = bytes.get(80..84)?.try_into().ok()?;
    Some(u64::from(u32::from_le_bytes(count)))
}

/// Reads an STL file (binary or ASCII, see the module docs); `name` names it in errors.
pub fn parse_stl(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    let mesh = if is_binary(bytes) || !looks_like_ascii(bytes) {
        parse_binary(bytes, name)?
    } else {
        parse_ascii(bytes, name)?
    };
    check_sizes(&mesh, name)?;
    Ok(mesh)
}

/// A corner's coordinates, checked finite once rounded to `f32`.
fn corner(xyz: [f64; 3], vertex: u64, at: Place, file: &str) -> Result<[f32; 3], MeshError> {
    let p = xyz.map(|v| v as f32);
    if p.iter().all(|v| v.is_finite()) {
        Ok(p)
    } else {
        Err(MeshError::NonFinite {
            file: file.to_owned(),
            at,
            vertex,
        })
    }
}

fn parse_binary(bytes: &[u8], file: &str) -> Result<Mesh, MeshError> {
    let Some(n) = binary_count(bytes) else {
        return Err(MeshError::Truncated {
            file: file.to_owned(),
            at: Place::Byte(bytes.len() as u64),
            detail: "a binary STL file holds an 80-byte header and a 4-byte facet count".into(),
        });
    };
    let want = 84 + 50 * n;
    let have = bytes.len() as u64;
    if have < want {
        return Err(MeshError::Truncated {
            file: file.to_owned(),
            at: Place::Byte(have),
            detail: format!("{n} facets of 50 bytes need {want} bytes, the file has {have}"),
        });
    }
    if have > want {
        return Err(MeshError::TrailingData {
            file: file.to_owned(),
            at: Place::Byte(want),
            detail: format!(
                "{} bytes after the {n} facets the count declares",
                have - want
            ),
        });
    }
    if 3 * n > u64::from(u32::MAX) {
        return Err(MeshError::TooLarge {
            file: file.to_owned(),
            detail: format!("{n} facets; vertex indices are u32"),
        });
    }
    let mut mesh = Mesh {
        geometries: Vec::new(),
        positions: Vec::with_capacity(3 * n as usize),
        triangles: Vec::with_capacity(n as usize),
    };
    for (i, facet) in bytes[84..].chunks_exact(50).enumerate() {
        for k in 0..3 {
            // After the facet's normal (12 bytes), three corners of 12 bytes.
            let at = 12 + 12 * k;
            let xyz: [f64; 3] = std::array::from_fn(|a| {
                let b = &facet[at + 4 * a..at + 4 * a + 4];
                f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            });
            let place = Place::Byte(84 + 50 * i as u64 + at as u64);
            mesh.positions
                .push(corner(xyz, (3 * i + k) as u64, place, file)?);
        }
        let v = 3 * i as u32;
        mesh.triangles.push([v, v + 1, v + 2]);
    }
    Ok(mesh)
}

/// The tokens of a text file with the line each is on.
fn tokens(bytes: &[u8]) -> impl Iterator<Item = (&[u8], u64)> {
    bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .flat_map(|(i, line)| {
            line.split(|b| b.is_ascii_whitespace())
                .filter(|t| !t.is_empty())
                .map(move |t| (t, i as u64 + 1))
        })
}

fn parse_ascii(bytes: &[u8], file: &str) -> Result<Mesh, MeshError> {
    let bad = |line: u64, detail: String| MeshError::Format {
        file: file.to_owned(),
        at: Place::Line(line),
        format: "ASCII STL",
        detail,
    };
    let mut mesh = Mesh::default();
    let mut toks = tokens(bytes).peekable();
    // The line of the last token read, for an error at the file's end.
    let last_line = std::cell::Cell::new(1u64);
    // Expects the keyword `word` next.
    let expect = |toks: &mut std::iter::Peekable<_>, word: &[u8]| -> Result<u64, MeshError> {
        match toks.next() {
            Some((t, line)) if t == word => {
                last_line.set(line);
                Ok(line)
            }
            Some((t, line)) => Err(bad(
                line,
                format!(
                    "expected `{}`, found `{}`",
                    String::from_utf8_lossy(word),
                    shown(t)
                ),
            )),
            None => Err(MeshError::Truncated {
                file: file.to_owned(),
                at: Place::Line(last_line.get()),
                detail: format!(
                    "the file ends where `{}` was expected",
                    String::from_utf8_lossy(word)
                ),
            }),
        }
    };
    let number = |t: Option<(&[u8], u64)>, what: &str| -> Result<f64, MeshError> {
        match t {
            Some((t, line)) => token(t, line, file, what, "a number"),
            None => Err(MeshError::Truncated {
                file: file.to_owned(),
                at: Place::Line(last_line.get()),
                detail: format!("the file ends in {what}"),
            }),
        }
    };
    while toks.peek().is_some() {
        expect(&mut toks, b"solid")?;
        // The solid's name: every token up to the first `facet` or `endsolid`.
        while toks
            .peek()
            .is_some_and(|(t, _)| *t != b"facet" && *t != b"endsolid")
        {
            toks.next();
        }
        loop {
            match toks.next() {
                Some((t, line)) if t == b"endsolid" => {
                    last_line.set(line);
                    // Its name, if any, on the same line.
                    while toks.peek().is_some_and(|&(_, l)| l == line) {
                        toks.next();
                    }
                    break;
                }
                Some((t, line)) if t == b"facet" => {
                    last_line.set(line);
                    expect(&mut toks, b"normal")?;
                    for _ in 0..3 {
                        number(toks.next(), "a facet's normal")?;
                    }
                    expect(&mut toks, b"outer")?;
                    expect(&mut toks, b"loop")?;
                    let first = mesh.positions.len();
                    if first + 3 > u32::MAX as usize {
                        return Err(MeshError::TooLarge {
                            file: file.to_owned(),
                            detail: "more than 2^32 corners; vertex indices are u32".into(),
                        });
                    }
                    for k in 0..3 {
                        let line = expect(&mut toks, b"vertex")?;
                        let xyz = [(); 3].map(|()| number(toks.next(), "a vertex"));
                        let [x, y, z] = xyz;
                        let p = corner([x?, y?, z?], (first + k) as u64, Place::Line(line), file)?;
                        mesh.positions.push(p);
                    }
                    expect(&mut toks, b"endloop")?;
                    expect(&mut toks, b"endfacet")?;
                    let v = first as u32;
                    mesh.triangles.push([v, v + 1, v + 2]);
                }
                Some((t, line)) => {
                    return Err(bad(
                        line,
                        format!("expected `facet` or `endsolid`, found `{}`", shown(t)),
                    ));
                }
                None => {
                    return Err(MeshError::Truncated {
                        file: file.to_owned(),
                        at: Place::Line(last_line.get()),
                        detail: "the file ends before `endsolid`".into(),
                    });
                }
            }
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn binary(facets: &[[[f32; 3]; 3]]) -> Vec<u8> {
        let mut b = vec![b's'; 80];
        b[..5].copy_from_slice(b"solid");
        b.extend((facets.len() as u32).to_le_bytes());
        for f in facets {
            b.extend([0u8; 12]);
            for c in f {
                for v in c {
                    b.extend(v.to_le_bytes());
                }
            }
            b.extend([0u8; 2]);
        }
        b
    }

    const TRI: [[[f32; 3]; 3]; 2] = [
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.5, 1.0]],
    ];

    const ASCII: &str = "solid two\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   \
        vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid two\nsolid\nfacet normal \
        0 0 0 outer loop vertex 0 0 1 vertex 1 0 1 vertex 0 1.5e0 1 endloop endfacet\nendsolid\n";

    #[test]
    fn binary_and_ascii_give_the_facets_in_order() {
        let want = Mesh {
            geometries: Vec::new(),
            positions: TRI.iter().flatten().copied().collect(),
            triangles: vec![[0, 1, 2], [3, 4, 5]],
        };
        // The binary file's header begins with `solid`, as many do.
        assert_eq!(parse_stl(&binary(&TRI), "b.stl").unwrap(), want);
        assert_eq!(parse_stl(ASCII.as_bytes(), "a.stl").unwrap(), want);
    }

    /// Every prefix of a valid file, and each with one byte changed, gives a mesh or an error
    /// (never a panic).
    #[test]
    fn cut_and_changed_files_never_panic() {
        for file in [binary(&TRI), ASCII.as_bytes().to_vec()] {
            crate::mesh::survives_damage(&file, |b| parse_stl(b, "a.stl"));
        }
    }

    #[test]
    fn malformed_files_are_errors_naming_the_place() {
        let b = binary(&TRI);
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b[..50].to_vec(), "a.stl: byte 50: truncated"),
            (b[..b.len() - 1].to_vec(), "a.stl: byte 183: truncated"),
            ([&b[..], b"x"].concat(), "a.stl: byte 184: data after"),
            (binary(&[]), "no triangles"),
            (
                binary(&[[[0.0, f32::NAN, 0.0], [1.0; 3], [2.0; 3]]]),
                "a.stl: byte 96: vertex 0 has a non-finite",
            ),
            (
                ASCII.replace("vertex 1 0 0", "vertex 1 x 0").into_bytes(),
                "a.stl: line 5: bad value: a vertex: `x`",
            ),
            (
                ASCII.replace("endloop\n endfacet", "endfacet").into_bytes(),
                "a.stl: line 7: bad ASCII STL: expected `endloop`, found `endfacet`",
            ),
            (
                ASCII.as_bytes()[..ASCII.find("endsolid two").unwrap()].to_vec(),
                "a.stl: line 8: truncated: the file ends before `endsolid`",
            ),
            (
                ASCII.replace("vertex 0 1 0", "vertex 0 1").into_bytes(),
                "a.stl: line 7: bad value: a vertex: `endloop`",
            ),
            (
                ASCII
                    .replace("vertex 0 0 0", "vertex 0 0 1e99")
                    .into_bytes(),
                "a.stl: line 4: vertex 0 has a non-finite",
            ),
            (b"solid x\nendsolid x\n".to_vec(), "no triangles"),
        ];
        for (bytes, want) in cases {
            let e = parse_stl(&bytes, "a.stl").unwrap_err().to_string();
            assert!(e.contains(want), "{want:?} not in {e:?}");
        }
    }
}
