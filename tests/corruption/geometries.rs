//! Corrupted `.oavm` files (format-spec.md §11): damage to the geometry table (§8.8), which a
//! scene reads whole and checks at open. Every byte of it changed: the section checksum catches
//! it. Records rewritten with every checksum recomputed, so that only the table's own rules
//! can catch them: a run that starts where the one before does not end, counts that do not add
//! up to the file's primitives, a non-finite transform, a name that is not UTF-8 or has a zero
//! inside it, an empty table. Each fails at open as a format error naming the geometry table,
//! never a panic.

use crate::fixtures::*;
use oavm::FormatError;

/// The dragon's first 9,000 triangles packed as three geometries (3,000 each), as bytes.
fn three_geometries() -> &'static [u8] {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES.get_or_init(|| {
        let mut mesh = dragon_part(9_000);
        mesh.geometries = (0..3)
            .map(|i| oavm::mesh::Geometry {
                name: format!("part {i}"),
                first_primitive: 3_000 * i,
                primitive_count: 3_000,
                transform: oavm::mesh::Geometry::IDENTITY,
            })
            .collect();
        let dir = tempfile::TempDir::new().unwrap();
        let path = dir.path().join("three.oavm");
        let opts = oavm::pack::PackOptions::default();
        oavm::pack::pack_mesh(mesh, "three", &path, &opts, &oavm::pack::Quiet).unwrap();
        std::fs::read(&path).unwrap()
    })
}

fn geometry_section(b: &[u8]) -> (usize, usize) {
    section_of(b, KIND_GEOMETRIES).expect("a geometry table")
}

#[test]
fn the_intact_table_opens_and_names_its_geometries() {
    let b = three_geometries();
    let scene = open(b).expect("the intact file opens");
    let names: Vec<_> = scene.geometries().iter().map(|g| g.name.clone()).collect();
    assert_eq!(names, ["part 0", "part 1", "part 2"]);
    assert_eq!(scene.locate(5_999), Some((1, 2_999)));
    assert_eq!(scene.locate(6_000), Some((2, 0)));
    assert_eq!(scene.locate(9_000), None);
    let (_, len) = geometry_section(b);
    assert_eq!(len, 3 * GEOMETRY_LEN);
}

#[test]
fn every_byte_of_the_table_changed_fails_at_open() {
    let b = three_geometries();
    let (at, len) = geometry_section(b);
    for i in at..at + len {
        let mut d = b.to_vec();
        d[i] ^= 0x5a;
        match open_error(&d, &format!("byte {i} of the geometry table changed")) {
            FormatError::Checksum { section, .. } => assert_eq!(section, "geometry table"),
            e => panic!("byte {i}: {e}"),
        }
    }
}

#[test]
fn tables_that_break_their_rules_fail_at_open() {
    let b = three_geometries();
    let (at, _) = geometry_section(b);
    let rec = move |g: usize| at + g * GEOMETRY_LEN;
    type Edit = Box<dyn Fn(&mut Vec<u8>)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "the second run starts one later",
            Box::new(move |d| write_u64(d, rec(1) + GEO_FIRST, 3_001)),
            "starts at primitive 3001",
        ),
        (
            "the first run starts at 1",
            Box::new(move |d| write_u64(d, rec(0) + GEO_FIRST, 1)),
            "starts at primitive 1",
        ),
        (
            "the last run is one short",
            Box::new(move |d| write_u64(d, rec(2) + GEO_COUNT, 2_999)),
            "hold 8999 primitives",
        ),
        (
            "a count near 2^64",
            Box::new(move |d| write_u64(d, rec(1) + GEO_COUNT, u64::MAX - 5)),
            "overflows",
        ),
        (
            "a transform entry is NaN",
            Box::new(move |d| write_u64(d, rec(1) + GEO_TRANSFORM + 8, f64::NAN.to_bits())),
            "non-finite transform",
        ),
        (
            "a name that is not UTF-8",
            Box::new(move |d| d[rec(0) + GEO_NAME] = 0xff),
            "not UTF-8",
        ),
        (
            "a zero inside a name",
            Box::new(move |d| d[rec(0) + GEO_NAME + 1] = 0),
            "not UTF-8",
        ),
    ];
    for (what, edit, want) in cases {
        let mut d = b.to_vec();
        edit(&mut d);
        fix_checksums(&mut d);
        match open_error(&d, what) {
            FormatError::Section { section, what: msg } => {
                assert_eq!(section, "geometry table", "{what}");
                assert!(msg.contains(want), "{what}: {msg:?} does not say {want:?}");
            }
            e => panic!("{what}: {e}"),
        }
    }
}
