//! Mesh input: PLY in its three encodings, OBJ through tobj, the primitive-id rule of
//! `../shared/RAYS.md`, every kind of bad input, and the real meshes of `../shared/scenes/`.
//!
//! PLY files are written here by a small writer ([`write_ply`]) so that the same mesh can be
//! read back from ascii, little- and big-endian binary. The readers' throughput is measured by
//! `tools/parse_bench.rs`.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use oavm::mesh::{LoadLimits, Mesh, MeshError, load, load_with, parse_obj, parse_ply};

// ---------------------------------------------------------------------------------------------
// A PLY writer

#[derive(Clone, Copy, Debug, PartialEq)]
enum Enc {
    Ascii,
    Le,
    Be,
}

const ENCODINGS: [Enc; 3] = [Enc::Ascii, Enc::Le, Enc::Be];

impl Enc {
    fn format(self) -> &'static str {
        match self {
            Enc::Ascii => "ascii",
            Enc::Le => "binary_little_endian",
            Enc::Be => "binary_big_endian",
        }
    }
}

#[derive(Clone, Debug)]
enum Prop {
    /// type, name
    S(&'static str, &'static str),
    /// count type, item type, name
    L(&'static str, &'static str, &'static str),
}

#[derive(Clone, Debug)]
enum Val {
    S(f64),
    L(Vec<f64>),
}

#[derive(Clone, Debug)]
struct Elem {
    name: &'static str,
    props: Vec<Prop>,
    rows: Vec<Vec<Val>>,
}

/// Appends `v` as PLY type `ty`.
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
    if enc == Enc::Ascii {
        match ty {
            "float" | "float32" => write!(out, "{}", v as f32),
            "double" | "float64" => write!(out, "{v:e}"),
            _ => write!(out, "{}", v as i64),
        }
        .unwrap();
        return;
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

fn write_header(enc: Enc, elems: &[Elem]) -> Vec<u8> {
    let mut out = Vec::new();
    writeln!(out, "ply\nformat {} 1.0", enc.format()).unwrap();
    writeln!(out, "comment written by tests/integration/mesh_input.rs").unwrap();
    writeln!(out, "obj_info nothing to see").unwrap();
    for e in elems {
        writeln!(out, "element {} {}", e.name, e.rows.len()).unwrap();
        for p in &e.props {
            match p {
                Prop::S(t, n) => writeln!(out, "property {t} {n}").unwrap(),
                Prop::L(c, t, n) => writeln!(out, "property list {c} {t} {n}").unwrap(),
            }
        }
    }
    writeln!(out, "end_header").unwrap();
    out
}

fn write_ply(enc: Enc, elems: &[Elem]) -> Vec<u8> {
    let mut out = write_header(enc, elems);
    for e in elems {
        for row in &e.rows {
            assert_eq!(row.len(), e.props.len(), "row of {}", e.name);
            for (i, (p, v)) in e.props.iter().zip(row).enumerate() {
                if enc == Enc::Ascii && i > 0 {
                    out.push(b' ');
                }
                match (p, v) {
                    (Prop::S(t, _), Val::S(v)) => encode(t, *v, enc, &mut out),
                    (Prop::L(c, t, _), Val::L(items)) => {
                        encode(c, items.len() as f64, enc, &mut out);
                        for item in items {
                            if enc == Enc::Ascii {
                                out.push(b' ');
                            }
                            encode(t, *item, enc, &mut out);
                        }
                    }
                    _ => panic!("value does not match property {p:?}"),
                }
            }
            if enc == Enc::Ascii {
                out.push(b'\n');
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

fn face_elem(count: &'static str, item: &'static str, faces: &[Vec<i64>]) -> Elem {
    Elem {
        name: "face",
        props: vec![Prop::L(count, item, "vertex_indices")],
        rows: faces
            .iter()
            .map(|f| vec![Val::L(f.iter().map(|&i| i as f64).collect())])
            .collect(),
    }
}

/// The usual layout: float x y z, then `list uchar int vertex_indices`.
fn simple_ply(enc: Enc, positions: &[[f64; 3]], faces: &[Vec<i64>]) -> Vec<u8> {
    write_ply(
        enc,
        &[
            vertex_elem("float", positions),
            face_elem("uchar", "int", faces),
        ],
    )
}

/// The mesh a correct reader must return, fan-triangulated here independently of the crate.
fn expected(positions: &[[f64; 3]], faces: &[Vec<i64>]) -> Mesh {
    let mut triangles = Vec::new();
    for f in faces {
        for k in 1..f.len().saturating_sub(1) {
            triangles.push([f[0] as u32, f[k] as u32, f[k + 1] as u32]);
        }
    }
    Mesh {
        geometries: Vec::new(),
        positions: positions.iter().map(|p| p.map(|c| c as f32)).collect(),
        triangles,
    }
}

/// Writes the mesh in all three encodings, checks each reads back as `expected`, and returns
/// the mesh read (so that the caller's own checks are on what the reader gave).
fn check_all_encodings(ty: &'static str, positions: &[[f64; 3]], faces: &[Vec<i64>]) -> Mesh {
    let want = expected(positions, faces);
    let mut read = Vec::new();
    for enc in ENCODINGS {
        let bytes = write_ply(
            enc,
            &[vertex_elem(ty, positions), face_elem("uchar", "int", faces)],
        );
        let got = parse_ply(&bytes, "case.ply").unwrap_or_else(|e| panic!("{enc:?}: {e}"));
        assert_eq!(got, want, "{enc:?}");
        read.push(got);
    }
    read.pop().expect("three encodings")
}

/// Asserts an error of the given kind whose message contains every needle.
macro_rules! assert_error {
    ($result:expr, $pattern:pat, $($needle:expr),+ $(,)?) => {{
        let e: MeshError = match $result {
            Ok(m) => panic!("expected an error, got a mesh of {} triangles", m.triangles.len()),
            Err(e) => e,
        };
        assert!(matches!(e, $pattern), "wrong kind of error: {e:?}");
        let message = e.to_string();
        $(assert!(message.contains($needle), "`{message}` does not contain `{}`", $needle);)+
        e
    }};
}

fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes")
}

const TETRA: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
];

fn tetra_faces() -> Vec<Vec<i64>> {
    vec![vec![0, 2, 1], vec![0, 1, 3], vec![0, 3, 2], vec![1, 2, 3]]
}

// ---------------------------------------------------------------------------------------------
// Real meshes

#[test]
fn bunny_ply_and_obj_give_the_same_mesh() {
    let ply = load(&scenes().join("bunny/bun_zipper.ply")).unwrap();
    let obj = load(&scenes().join("bunny/stanford-bunny.obj")).unwrap();
    for mesh in [&ply, &obj] {
        assert_eq!(mesh.triangles.len(), 69_451);
        assert_eq!(mesh.positions.len(), 35_947);
    }
    // Same vertex order, same faces: the triangles are identical index for index.
    assert_eq!(ply.triangles, obj.triangles);
    // The OBJ was printed with 6 decimals, the PLY with 6 significant digits, so positions
    // agree to half a unit in the 6th decimal plus f32 rounding, not to f32 rounding alone.
    let mut worst = 0f32;
    for (a, b) in ply.positions.iter().zip(&obj.positions) {
        for (x, y) in a.iter().zip(b) {
            worst = worst.max((x - y).abs());
        }
    }
    assert!(worst <= 5e-7 + 1e-8, "positions differ by up to {worst}");
    assert!(
        worst > 0.0,
        "the two files were expected to differ in rounding"
    );
}

/// The bunny written here as binary STL, ASCII STL and OFF (by writers of this test, from the
/// PLY's arrays) reads back as the PLY's triangles, primitive id for primitive id, through
/// [`load`] (by extension and by content) — corners bit for bit (binary STL, OFF printed with
/// `{:?}`, which round-trips f32) and ASCII STL printed the same way.
#[test]
fn bunny_stl_and_off_give_the_ply_triangles() {
    let ply = load(&scenes().join("bunny/bun_zipper.ply")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut bin = vec![0u8; 80];
    bin.extend((ply.triangles.len() as u32).to_le_bytes());
    let mut ascii = String::from("solid bunny\n");
    for i in 0..ply.triangles.len() {
        bin.extend([0u8; 12]);
        ascii.push_str(" facet normal 0 0 0\n  outer loop\n");
        for c in ply.triangle(i) {
            c.iter().for_each(|v| bin.extend(v.to_le_bytes()));
            ascii.push_str(&format!("   vertex {:?} {:?} {:?}\n", c[0], c[1], c[2]));
        }
        bin.extend([0u8; 2]);
        ascii.push_str("  endloop\n endfacet\n");
    }
    ascii.push_str("endsolid bunny\n");
    let mut off = format!("OFF\n{} {} 0\n", ply.positions.len(), ply.triangles.len());
    for p in &ply.positions {
        off.push_str(&format!("{:?} {:?} {:?}\n", p[0], p[1], p[2]));
    }
    for t in &ply.triangles {
        off.push_str(&format!("3 {} {} {}\n", t[0], t[1], t[2]));
    }
    let write = |name: &str, bytes: &[u8]| {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    };
    let files = [
        write("bunny.stl", &bin),
        write("bunny-ascii.stl", ascii.as_bytes()),
        write("bunny.off", off.as_bytes()),
        // No extension: told apart by their bytes.
        write("bunny-stl", &bin),
        write("bunny-ascii-stl", ascii.as_bytes()),
        write("bunny-off", off.as_bytes()),
    ];
    for path in files {
        let mesh = load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(mesh.triangles.len(), 69_451, "{}", path.display());
        for i in 0..mesh.triangles.len() {
            assert_eq!(
                mesh.triangle(i),
                ply.triangle(i),
                "{} triangle {i}",
                path.display()
            );
        }
    }
    // A malformed one through `load`: a clean error naming the file and the place.
    let cut = write("cut.stl", &bin[..bin.len() - 7]);
    let e = load(&cut).unwrap_err().to_string();
    assert!(
        e.contains("cut.stl: byte") && e.contains("truncated"),
        "{e}"
    );
    let bad = write("bad.off", off.replacen("3 0 ", "3 99999999 ", 1).as_bytes());
    let e = load(&bad).unwrap_err().to_string();
    assert!(
        e.contains("bad.off: line") && e.contains("refers to vertex 99999999"),
        "{e}"
    );
}

#[test]
fn dragon_res4_loads() {
    let mesh = load(&scenes().join("dragon/dragon_vrip_res4.ply")).unwrap();
    assert_eq!(mesh.triangles.len(), 11_102);
    assert_eq!(mesh.positions.len(), 5_205);
    assert!(
        mesh.triangles
            .iter()
            .flatten()
            .all(|&i| (i as usize) < 5_205)
    );
}

// ---------------------------------------------------------------------------------------------
// Encodings and layouts

/// A file with everything a reader must skip: other elements before, between and after, extra
/// vertex and face properties (scalar and list) before and after the ones we use, doubles.
fn rich_elements() -> (Vec<Elem>, Mesh) {
    let positions = [
        [0.1, -0.2, 0.3],
        [1e-30, 1e30, -7.25],
        [12345.678901234, -0.0, 3.0e-7],
        [1.0 / 3.0, 2.0 / 3.0, 1.0],
        [-1e7, 1e7 + 1.0, 0.5],
        // Exactly halfway between the f32s 1 and 1 + 2^-23; its shortest decimal form lies
        // just above. Read as f64 then rounded (to even) it is 1; read straight as f32, more.
        [1.0 + f64::powi(2.0, -24), 0.0, 0.0],
    ];
    let faces: Vec<Vec<i64>> = vec![
        vec![0, 1, 2],
        vec![0, 1, 2, 3],
        vec![4, 3, 2, 1, 0],
        vec![1, 4],
    ];
    let material = Elem {
        name: "material",
        props: vec![
            Prop::S("uchar", "red"),
            Prop::L("uchar", "float", "spectrum"),
            Prop::S("float", "shininess"),
        ],
        rows: vec![
            vec![Val::S(255.0), Val::L(vec![0.5, 0.25]), Val::S(0.5)],
            vec![Val::S(3.0), Val::L(vec![]), Val::S(-1.0)],
        ],
    };
    let vertex = Elem {
        name: "vertex",
        props: vec![
            Prop::S("uchar", "quality"),
            Prop::S("double", "x"),
            Prop::S("float", "confidence"),
            Prop::S("float64", "y"),
            Prop::L("uint8", "int16", "neighbours"),
            Prop::S("double", "z"),
            Prop::S("int32", "id"),
        ],
        rows: positions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                vec![
                    Val::S(i as f64),
                    Val::S(p[0]),
                    Val::S(0.75),
                    Val::S(p[1]),
                    Val::L((0..i).map(|k| -(k as f64)).collect()),
                    Val::S(p[2]),
                    Val::S(-(i as f64) * 1000.0),
                ]
            })
            .collect(),
    };
    let edge = Elem {
        name: "edge",
        props: vec![Prop::S("int", "vertex1"), Prop::S("int", "vertex2")],
        rows: vec![
            vec![Val::S(0.0), Val::S(1.0)],
            vec![Val::S(1.0), Val::S(2.0)],
            vec![Val::S(2.0), Val::S(70000.0)],
        ],
    };
    let face = Elem {
        name: "face",
        props: vec![
            Prop::S("uchar", "flags"),
            Prop::L("ushort", "uint", "vertex_indices"),
            Prop::L("int", "float", "texcoord"),
            Prop::S("uint16", "tag"),
        ],
        rows: faces
            .iter()
            .map(|f| {
                vec![
                    Val::S(7.0),
                    Val::L(f.iter().map(|&i| i as f64).collect()),
                    Val::L(vec![0.25; 2 * f.len()]),
                    Val::S(65535.0),
                ]
            })
            .collect(),
    };
    let trailer = Elem {
        name: "trailer",
        props: vec![Prop::L("char", "double", "stuff"), Prop::S("short", "s")],
        rows: vec![vec![Val::L(vec![1.5, 2.5, 3.5]), Val::S(-32768.0)]],
    };
    (
        vec![material, vertex, edge, face, trailer],
        expected(&positions, &faces),
    )
}

#[test]
fn ascii_little_and_big_endian_give_the_same_mesh() {
    let (elems, want) = rich_elements();
    for enc in ENCODINGS {
        let bytes = write_ply(enc, &elems);
        let got = parse_ply(&bytes, "rich.ply").unwrap_or_else(|e| panic!("{enc:?}: {e}"));
        assert_eq!(got, want, "{enc:?}");
        // What the reader gave, spelled out: the doubles were rounded once, from f64 to f32
        // (1 + 2^-24 read straight as an f32 would not be 1), and the faces were fanned.
        assert_eq!(got.positions[3][0], (1.0f64 / 3.0) as f32, "{enc:?}");
        assert_eq!(got.positions[5][0], 1.0, "{enc:?}");
        assert_eq!(got.triangles.len(), 1 + 2 + 3, "{enc:?}");
    }
}

#[test]
fn every_integer_type_works_for_counts_and_indices() {
    let ints = [
        "uchar", "uint8", "char", "int8", "ushort", "uint16", "short", "int16", "uint", "uint32",
        "int", "int32",
    ];
    let faces = tetra_faces();
    let want = expected(&TETRA, &faces);
    for (n, count) in ints.iter().enumerate() {
        for item in ints {
            for enc in ENCODINGS {
                let mut face = face_elem(count, item, &faces);
                // Both names of the index list.
                if n % 2 == 1 {
                    face.props = vec![Prop::L(count, item, "vertex_index")];
                }
                let bytes = write_ply(enc, &[vertex_elem("float32", &TETRA), face]);
                let got = parse_ply(&bytes, "types.ply")
                    .unwrap_or_else(|e| panic!("{count} {item} {enc:?}: {e}"));
                assert_eq!(got, want, "{count} {item} {enc:?}");
            }
        }
    }
}

#[test]
fn face_element_may_come_before_vertex_element() {
    let faces = tetra_faces();
    for enc in ENCODINGS {
        let bytes = write_ply(
            enc,
            &[
                face_elem("uchar", "int", &faces),
                vertex_elem("double", &TETRA),
            ],
        );
        assert_eq!(
            parse_ply(&bytes, "case.ply").unwrap(),
            expected(&TETRA, &faces)
        );
    }
}

#[test]
fn crlf_line_endings_are_accepted() {
    let faces = tetra_faces();
    let want = expected(&TETRA, &faces);
    let ascii = simple_ply(Enc::Ascii, &TETRA, &faces);
    let crlf: Vec<u8> = ascii
        .iter()
        .flat_map(|&b| {
            if b == b'\n' {
                vec![b'\r', b'\n']
            } else {
                vec![b]
            }
        })
        .collect();
    assert_eq!(parse_ply(&crlf, "crlf.ply").unwrap(), want);
    // A binary body after a CRLF header.
    let binary = simple_ply(Enc::Le, &TETRA, &faces);
    let split = binary
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let mut mixed: Vec<u8> = binary[..split]
        .iter()
        .flat_map(|&b| {
            if b == b'\n' {
                vec![b'\r', b'\n']
            } else {
                vec![b]
            }
        })
        .collect();
    mixed.extend_from_slice(&binary[split..]);
    assert_eq!(parse_ply(&mixed, "crlf-binary.ply").unwrap(), want);
}

#[test]
fn ascii_blank_lines_and_tabs_between_records_are_accepted() {
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
                \n0\t0 0\n  1 0 0  \n\n0 1 0\n3 0 1 2\n\n";
    let mesh = parse_ply(text.as_bytes(), "blank.ply").unwrap();
    assert_eq!(mesh.triangles, vec![[0, 1, 2]]);
    assert_eq!(mesh.positions[1], [1.0, 0.0, 0.0]);
}

// ---------------------------------------------------------------------------------------------
// Primitive ids

#[test]
fn ply_face_ids_follow_the_fan_rule() {
    let positions: Vec<[f64; 3]> = (0..8).map(|i| [i as f64, (i * i) as f64, 0.0]).collect();
    let faces = vec![
        vec![0, 1, 2],
        vec![3, 4, 5, 6],
        vec![7, 6, 5, 4, 3],
        vec![1, 2],
        vec![5],
        vec![],
        vec![2, 4, 6],
    ];
    let mesh = check_all_encodings("float", &positions, &faces);
    // Written out, not derived: ids 0..=6 and the polygons that produced them.
    assert_eq!(
        mesh.triangles,
        vec![
            [0, 1, 2],
            [3, 4, 5],
            [3, 5, 6],
            [7, 6, 5],
            [7, 5, 4],
            [7, 4, 3],
            [2, 4, 6],
        ]
    );
}

#[test]
fn obj_face_ids_follow_f_lines_across_objects_groups_and_materials() {
    let text = "\
# ids must follow the f lines
mtllib scene.mtl
v 0 0 0
v 1 0 0
v 2 0 0
v 3 0 0
v 4 0 0
v 5 0 0
v 6 0 0
v 7 0 0
vt 0 0
vt 1 0
vn 0 0 1
vn 0 1 0
o first
f 1 2 3
f 1 2 3 4
g group
usemtl red
f 5 6 7 8 1
l 1 2 3
f 1 2
f 3
f
usemtl blue
f -1 -2 -3
o second
v 8 0 0
f 9/1/1 1//2 2/2
g
s 1
f 2 3 4 5 6 7
usemtl red
f 4 -1 9
";
    let mesh = parse_obj(text.as_bytes(), "ids.obj").unwrap();
    assert_eq!(
        mesh.triangles,
        vec![
            [0, 1, 2],
            [0, 1, 2],
            [0, 2, 3],
            [4, 5, 6],
            [4, 6, 7],
            [4, 7, 0],
            [7, 6, 5],
            [8, 0, 1],
            [1, 2, 3],
            [1, 3, 4],
            [1, 4, 5],
            [1, 5, 6],
            [3, 8, 8],
        ]
    );
    // Every `v` line, in file order.
    let xs: Vec<f32> = mesh.positions.iter().map(|p| p[0]).collect();
    assert_eq!(xs, (0..9).map(|i| i as f32).collect::<Vec<_>>());
}

#[test]
fn obj_vertex_weights_colours_and_unused_vertices() {
    let text = "v 2 4 6 2\nv 1 0 0 0.5 0.5 0.5\nv 0 1 0\nv 9 9 9\nf 1 2 3\n";
    let mesh = parse_obj(text.as_bytes(), "w.obj").unwrap();
    assert_eq!(
        mesh.positions,
        vec![
            [1.0, 2.0, 3.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [9.0, 9.0, 9.0]
        ]
    );
    assert_eq!(mesh.triangles, vec![[0, 1, 2]]);
}

// ---------------------------------------------------------------------------------------------
// Awkward but valid meshes

#[test]
fn single_triangle() {
    let mesh = check_all_encodings(
        "float",
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        &[vec![0, 1, 2]],
    );
    assert_eq!(mesh.triangles.len(), 1);
    let obj = parse_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3", "one.obj").unwrap();
    assert_eq!(obj, mesh);
}

#[test]
fn flat_grid() {
    let n = 5;
    let positions: Vec<[f64; 3]> = (0..n * n)
        .map(|i| [(i % n) as f64, (i / n) as f64, 0.0])
        .collect();
    let faces: Vec<Vec<i64>> = (0..n - 1)
        .flat_map(|y| (0..n - 1).map(move |x| y * n + x))
        .map(|i| vec![i, i + 1, i + n + 1, i + n])
        .collect();
    let mesh = check_all_encodings("float", &positions, &faces);
    assert_eq!(mesh.triangles.len(), 2 * 16);
    assert!(mesh.positions.iter().all(|p| p[2] == 0.0));
}

#[test]
fn far_from_the_origin() {
    let positions = [
        [1e7, 1e7, 1e7],
        [1e7 + 1.0, 1e7, 1e7],
        [1e7, 1e7 + 2.0, 1e7 + 0.5],
    ];
    for ty in ["float", "double"] {
        let mesh = check_all_encodings(ty, &positions, &[vec![0, 1, 2]]);
        assert_eq!(mesh.positions[1][0], 10_000_001.0);
    }
}

#[test]
fn tiny_and_huge_scales() {
    for scale in [1e-30, 1e30] {
        let positions = TETRA.map(|p| p.map(|c| c * scale + scale));
        for ty in ["float", "double"] {
            let mesh = check_all_encodings(ty, &positions, &tetra_faces());
            assert_eq!(mesh.positions[0][0], scale as f32);
            assert!(mesh.positions[0][0] > 0.0 && mesh.positions[0][0].is_finite());
        }
    }
}

#[test]
fn long_slivers() {
    let positions = [
        [0.0, 0.0, 0.0],
        [1e6, 0.0, 0.0],
        [1e6, 1e-6, 0.0],
        [-1e6, 1e-7, 1e-7],
    ];
    let mesh = check_all_encodings("double", &positions, &[vec![0, 1, 2], vec![0, 3, 1]]);
    assert_eq!(mesh.positions[2][1], 1e-6f64 as f32);
}

#[test]
fn duplicate_and_degenerate_triangles_keep_their_ids() {
    let faces = vec![
        vec![0, 1, 2],
        vec![0, 1, 2],
        vec![0, 0, 0],
        vec![0, 1, 1],
        vec![3, 2, 1],
    ];
    let mesh = check_all_encodings("float", &TETRA, &faces);
    assert_eq!(
        mesh.triangles,
        vec![[0, 1, 2], [0, 1, 2], [0, 0, 0], [0, 1, 1], [3, 2, 1]]
    );
}

// ---------------------------------------------------------------------------------------------
// Files and formats

#[test]
fn files_over_the_size_limit_are_refused_and_point_to_the_streaming_pack() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("tetra.ply");
    let bytes = simple_ply(Enc::Le, &TETRA, &tetra_faces());
    std::fs::write(&ply, &bytes).unwrap();
    let len = bytes.len() as u64;
    let at_most = |max_file_bytes| load_with(&ply, None, &LoadLimits { max_file_bytes });
    assert_eq!(at_most(len).unwrap(), expected(&TETRA, &tetra_faces()));
    let e = assert_error!(
        at_most(len - 1),
        MeshError::FileTooLarge { .. },
        "tetra.ply",
        &format!("{len} bytes"),
        "oavm-pack --mem-budget"
    );
    assert!(
        matches!(e, MeshError::FileTooLarge { bytes, limit, .. } if bytes == len && limit == len - 1)
    );
    // OBJ too; and a sparse file of a gibibyte is refused by its size, without reading it.
    let obj = dir.path().join("one.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let limits = LoadLimits { max_file_bytes: 10 };
    assert_error!(
        load_with(&obj, None, &limits),
        MeshError::FileTooLarge { .. },
        "one.obj"
    );
    let big = dir.path().join("big.ply");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(1 << 30)
        .unwrap();
    let limits = LoadLimits {
        max_file_bytes: 1 << 20,
    };
    assert_error!(
        load_with(&big, None, &limits),
        MeshError::FileTooLarge {
            bytes: 1073741824,
            ..
        },
        "big.ply"
    );
    // `load` reads with the documented default.
    assert_eq!(LoadLimits::default().max_file_bytes, 64 << 30);
    assert_eq!(
        LoadLimits::default().max_file_bytes,
        LoadLimits::DEFAULT_MAX_FILE_BYTES
    );
}

#[test]
fn missing_file_is_an_io_error_naming_the_path() {
    assert_error!(
        load(Path::new("/nonexistent/dir/missing.ply")),
        MeshError::Io { .. },
        "/nonexistent/dir/missing.ply",
        "cannot read"
    );
}

#[test]
fn unknown_format_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "hello world\nthis is not a mesh\n").unwrap();
    assert_error!(
        load(&text),
        MeshError::UnknownFormat { .. },
        "notes.txt",
        "neither"
    );
    let fake = dir.path().join("fake.ply");
    std::fs::write(&fake, [0u8, 159, 146, 150, 1, 2, 3]).unwrap();
    assert_error!(
        load(&fake),
        MeshError::UnknownFormat { .. },
        "fake.ply",
        "magic"
    );
    let empty = dir.path().join("empty.mesh");
    std::fs::write(&empty, "").unwrap();
    assert_error!(load(&empty), MeshError::UnknownFormat { .. }, "empty.mesh");
}

#[test]
fn load_picks_the_format_by_content_then_extension() {
    let dir = tempfile::tempdir().unwrap();
    // PLY content under a misleading name.
    let ply = dir.path().join("mesh.obj");
    std::fs::write(&ply, simple_ply(Enc::Be, &TETRA, &tetra_faces())).unwrap();
    assert_eq!(load(&ply).unwrap(), expected(&TETRA, &tetra_faces()));
    // OBJ content without an extension.
    let obj = dir.path().join("mesh");
    std::fs::write(&obj, "# a comment\n\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    assert_eq!(load(&obj).unwrap().triangles, vec![[0, 1, 2]]);
    // An .obj file is OBJ even when its first line is not an OBJ statement (tobj skips it).
    let odd = dir.path().join("odd.obj");
    std::fs::write(&odd, "hello\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    assert_eq!(load(&odd).unwrap().triangles.len(), 1);
}

// ---------------------------------------------------------------------------------------------
// Bad PLY headers

#[test]
fn bad_headers_name_the_line() {
    const V: &str = "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    const F: &str = "element face 1\nproperty list uchar int vertex_indices\n";
    const BODY: &str = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let cases: Vec<(String, u64, &str)> = vec![
        (
            format!("plx\nformat ascii 1.0\n{V}{F}end_header\n{BODY}"),
            1,
            "magic",
        ),
        (
            format!("ply\nformat ascii 2.0\n{V}{F}end_header\n"),
            2,
            "format",
        ),
        (
            format!("ply\nformat text 1.0\n{V}{F}end_header\n"),
            2,
            "unknown format `text`",
        ),
        (
            format!("ply\n{V}{F}end_header\n{BODY}"),
            8,
            "no `format` line",
        ),
        (
            format!("ply\nformat ascii 1.0\nformat ascii 1.0\n{V}{F}end_header\n"),
            3,
            "second `format`",
        ),
        (
            format!("ply\nformat ascii 1.0\n{V}property flt w\n{F}end_header\n"),
            7,
            "unknown type `flt`",
        ),
        (
            format!("ply\nformat ascii 1.0\nproperty float x\n{V}{F}end_header\n"),
            3,
            "before any `element`",
        ),
        (
            format!("ply\nformat ascii 1.0\n{V}{F}{BODY}"),
            9,
            "unknown header line starting with `0`",
        ),
        (format!("ply\nformat ascii 1.0\n{V}{F}"), 8, "end_header"),
        (
            format!("ply\nformat ascii 1.0\n{F}end_header\n3 0 1 2\n"),
            5,
            "no `vertex` element",
        ),
        (
            format!("ply\nformat ascii 1.0\n{V}end_header\n{BODY}"),
            7,
            "no `face` element",
        ),
        (
            format!(
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n{F}end_header\n"
            ),
            3,
            "no property `z`",
        ),
        (
            format!(
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty int x\nproperty float y\nproperty float z\n{F}end_header\n"
            ),
            4,
            "float or double",
        ),
        (
            format!("ply\nformat ascii 1.0\n{V}element face 1\nproperty uchar flags\nend_header\n"),
            7,
            "vertex_indices",
        ),
        (
            format!(
                "ply\nformat ascii 1.0\n{V}element face 1\nproperty list uchar float vertex_indices\nend_header\n"
            ),
            8,
            "list of integers",
        ),
        (
            format!(
                "ply\nformat ascii 1.0\n{V}element face 1\nproperty list float int vertex_indices\nend_header\n"
            ),
            8,
            "length type",
        ),
        (
            "ply\nformat ascii 1.0\nelement vertex many\n".to_owned(),
            3,
            "count",
        ),
        (
            "ply\nformat ascii 1.0\nelement vertex -3\n".to_owned(),
            3,
            "count",
        ),
        (
            format!("ply\nformat ascii 1.0\n{V}{F}texture foo.png\nend_header\n"),
            9,
            "unknown header line",
        ),
        (
            format!("ply\nformat ascii 1.0\n{V}{V}{F}end_header\n"),
            7,
            "second `vertex`",
        ),
    ];
    for (text, line, needle) in cases {
        let result = parse_ply(text.as_bytes(), "head.ply");
        assert_error!(
            result,
            MeshError::Header { .. },
            "head.ply",
            &format!("line {line}:"),
            needle
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Bad PLY bodies

const ASCII_HEAD: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n\
    property float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\n\
    end_header\n";
// Body lines: 10..=13 vertices, 14..=15 faces.

fn ascii_case(body: &str) -> Vec<u8> {
    format!("{ASCII_HEAD}{body}").into_bytes()
}

#[test]
fn truncated_ascii() {
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0"),
        "cut.ply",
    );
    assert_error!(
        r,
        MeshError::Truncated { .. },
        "cut.ply",
        "line 15",
        "face 1"
    );
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n"),
        "cut.ply",
    );
    assert_error!(
        r,
        MeshError::Truncated { .. },
        "cut.ply",
        "line 15",
        "before face 1"
    );
    let r = parse_ply(&ascii_case("0 0 0\n1 0 0\n0 1"), "cut.ply");
    assert_error!(r, MeshError::Truncated { .. }, "cut.ply", "line 10");
}

#[test]
fn truncated_binary() {
    let bytes = simple_ply(Enc::Le, &TETRA, &tetra_faces());
    let header = write_header(
        Enc::Le,
        &[
            vertex_elem("float", &TETRA),
            face_elem("uchar", "int", &tetra_faces()),
        ],
    )
    .len();
    // Inside vertex 2: fixed-size records, so the reader knows which one.
    let cut = &bytes[..header + 2 * 12 + 5];
    let at = format!("byte {}", header + 2 * 12);
    assert_error!(
        parse_ply(cut, "cut.ply"),
        MeshError::Truncated { .. },
        "cut.ply",
        &at,
        "vertex 2"
    );
    // Inside face 3's indices.
    let cut = &bytes[..bytes.len() - 3];
    let at = format!("byte {}", bytes.len() - 13);
    assert_error!(
        parse_ply(cut, "cut.ply"),
        MeshError::Truncated { .. },
        "cut.ply",
        &at,
        "face 3"
    );
    // Every prefix is an error, never a panic.
    for n in 0..bytes.len() {
        assert!(parse_ply(&bytes[..n], "cut.ply").is_err(), "prefix {n}");
    }
}

#[test]
fn ascii_records_must_hold_exactly_their_values() {
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3\n"),
        "count.ply",
    );
    assert_error!(
        r,
        MeshError::CountMismatch { .. },
        "count.ply",
        "line 11",
        "vertex 1"
    );
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0 7\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3\n"),
        "count.ply",
    );
    assert_error!(
        r,
        MeshError::CountMismatch { .. },
        "count.ply",
        "line 11",
        "more values"
    );
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n4 0 1 2\n3 0 2 3\n"),
        "count.ply",
    );
    assert_error!(
        r,
        MeshError::CountMismatch { .. },
        "count.ply",
        "line 14",
        "face 0"
    );
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n2 0 1 2\n3 0 2 3\n"),
        "count.ply",
    );
    assert_error!(
        r,
        MeshError::CountMismatch { .. },
        "count.ply",
        "line 14",
        "more values"
    );
}

#[test]
fn data_after_the_last_element_is_an_error() {
    let body = "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3\n";
    let ok = parse_ply(&ascii_case(&format!("{body}\n  \n")), "tail.ply");
    assert_eq!(ok.unwrap().triangles.len(), 2);
    let r = parse_ply(&ascii_case(&format!("{body}\n3 1 2 3\n")), "tail.ply");
    assert_error!(r, MeshError::TrailingData { .. }, "tail.ply", "line 17");
    let mut bytes = simple_ply(Enc::Be, &TETRA, &tetra_faces());
    let len = bytes.len();
    bytes.push(b'\n');
    let r = parse_ply(&bytes, "tail.ply");
    assert_error!(
        r,
        MeshError::TrailingData { .. },
        "tail.ply",
        &format!("byte {len}"),
        "1 bytes"
    );
}

#[test]
fn bad_values_are_errors() {
    let r = parse_ply(
        &ascii_case("0 0 0\n1 O 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3\n"),
        "val.ply",
    );
    assert_error!(r, MeshError::BadValue { .. }, "val.ply", "line 11", "`O`");
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n256 0 1 2\n3 0 2 3\n"),
        "val.ply",
    );
    assert_error!(r, MeshError::BadValue { .. }, "val.ply", "line 14", "`256`");
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2.0\n3 0 2 3\n"),
        "val.ply",
    );
    assert_error!(r, MeshError::BadValue { .. }, "val.ply", "line 14", "`2.0`");
    // A negative list length in binary (signed length type).
    for enc in [Enc::Le, Enc::Be] {
        let mut bytes = write_ply(
            enc,
            &[
                vertex_elem("float", &TETRA),
                face_elem("char", "int", &tetra_faces()),
            ],
        );
        let face0 = bytes.len() - 4 * 13;
        bytes[face0] = 0xff;
        let r = parse_ply(&bytes, "val.ply");
        assert_error!(
            r,
            MeshError::BadValue { .. },
            "val.ply",
            &format!("byte {face0}"),
            "negative"
        );
    }
}

