//! The streaming PLY reader (`oavm::mesh::stream::PlyStream`) against the in-memory one
//! (`parse_ply`): every file here is written to a temporary directory, read both ways, and must
//! give the same positions and the same triangles by primitive id, or the same error.
//!
//! The streaming reader's throughput is measured by `tools/stream_bench.rs`.

use std::cell::Cell;
use std::path::{Path, PathBuf};

use oavm::mesh::stream::PlyStream;
use oavm::mesh::{MeshError, parse_ply};

// ---------------------------------------------------------------------------------------------
// A binary PLY writer

#[derive(Clone, Copy, Debug, PartialEq)]
enum Enc {
    Le,
    Be,
}

const ENCODINGS: [Enc; 2] = [Enc::Le, Enc::Be];

/// A property: `S(type, name)` or `L(count type, item type, name)`.
#[derive(Clone, Debug)]
enum Prop {
    S(&'static str, &'static str),
    L(&'static str, &'static str, &'static str),
}

/// A value: a scalar, or a list (its length written as `items.len()` unless `len` says).
#[derive(Clone, Debug)]
enum Val {
    S(f64),
    L(Vec<f64>),
    /// A list whose written length is the first value, then the items.
    LenL(f64, Vec<f64>),
}

#[derive(Clone, Debug)]
struct Elem {
    name: &'static str,
    props: Vec<Prop>,
    rows: Vec<Vec<Val>>,
}

fn encode(ty: &str, v: f64, enc: Enc, out: &mut Vec<u8>) {
    macro_rules! bin {
        ($t:ty) => {{
            let x = v as $t;
            out.extend_from_slice(&if enc == Enc::Le {
                x.to_le_bytes()
            } else {
                x.to_be_bytes()
            });
        }};
    }
    match ty {
        "char" | "int8" => bin!(i8),
        "uchar" | "uint8" => bin!(u8),
        "short" | "int16" => bin!(i16),
        "ushort" | "uint16" => bin!(u16),
        "int" | "int32" => bin!(i32),
        "uint" | "uint32" => bin!(u32),
        "float" | "float32" => bin!(f32),
        "double" | "float64" => bin!(f64),
        _ => panic!("unknown type {ty}"),
    }
}

fn header(format: &str, elems: &[Elem]) -> Vec<u8> {
    let mut out = format!("ply\nformat {format} 1.0\ncomment tests/integration/mesh_stream.rs\n");
    for e in elems {
        out += &format!("element {} {}\n", e.name, e.rows.len());
        for p in &e.props {
            out += &match p {
                Prop::S(t, n) => format!("property {t} {n}\n"),
                Prop::L(c, t, n) => format!("property list {c} {t} {n}\n"),
            };
        }
    }
    out += "end_header\n";
    out.into_bytes()
}

fn write_ply(enc: Enc, elems: &[Elem]) -> Vec<u8> {
    let format = match enc {
        Enc::Le => "binary_little_endian",
        Enc::Be => "binary_big_endian",
    };
    let mut out = header(format, elems);
    for e in elems {
        for row in &e.rows {
            assert_eq!(row.len(), e.props.len(), "row of {}", e.name);
            for (p, v) in e.props.iter().zip(row) {
                match (p, v) {
                    (Prop::S(t, _), Val::S(v)) => encode(t, *v, enc, &mut out),
                    (Prop::L(c, t, _), Val::L(items)) => {
                        encode(c, items.len() as f64, enc, &mut out);
                        items.iter().for_each(|&i| encode(t, i, enc, &mut out));
                    }
                    (Prop::L(c, t, _), Val::LenL(len, items)) => {
                        encode(c, *len, enc, &mut out);
                        items.iter().for_each(|&i| encode(t, i, enc, &mut out));
                    }
                    _ => panic!("value {v:?} does not match property {p:?}"),
                }
            }
        }
    }
    out
}

fn vertex_elem(ty: &'static str, positions: &[[f64; 3]]) -> Elem {
    Elem {
        name: "vertex",
        props: vec![Prop::S(ty, "x"), Prop::S(ty, "y"), Prop::S(ty, "z")],
        rows: positions
            .iter()
            .map(|p| p.iter().map(|&c| Val::S(c)).collect())
            .collect(),
    }
}

fn face_elem(faces: &[Vec<i64>]) -> Elem {
    Elem {
        name: "face",
        props: vec![Prop::L("uchar", "int", "vertex_indices")],
        rows: faces
            .iter()
            .map(|f| vec![Val::L(f.iter().map(|&i| i as f64).collect())])
            .collect(),
    }
}

fn grid(n: usize) -> (Vec<[f64; 3]>, Vec<Vec<i64>>) {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            positions.push([i as f64 * 0.5, j as f64 * 0.25, ((i * j) % 7) as f64]);
        }
    }
    let w = (n + 1) as i64;
    let mut faces = Vec::new();
    for j in 0..n as i64 {
        for i in 0..n as i64 {
            let a = j * w + i;
            // Quads, triangles, a pentagon now and then (a repeated corner), in turn.
            match (i + j) % 3 {
                0 => faces.push(vec![a, a + 1, a + w + 1, a + w]),
                1 => {
                    faces.push(vec![a, a + 1, a + w + 1]);
                    faces.push(vec![a, a + w + 1, a + w]);
                }
                _ => faces.push(vec![a, a + 1, a + w + 1, a + w + 1, a + w]),
            }
        }
    }
    (positions, faces)
}

