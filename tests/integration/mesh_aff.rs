//! BART AFF scenes (`oavm::mesh::aff`): the three real scenes' counts, views and animation;
//! small scenes built here for each statement; bad input of every kind; random mutations.
//!
//! The real scenes live in `../shared/scenes/bart/`; a test that wants one fails when it is not
//! there.

use std::collections::HashMap;
use std::io;
use std::path::{Path, PathBuf};

use oavm::mesh::aff::AffMaterial;
use oavm::mesh::{
    AffScene, LoadLimits, Mesh, MeshError, Place, load, load_aff, load_at, load_with, parse_aff,
    parse_aff_with,
};
use oavm::rays::SplitMix64;

// ---------------------------------------------------------------------------------------------
// The real scenes

/// A file of the BART scenes. They are part of the test data: a missing file fails the test
/// that wants it (a skipped test would pass without checking anything).
fn bart(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes/bart")
        .join(rel);
    assert!(
        p.is_file(),
        "{} is missing: the BART scenes are test data, expected in ../shared/scenes/bart next to \
         the crate (see ../shared/scenes/README.md)",
        p.display()
    );
    p
}

fn scene(rel: &str, time: Option<f64>) -> AffScene {
    let p = bart(rel);
    load_aff(&p, time).unwrap_or_else(|e| panic!("{e}"))
}

/// Triangles whose corners differ between two poses of one scene.
fn moved(a: &Mesh, b: &Mesh) -> usize {
    assert_eq!(a.triangles, b.triangles);
    (0..a.triangles.len())
        .filter(|&i| a.triangle(i) != b.triangle(i))
        .count()
}

#[test]
fn kitchen_has_the_papers_counts_and_its_viewpoint() {
    let s = scene("kitchen/kitchen.aff", None);
    assert_eq!(s.faces(), 110_561);
    assert_eq!(s.mesh.triangles.len(), 110_561);
    assert_eq!(s.mesh.positions.len(), 63_706);
    assert_eq!(
        s.counts.animated_triangles + s.counts.cones + s.counts.spheres,
        0
    );
    assert_eq!(s.animation, Some((0.0, 20.0, 800)));
    assert_eq!(s.time, 0.0);
    let v = s.view.expect("the kitchen has a viewpoint");
    assert_eq!(v.from, [1.05369, 1.13876, 1.36377]);
    assert_eq!(v.at, [0.965979, 1.11824, 1.32034]);
    assert_eq!(v.up, [0.0, 1.0, 0.0]);
    assert_eq!(
        (v.angle_deg, v.hither, v.resolution),
        (40.0, 0.01, (800, 600))
    );
    assert_eq!(s.lights.len(), 6);
    assert_eq!(s.lights[0], [2.15, 2.00, 0.90]);

    // The toy car drives: some triangles move between t = 0 and t = 10, most stay.
    let later = scene("kitchen/kitchen.aff", Some(10.0));
    let n = moved(&s.mesh, &later.mesh);
    assert!(n > 1000 && n < 20_000, "{n} triangles moved");
    // The file's start time is the default.
    let at0 = scene("kitchen/kitchen.aff", Some(0.0));
    assert_eq!(at0.mesh, s.mesh);
}

/// The kitchen's shading statements: its 27 distinct `fm` materials (after the default), the
/// material of every triangle, the six coloured lights, the background and the ambient light.
#[test]
fn kitchen_keeps_its_materials_lights_and_background() {
    let s = scene("kitchen/kitchen.aff", None);
    assert_eq!(s.materials.len(), 28);
    assert_eq!(s.materials[0], AffMaterial::DEFAULT);
    assert_eq!(s.material_of.len(), s.mesh.triangles.len());
    assert!(
        s.material_of
            .iter()
            .all(|&m| (m as usize) < s.materials.len())
    );
    // Every triangle follows some `fm` (the scene sets one before its first primitive), and
    // every material read is used but one: kitchen.aff's own `fm 0.6 0.4 0.2 ...`, which the
    // car's include replaces before any primitive.
    let mut used = vec![0usize; s.materials.len()];
    for &m in &s.material_of {
        used[m as usize] += 1;
    }
    let unused: Vec<usize> = (0..used.len()).filter(|&i| used[i] == 0).collect();
    assert_eq!(unused, [0, 20], "{used:?}");
    assert_eq!(s.materials[20].ambient, [0.6, 0.4, 0.2]);
    // The glass (param_glass.aff: `fm 0.065 ... 20 0.85 1.55`) is transmissive and used.
    let glass = s
        .materials
        .iter()
        .position(|m| m.transmittance == 0.85 && m.ior == 1.55 && m.ambient == [0.065; 3])
        .expect("the kitchen's glass");
    assert!(used[glass] > 0);
    assert_eq!(s.materials[glass].specular, [0.05; 3]);
    assert_eq!(s.materials[glass].shine, 20.0);
    // A mirror-like metal: `fm 0.05 0.05 0.05 0.0 0.0 0.0 0.90 0.90 0.90 97.4304 0.0 0.0`.
    assert!(s.materials.iter().any(|m| m.specular == [0.9; 3]
        && m.diffuse == [0.0; 3]
        && m.shine == 97.4304
        && m.transmittance == 0.0));
    assert_eq!(s.light_colours.len(), s.lights.len());
    assert_eq!(
        s.light_colours,
        vec![[0.3; 3], [0.3; 3], [0.3; 3], [0.3; 3], [0.4; 3], [0.4; 3]]
    );
    assert_eq!(s.lights[4], [4.35, 1.40, 1.00]);
    assert_eq!(s.background, [0.5, 0.5, 1.0]);
    assert_eq!(s.ambient, [2.5; 3]);
    // Posed later, the same triangles keep the same materials.
    let later = scene("kitchen/kitchen.aff", Some(10.0));
    assert_eq!(later.material_of, s.material_of);
    assert_eq!(later.materials, s.materials);
}

