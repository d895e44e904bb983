//! Local updates written as generations (format-spec §2.1, §8.6; `oavm::pack::update`):
//!
//! - after any sequence of updates, a file answers every ray set exactly as a fresh pack of the
//!   same triangles (closest hit `t` and primitive bit for bit, any hit), passes verify, and
//!   agrees with the f64 brute force on both outcomes;
//! - the updates do reach the cases the paper's section 3 names: blocks emptied whole (a link
//!   turns into an empty leaf of the top tree and merges with its siblings), empty top-tree
//!   leaves filled, triangles inserted past the end and removed;
//! - readers that opened a generation keep answering as it while later ones are written;
//! - what an update refuses (a file without the primitive table, geometry outside the root
//!   cube, a second updater) leaves the file byte for byte as it was.

use crate::common;

use std::path::Path;

use crate::common::{compare_with_reference, shared_scene};
use oavm::pack::update::{UpdateOptions, UpdateReport, Updater};
use oavm::pack::{PackOptions, Quiet};
use oavm::rays::{self, Bounds, Camera};
use oavm::{Hit, Mesh, Ray, Scene};
use tempfile::TempDir;

/// Ray sets over `bounds`: random rays through the scene, primary rays of a view framing it,
/// and shadow rays from their hits to a light above.
fn ray_sets(scene: &Scene<oavm::os::MappedFile>, bounds: &Bounds) -> Vec<Ray> {
    let mut all = rays::random_rays(bounds, 30_000, 11);
    let primary = Camera::framing(bounds).primary_rays(160, 120);
    let mut hits = vec![Hit::MISS; primary.len()];
    scene.intersect_batch(&primary, &mut hits).unwrap();
    let c = bounds.centre();
    let light = [c[0] as f32, (c[1] + bounds.diagonal()) as f32, c[2] as f32];
    all.extend(rays::shadow_rays(&primary, &hits, light));
    all.extend(primary);
    all
}

/// Closest hits (bits of `t`, primitive) and any-hit answers of `scene` to `rays`.
fn answers<D: AsRef<[u8]> + oavm::logical::BlockSource>(
    scene: &Scene<D>,
    rays: &[Ray],
) -> (Vec<(u32, u32)>, Vec<u8>) {
    let mut hits = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(rays, &mut hits).unwrap();
    let mut occ = vec![0u8; rays.len()];
    scene.occluded_batch(rays, &mut occ).unwrap();
    (hits.iter().map(|h| (h.t.to_bits(), h.prim)).collect(), occ)
}

fn pack_mesh(mesh: &Mesh, out: &Path, updatable: bool) {
    let opts = PackOptions {
        updatable,
        ..PackOptions::default()
    };
    oavm::pack::pack_mesh(mesh.clone(), "test mesh", out, &opts, &Quiet).unwrap();
}

fn verify(path: &Path) {
    let scene = Scene::open(path).unwrap();
    let r = scene.verify().unwrap();
    assert!(r.is_ok(), "{}: {:?}", path.display(), r.defects);
}

/// The updated file at `updated` answers as a fresh pack of `mesh` on rays through `bounds`,
/// has its triangle counts and mesh bounds, verifies, and agrees with the f64 reference (which
/// must find hits).
fn check_same_as_fresh(updated: &Path, mesh: &Mesh, bounds: &Bounds, what: &str) {
    verify(updated);
    let dir = TempDir::new().unwrap();
    let fresh = dir.path().join("fresh.oavm");
    pack_mesh(mesh, &fresh, false);
    let a = Scene::open(updated).unwrap();
    let b = Scene::open(&fresh).unwrap();
    // The header's counts and mesh bounds are the fresh pack's too (an update that moves a
    // triangle off the bounds finds them again over the whole primitive table).
    let counts = |s: &Scene<oavm::os::MappedFile>| {
        let h = *s.file().header();
        (
            h.input_triangles,
            h.stored_triangles,
            h.mesh_min,
            h.mesh_max,
        )
    };
    assert_eq!(
        counts(&a),
        counts(&b),
        "{what}: header counts and mesh bounds"
    );
    let rays = ray_sets(&b, bounds);
    let (ha, oa) = answers(&a, &rays);
    let (hb, ob) = answers(&b, &rays);
    let hit_count = hb.iter().filter(|h| h.1 != u32::MAX).count();
    assert!(hit_count >= 1000, "{what}: only {hit_count} hits");
    let differ = ha.iter().zip(&hb).filter(|(x, y)| x != y).count();
    assert_eq!(
        differ, 0,
        "{what}: {differ} closest hits differ from a fresh pack"
    );
    assert_eq!(oa, ob, "{what}: any-hit answers differ from a fresh pack");
    compare_with_reference(mesh, &a, &rays, 29).require(20, 2, what);
}

