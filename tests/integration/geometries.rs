//! Several meshes in one file (format-spec §8.8): the geometry table written by `oavm-pack A B
//! OUT`, by a glTF scene and by `pack_mesh` with geometries; what it changes (nothing but the
//! table: the same blocks, the same answers) and what it maps (each hit's primitive to its
//! geometry and its index there, checked against the meshes' own triangle counts); kept by
//! ropes, occluders, compaction and updates, which grow, replace or refuse it as documented.

use std::path::Path;

use oavm::mesh::Geometry;
use oavm::pack::update::{UpdateOptions, Updater};
use oavm::pack::{PackOptions, Quiet};
use oavm::physical::format::SectionKind;
use oavm::rays::random_rays;
use oavm::{Hit, Mesh, Scene};
use tempfile::TempDir;

use crate::common::{self, bin, run};

const BUNNY: &str = "bunny/bun_zipper.ply";
const CORNELL: &str = "cornell_box/CornellBox-Original.obj";

fn geometry(name: &str, first: u64, count: u64) -> Geometry {
    Geometry {
        name: name.into(),
        first_primitive: first,
        primitive_count: count,
        transform: Geometry::IDENTITY,
    }
}

/// Closest hits of `scene` to `rays`, as (bits of t, primitive).
fn answers(scene: &Scene, rays: &[oavm::Ray]) -> Vec<(u32, u32)> {
    let mut hits = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(rays, &mut hits).unwrap();
    hits.iter().map(|h| (h.t.to_bits(), h.prim)).collect()
}

#[test]
fn several_mesh_files_are_one_file_with_a_table() {
    let dir = TempDir::new().unwrap();
    let (bunny, cornell) = (common::shared_scene(BUNNY), common::shared_scene(CORNELL));
    let (nb, nc) = (
        common::load_shared(BUNNY).triangles.len() as u64,
        common::load_shared(CORNELL).triangles.len() as u64,
    );
    let both = dir.path().join("both.oavm");
    let (o, _, err) = run(bin("oavm-pack").arg(&bunny).arg(&cornell).arg(&both));
    assert!(o.status.success(), "{err}");

    // The same triangles as one mesh, without a table.
    let joined = Mesh::join(vec![
        ("a".into(), common::load_shared(BUNNY)),
        ("b".into(), common::load_shared(CORNELL)),
    ])
    .unwrap();
    let plain_mesh = Mesh {
        geometries: Vec::new(),
        ..joined.clone()
    };
    let plain = dir.path().join("plain.oavm");
    oavm::pack::pack_mesh(plain_mesh, "plain", &plain, &PackOptions::default(), &Quiet).unwrap();

    let s = Scene::open(&both).unwrap();
    assert_eq!(
        s.geometries(),
        [
            geometry("bun_zipper.ply", 0, nb),
            geometry("CornellBox-Original.obj", nb, nc)
        ]
    );
    let p = Scene::open(&plain).unwrap();
    assert!(p.geometries().is_empty());
    // Nothing but the table differs: the blocks, byte for byte, and so every answer.
    assert_eq!(
        s.file().section_bytes(SectionKind::Blocks),
        p.file().section_bytes(SectionKind::Blocks)
    );
    // Rays through the whole scene and through the bunny's box (the bunny is small in it).
    let mut rays = random_rays(&common::bounds(&joined), 10_000, 5);
    rays.extend(random_rays(
        &common::bounds(&common::load_shared(BUNNY)),
        10_000,
        6,
    ));
    let (a, b) = (answers(&s, &rays), answers(&p, &rays));
    assert_eq!(a, b);
    // Hits on both meshes, each located where its mesh's triangles are.
    let mut per = [0usize; 2];
    for &(_, prim) in a.iter().filter(|h| h.1 != Hit::MISS.prim) {
        let (g, local) = s.locate(prim).unwrap();
        let want = if (prim as u64) < nb {
            (0, prim as u64)
        } else {
            (1, prim as u64 - nb)
        };
        assert_eq!((g, local), want, "primitive {prim}");
        per[g as usize] += 1;
    }
    assert!(per[0] > 100 && per[1] > 100, "hits per geometry {per:?}");
    assert_eq!(s.locate((nb + nc) as u32), None);
    // A file of one mesh locates everything in geometry 0.
    assert_eq!(p.locate(7), Some((0, 7)));

    // inspect lists the table; --mem-budget (a streamed PLY) is refused for several meshes.
    let (o, out, _) = run(bin("oavm-inspect").arg(&both).arg("--json"));
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["geometries"]["Ok"][1]["name"], "CornellBox-Original.obj");
    assert_eq!(v["geometries"]["Ok"][1]["first_primitive"], nb);
    let refused = dir.path().join("refused.oavm");
    let (o, _, err) = run(bin("oavm-pack")
        .arg(&bunny)
        .arg(&cornell)
        .arg(&refused)
        .args(["--mem-budget", "64M"]));
    assert!(
        !o.status.success() && err.contains("several meshes"),
        "{err}"
    );
    assert!(!refused.exists());
}