#[test]
fn robots_have_the_papers_counts_and_walk() {
    let s = scene("robot/Robot.aff", None);
    assert_eq!(s.faces(), 71_708);
    assert_eq!(s.mesh.triangles.len(), 71_708);
    assert_eq!(s.mesh.positions.len(), 134_127);
    assert_eq!(s.animation, Some((0.0, 50.0, 800)));
    let later = scene("robot/Robot.aff", Some(25.0));
    // The city (city2.aff, 9,218 triangles) stands still; every part of the ten robots moves.
    assert_eq!(moved(&s.mesh, &later.mesh), 71_708 - 9_218);
}

#[test]
fn museum_has_the_papers_counts_and_its_animated_triangles_move() {
    let s = scene("museum/museum5.aff", None);
    assert_eq!(s.faces(), 10_143);
    assert_eq!(s.counts.animated_triangles, 1_024);
    assert_eq!(s.counts.cones, 8);
    // 10,284 triangles from the polygons, 1,024 animated, 8 cones of 32 triangles.
    assert_eq!(
        s.mesh.triangles.len(),
        10_284 + 1_024 + 8 * 2 * oavm::mesh::aff::CONE_SEGMENTS as usize
    );
    assert_eq!(
        s.time, -1.0,
        "`a -1.0 5.0 300`: the default time is the start"
    );
    let a = scene("museum/museum5.aff", Some(0.5));
    let b = scene("museum/museum5.aff", Some(2.5));
    let n = moved(&a.mesh, &b.mesh);
    assert!(n > 900 && n <= 1_024, "{n} triangles moved");
}

#[test]
fn load_dispatches_aff_and_load_at_rejects_a_time_for_other_formats() {
    let p = bart("museum/museum5.aff");
    let mesh = load(&p).unwrap();
    assert_eq!(mesh, load_aff(&p, None).unwrap().mesh);
    assert_eq!(
        load_at(&p, Some(2.0)).unwrap(),
        load_aff(&p, Some(2.0)).unwrap().mesh
    );
    let bunny = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bunny.ply");
    let e = load_at(&bunny, Some(1.0)).unwrap_err();
    assert!(matches!(e, MeshError::NotAnimated { .. }), "{e}");
}

/// An xxh3 digest of everything a pose yields: the mesh (f32 position bytes, then triangle
/// indices, little-endian), then the lights and the camera path (f64 bits).
fn digest(s: &AffScene) -> (u64, u64) {
    let mut mesh = Vec::new();
    for p in &s.mesh.positions {
        for c in p {
            mesh.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &s.mesh.triangles {
        for i in t {
            mesh.extend_from_slice(&i.to_le_bytes());
        }
    }
    let mut rest = Vec::new();
    let mut put = |v: [f64; 3]| {
        v.iter()
            .for_each(|c| rest.extend_from_slice(&c.to_le_bytes()))
    };
    s.lights.iter().for_each(|&l| put(l));
    if let Some(c) = s.camera_path {
        put(c.from);
        put(c.at);
        put(c.up);
    }
    (
        xxhash_rust::xxh3::xxh3_64(&mesh),
        xxhash_rust::xxh3::xxh3_64(&rest),
    )
}

/// Digests of the three scenes posed at the start, a quarter (an off-key time), the middle and
/// the end of their animation, recorded with the reader as it was before it used glam and
/// evaluated each animation once: any change of arithmetic that moves one bit of one vertex
/// shows here.
#[test]
fn poses_of_the_real_scenes_are_bit_identical_to_the_recorded_digests() {
    const RECORDED: &[(&str, f64, u64, u64)] = &[
        (
            "kitchen/kitchen.aff",
            0.0,
            0xdffe3e4b15fdd00d,
            0x8c2b72a474e9503e,
        ),
        (
            "kitchen/kitchen.aff",
            5.3,
            0xc15c8634b1c23b37,
            0x91bb8b7736326b74,
        ),
        (
            "kitchen/kitchen.aff",
            10.0,
            0xfcf0330297faddd5,
            0xd3c67a6c967595fe,
        ),
        (
            "kitchen/kitchen.aff",
            20.0,
            0xe783811c6bf19a13,
            0xe1e73d8750166d6f,
        ),
        (
            "robot/Robot.aff",
            0.0,
            0x5c1157efdfe791d7,
            0x7567727496893861,
        ),
        (
            "robot/Robot.aff",
            12.7,
            0x4af170d16e0e5316,
            0x417bf81330f4538a,
        ),
        (
            "robot/Robot.aff",
            25.0,
            0x3460e7abc6afeb95,
            0x7eaabe8f41d185a5,
        ),
        (
            "robot/Robot.aff",
            50.0,
            0xaebd25eecc191ea1,
            0x4a9c6391476f9414,
        ),
        (
            "museum/museum5.aff",
            -1.0,
            0xb4901757bdaacf95,
            0x643581104800ddad,
        ),
        (
            "museum/museum5.aff",
            0.6,
            0x959a27260d1d9c8a,
            0x9279a04f484a8eb1,
        ),
        (
            "museum/museum5.aff",
            2.0,
            0xf2ff4ca1dd418643,
            0x581d1121d3069c21,
        ),
        (
            "museum/museum5.aff",
            5.0,
            0x8a8c03763c819170,
            0x5fe16559d0a05a7d,
        ),
    ];
    let mut got = Vec::new();
    for (rel, times) in [
        ("kitchen/kitchen.aff", [0.0, 5.3, 10.0, 20.0]),
        ("robot/Robot.aff", [0.0, 12.7, 25.0, 50.0]),
        ("museum/museum5.aff", [-1.0, 0.6, 2.0, 5.0]),
    ] {
        for t in times {
            let (m, r) = digest(&scene(rel, Some(t)));
            got.push((rel, t, m, r));
        }
    }
    let text: Vec<String> = got
        .iter()
        .map(|(rel, t, m, r)| format!("(\"{rel}\", {t:?}, {m:#018x}, {r:#018x}),"))
        .collect();
    assert_eq!(got, RECORDED, "digests now:\n{}", text.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Small scenes in memory

/// Parses `files["top.aff"]` with includes from `files`, all under the directory `mem/`.
fn parse_files(files: &[(&str, &str)], time: Option<f64>) -> Result<AffScene, MeshError> {
    let map: HashMap<PathBuf, Vec<u8>> = files
        .iter()
        .map(|(n, t)| (Path::new("mem").join(n), t.as_bytes().to_vec()))
        .collect();
    let top = Path::new("mem/top.aff");
    parse_aff_with(&map[top], top, time, &mut |p: &Path| {
        map.get(&lexical(p))
            .cloned()
            .ok_or_else(|| io::Error::new(io::ErrorKind::NotFound, "no such file"))
    })
}

/// `p` with `x/..` folded, as a file system would resolve it without symbolic links.
fn lexical(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            c => out.push(c),
        }
    }
    out
}

fn parse(text: &str) -> Result<AffScene, MeshError> {
    parse_files(&[("top.aff", text)], None)
}

fn close(a: [f32; 3], b: [f64; 3]) -> bool {
    a.iter().zip(b).all(|(x, y)| (*x as f64 - y).abs() < 1e-5)
}

#[test]
fn polygons_are_fan_triangulated_in_file_order() {
    let s = parse(
        "# a comment\n\
         p 4  0 0 0  1 0 0  1 1 0  0 1 0 % and another\n\
         tt wood.ppm  0 0 1 0 0  1 0 1 1 0  0 1 1 0 1\n\
         pp 3  0 0 2 0 0 1  1 0 2 0 0 1  0 1 2 0 0 1\n\
         ttp t.ppm  0 0 3 0 0 1 0 0  1 0 3 0 0 1 1 0  0 1 3 0 0 1 0 1\n",
    )
    .unwrap();
    assert_eq!(s.faces(), 4);
    assert_eq!(
        s.mesh.triangles,
        vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [7, 8, 9], [10, 11, 12]]
    );
    assert_eq!(s.mesh.positions[12], [0.0, 1.0, 3.0]);
    assert!(s.view.is_none() && s.animation.is_none());
}

#[test]
fn meshes_read_vertex_normal_and_texture_indices() {
    let s = parse(
        "m vertices 4  0 0 0  1 0 0  1 1 0  0 1 0\n\
         normals 1  0 0 1\n\
         texturecoords 2 floor.ppm  0 0  1 1\n\
         triangles 2\n 0 1 2  0 0 0  0 1 1\n 0 2 3  0 0 0  0 1 0\n\
         m vertices 3 0 0 1 1 0 1 0 1 1 triangles 1 2 1 0\n",
    )
    .unwrap();
    assert_eq!(s.faces(), 3);
    assert_eq!(s.mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [6, 5, 4]]);
}