fn commit(u: Updater) -> UpdateReport {
    u.commit(&UpdateOptions::default()).unwrap()
}

/// The kitchen, packed at time 0 and updated frame by frame through its animation (forward,
/// then back to an earlier time), answers as a fresh pack of each frame; each update rebuilds a
/// few of its blocks, not all.
#[test]
fn kitchen_frames_answer_as_fresh_packs() {
    let scene = shared_scene("bart/kitchen/kitchen.aff");
    let dir = TempDir::new().unwrap();
    let file = dir.path().join("kitchen.oavm");
    let frames = [0.0, 7.5, 19.0, 3.0];
    let meshes: Vec<Mesh> = frames
        .iter()
        .map(|&t| oavm::mesh::load_at(&scene, Some(t)).unwrap())
        .collect();
    pack_mesh(&meshes[0], &file, true);
    let mut rebuilt_some = false;
    for (i, (&t, mesh)) in frames.iter().zip(&meshes).enumerate().skip(1) {
        let mut u = Updater::open(&file).unwrap();
        let changed = u.set_mesh(mesh).unwrap();
        let r = commit(u);
        assert_eq!(r.generation, i as u64 + 1);
        assert!(changed > 0, "frame {t}: nothing moved");
        assert!(r.moved > 0 && r.blocks_rebuilt > 0, "{r:?}");
        assert!(
            r.blocks_rebuilt < r.blocks_before / 2,
            "frame {t}: {} of {} blocks rebuilt: not local",
            r.blocks_rebuilt,
            r.blocks_before
        );
        rebuilt_some = true;
        check_same_as_fresh(
            &file,
            mesh,
            &common::bounds(mesh),
            &format!("kitchen at {t}"),
        );
    }
    assert!(rebuilt_some);
}

/// A grid of small separated quads: many blocks, so that edits can empty some whole and fill
/// empty regions of the top tree.
fn quads(n: u32, size: f32) -> Mesh {
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..4 {
                let (x, y, z) = (i as f32 * 2.0, j as f32 * 2.0, (k * 7 % 5) as f32 * 2.0);
                let b = positions.len() as u32;
                positions.extend([
                    [x, y, z],
                    [x + size, y, z + 0.1],
                    [x + size, y + size, z],
                    [x, y + size, z + 0.1],
                ]);
                triangles.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
            }
        }
    }
    common::mesh(positions, triangles)
}