#[test]
fn indices_out_of_range_name_the_face_and_index() {
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 4 3\n"),
        "idx.ply",
    );
    let e = assert_error!(
        r,
        MeshError::IndexOutOfRange { .. },
        "idx.ply",
        "line 15",
        "face 1",
        "vertex 4",
        "4 vertices"
    );
    assert!(matches!(
        e,
        MeshError::IndexOutOfRange {
            face: 1,
            index: 4,
            vertices: 4,
            ..
        }
    ));
    for enc in [Enc::Le, Enc::Be] {
        let mut faces = tetra_faces();
        faces[2][1] = 4_000_000_000;
        let bytes = write_ply(
            enc,
            &[
                face_elem("uchar", "uint", &faces),
                vertex_elem("double", &TETRA),
            ],
        );
        let header = bytes.len() - 4 * 13 - 4 * 24;
        let at = format!("byte {}", header + 2 * 13);
        let r = parse_ply(&bytes, "idx.ply");
        assert_error!(
            r,
            MeshError::IndexOutOfRange { .. },
            "idx.ply",
            &at,
            "face 2",
            "vertex 4000000000"
        );
    }
}

#[test]
fn negative_ply_indices_are_errors() {
    let r = parse_ply(
        &ascii_case("0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 -1 3\n"),
        "neg.ply",
    );
    assert_error!(
        r,
        MeshError::NegativeIndex { .. },
        "neg.ply",
        "line 15",
        "face 1",
        "-1"
    );
    let mut faces = tetra_faces();
    faces[3][2] = -5;
    let bytes = write_ply(
        Enc::Le,
        &[
            vertex_elem("float", &TETRA),
            face_elem("uchar", "int", &faces),
        ],
    );
    let at = format!("byte {}", bytes.len() - 13);
    let r = parse_ply(&bytes, "neg.ply");
    assert_error!(
        r,
        MeshError::NegativeIndex { .. },
        "neg.ply",
        &at,
        "face 3",
        "-5"
    );
}