#[test]
fn static_transforms_compose_on_a_stack() {
    // Scale by 2, turn 90 degrees about +z, move by (10, 0, 0); inside, move by (0, 0, 5).
    let s = parse(
        "xs 2 2 2  0 0 1 90  10 0 0 {\n\
           p 3  1 0 0  0 1 0  0 0 1\n\
           xs 1 1 1  1 0 0 0  0 0 5 { p 3 1 0 0 0 0 0 0 0 0 }\n\
         }\n\
         p 3  1 0 0  0 1 0  0 0 1\n",
    )
    .unwrap();
    let p = &s.mesh.positions;
    assert!(close(p[0], [10.0, 2.0, 0.0]), "{:?}", p[0]);
    assert!(close(p[1], [8.0, 0.0, 0.0]), "{:?}", p[1]);
    assert!(close(p[2], [10.0, 0.0, 2.0]), "{:?}", p[2]);
    // Inner: x' = R S (x + (0,0,5)) + t.
    assert!(close(p[3], [10.0, 2.0, 10.0]), "{:?}", p[3]);
    // After the `}`: untouched.
    assert_eq!(p[6], [1.0, 0.0, 0.0]);
}

const KEYS: &str = "k mover {\n\
    transl 5\n\
    -1 -4 0 0  0 0 0\n\
     0 0 0 0  0 0 0\n\
     1 4 0 0  0 0 0\n\
     2 8 0 0  0 0 0\n\
     3 12 0 0  0 0 0\n\
    rot 4\n\
    -1 0 1 0 0  0 0 0\n\
     0 0 1 0 0  0 0 0\n\
     2 0 1 0 180  0 0 0\n\
     3 0 1 0 270  0 0 0\n\
}\n";

const MOVER: &str = "x mover { p 3  1 0 0  0 1 0  0 0 1 }\n";

#[test]
fn animated_transforms_follow_their_keys_before_or_after_the_x() {
    let after = format!("{MOVER}{KEYS}");
    let before = format!("{KEYS}{MOVER}");
    for t in [0.0, 0.5, 1.0, 2.0] {
        let a = parse_files(&[("top.aff", &after)], Some(t)).unwrap();
        let b = parse_files(&[("top.aff", &before)], Some(t)).unwrap();
        assert_eq!(a.mesh, b.mesh, "t = {t}");
    }
    let at = |t: f64| parse_files(&[("top.aff", &after)], Some(t)).unwrap().mesh;
    // t = 0: no rotation, no translation.
    assert_eq!(at(0.0).positions[0], [1.0, 0.0, 0.0]);
    // t = 2: half a turn about +y, moved to x = 8: (1,0,0) -> (-1,0,0) + (8,0,0).
    assert!(close(at(2.0).positions[0], [7.0, 0.0, 0.0]));
    // Times outside [key 1, key n-2] clamp.
    assert_eq!(at(-5.0), at(0.0));
    assert_eq!(at(9.0), at(2.0));
    // Catmull-Rom through evenly spaced collinear keys: x = 4 t.
    assert!((at(0.5).positions[1][0] - 2.0).abs() < 1e-5);
    // An `x` with no keyframes is the identity.
    let plain = parse("x nobody { p 3 1 0 0 0 1 0 0 0 1 }").unwrap();
    assert_eq!(plain.mesh.positions[0], [1.0, 0.0, 0.0]);
}