/// Edits by primitive id: a region emptied (whole blocks removed: links become empty leaves
/// merged with their siblings), triangles inserted past the end into an empty part of the
/// root cube (empty top-tree leaves filled), a block's worth moved by a transform, a few
/// removed; each state answers as a fresh pack of the same triangles.
#[test]
fn edits_by_primitive_id_answer_as_fresh_packs() {
    let mut mesh = quads(24, 1.2);
    // One far corner triangle, so that the root cube has empty room in its far part.
    let b = mesh.positions.len() as u32;
    mesh.positions
        .extend([[80.0, 80.0, 80.0], [79.0, 80.0, 80.0], [80.0, 79.0, 80.0]]);
    mesh.triangles.push([b, b + 1, b + 2]);
    let bounds = common::bounds(&mesh);
    let dir = TempDir::new().unwrap();
    let file = dir.path().join("quads.oavm");
    let opts = PackOptions {
        updatable: true,
        blocks: oavm::physical::BlockOptions {
            block_size: 16 * 1024,
            compress: None,
            chunk_groups: 8,
            lean: false,
        },
        ..PackOptions::default()
    };
    oavm::pack::pack_mesh(mesh.clone(), "quads", &file, &opts, &Quiet).unwrap();
    let mut current: Vec<Option<[[f32; 3]; 3]>> = (0..mesh.triangles.len())
        .map(|i| Some(mesh.triangle(i)))
        .collect();
    let as_mesh = |tris: &[Option<[[f32; 3]; 3]>]| -> Mesh {
        // Removed primitives stay as degenerate triangles, which hold the id and no triangle.
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        for t in tris {
            let v = t.unwrap_or([[0.0; 3]; 3]);
            let b = positions.len() as u32;
            positions.extend(v);
            triangles.push([b, b + 1, b + 2]);
        }
        common::mesh(positions, triangles)
    };

    // 1. Empty a whole region: every quad with i < 8.
    let mut u = Updater::open(&file).unwrap();
    for (p, t) in current.iter_mut().enumerate() {
        if t.is_some_and(|v| v[0][0] < 16.0) {
            u.remove(p as u32).unwrap();
            *t = None;
        }
    }
    let r = commit(u);
    assert!(r.removed > 1000 && r.blocks_rebuilt > 0, "{r:?}");
    assert!(
        r.top_empty_after > r.top_empty_before,
        "emptied blocks did not become empty top-tree leaves: {r:?}"
    );
    check_same_as_fresh(&file, &as_mesh(&current), &bounds, "region emptied");

    // 2. Insert triangles past the end, in the empty far part of the root cube.
    let mut u = Updater::open(&file).unwrap();
    for i in 0..40 {
        let x = 60.0 + i as f32 * 0.4;
        let v = [[x, 5.0, 40.0], [x + 0.3, 5.0, 40.0], [x, 6.0, 41.0]];
        let p = u.insert(v).unwrap();
        assert_eq!(p as usize, current.len());
        current.push(Some(v));
    }
    let r = commit(u);
    assert_eq!(r.inserted, 40, "{r:?}");
    assert!(r.empty_leaves_filled > 0, "{r:?}");
    check_same_as_fresh(&file, &as_mesh(&current), &bounds, "inserted past the end");

    // 3. Move an object (the quads of column 12) by a transform, and remove a few others.
    let mut u = Updater::open(&file).unwrap();
    let m = glam::DAffine3::from_rotation_translation(
        glam::DQuat::from_rotation_z(0.3),
        glam::DVec3::new(1.5, -0.5, 2.0),
    );
    let column: Vec<u32> = (0..current.len() as u32)
        .filter(|&p| current[p as usize].is_some_and(|v| (24.0..25.5).contains(&v[0][0])))
        .collect();
    assert!(!column.is_empty());
    for &p in &column {
        u.transform(p..p + 1, &m).unwrap();
        current[p as usize] = u.triangle(p);
    }
    for p in (3000..3100).step_by(7) {
        u.remove(p).unwrap();
        current[p as usize] = None;
    }
    let r = commit(u);
    assert!(r.moved as usize >= column.len() && r.removed > 0, "{r:?}");
    check_same_as_fresh(&file, &as_mesh(&current), &bounds, "moved and removed");

    // 4. Put the region back.
    let mut u = Updater::open(&file).unwrap();
    for p in 0..mesh.triangles.len() as u32 {
        if current[p as usize].is_none() {
            u.set(p, mesh.triangle(p as usize)).unwrap();
            current[p as usize] = Some(mesh.triangle(p as usize));
        }
    }
    let r = commit(u);
    assert!(r.inserted > 1000, "{r:?}");
    assert!(r.top_empty_after < r.top_empty_before, "{r:?}");
    check_same_as_fresh(&file, &as_mesh(&current), &bounds, "region filled again");
    assert_eq!(Scene::open(&file).unwrap().file().header().generation, 5);
}