#[test]
fn non_finite_coordinates_name_the_vertex() {
    for (value, line) in [("nan", 12), ("inf", 12), ("-infinity", 12), ("1e39", 12)] {
        let body = format!("0 0 0\n1 0 0\n0 {value} 0\n0 0 1\n3 0 1 2\n3 0 2 3\n");
        let r = parse_ply(&ascii_case(&body), "nan.ply");
        assert_error!(
            r,
            MeshError::NonFinite { .. },
            "nan.ply",
            &format!("line {line}"),
            "vertex 2"
        );
    }
    // A double beyond the f32 range, and a binary NaN; both in unused vertices too.
    for enc in ENCODINGS {
        for bad in [1e300, f64::NAN] {
            let mut positions = TETRA.to_vec();
            positions.push([0.0, 0.0, bad]);
            let bytes = write_ply(
                enc,
                &[
                    vertex_elem("double", &positions),
                    face_elem("uchar", "int", &tetra_faces()),
                ],
            );
            let r = parse_ply(&bytes, "nan.ply");
            let place = if enc == Enc::Ascii {
                "line 16"
            } else {
                "byte "
            };
            assert_error!(
                r,
                MeshError::NonFinite { vertex: 4, .. },
                "nan.ply",
                place,
                "vertex 4"
            );
        }
    }
}