#[test]
fn visibility_keys_hide_subtrees() {
    let text = "p 3 0 0 0 1 0 0 0 1 0\n\
                x blink { p 3 0 0 1 1 0 1 0 1 1 }\n\
                p 3 0 0 2 1 0 2 0 1 2\n\
                k blink { visibility 2  1 0  2 1 }\n";
    let tris = |t: f64| {
        parse_files(&[("top.aff", text)], Some(t))
            .unwrap()
            .mesh
            .triangles
    };
    assert_eq!(tris(0.0).len(), 3);
    assert_eq!(tris(1.5), vec![[0, 1, 2], [6, 7, 8]]);
    assert_eq!(tris(2.0).len(), 3);
}

#[test]
fn animated_triangles_interpolate_linearly_and_clamp() {
    let text = "a 0 2 3\n\
                tpa 2\n\
                0  0 0 0 0 0 1  1 0 0 0 0 1  0 1 0 0 0 1\n\
                2  0 0 4 0 0 1  1 0 4 0 0 1  0 1 4 0 0 1\n";
    let z = |t: Option<f64>| parse_files(&[("top.aff", text)], t).unwrap().mesh.positions[0][2];
    assert_eq!(z(None), 0.0);
    assert_eq!(z(Some(0.5)), 1.0);
    assert_eq!(z(Some(7.0)), 4.0);
    assert_eq!(z(Some(-7.0)), 0.0);
    let s = parse(text).unwrap();
    assert_eq!((s.faces(), s.counts.animated_triangles), (0, 1));
}