// ---------------------------------------------------------------------------------------------
// Reading both ways

struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!(
            "oavm-mesh-stream-{tag}-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

type Tri = [[f32; 3]; 3];

/// Reads `path` with `PlyStream` (positions, then one triangle pass in batches of `batch`),
/// checking the batches on the way; the error as its message.
fn stream(path: &Path, batch: usize) -> Result<(Vec<[f32; 3]>, Vec<Tri>), String> {
    let s = PlyStream::open(path).map_err(|e| e.to_string())?;
    let len = s.file_len();
    let last = Cell::new(0u64);
    let progress = |done: u64| {
        assert!(done >= last.get(), "progress went back");
        assert!(done <= len);
        last.set(done);
    };
    let positions = s.read_positions(&progress).map_err(|e| e.to_string())?;
    assert_eq!(positions.len() as u64, s.vertex_count());
    last.set(0);
    let mut tris = Vec::new();
    let n = s
        .for_each_triangle_batch(&positions, batch, &progress, &mut |b| {
            assert!(
                !b.is_empty() && b.len() <= batch.max(1),
                "batch of {}",
                b.len()
            );
            for &(prim, t) in b {
                assert_eq!(prim as usize, tris.len(), "primitive ids in order");
                tris.push(t);
            }
            Ok(())
        })
        .map_err(|e| match e {
            oavm::Error::Mesh(m) => m.to_string(),
            other => panic!("not a mesh error: {other}"),
        })?;
    assert_eq!(n as usize, tris.len());
    assert_eq!(last.get(), len, "the last progress is the end of the file");
    Ok((positions, tris))
}

/// `parse_ply` on the bytes, the file named as `PlyStream` names it.
fn in_memory(path: &Path, bytes: &[u8]) -> Result<(Vec<[f32; 3]>, Vec<Tri>), String> {
    let mesh = parse_ply(bytes, &path.display().to_string()).map_err(|e| e.to_string())?;
    let tris = (0..mesh.triangles.len())
        .map(|i| mesh.triangle(i))
        .collect();
    Ok((mesh.positions, tris))
}

/// Both readers on `bytes`: the same mesh or the same error (returned).
fn same(dir: &TempDir, name: &str, bytes: &[u8]) -> Result<(Vec<[f32; 3]>, Vec<Tri>), String> {
    let path = dir.write(name, bytes);
    let want = in_memory(&path, bytes);
    for batch in [1, 7, 4096] {
        let got = stream(&path, batch);
        match (&want, &got) {
            (Ok(w), Ok(g)) => {
                assert!(w.0 == g.0, "{name}: positions differ");
                assert!(w.1 == g.1, "{name}: triangles differ");
            }
            (Err(w), Err(g)) => assert_eq!(w, g, "{name}: not the same error"),
            _ => panic!("{name} (batch {batch}): parse_ply gave {want:?}, the stream {got:?}"),
        }
    }
    want
}

// ---------------------------------------------------------------------------------------------
// Good files

#[test]
fn bunny_as_binary() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/bunny/bun_zipper.ply");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (the test scenes are expected in ../shared/scenes)",
            path.display()
        )
    });
    let mesh = parse_ply(&bytes, "bunny").unwrap();
    // Re-encoded with its own extra properties (confidence, intensity), as floats.
    let vertex = Elem {
        name: "vertex",
        props: ["x", "y", "z", "confidence", "intensity"]
            .map(|n| Prop::S("float", n))
            .to_vec(),
        rows: mesh
            .positions
            .iter()
            .map(|p| {
                let mut row: Vec<Val> = p.iter().map(|&c| Val::S(c.into())).collect();
                row.extend([Val::S(0.5), Val::S(0.25)]);
                row
            })
            .collect(),
    };
    let faces: Vec<Vec<i64>> = mesh
        .triangles
        .iter()
        .map(|t| t.iter().map(|&i| i.into()).collect())
        .collect();
    let dir = TempDir::new("bunny");
    for enc in ENCODINGS {
        let (positions, tris) = same(
            &dir,
            "bunny.ply",
            &write_ply(enc, &[vertex.clone(), face_elem(&faces)]),
        )
        .unwrap();
        assert_eq!(positions, mesh.positions);
        assert_eq!(tris.len(), mesh.triangles.len());
        // Face before vertex too.
        same(
            &dir,
            "bunny-fv.ply",
            &write_ply(enc, &[face_elem(&faces), vertex.clone()]),
        )
        .unwrap();
    }
}