#[test]
fn a_mesh_without_triangles_is_an_error() {
    let no_faces = simple_ply(Enc::Ascii, &TETRA, &[]);
    assert_error!(
        parse_ply(&no_faces, "empty.ply"),
        MeshError::Empty { .. },
        "empty.ply"
    );
    let small = simple_ply(Enc::Le, &TETRA, &[vec![0, 1], vec![2], vec![]]);
    assert_error!(
        parse_ply(&small, "empty.ply"),
        MeshError::Empty { .. },
        "empty.ply"
    );
    let nothing = b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n\
        property float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\n\
        end_header\n";
    assert_error!(
        parse_ply(nothing, "empty.ply"),
        MeshError::Empty { .. },
        "empty.ply"
    );
}

#[test]
fn huge_declared_counts_are_errors_not_allocations() {
    let body = "0 0 0\n".repeat(150);
    for count in ["1000000000000", "18446744073709551615"] {
        let text = ASCII_HEAD.replace("element vertex 4", &format!("element vertex {count}"));
        let r = parse_ply(format!("{text}{body}").as_bytes(), "huge.ply");
        assert_error!(r, MeshError::Truncated { .. }, "huge.ply", "line 10", count);
        let text = ASCII_HEAD.replace("element face 2", &format!("element face {count}"));
        let r = parse_ply(
            format!("{text}0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n").as_bytes(),
            "huge.ply",
        );
        assert_error!(r, MeshError::Truncated { .. }, "huge.ply", "line 14", count);
    }
    for enc in [Enc::Le, Enc::Be] {
        let header = write_header(
            enc,
            &[
                vertex_elem("float", &TETRA),
                face_elem("uchar", "int", &tetra_faces()),
            ],
        );
        let header = String::from_utf8(header)
            .unwrap()
            .replace("element vertex 4", "element vertex 1000000000000");
        let mut bytes = header.clone().into_bytes();
        bytes.extend(std::iter::repeat_n(0u8, 1000));
        let r = parse_ply(&bytes, "huge.ply");
        let at = format!("byte {}", header.len() + 83 * 12);
        assert_error!(r, MeshError::Truncated { .. }, "huge.ply", &at, "vertex 83");
        // A face list claiming four billion corners.
        let mut bytes = write_ply(
            enc,
            &[
                vertex_elem("float", &TETRA),
                face_elem("uint", "int", &tetra_faces()),
            ],
        );
        let face0 = bytes.len() - 4 * 16;
        bytes[face0..face0 + 4].copy_from_slice(&[0xff, 0xff, 0xff, 0xf0]);
        let r = parse_ply(&bytes, "huge.ply");
        assert_error!(
            r,
            MeshError::Truncated { .. },
            "huge.ply",
            &format!("byte {face0}"),
            "face 0"
        );
    }
    // An ascii list claiming four billion corners ends with its line.
    let text = ASCII_HEAD.replace("list uchar int", "list uint int");
    let r = parse_ply(
        format!("{text}0 0 0\n1 0 0\n0 1 0\n0 0 1\n4294967295 0 1 2\n3 0 1 2\n").as_bytes(),
        "huge.ply",
    );
    assert_error!(
        r,
        MeshError::CountMismatch { .. },
        "huge.ply",
        "line 14",
        "face 0"
    );
}