#[test]
fn cones_and_spheres_are_tessellated() {
    let s = parse("c 0 0 0 1  0 2 0 0.5\ns 0 0 0 3\n").unwrap();
    assert_eq!((s.counts.cones, s.counts.spheres, s.faces()), (1, 1, 0));
    let cone = 2 * oavm::mesh::aff::CONE_SEGMENTS as usize;
    let sphere =
        2 * oavm::mesh::aff::SPHERE_SLICES as usize * (oavm::mesh::aff::SPHERE_STACKS as usize - 1);
    assert_eq!(sphere, 960);
    assert_eq!(s.mesh.triangles.len(), cone + sphere);
    // The cone's corners lie on its two rings; the sphere's on the sphere.
    for (i, p) in s.mesh.positions.iter().enumerate() {
        let [x, y, z] = p.map(|c| c as f64);
        if i < 2 * oavm::mesh::aff::CONE_SEGMENTS as usize {
            let r = (x * x + z * z).sqrt();
            assert!((y == 0.0 && (r - 1.0).abs() < 1e-6) || (y == 2.0 && (r - 0.5).abs() < 1e-6));
        } else {
            assert!(((x * x + y * y + z * z).sqrt() - 3.0).abs() < 1e-5);
        }
    }
    // Outward facing: the first cone triangle's normal points away from the axis.
    let [a, b, c] = s.mesh.triangle(0).map(|p| p.map(|x| x as f64));
    let n = cross(sub(b, a), sub(c, a));
    let mid = [(a[0] + b[0]) / 2.0, 0.0, (a[2] + b[2]) / 2.0];
    assert!(n[0] * mid[0] + n[2] * mid[2] > 0.0);
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `fm` as the twelve numbers of a material, for comparisons.
fn fm(m: &AffMaterial) -> Vec<f32> {
    let mut v = [m.ambient, m.diffuse, m.specular].concat();
    v.extend([m.shine, m.transmittance, m.ior]);
    v
}

/// Each triangle takes the material current when its statement is read, in reading order
/// across transforms and includes; equal materials share an entry; invisible triangles leave
/// with their materials.
#[test]
fn materials_follow_the_triangles_in_reading_order() {
    let files = [
        (
            "top.aff",
            "p 3 0 0 0 1 0 0 0 1 0
             f 1 0.5 0 0.5 0.25 10 0 1
             p 4 0 0 1 1 0 1 1 1 1 0 1 1
             xs 1 1 1 0 0 1 0 0 0 0 {
               fm 0.1 0.2 0.3  0.4 0.5 0.6  0.7 0.8 0.9  20 0.5 1.5
               x blink { p 3 0 0 2 1 0 2 0 1 2 }
             }
             p 3 0 0 3 1 0 3 0 1 3
             i 0 sub.aff
             m vertices 3 0 0 5 1 0 5 0 1 5 triangles 2 0 1 2 2 1 0
             f 1 0.5 0 0.5 0.25 10 0 1
             tpa 1 0  0 0 6 0 0 1  1 0 6 0 0 1  0 1 6 0 0 1
             k blink { visibility 2  1 0  2 1 }
",
        ),
        (
            "sub.aff",
            "tt t.ppm 0 0 4 0 0 1 0 4 1 0 0 1 4 0 1
fm 0 0 0 1 1 1 0 0 0 0 0 0
",
        ),
    ];
    let s = parse_files(&files, None).unwrap();
    // Triangles: p (1), p quad (2), blink (1), p (1), tt (1), m (2), tpa (1).
    assert_eq!(s.mesh.triangles.len(), 9);
    assert_eq!(s.material_of, vec![0, 1, 1, 2, 2, 2, 3, 3, 1]);
    assert_eq!(s.materials.len(), 4);
    assert_eq!(s.materials[0], AffMaterial::DEFAULT);
    assert_eq!(
        fm(&s.materials[1]),
        [
            0.5, 0.25, 0.0, 0.5, 0.25, 0.0, 0.25, 0.25, 0.25, 10.0, 0.0, 1.0
        ]
    );
    assert_eq!(
        fm(&s.materials[2]),
        [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 20.0, 0.5, 1.5]
    );
    assert_eq!(
        fm(&s.materials[3]),
        [0., 0., 0., 1., 1., 1., 0., 0., 0., 0., 0., 0.]
    );
    // At t = 1.5 the blinking triangle (the fourth) is hidden, with its material.
    let hidden = parse_files(&files, Some(1.5)).unwrap();
    assert_eq!(hidden.mesh.triangles.len(), 8);
    assert_eq!(hidden.material_of, vec![0, 1, 1, 2, 2, 3, 3, 1]);
    assert_eq!(hidden.mesh.triangles[3], s.mesh.triangles[4]);
    // Cones and spheres take the current material for all their triangles.
    let s = parse(
        "c 0 0 0 1 0 1 0 1
f 0 1 0 1 0 0 0 1
s 0 0 0 1
",
    )
    .unwrap();
    let cone = 2 * oavm::mesh::aff::CONE_SEGMENTS as usize;
    assert_eq!(s.material_of.len(), cone + 960);
    assert!(s.material_of[..cone].iter().all(|&m| m == 0));
    assert!(s.material_of[cone..].iter().all(|&m| m == 1));
    // No material at all: one default entry.
    let s = parse(
        "p 3 0 0 0 1 0 0 0 1 0
",
    )
    .unwrap();
    assert_eq!((s.materials.len(), s.material_of.clone()), (1, vec![0]));
    // BART's defaults: a black background, a white ambient light.
    assert_eq!((s.background, s.ambient), ([0.0; 3], [1.0; 3]));
}

#[test]
fn lights_keep_their_colours_and_the_last_background_and_ambient_count() {
    let s = parse(
        "b 0.1 0.2 0.3
am 0.5 0.5 0.5
         l 1 2 3
         xs 1 1 1 0 0 1 0 10 0 0 { l 0 0 0  0.25 0.5 0.75 }
         l 4 5 6 1 1 0
         b 0 0 1
am 2 2 2
         p 3 0 0 0 1 0 0 0 1 0
",
    )
    .unwrap();
    assert_eq!(
        s.lights,
        vec![[1.0, 2.0, 3.0], [10.0, 0.0, 0.0], [4.0, 5.0, 6.0]]
    );
    assert_eq!(
        s.light_colours,
        vec![[1.0; 3], [0.25, 0.5, 0.75], [1.0, 1.0, 0.0]]
    );
    assert_eq!(s.background, [0.0, 0.0, 1.0]);
    assert_eq!(s.ambient, [2.0; 3]);
}

#[test]
fn includes_are_relative_and_honour_the_detail_level() {
    let s = parse_files(
        &[
            (
                "top.aff",
                "i 0 sub/a.aff\ni 1 sub/hidden.aff\nd 1\ni 1 sub/b.aff\n",
            ),
            ("sub/a.aff", "i 0 c.aff\n"),
            ("sub/c.aff", "p 3 0 0 0 1 0 0 0 1 0\n"),
            ("sub/b.aff", "xs 1 1 1 0 0 1 0 0 0 7 { i 0 ../sub/c.aff }\n"),
        ],
        None,
    )
    .unwrap();
    assert_eq!(s.faces(), 2);
    assert_eq!(s.mesh.positions[3], [0.0, 0.0, 7.0]);
}

#[test]
fn the_view_block_is_read_in_any_order() {
    let s = parse(
        "v\nresolution 64 48\nat 0 0 0\nfrom 0 0 5\nangle 30\nup 0 1 0\nhither 0.5\n\
         p 3 0 0 0 1 0 0 0 1 0\n",
    )
    .unwrap();
    let v = s.view.unwrap();
    assert_eq!(
        (v.from, v.at, v.resolution),
        ([0.0, 0.0, 5.0], [0.0; 3], (64, 48))
    );
    assert!(oavm::rays::Camera::look_at(v.from, v.at, v.up, v.angle_deg).is_ok());
    assert!(oavm::rays::Camera::look_at(v.from, v.at, [0.0, 0.0, 1.0], 30.0).is_err());
    assert!(oavm::rays::Camera::look_at(v.from, v.from, v.up, 30.0).is_err());
    assert!(oavm::rays::Camera::look_at(v.from, v.at, v.up, 180.0).is_err());
}

// ---------------------------------------------------------------------------------------------
// Bad input

/// The error at the bottom of the include chain, with the line it names.
fn inner_line(e: &MeshError) -> (String, u64) {
    match e.innermost() {
        MeshError::Aff { file, line, .. } => (file.clone(), *line),
        MeshError::Truncated {
            file,
            at: Place::Line(line),
            ..
        }
        | MeshError::BadValue {
            file,
            at: Place::Line(line),
            ..
        } => (file.clone(), *line),
        other => panic!("unexpected error kind: {other}"),
    }
}

#[track_caller]
fn fails(text: &str, line: u64, words: &str) -> MeshError {
    let e = parse(text).expect_err("should fail");
    let msg = e.to_string();
    assert_eq!(inner_line(&e), ("mem/top.aff".into(), line), "{msg}");
    assert!(msg.contains(words), "{msg:?} should say {words:?}");
    e
}

#[test]
fn truncated_statements_name_the_file_and_line() {
    let e = fails(
        "p 3 0 0 0 1 0 0 0 1 0\nm vertices 3\n0 0 0\n1 0 0\n",
        4,
        "ends where",
    );
    assert!(matches!(e, MeshError::Truncated { .. }));
    fails(
        "m vertices 2 0 0 0 1 1 1\ntriangles 1\n0 1",
        3,
        "ends where",
    );
    fails("xs 1 1 1 0 0 1 0 0 0", 1, "ends where");
    fails("v from 0 0 0 at", 1, "ends where");
    fails("k a { transl 4\n0 0 0 0 0 0 0\n", 2, "ends where");
}

#[test]
fn bad_numbers_and_non_finite_values_are_rejected() {
    let e = fails("p 3\n0 0 0\n1 zero 0\n0 1 0\n", 3, "found `zero`");
    assert!(matches!(e, MeshError::BadValue { .. }));
    fails("p 3 0 0 0\n1 NaN 0\n0 1 0\n", 2, "not a finite number");
    fails("p 3 0 0 0 1 inf 0 0 1 0\n", 1, "not a finite number");
    fails("p 3 0 0 0 1 1e999 0 0 1 0\n", 1, "not a finite number");
    fails("p -3 0 0 0\n", 1, "non-negative integer");
    fails("p 3.5 0 0 0\n", 1, "non-negative integer");
    fails(
        "m vertices 99999999999999999999999 0 0 0",
        1,
        "non-negative integer",
    );
    fails("a 0 1 -5\np 3 0 0 0 1 0 0 0 1 0", 1, "non-negative integer");
    // Materials, backgrounds and light colours: numbers finite as f32.
    fails(
        "f 1 1 1 1 0 0\n0 nan 1\np 3 0 0 0 1 0 0 0 1 0",
        2,
        "not a finite number",
    );
    fails(
        "fm 1 1 1 1 1 1\n1 1 1 1e39 0 0",
        2,
        "range of a 32-bit float",
    );
    fails("fm 1 1 1 1 1 1 1 1 1 1 0", 1, "ends where");
    fails("b 0 0 x", 1, "found `x`");
    fails("am 0 0 1e300", 1, "range of a 32-bit float");
    fails("l 0 0 0 1 1 inf", 1, "not a finite number");
    fails("l 0 0 0 1 1", 1, "ends where");
    // A transform that overflows f32.
    let e = parse("xs 1e300 1 1 0 0 1 0 0 0 0 { p 3 1 0 0 0 1 0 0 0 1 }").unwrap_err();
    assert!(matches!(e, MeshError::NonFinite { .. }), "{e}");
    let e = parse_files(&[("top.aff", "p 3 0 0 0 1 0 0 0 1 0")], Some(f64::NAN)).unwrap_err();
    assert!(matches!(e, MeshError::BadTime { .. }), "{e}");
}

#[test]
fn huge_counts_fail_without_allocating_for_them() {
    fails("m vertices 18446744073709551615 0 0 0", 1, "ends where");
    fails("p 4000000000 0 0 0 1 1 1", 1, "ends where");
    fails(
        "m vertices 3 0 0 0 1 0 0 0 1 0 triangles 4000000000 0 1 2",
        1,
        "ends where",
    );
    fails("tpa 4000000000 0", 1, "ends where");
    fails("k a { rot 4000000000 0 0 1 0 0 0 0 0", 1, "ends where");
    fails("tpa 0", 1, "no keys");
}

#[test]
fn structural_errors_are_reported() {
    fails(
        "p 3 0 0 0 1 0 0 0 1 0\nsphere 0 0 0 1\n",
        2,
        "unknown keyword `sphere`",
    );
    fails("p 3 0 0 0 1 0 0 0 1 0\n}\n", 2, "without a matching");
    fails(
        "xs 1 1 1 0 0 1 0 0 0 0\n{\np 3 0 0 0 1 0 0 0 1 0\n",
        1,
        "not closed",
    );
    fails("xs 1 1 1 0 0 1 0 0 0 0 p 3", 1, "expected `{`");
    fails(
        "m vertices 3 0 0 0 1 0 0 0 1 0\ntriangles 1\n0 1 3\n",
        3,
        "vertex index 2",
    );
    fails(
        "m vertices 3 0 0 0 1 0 0 0 1 0\ntriangles 1\n0 -1 2\n",
        3,
        "is -1",
    );
    fails(
        "m vertices 3 0 0 0 1 0 0 0 1 0 normals 1 0 0 1\ntriangles 1\n0 1 2 0 0 1\n",
        3,
        "normal index 2",
    );
    fails(
        "m vertices 3 0 0 0 1 0 0 0 1 0\nfaces 1\n",
        2,
        "expected `normals`",
    );
    fails("m\npoints 3\n", 2, "expected `vertices`");
    fails("k a {\n transl 3\n", 2, "at least 4");
    fails("k a {\n wobble 4\n", 2, "unknown motion");
    fails(
        "v from 0 0 0 at 0 0 1 up 0 1 0 angle 40 hither 1\n",
        1,
        "no `resolution`",
    );
    fails("v resolution 0 600\n", 1, "positive integer");
    fails("c 1 2 3 1 1 2 3 1\n", 1, "same point");
    let e = parse("# nothing but a comment\nfm 1 1 1 1 1 1 1 1 1 1 1 1\n").unwrap_err();
    assert!(matches!(e, MeshError::Empty { .. }), "{e}");
}

#[test]
fn include_errors_show_the_chain() {
    // An error two files down names both including statements and the file where it is.
    let e = parse_files(
        &[
            ("top.aff", "p 3 0 0 0 1 0 0 0 1 0\n\ni 0 a.aff\n"),
            ("a.aff", "\ni 0 b.aff\n"),
            ("b.aff", "p 3\n0 0 0\n0 x 0\n"),
        ],
        None,
    )
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.starts_with("mem/top.aff: line 3: in the file included here: mem/a.aff: line 2: in the file included here: mem/b.aff: line 3: bad value"),
        "{msg}"
    );
    assert_eq!(inner_line(&e), ("mem/b.aff".into(), 3));

    // A missing file.
    let e = parse_files(&[("top.aff", "i 0 gone.aff")], None).unwrap_err();
    assert!(
        matches!(e.innermost(), MeshError::Io { path, .. } if path == Path::new("mem/gone.aff")),
        "{e}"
    );
    assert!(matches!(e, MeshError::Included { line: 1, .. }));

    // A cycle, also through `..`.
    let e = parse_files(
        &[
            ("top.aff", "i 0 d/a.aff"),
            ("d/a.aff", "i 0 ../b.aff"),
            ("b.aff", "i 0 top.aff"),
        ],
        None,
    )
    .unwrap_err();
    assert!(e.to_string().contains("include cycle"), "{e}");
    assert_eq!(inner_line(&e).0, "mem/d/../b.aff");
    let e = parse("i 0 top.aff").unwrap_err();
    assert!(e.to_string().contains("include cycle"), "{e}");

    // Too deep.
    let mut files: Vec<(String, String)> = vec![("top.aff".into(), "i 0 f0.aff".into())];
    for i in 0..40 {
        files.push((format!("f{i}.aff"), format!("i 0 f{}.aff", i + 1)));
    }
    let refs: Vec<(&str, &str)> = files
        .iter()
        .map(|(a, b)| (a.as_str(), b.as_str()))
        .collect();
    let e = parse_files(&refs, None).unwrap_err();
    assert!(e.to_string().contains("nest deeper"), "{e}");
}