#[test]
fn quads_polygons_and_short_faces() {
    let (positions, mut faces) = grid(13);
    faces.insert(3, vec![0, 1]);
    faces.insert(5, vec![]);
    faces.push(vec![2]);
    let dir = TempDir::new("poly");
    for enc in ENCODINGS {
        for ty in ["float", "double"] {
            let (_, tris) = same(
                &dir,
                "grid.ply",
                &write_ply(enc, &[vertex_elem(ty, &positions), face_elem(&faces)]),
            )
            .unwrap();
            let fan: usize = faces.iter().map(|f| f.len().saturating_sub(2)).sum();
            assert_eq!(tris.len(), fan);
        }
    }
}

/// Vertex and face properties of every kind around the ones we use, other elements around,
/// before and between them, and a vertex element with a list (records of varying size).
#[test]
fn extra_properties_and_elements() {
    let (positions, faces) = grid(6);
    let vertex = Elem {
        name: "vertex",
        props: vec![
            Prop::S("uchar", "red"),
            Prop::S("double", "z"),
            Prop::L("ushort", "float", "uv"),
            Prop::S("float", "x"),
            Prop::S("short", "flags"),
            Prop::S("double", "y"),
            Prop::S("uint", "id"),
        ],
        rows: positions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                vec![
                    Val::S((i % 200) as f64),
                    Val::S(p[2]),
                    Val::L(vec![0.5; i % 3]),
                    Val::S(p[0]),
                    Val::S(-7.0),
                    Val::S(p[1]),
                    Val::S(i as f64),
                ]
            })
            .collect(),
    };
    let face = Elem {
        name: "face",
        props: vec![
            Prop::S("int", "material"),
            Prop::L("char", "double", "weights"),
            Prop::L("ushort", "uint", "vertex_index"),
            Prop::S("float", "area"),
        ],
        rows: faces
            .iter()
            .enumerate()
            .map(|(i, f)| {
                vec![
                    Val::S(i as f64),
                    Val::L(vec![1.0; i % 4]),
                    Val::L(f.iter().map(|&v| v as f64).collect()),
                    Val::S(0.5),
                ]
            })
            .collect(),
    };
    let edge = Elem {
        name: "edge",
        props: vec![Prop::S("int", "vertex1"), Prop::L("uchar", "int", "more")],
        rows: (0..9)
            .map(|i| vec![Val::S(i as f64), Val::L(vec![2.0; i])])
            .collect(),
    };
    let empty = Elem {
        name: "nothing",
        props: vec![],
        rows: vec![vec![]; 1000],
    };
    let dir = TempDir::new("extra");
    for enc in ENCODINGS {
        for (i, order) in [
            vec![&vertex, &face, &edge],
            vec![&edge, &vertex, &empty, &face],
            vec![&face, &edge, &vertex],
            vec![&empty, &face, &vertex, &edge],
        ]
        .iter()
        .enumerate()
        {
            let elems: Vec<Elem> = order.iter().map(|&e| e.clone()).collect();
            same(&dir, &format!("extra{i}.ply"), &write_ply(enc, &elems)).unwrap();
        }
        // Fixed-size vertex records with extra scalars, after the faces.
        let mut fixed = vertex.clone();
        fixed.props.remove(2);
        fixed.rows.iter_mut().for_each(|r| {
            r.remove(2);
        });
        same(&dir, "fixed.ply", &write_ply(enc, &[face.clone(), fixed])).unwrap();
    }
}