// ---------------------------------------------------------------------------------------------
// Bad OBJ

#[test]
fn obj_indices_out_of_range_name_the_line_and_face() {
    let head = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    let cases = [
        ("f 1 2 3\nf 1 2 4\n", "line 5", "face 2", "vertex 4"),
        (
            "f 1 2 3\no next\nf 0 1 2\ng other\n",
            "line 6",
            "face 2",
            "vertex 0",
        ),
        ("f 1 2 3\nf -1 -2 -4\n", "line 5", "face 2", "vertex -4"),
        (
            "f 1 2 3\nf 1 2 99999999999999\nf 1 2 3\n",
            "line 5",
            "face 2",
            "vertex 99999999999999",
        ),
    ];
    for (faces, line, face, vertex) in cases {
        let r = parse_obj(format!("{head}{faces}").as_bytes(), "idx.obj");
        assert_error!(
            r,
            MeshError::IndexOutOfRange { .. },
            "idx.obj",
            line,
            face,
            vertex,
            "3 vertices"
        );
    }
}

#[test]
fn bad_obj_statements_name_the_line() {
    let r = parse_obj(b"v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n", "bad.obj");
    assert_error!(
        r,
        MeshError::Obj { .. },
        "bad.obj",
        "line 2",
        "vertex 2",
        "`zero`"
    );
    let r = parse_obj(b"v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "bad.obj");
    assert_error!(r, MeshError::Obj { .. }, "bad.obj", "line 2", "vertex 2");
    let r = parse_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n# ok\nf 1 2 x\n", "bad.obj");
    assert_error!(
        r,
        MeshError::Obj { .. },
        "bad.obj",
        "line 5",
        "face parse error"
    );
    let r = parse_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/1/1/1\n", "bad.obj");
    assert_error!(r, MeshError::Obj { .. }, "bad.obj", "line 4");
    let r = parse_obj(
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\n\xff\xfe bad\nf 1 2 3\n",
        "bad.obj",
    );
    assert_error!(r, MeshError::Obj { .. }, "bad.obj", "line 4");
    let r = parse_obj(b"v 0 0 0\nv 1 0 0 0\n", "bad.obj");
    assert_error!(r, MeshError::Obj { .. }, "bad.obj", "line 2", "w is 0");
}

#[test]
fn obj_non_finite_and_empty_are_errors() {
    // The NaN vertex is not used by any face: still an error, as in PLY.
    let r = parse_obj(
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nf 1 2 3\n",
        "nan.obj",
    );
    assert_error!(
        r,
        MeshError::NonFinite { vertex: 4, .. },
        "nan.obj",
        "line 4",
        "vertex 4"
    );
    let r = parse_obj(b"v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n", "nan.obj");
    assert_error!(
        r,
        MeshError::NonFinite { vertex: 2, .. },
        "nan.obj",
        "line 2"
    );
    let r = parse_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nl 1 2 3\n", "empty.obj");
    assert_error!(r, MeshError::Empty { .. }, "empty.obj");
    assert_error!(
        parse_obj(b"", "empty.obj"),
        MeshError::Empty { .. },
        "empty.obj"
    );
}

// ---------------------------------------------------------------------------------------------
// No input panics

/// A small deterministic generator (xorshift64*).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

#[test]
fn mutated_files_never_panic() {
    let (elems, _) = rich_elements();
    let mut samples: Vec<(Vec<u8>, bool)> = ENCODINGS
        .iter()
        .map(|&enc| (write_ply(enc, &elems), true))
        .collect();
    samples.push((
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\no a\nf 1/1/1 2//1 3 -1\nusemtl m\nf -3 -2 -1\n"
            .to_vec(),
        false,
    ));
    let interesting: &[u8] = b"0123456789-+.eE \n\r\t/xnaif\xff\x00";
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut errors = 0;
    for (sample, is_ply) in &samples {
        let parse = |b: &[u8]| {
            if *is_ply {
                parse_ply(b, "fuzz.ply")
            } else {
                parse_obj(b, "fuzz.obj")
            }
        };
        for n in 0..=sample.len() {
            errors += parse(&sample[..n]).is_err() as usize;
        }
        for _ in 0..3000 {
            let mut bytes = sample.clone();
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(bytes.len());
                match rng.below(4) {
                    0 => bytes[i] = rng.next() as u8,
                    1 => bytes[i] = interesting[rng.below(interesting.len())],
                    2 => {
                        bytes.remove(i);
                    }
                    _ => bytes.insert(i, interesting[rng.below(interesting.len())]),
                }
            }
            errors += parse(&bytes).is_err() as usize;
        }
    }
    // Most mutations break the file; the reader noticed rather than accepting everything.
    assert!(errors > 3000, "only {errors} errors");
}