#[test]
fn exponential_includes_hit_the_byte_budget() {
    // Each level includes the next twice: 2^24 copies of a 40-byte file would be read.
    let mut files: Vec<(String, String)> = vec![("top.aff".into(), "i 0 l0.aff".into())];
    for i in 0..24 {
        files.push((
            format!("l{i}.aff"),
            format!("i 0 l{0}.aff\ni 0 l{0}.aff\n", i + 1),
        ));
    }
    files.push(("l24.aff".into(), "p 3 0 0 0 1 0 0 0 1 0 # padding\n".into()));
    let refs: Vec<(&str, &str)> = files
        .iter()
        .map(|(a, b)| (a.as_str(), b.as_str()))
        .collect();
    let e = parse_files(&refs, None).unwrap_err();
    assert!(matches!(e.innermost(), MeshError::TooLarge { .. }), "{e}");
}

#[test]
fn includes_larger_than_the_budget_left_are_refused_naming_the_file_and_line() {
    use oavm::mesh::aff::{INCLUDE_COST, MAX_PARSED_BYTES};
    let dir = tempfile::tempdir().unwrap();
    let top = dir.path().join("top.aff");
    let text = "p 3 0 0 0 1 0 0 0 1 0\n\ni 0 big.aff\n";
    std::fs::write(&top, text).unwrap();
    // Sparse: it would fit the budget alone, not after the top file and the inclusion cost.
    let big = dir.path().join("big.aff");
    let size = MAX_PARSED_BYTES - INCLUDE_COST - text.len() as u64 + 1;
    std::fs::File::create(&big).unwrap().set_len(size).unwrap();
    for e in [
        load_aff(&top, None).unwrap_err(),
        parse_aff(text.as_bytes(), &top.display().to_string(), None).unwrap_err(),
    ] {
        assert!(matches!(e, MeshError::Included { line: 3, .. }), "{e}");
        let inner = e.innermost();
        assert!(
            matches!(inner, MeshError::TooLarge { file, .. } if file.ends_with("big.aff")),
            "{e}"
        );
        let msg = e.to_string();
        assert!(msg.contains(&format!("holds {size} bytes")), "{msg}");
        assert!(msg.contains(&format!("{} bytes left", size - 1)), "{msg}");
    }
    // A small include is read (and is not AFF: a NUL is an unknown keyword).
    std::fs::File::create(&big).unwrap().set_len(2).unwrap();
    let e = load_aff(&top, None).unwrap_err();
    assert!(matches!(e.innermost(), MeshError::Aff { .. }), "{e}");

    // The top file alone over the budget.
    let huge = dir.path().join("huge.aff");
    std::fs::File::create(&huge)
        .unwrap()
        .set_len(MAX_PARSED_BYTES + 1)
        .unwrap();
    let e = load_aff(&huge, None).unwrap_err();
    assert!(matches!(e, MeshError::TooLarge { .. }), "{e}");
    assert!(e.to_string().contains("huge.aff"), "{e}");

    // `load_with` lowers the budget of a scene to its limit.
    let museum = bart("museum/museum5.aff");
    let limits = LoadLimits {
        max_file_bytes: 100_000,
    };
    let e = load_with(&museum, None, &limits).unwrap_err();
    assert!(matches!(e.innermost(), MeshError::TooLarge { .. }), "{e}");
    assert!(e.to_string().contains("100000 bytes"), "{e}");
    let limits = LoadLimits {
        max_file_bytes: 100_000_000,
    };
    assert_eq!(
        load_with(&museum, None, &limits).unwrap(),
        load(&museum).unwrap()
    );
}