#[test]
fn every_integer_type_for_counts_and_indices() {
    let (positions, faces) = grid(4);
    let dir = TempDir::new("ints");
    for count in ["char", "uchar", "short", "ushort", "int", "uint"] {
        for item in ["char", "uchar", "short", "ushort", "int", "uint"] {
            let face = Elem {
                name: "face",
                props: vec![Prop::L(count, item, "vertex_indices")],
                ..face_elem(&faces)
            };
            for enc in ENCODINGS {
                same(
                    &dir,
                    "ints.ply",
                    &write_ply(enc, &[vertex_elem("float", &positions), face.clone()]),
                )
                .unwrap();
            }
        }
    }
}

#[test]
fn files_without_triangles_are_the_same_error() {
    let dir = TempDir::new("empty");
    let positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    for enc in ENCODINGS {
        for faces in [vec![], vec![vec![0, 1], vec![2]]] {
            let err = same(
                &dir,
                "empty.ply",
                &write_ply(enc, &[vertex_elem("float", &positions), face_elem(&faces)]),
            )
            .unwrap_err();
            assert!(err.contains("no triangles"), "{err}");
        }
        // No vertices, no faces.
        let err = same(
            &dir,
            "nothing.ply",
            &write_ply(enc, &[vertex_elem("float", &[]), face_elem(&[])]),
        )
        .unwrap_err();
        assert!(err.contains("no triangles"), "{err}");
    }
}

// ---------------------------------------------------------------------------------------------
// Bad files: the same error as parse_ply

fn small(enc: Enc, faces: Vec<Vec<Val>>, face_first: bool) -> Vec<u8> {
    let (positions, _) = grid(2);
    let face = Elem {
        name: "face",
        props: vec![Prop::L("char", "int", "vertex_indices")],
        rows: faces,
    };
    let vertex = vertex_elem("float", &positions);
    if face_first {
        write_ply(enc, &[face, vertex])
    } else {
        write_ply(enc, &[vertex, face])
    }
}

fn l(items: &[f64]) -> Vec<Val> {
    vec![Val::L(items.to_vec())]
}