#[test]
fn passes_over_a_file_keep_its_table() {
    let dir = TempDir::new().unwrap();
    let mut mesh = common::load_shared(BUNNY);
    let n = mesh.triangles.len() as u64;
    mesh.geometries = vec![geometry("ears", 0, 1000), geometry("rest", 1000, n - 1000)];
    mesh.geometries[1].transform[0][3] = 2.5;
    let opts = |ropes, occluders| PackOptions {
        ropes,
        occluders,
        ..PackOptions::default()
    };
    for (name, o) in [
        ("ropes", opts(true, false)),
        ("occluders", opts(false, true)),
    ] {
        let path = dir.path().join(format!("{name}.oavm"));
        oavm::pack::pack_mesh(mesh.clone(), name, &path, &o, &Quiet).unwrap();
        assert_eq!(
            Scene::open(&path).unwrap().geometries(),
            mesh.geometries,
            "{name}"
        );
    }
    let path = dir.path().join("u.oavm");
    let updatable = PackOptions {
        updatable: true,
        ..PackOptions::default()
    };
    oavm::pack::pack_mesh(mesh.clone(), "u", &path, &updatable, &Quiet).unwrap();
    let mut u = Updater::open(&path).unwrap();
    assert_eq!(u.geometries(), mesh.geometries);
    u.insert(mesh.triangle(0)).unwrap();
    u.commit(&UpdateOptions::default()).unwrap();
    let s = Scene::open(&path).unwrap();
    assert_eq!(
        s.geometries()[1].primitive_count,
        n - 1000 + 1,
        "an insert joins the last"
    );
    assert_eq!(s.locate(n as u32), Some((1, n - 1000)));
    drop(s);
    let compacted = dir.path().join("c.oavm");
    oavm::pack::update::compact(&path, &compacted).unwrap();
    assert_eq!(
        Scene::open(&compacted).unwrap().geometries(),
        Scene::open(&path).unwrap().geometries()
    );
}

#[test]
fn an_update_replaces_keeps_or_refuses_the_table() {
    let dir = TempDir::new().unwrap();
    let mut mesh = common::load_shared(BUNNY);
    let n = mesh.triangles.len() as u64;
    mesh.geometries = vec![geometry("a", 0, 100), geometry("b", 100, n - 100)];
    let path = dir.path().join("u.oavm");
    let updatable = PackOptions {
        updatable: true,
        ..PackOptions::default()
    };
    oavm::pack::pack_mesh(mesh.clone(), "u", &path, &updatable, &Quiet).unwrap();
    let tables = |p: &Path| Scene::open(p).unwrap().geometries().to_vec();

    // A mesh without geometries, shorter: the last geometry ends where it does.
    let mut shorter = mesh.clone();
    shorter.geometries.clear();
    shorter.triangles.truncate(n as usize - 50);
    let mut u = Updater::open(&path).unwrap();
    u.set_mesh(&shorter).unwrap();
    u.commit(&UpdateOptions::default()).unwrap();
    assert_eq!(
        tables(&path),
        [geometry("a", 0, 100), geometry("b", 100, n - 150)]
    );

    // One shorter than the last geometry's start: refused, the file as it was.
    let mut tiny = shorter.clone();
    tiny.triangles.truncate(50);
    let mut u = Updater::open(&path).unwrap();
    let e = u.set_mesh(&tiny).unwrap_err().to_string();
    assert!(e.contains("give the new mesh's geometries"), "{e}");
    drop(u);
    assert_eq!(tables(&path)[1].primitive_count, n - 150);

    // A mesh with geometries replaces the table; one whose table does not cover it is refused.
    let mut three = mesh.clone();
    three.geometries = vec![
        geometry("x", 0, 10),
        geometry("y", 10, 10),
        geometry("z", 20, n - 20),
    ];
    let mut u = Updater::open(&path).unwrap();
    u.set_mesh(&three).unwrap();
    u.commit(&UpdateOptions::default()).unwrap();
    assert_eq!(tables(&path), three.geometries);
    let mut bad = three.clone();
    bad.geometries[2].primitive_count -= 1;
    let e = Updater::open(&path)
        .unwrap()
        .set_mesh(&bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("hold"), "{e}");
}

#[test]
fn a_gltf_scene_is_a_geometry_per_node() {
    // The cornell box's triangles as a glTF of two nodes placing one mesh: one as it is, one
    // moved 3 along x; the file's table names the nodes and the second's transform.
    let dir = TempDir::new().unwrap();
    let m = common::load_shared(CORNELL);
    let mut bin = Vec::new();
    for p in &m.positions {
        p.iter()
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    let idx_at = bin.len();
    for t in &m.triangles {
        t.iter()
            .for_each(|i| bin.extend_from_slice(&i.to_le_bytes()));
    }
    use base64::Engine;
    let uri = base64::engine::general_purpose::STANDARD.encode(&bin);
    let b = common::bounds(&m);
    let (lo, hi) = (b.min, b.max);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0,1]}}],
        "nodes":[{{"name":"box","mesh":0}},{{"name":"moved","mesh":0,"translation":[3,0,0]}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "buffers":[{{"byteLength":{len},"uri":"data:application/octet-stream;base64,{uri}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{idx_at}}},
                       {{"buffer":0,"byteOffset":{idx_at},"byteLength":{il}}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":{nv},"type":"VEC3",
                       "min":{lo:?},"max":{hi:?}}},
                     {{"bufferView":1,"componentType":5125,"count":{ni},"type":"SCALAR"}}]}}"#,
        len = bin.len(),
        il = bin.len() - idx_at,
        nv = m.positions.len(),
        ni = 3 * m.triangles.len(),
    );
    let gltf = dir.path().join("two.gltf");
    std::fs::write(&gltf, json).unwrap();
    let out = dir.path().join("two.oavm");
    common::pack(&gltf, &out, &[]);
    let s = Scene::open(&out).unwrap();
    let nt = m.triangles.len() as u64;
    let mut moved = Geometry::IDENTITY;
    moved[0][3] = 3.0;
    let want = [
        geometry("box", 0, nt),
        Geometry {
            transform: moved,
            ..geometry("moved", nt, nt)
        },
    ];
    assert_eq!(s.geometries(), want);
}