// ---------------------------------------------------------------------------------------------
// Random mutations

const SEED_SCENE: &str = "b 0.5 0.5 1\nv\nfrom 0 1 5\nat 0 0 0\nup 0 1 0\nangle 40\nhither 0.1\n\
resolution 32 24\nam 1 1 1\nl 1 5 1 1 1 1\na 0 2 10\n\
fm 0.2 0.2 0.2 0.4 0.4 0.4 0.5 0.5 0.5 20 0 1\n\
xs 1 2 1 0 1 0 30 0.5 0 0 {\n p 4 0 0 0 1 0 0 1 1 0 0 1 0\n i 0 part.aff\n}\n\
x spin {\n tt t.ppm 0 0 1 0 0 1 0 1 1 0 0 1 1 0 1\n c 0 0 0 1 0 1 0 0\n}\n\
k spin {\n transl 4\n -1 0 0 0 0 0 0\n 0 0 0 0 0 0 0\n 1 1 0 0 0 0 0\n 2 2 0 0 0 0 0\n\
 rot 4\n -1 0 1 0 0 0 0 0\n 0 0 1 0 90 0 0 0\n 1 0 1 0 180 0 0 0\n 2 0 1 0 270 0 0 0\n}\n\
tpa 2\n0 0 0 0 0 0 1 1 0 0 0 0 1 0 1 0 0 0 1\n2 0 0 1 0 0 1 1 0 1 0 0 1 0 1 1 0 0 1\n\
s 0 3 0 0.5\n";

const PART: &str = "m\nvertices 4\n0 0 0\n1 0 0\n1 1 0\n0 1 0\nnormals 1\n0 0 1\n\
texturecoords 2 w.ppm\n0 0\n1 1\ntriangles 2\n0 1 2 0 0 0 0 1 1\n0 2 3 0 0 0 0 1 0\n";