/// A reader that opened a generation answers as it, bit for bit, while later generations are
/// written, and a reader that opens after an update answers as the new one.
#[test]
fn readers_keep_their_generation() {
    let mesh = common::load_shared("bunny/bun_zipper.ply");
    let bounds = common::bounds(&mesh);
    let dir = TempDir::new().unwrap();
    let file = dir.path().join("bunny.oavm");
    // Room above the bunny for its top to move into.
    let opts = PackOptions {
        updatable: true,
        bounds: Some((
            bounds.min,
            [bounds.max[0], bounds.max[1] + 0.05, bounds.max[2]],
        )),
        ..PackOptions::default()
    };
    oavm::pack::pack_mesh(mesh.clone(), "bunny", &file, &opts, &Quiet).unwrap();
    let first = Scene::open(&file).unwrap();
    let rays = ray_sets(&first, &bounds);
    let before = answers(&first, &rays);

    // Three updates: move the bunny's upper half up a little, then further.
    let mut moved = mesh.clone();
    for step in 1..=3 {
        for p in moved.positions.iter_mut() {
            if p[1] > 0.12 {
                p[1] += 0.002;
            }
        }
        let mut u = Updater::open(&file).unwrap();
        u.set_mesh(&moved).unwrap();
        let r = commit(u);
        assert_eq!(r.generation, step + 1);
        // The first reader still reads generation 1: same answers as before any update.
        assert!(answers(&first, &rays) == before, "after update {step}");
    }
    let last = Scene::open(&file).unwrap();
    assert_eq!(last.file().header().generation, 4);
    let after = answers(&last, &rays);
    assert!(after != before, "the updates changed no answer");
    check_same_as_fresh(&file, &moved, &bounds, "bunny moved");
}

/// What an update refuses leaves the file as it was, with an error that says why.
#[test]
fn refused_updates_leave_the_file_as_it_was() {
    let mesh = common::load_shared("bunny/bun_zipper.ply");
    let dir = TempDir::new().unwrap();
    let plain = dir.path().join("plain.oavm");
    pack_mesh(&mesh, &plain, false);
    let e = Updater::open(&plain).err().unwrap().to_string();
    assert!(e.contains("--updatable"), "{e}");

    let file = dir.path().join("bunny.oavm");
    pack_mesh(&mesh, &file, true);
    let bytes = std::fs::read(&file).unwrap();
    // Outside the root cube.
    let mut u = Updater::open(&file).unwrap();
    u.set(0, [[5.0, 0.0, 0.0], [5.1, 0.0, 0.0], [5.0, 0.1, 0.0]])
        .unwrap();
    let e = u
        .commit(&UpdateOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("outside the file's root cube"), "{e}");
    assert!(std::fs::read(&file).unwrap() == bytes);
    // Past the primitives, and non-finite corners.
    let mut u = Updater::open(&file).unwrap();
    assert!(u.set(mesh.triangles.len() as u32, [[0.0; 3]; 3]).is_err());
    assert!(
        u.set(0, [[f32::NAN, 0.0, 0.0], [0.0; 3], [0.0; 3]])
            .is_err()
    );
    // A second updater while one holds the file.
    let e = Updater::open(&file).err().unwrap().to_string();
    assert!(e.contains("another update holds the file"), "{e}");
    drop(u);
    assert!(std::fs::read(&file).unwrap() == bytes);
    assert!(Updater::open(&file).is_ok());
}