#[test]
fn indices_out_of_range() {
    let dir = TempDir::new("range");
    for enc in ENCODINGS {
        for face_first in [false, true] {
            // The largest index is reported, at its first face, as parse_ply does.
            let faces = vec![
                l(&[0.0, 1.0, 2.0]),
                l(&[0.0, 9.0, 2.0]),
                l(&[0.0, 1.0, 2.0, 3.0]),
                l(&[12.0, 1.0, 2.0]),
                l(&[0.0, 11.0, 12.0]),
                l(&[0.0, 1.0, 2.0]),
            ];
            let err = same(&dir, "range.ply", &small(enc, faces, face_first)).unwrap_err();
            assert!(
                err.contains("face 3 refers to vertex 12, but the file has 9 vertices"),
                "{err}"
            );
            // Out of range, then the file ends early (in the last face, or with the faces
            // first, in the last vertex): the truncation is reported, since indices are
            // checked only once the whole body is read.
            let mut bytes = small(
                enc,
                vec![l(&[0.0, 1.0, 99.0]), l(&[0.0, 1.0, 2.0])],
                face_first,
            );
            bytes.pop();
            let err = same(&dir, "range-trunc.ply", &bytes).unwrap_err();
            assert!(err.contains("truncated"), "{err}");
        }
    }
}

#[test]
fn negative_indices_and_list_lengths() {
    let dir = TempDir::new("neg");
    for enc in ENCODINGS {
        for face_first in [false, true] {
            let faces = vec![l(&[0.0, 1.0, 2.0]), l(&[0.0, -3.0, 2.0])];
            let err = same(&dir, "neg.ply", &small(enc, faces, face_first)).unwrap_err();
            assert!(err.contains("negative vertex index -3"), "{err}");
            let faces = vec![
                l(&[0.0, 1.0, 2.0]),
                vec![Val::LenL(-2.0, vec![0.0, 1.0, 2.0])],
            ];
            let err = same(&dir, "neglen.ply", &small(enc, faces, face_first)).unwrap_err();
            assert!(err.contains("negative list length -2"), "{err}");
            // A list longer than the file.
            let faces = vec![vec![Val::LenL(100.0, vec![0.0, 1.0, 2.0])]];
            let err = same(&dir, "longlist.ply", &small(enc, faces, face_first)).unwrap_err();
            assert!(err.contains("truncated"), "{err}");
        }
    }
}

#[test]
fn every_truncation_and_trailing_bytes() {
    let dir = TempDir::new("trunc");
    for enc in ENCODINGS {
        for face_first in [false, true] {
            let faces = vec![l(&[0.0, 1.0, 2.0, 3.0]), l(&[4.0, 5.0, 6.0])];
            let bytes = small(enc, faces, face_first);
            let body = bytes
                .windows(11)
                .position(|w| w == b"end_header\n")
                .unwrap()
                + 11;
            for cut in body..bytes.len() {
                let err = same(&dir, "cut.ply", &bytes[..cut]).unwrap_err();
                assert!(err.contains("truncated"), "cut at {cut}: {err}");
            }
            let mut longer = bytes.clone();
            longer.extend_from_slice(b"xyz");
            let err = same(&dir, "long.ply", &longer).unwrap_err();
            assert!(err.contains("data after the last element"), "{err}");
            // Counts beyond the file (and beyond u32 indices): truncated, both ways.
            let text = String::from_utf8_lossy(&bytes[..body]).into_owned();
            for (from, to) in [
                ("element vertex 9", "element vertex 5000000000"),
                ("element face 2", "element face 18446744073709551615"),
            ] {
                let mut huge = text.replace(from, to).into_bytes();
                huge.extend_from_slice(&bytes[body..]);
                let err = same(&dir, "huge.ply", &huge).unwrap_err();
                assert!(err.contains("truncated"), "{err}");
            }
            // Header-only damage: the header's own errors.
            for cut in [0, 3, 20, body - 1] {
                same(&dir, "head.ply", &bytes[..cut]).unwrap_err();
            }
        }
    }
}