const WORDS: &[&str] = &[
    " ",
    "\n",
    "{",
    "}",
    "0",
    "-1",
    "3",
    "4",
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "99999999999",
    "18446744073709551616",
    "xs",
    "x",
    "k",
    "m",
    "p",
    "tpa",
    "i 0 part.aff",
    "i 0 top.aff",
    "i 0 missing.aff",
    "vertices",
    "triangles",
    "normals",
    "transl",
    "rot",
    "scale",
    "visibility",
    "#",
    "%",
    "v",
    "from",
    "resolution",
    "c",
    "s",
    "}",
    "{",
    "0.0000001",
];

fn mutate(rng: &mut SplitMix64, text: &[u8]) -> Vec<u8> {
    let mut out = text.to_vec();
    let edits = 1 + rng.next_u64() % 4;
    for _ in 0..edits {
        let len = out.len().max(1);
        let at = (rng.next_u64() % len as u64) as usize;
        match rng.next_u64() % 8 {
            6 | 7 => {
                // Change a digit: mostly keeps the scene readable, moves things around.
                if let Some(i) = (0..out.len())
                    .map(|k| (at + k) % out.len())
                    .find(|&i| out[i].is_ascii_digit())
                {
                    out[i] = b'0' + (rng.next_u64() % 10) as u8;
                }
            }
            0 => {
                if !out.is_empty() {
                    let i = at.min(out.len() - 1);
                    out[i] = (rng.next_u64() % 256) as u8;
                }
            }
            1 => {
                let end = (at + 1 + (rng.next_u64() % 12) as usize).min(out.len());
                out.drain(at.min(out.len())..end);
            }
            2 => out.truncate(at),
            _ => {
                let w = WORDS[(rng.next_u64() % WORDS.len() as u64) as usize];
                let at = at.min(out.len());
                out.splice(at..at, format!(" {w} ").into_bytes());
            }
        }
    }
    out
}

#[test]
fn random_mutations_never_panic() {
    let mut rng = SplitMix64::new(0xAFF);
    let base = parse_files(&[("top.aff", SEED_SCENE), ("part.aff", PART)], None).unwrap();
    assert_eq!(base.faces(), 4);
    let (mut ok, mut err) = (0, 0);
    for round in 0..4000 {
        let mut top = SEED_SCENE.as_bytes().to_vec();
        let mut part = PART.as_bytes().to_vec();
        if round % 3 == 0 {
            part = mutate(&mut rng, &part);
        } else {
            top = mutate(&mut rng, &top);
        }
        let map: HashMap<PathBuf, Vec<u8>> = [
            (PathBuf::from("mem/top.aff"), top.clone()),
            (PathBuf::from("mem/part.aff"), part),
        ]
        .into_iter()
        .collect();
        let time = [None, Some(-3.0), Some(0.7), Some(1e300)][round % 4];
        let r = parse_aff_with(&top, Path::new("mem/top.aff"), time, &mut |p: &Path| {
            map.get(p)
                .cloned()
                .ok_or_else(|| io::Error::new(io::ErrorKind::NotFound, "no such file"))
        });
        match r {
            Ok(s) => {
                ok += 1;
                let n = s.mesh.positions.len();
                assert!(s.mesh.triangles.iter().flatten().all(|&i| (i as usize) < n));
                assert!(s.mesh.positions.iter().flatten().all(|c| c.is_finite()));
            }
            Err(e) => {
                err += 1;
                assert!(!e.to_string().is_empty());
            }
        }
    }
    eprintln!("{ok} mutated scenes read, {err} rejected");
    assert!(ok > 150 && err > 150, "{ok} ok, {err} errors");
}

// ---------------------------------------------------------------------------------------------
// The binaries: oavm-pack --time, oavm-trace --view

fn run(cmd: &mut std::process::Command) -> std::process::Output {
    cmd.stdin(std::process::Stdio::null())
        .output()
        .expect("cannot spawn the binary")
}

fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    let be = |o: usize| u32::from_be_bytes(b[o..o + 4].try_into().unwrap());
    (be(16), be(20))
}

#[test]
fn pack_poses_a_scene_at_a_time_and_trace_takes_its_view() {
    let museum = bart("museum/museum5.aff");
    let dir = tempfile::tempdir().unwrap();
    let pack = env!("CARGO_BIN_EXE_oavm-pack");
    let trace = env!("CARGO_BIN_EXE_oavm-trace");
    let (a, b) = (dir.path().join("a.oavm"), dir.path().join("b.oavm"));
    for (out, t) in [(&a, "0.5"), (&b, "-0.5")] {
        let o = run(std::process::Command::new(pack)
            .arg(&museum)
            .arg(out)
            .arg(format!("--time={t}"))
            .arg("--json"));
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["time"].as_f64(), Some(t.parse().unwrap()));
        assert_eq!(v["input_triangles"].as_u64(), Some(11_564));
    }
    assert_ne!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());

    // A time for a PLY file is an error that says why.
    let bunny = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bunny.ply");
    let o = run(std::process::Command::new(pack)
        .arg(&bunny)
        .arg(dir.path().join("c.oavm"))
        .args(["--time", "1"]));
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("only BART AFF scenes"));

    // --view: the scene's resolution unless --width/--height say otherwise.
    let png = dir.path().join("m.png");
    let o = run(std::process::Command::new(trace)
        .arg(&a)
        .arg("--view")
        .arg(&museum)
        .arg("-o")
        .arg(&png));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(png_size(&png), (800, 600));
    let o = run(std::process::Command::new(trace)
        .arg(&a)
        .arg("--view")
        .arg(&museum)
        .args(["--width", "64", "-o"])
        .arg(&png));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(png_size(&png), (64, 600));
    // --view and --eye do not go together.
    let o = run(std::process::Command::new(trace)
        .arg(&a)
        .arg("--view")
        .arg(&museum)
        .args(["--eye", "0,0,0"]));
    assert_eq!(o.status.code(), Some(2));
}