/// An update only appends and writes the other header slot (format-spec §2.1): every byte of
/// the previous generation is as it was. A crash can leave any prefix of the appended bytes,
/// or a torn header slot: each such file opens as the previous generation (or, once the slot is
/// whole, the new one), verifies, and answers as it; a later update works on it.
#[test]
fn interrupted_updates_leave_a_readable_generation() {
    let mesh = common::load_shared("bunny/bun_zipper.ply");
    let bounds = common::bounds(&mesh);
    let dir = TempDir::new().unwrap();
    let file = dir.path().join("bunny.oavm");
    pack_mesh(&mesh, &file, true);
    let old = std::fs::read(&file).unwrap();
    let rays = ray_sets(&Scene::open(&file).unwrap(), &bounds);
    let before = answers(&Scene::open(&file).unwrap(), &rays);
    let mut moved = mesh.clone();
    for p in moved.positions.iter_mut().filter(|p| p[1] > 0.1) {
        p[0] += 0.003;
    }
    let mut u = Updater::open(&file).unwrap();
    u.set_mesh(&moved).unwrap();
    commit(u);
    let new = std::fs::read(&file).unwrap();
    let after = answers(&Scene::open(&file).unwrap(), &rays);
    assert!(after != before);
    let (slot, data) = (2048..4096, 4096..old.len());
    assert!(old[slot.clone()].iter().all(|&b| b == 0));
    assert!(new[..2048] == old[..2048], "slot 0 was written");
    assert!(
        new[data.clone()] == old[data.clone()],
        "the previous generation's bytes changed"
    );
    assert!(new.len() > old.len());

    let check = |bytes: &[u8], generation: u64, want: &(Vec<(u32, u32)>, Vec<u8>), what: &str| {
        let p = dir.path().join("crashed.oavm");
        std::fs::write(&p, bytes).unwrap();
        let s = Scene::open(&p).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(s.file().header().generation, generation, "{what}");
        let r = s.verify().unwrap();
        assert!(r.is_ok(), "{what}: {:?}", r.defects);
        assert!(answers(&s, &rays) == *want, "{what}: answers");
        p
    };
    // Any prefix of the appended bytes, the slot not yet written.
    let appended = old.len()..new.len();
    for i in 0..12 {
        let cut = appended.start + (appended.len() * i) / 11;
        let mut b = new[..cut].to_vec();
        b[slot.clone()].fill(0);
        check(&b, 1, &before, &format!("appended bytes cut at {cut}"));
    }
    // All appended, the new slot torn after n bytes (the rest as it was: zero), or garbage.
    for n in [1, 8, 100, 255, 256, 300, 600] {
        let mut b = new.clone();
        b[2048 + n..4096].fill(0);
        check(&b, 1, &before, &format!("slot torn after {n} bytes"));
    }
    let mut b = new.clone();
    b[2048 + 40] ^= 0x10;
    check(&b, 1, &before, "slot with a flipped bit");
    let p = check(&new, 2, &after, "the whole update");
    // An update on a crashed file (appended bytes cut half way) works, after them.
    let mut b = new[..appended.start + appended.len() / 2].to_vec();
    b[slot].fill(0);
    let p2 = check(&b, 1, &before, "half appended");
    let mut u = Updater::open(&p2).unwrap();
    u.set_mesh(&moved).unwrap();
    let r = commit(u);
    assert_eq!(r.generation, 2);
    check(
        &std::fs::read(&p2).unwrap(),
        2,
        &after,
        "updated after a crash",
    );
    let _ = p;
}