#[test]
fn non_finite_coordinates() {
    let dir = TempDir::new("nan");
    for enc in ENCODINGS {
        for ty in ["float", "double"] {
            let mut positions = grid(2).0;
            positions[5][1] = f64::NAN;
            positions[7][0] = 1e300; // finite as a double, not as a float
            let faces = face_elem(&[vec![0, 1, 2], vec![9, 1, 2]]);
            let err = same(
                &dir,
                "nan.ply",
                &write_ply(enc, &[faces, vertex_elem(ty, &positions)]),
            )
            .unwrap_err();
            assert!(err.contains("vertex 5 has a non-finite"), "{err}");
        }
    }
}

#[test]
fn ascii_is_a_clear_error() {
    let dir = TempDir::new("ascii");
    let path = dir.write(
        "a.ply",
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
          property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
          0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    );
    assert!(oavm::mesh::load(&path).is_ok());
    let err = PlyStream::open(&path).err().expect("an error").to_string();
    assert!(err.contains("line 2"), "{err}");
    assert!(err.contains("binary PLY"), "{err}");
    assert!(err.contains("without `--mem-budget`"), "{err}");
}

#[test]
fn missing_files_and_wrong_positions() {
    let dir = TempDir::new("io");
    let missing = dir.0.join("missing.ply");
    match PlyStream::open(&missing) {
        Err(e @ MeshError::Io { .. }) => assert!(e.to_string().contains("missing.ply")),
        other => panic!("{:?}", other.map(|_| ())),
    }
    let (positions, faces) = grid(3);
    let path = dir.write(
        "g.ply",
        &write_ply(
            Enc::Le,
            &[vertex_elem("float", &positions), face_elem(&faces)],
        ),
    );
    let s = PlyStream::open(&path).unwrap();
    assert_eq!((s.vertex_count(), s.face_count()), (16, faces.len() as u64));
    let err = s
        .for_each_triangle_batch(&[[0.0; 3]; 3], 10, &|_| {}, &mut |_| Ok(()))
        .unwrap_err();
    assert!(matches!(err, oavm::Error::Invalid(_)), "{err}");
    // An error of the consumer ends the pass and comes back as it is.
    let positions = s.read_positions(&|_| {}).unwrap();
    let err = s
        .for_each_triangle_batch(&positions, 4, &|_| {}, &mut |_| {
            Err(oavm::Error::Build("stop".into()))
        })
        .unwrap_err();
    assert!(
        matches!(&err, oavm::Error::Build(m) if m == "stop"),
        "{err}"
    );
}

/// Random damage to small files: both readers agree, and neither panics.
#[test]
fn mutated_files_give_the_same_result() {
    let dir = TempDir::new("mutate");
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        state >> 33
    };
    let (positions, faces) = grid(3);
    let mut sources = Vec::new();
    for enc in ENCODINGS {
        sources.push(write_ply(
            enc,
            &[vertex_elem("float", &positions), face_elem(&faces)],
        ));
        sources.push(write_ply(
            enc,
            &[face_elem(&faces), vertex_elem("double", &positions)],
        ));
    }
    let (mut ok, mut err) = (0, 0);
    for round in 0..2000 {
        let mut bytes = sources[round % sources.len()].clone();
        let body = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        for _ in 0..1 + next() % 3 {
            // Mostly the body, sometimes the header's digits.
            let at = if next().is_multiple_of(8) || bytes.len() <= body {
                next() as usize % body.min(bytes.len())
            } else {
                body + next() as usize % (bytes.len() - body)
            };
            match next() % 4 {
                0 => bytes[at] = next() as u8,
                1 => bytes[at] ^= 0x80,
                2 => bytes.truncate(at.max(1)),
                _ => bytes.insert(at, next() as u8),
            }
        }
        match same(&dir, "m.ply", &bytes) {
            Ok(_) => ok += 1,
            Err(_) => err += 1,
        }
    }
    assert!(ok > 100 && err > 100, "{ok} good, {err} bad");
}