/// `oavm-pack --updatable`, `oavm-update` with a BART scene at a time, `--json`, and
/// `--compact`: the file after each answers as a fresh pack of the frame; the compacted file is
/// generation 1, smaller, with no free entry, and answers the same.
#[test]
fn cli_updates_and_compacts() {
    let scene = shared_scene("bart/kitchen/kitchen.aff");
    let dir = TempDir::new().unwrap();
    let file = dir.path().join("k.oavm");
    common::pack(&scene, &file, &["--updatable", "--time", "0"]);
    for t in ["6", "9.5"] {
        let (out, stdout, stderr) = common::run(
            common::bin("oavm-update")
                .arg(&file)
                .arg(&scene)
                .args(["--time", t, "--json"]),
        );
        assert!(out.status.success(), "{stderr}");
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert!(v["update"]["moved"].as_u64().unwrap() > 0, "{stdout}");
        assert!(
            v["update"]["bytes_written"].as_u64().unwrap() > 0,
            "{stdout}"
        );
    }
    let mesh = oavm::mesh::load_at(&scene, Some(9.5)).unwrap();
    let bounds = common::bounds(&mesh);
    check_same_as_fresh(&file, &mesh, &bounds, "kitchen at 9.5 through the CLI");
    let before = std::fs::metadata(&file).unwrap().len();
    let rays = ray_sets(&Scene::open(&file).unwrap(), &bounds);
    let want = answers(&Scene::open(&file).unwrap(), &rays);
    let (out, stdout, stderr) = common::run(
        common::bin("oavm-update")
            .arg(&file)
            .args(["--compact", "--json"]),
    );
    assert!(out.status.success(), "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["compacted"]["generation"].as_u64(), Some(3), "{stdout}");
    let after = std::fs::metadata(&file).unwrap().len();
    assert!(after < before, "compacting {before} bytes gave {after}");
    let s = Scene::open(&file).unwrap();
    assert_eq!(s.file().header().generation, 1);
    assert!(s.file().directory().iter().all(|e| !e.is_free()));
    assert!(answers(&s, &rays) == want);
    verify(&file);
    // And it updates on.
    let (out, _, stderr) = common::run(
        common::bin("oavm-update")
            .arg(&file)
            .arg(&scene)
            .args(["--time", "12"]),
    );
    assert!(out.status.success(), "{stderr}");
    verify(&file);
    // A file without the table: a clear error, a non-zero exit, the file untouched.
    let plain = dir.path().join("plain.oavm");
    common::pack(&scene, &plain, &[]);
    let bytes = std::fs::read(&plain).unwrap();
    let (out, _, stderr) = common::run(common::bin("oavm-update").arg(&plain).arg(&scene));
    assert!(!out.status.success());
    assert!(stderr.contains("--updatable"), "{stderr}");
    assert!(std::fs::read(&plain).unwrap() == bytes);
}

/// The streaming pack (`--mem-budget`) writes the same primitive table as the in-memory one,
/// and its file updates the same way.
#[test]
fn streamed_updatable_files_update() {
    let mesh = common::load_shared("dragon/dragon_vrip_res3.ply");
    let dir = TempDir::new().unwrap();
    let ply = dir.path().join("dragon.ply");
    std::fs::write(&ply, common::binary_ply(&mesh)).unwrap();
    let b = common::bounds(&mesh);
    let room = (b.min, [b.max[0], b.max[1] + 0.02, b.max[2]]);
    let streamed = dir.path().join("streamed.oavm");
    let opts = PackOptions {
        updatable: true,
        bounds: Some(room),
        mem_budget: Some(4 << 20),
        ..PackOptions::default()
    };
    let r = oavm::pack::pack(&ply, &streamed, &opts, &Quiet).unwrap();
    assert!(
        r.streaming.is_some_and(|s| s.chunks > 1),
        "not streamed in chunks"
    );
    let in_memory = dir.path().join("memory.oavm");
    let opts = PackOptions {
        mem_budget: None,
        ..opts
    };
    oavm::pack::pack(&ply, &in_memory, &opts, &Quiet).unwrap();
    let table = |p: &Path| {
        let s = Scene::open(p).unwrap();
        let f = s.file();
        let chunks: &[oavm::physical::format::PrimChunk] =
            f.records(oavm::physical::format::SectionKind::Prims);
        chunks
            .iter()
            .flat_map(|c| f.bytes()[c.offset as usize..(c.offset + 36 * c.count) as usize].to_vec())
            .collect::<Vec<u8>>()
    };
    assert!(
        table(&streamed) == table(&in_memory),
        "primitive tables differ"
    );
    verify(&streamed);
    let mut moved = mesh.clone();
    for p in moved.positions.iter_mut().filter(|p| p[0] > 0.0) {
        p[1] += 0.01;
    }
    let mut u = Updater::open(&streamed).unwrap();
    u.set_mesh(&moved).unwrap();
    let r = commit(u);
    assert!(r.moved > 1000, "{r:?}");
    check_same_as_fresh(
        &streamed,
        &moved,
        &common::bounds(&moved),
        "streamed dragon moved",
    );
}
