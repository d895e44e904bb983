//! The files the tests damage: the dragon's smallest decimation (or its first triangles) built
//! with clusters or lists, raw or zstd, with ropes, occluders or a primitive table, and updated.

use std::sync::OnceLock;

use oavm::pack::LeafKind;
use oavm::physical::BlockOptions;
use oavm::rays::{Bounds, Camera, SplitMix64, random_rays};
use oavm::{BuildOptions, Mesh, Ray};

use super::*;

pub fn random_dir(rng: &mut SplitMix64) -> [f32; 3] {
    let z = 2.0 * rng.next_f64() - 1.0;
    let phi = std::f64::consts::TAU * rng.next_f64();
    let r = (1.0 - z * z).sqrt();
    [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]
}

/// Random rays around the mesh, a small camera image, rays aimed at random triangles from all
/// sides (so that a part of a mesh still gets hit often), and axis-parallel rays from the
/// centre of the mesh's box (directions with zero components take their own path through the
/// tracer).
pub fn ray_set(mesh: &Mesh, b: &Bounds) -> Vec<Ray> {
    let mut rays = random_rays(b, 192, 0x0a5e);
    rays.extend(Camera::framing(b).primary_rays(16, 12));
    let mut rng = SplitMix64::new(0xa1ed);
    let diag = b.diagonal() as f32;
    for _ in 0..128 {
        let t = mesh.triangle((rng.next_u64() % mesh.triangles.len() as u64) as usize);
        let (u, v) = (rng.next_f64() as f32 * 0.5, rng.next_f64() as f32 * 0.5);
        let aim: [f32; 3] =
            std::array::from_fn(|k| t[0][k] + u * (t[1][k] - t[0][k]) + v * (t[2][k] - t[0][k]));
        let d = random_dir(&mut rng);
        let origin = std::array::from_fn(|k| aim[k] - d[k] * diag);
        rays.push(Ray::new(origin, d, 0.0, f32::INFINITY));
    }
    let c = b.centre().map(|x| x as f32);
    for k in 0..3 {
        for s in [-1.0f32, 1.0] {
            let mut d = [0.0; 3];
            d[k] = s;
            rays.push(Ray::new(c, d, 0.0, f32::INFINITY));
        }
    }
    rays
}

pub fn leaf4() -> BuildOptions {
    BuildOptions {
        leaf_size: 4,
        ..BuildOptions::default()
    }
}

/// Blocks of 16 KiB (about a hundred on the default file), raw or zstd.
pub fn blocks_16k(compress: bool) -> BlockOptions {
    BlockOptions {
        block_size: 16384,
        compress: compress.then_some(3),
    }
}

/// Blocks of 4 KiB, the smallest (about five hundred on the deep file).
pub fn blocks_4k(compress: bool) -> BlockOptions {
    BlockOptions {
        block_size: 4096,
        compress: compress.then_some(3),
    }
}

/// The dragon's smallest decimation with the default build options (clusters), raw blocks.
pub fn default_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::new(
            "dragon res4, default, raw",
            dragon(),
            BuildOptions::default(),
            blocks_16k(false),
        )
    })
}

/// The same, zstd-compressed blocks.
pub fn default_zstd_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::new(
            "dragon res4, default, zstd",
            dragon(),
            BuildOptions::default(),
            blocks_16k(true),
        )
    })
}

/// The dragon's smallest decimation with the default build options of leaf lists (format 3's
/// leaves, `--leaf list`), raw blocks.
pub fn list_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::new(
            "dragon res4, lists, raw",
            dragon(),
            BuildOptions::with_leaf(LeafKind::List),
            blocks_16k(false),
        )
    })
}

/// The same, zstd-compressed blocks.
pub fn list_zstd_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::new(
            "dragon res4, lists, zstd",
            dragon(),
            BuildOptions::with_leaf(LeafKind::List),
            blocks_16k(true),
        )
    })
}

/// Part of the dragon with leaf size 4: a deep tree (many levels, a deep top tree, rank words,
/// merged volumes) of small clusters, small blocks, raw.
pub fn deep_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::new(
            "dragon res4, 600 triangles, K=4, raw",
            &dragon_part(600),
            leaf4(),
            blocks_4k(false),
        )
    })
}

/// The same, zstd-compressed blocks.
pub fn deep_zstd_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::new(
            "dragon res4, 600 triangles, K=4, zstd",
            &dragon_part(600),
            leaf4(),
            blocks_4k(true),
        )
    })
}

/// The default file (clusters, raw blocks) with ropes (§8.4), added by `add_ropes` as
/// `oavm-pack --ropes` adds them; traced by the walk that follows them.
pub fn roped_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::build(
            "dragon res4, default, ropes, raw",
            dragon(),
            BuildOptions::default(),
            blocks_16k(false),
            true,
            false,
        )
    })
}

/// The file of leaf lists, zstd-compressed blocks, with ropes (each block decoded, given its
/// ropes and compressed again).
pub fn roped_list_zstd_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::build(
            "dragon res4, lists, ropes, zstd",
            dragon(),
            BuildOptions::with_leaf(LeafKind::List),
            blocks_16k(true),
            true,
            false,
        )
    })
}

/// The deep file's mesh (part of the dragon, clusters of leaf size 4) in raw blocks of 16 KiB,
/// with occluders (§8.5), added by `add_occluders` with the default parameters as `oavm-pack
/// --occluders` adds them; traced by the default walk (top-down, in a file of clusters), whose
/// any-hit queries test them. (With the default leaf size of 512 a block's tree is too shallow
/// for the default parameters to choose any: the deep trees of leaf size 4 get hundreds.)
/// `add_occluders` refuses a file of lists (only the top-down walk, of files of clusters,
/// tests occluders), so there is no file of lists with occluders.
pub fn occluded_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::build(
            "dragon res4, 600 triangles, K=4, 16 KiB blocks, occluders, raw",
            &dragon_part(600),
            leaf4(),
            blocks_16k(false),
            false,
            true,
        )
    })
}

/// The same, zstd-compressed blocks (each block decoded, given its occluders and compressed
/// again).
pub fn occluded_zstd_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        Fixture::build(
            "dragon res4, 600 triangles, K=4, 16 KiB blocks, occluders, zstd",
            &dragon_part(600),
            leaf4(),
            blocks_16k(true),
            false,
            true,
        )
    })
}

/// The dragon's smallest decimation with the default build options, raw blocks, packed
/// `--updatable` as `oavm-pack` packs it (`pack_mesh`, to disk): the primitive table (§8.6),
/// its chunks after the blocks and its chunk directory the last section.
pub fn updatable_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| updatable("dragon res4, updatable, raw", false))
}

/// The same, zstd-compressed blocks (so that a block rewritten and compressed again moves the
/// chunks after it).
pub fn updatable_zstd_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| updatable("dragon res4, updatable, zstd", true))
}

pub fn updatable(name: &str, compress: bool) -> Fixture {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("updatable.oavm");
    let opts = oavm::pack::PackOptions {
        build: BuildOptions::default(),
        blocks: blocks_16k(compress),
        updatable: true,
        ..oavm::pack::PackOptions::default()
    };
    oavm::pack::pack_mesh(dragon().clone(), "dragon", &path, &opts, &oavm::pack::Quiet)
        .expect("pack --updatable");
    let bytes = std::fs::read(&path).expect("read");
    let expect = Expect {
        compressed: compress,
        prims: true,
        ..Expect::new(LeafKind::Cluster)
    };
    let fix = Fixture::examine(name, dragon(), bytes, expect);
    // The table adds to the file and changes no block: the blocks are the file without it's.
    let plain = match compress {
        false => default_file(),
        true => default_zstd_file(),
    };
    assert_eq!(fix.dir.len(), plain.dir.len(), "{name}: blocks");
    for (b, (e, p)) in fix.dir.iter().zip(&plain.dir).enumerate() {
        assert!(
            fix.bytes[e.stored()] == plain.bytes[p.stored()] && e.offset == p.offset,
            "{name}: block {b} is not the file without the table's"
        );
    }
    fix
}

/// The triangles an update of [`updated_file`] removes, moves and inserts.
pub struct UpdateEdits {
    pub removed: Vec<u32>,
    pub moved: Vec<u32>,
    pub inserted: Vec<u32>,
}

/// [`updatable_file`] updated in place (`Updater`, §2.1): every primitive of three blocks in
/// the middle of the directory removed (so that their entries stay free, §8.2: the blocks
/// rebuilt around them need fewer), the first 24 triangles of another block moved a hundredth
/// of the way to the mesh's centre, and two triangles inserted: generation 2, in slot 1; its
/// data region holds generation 1's blocks, chunks and sections as well as its own.
pub fn updated_file() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let before = updatable_file();
        let (mesh, bytes, edits) = update_of(before);
        let old_dir = &before.dir;
        let new_dir = directory(&bytes);
        // The blocks the update wrote (new bytes in an old entry, or a new entry).
        let written: Vec<usize> = (0..new_dir.len())
            .filter(|&b| {
                !new_dir[b].free
                    && old_dir.get(b).is_none_or(|o| {
                        (o.offset, o.stored_len) != (new_dir[b].offset, new_dir[b].stored_len)
                    })
            })
            .collect();
        assert!(!written.is_empty(), "the update wrote no block");
        let free = new_dir.iter().filter(|e| e.free).count();
        eprintln!(
            "update: {} removed, {} moved, {} inserted; blocks {:?} written, {free} free entries",
            edits.removed.len(),
            edits.moved.len(),
            edits.inserted.len(),
            written
        );
        let expect = Expect {
            prims: true,
            generation: 2,
            previous: Some(before.bytes.clone()),
            removed: edits.removed,
            detail: vec![written[0], written[written.len() - 1]],
            ..Expect::new(LeafKind::Cluster)
        };
        Fixture::examine(
            "dragon res4, updatable, raw, generation 2",
            &mesh,
            bytes,
            expect,
        )
    })
}

/// Updates a copy of `before`'s file (see [`updated_file`]): the mesh it then holds (a removed
/// primitive keeps its old triangle there), the file's bytes, and the edits.
pub fn update_of(before: &Fixture) -> (Mesh, Vec<u8>, UpdateEdits) {
    use oavm::pack::update::{UpdateOptions, Updater};
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("updated.oavm");
    std::fs::write(&path, &before.bytes).expect("write");
    let prims_of = |b: usize| {
        let mut p: Vec<u32> = block_triangles(&before.decoded[b])
            .iter()
            .map(|t| read_u32(t, 36))
            .collect();
        p.sort_unstable();
        p.dedup();
        p
    };
    let n = before.dir.len();
    let mut removed: Vec<u32> = (n / 2 - 1..=n / 2 + 1).flat_map(prims_of).collect();
    removed.sort_unstable();
    removed.dedup();
    let mut moved: Vec<u32> = prims_of(n / 4)
        .into_iter()
        .filter(|p| removed.binary_search(p).is_err())
        .collect();
    moved.truncate(24);
    let mut mesh = dragon().clone();
    let bounds = crate::common::bounds(&mesh);
    let centre = bounds.centre();
    let mut u = Updater::open(&path).expect("open for an update");
    assert_eq!(u.generation(), 1);
    for &p in &removed {
        u.remove(p).expect("remove");
    }
    let towards = |v: [f32; 3], f: f64| -> [f32; 3] {
        std::array::from_fn(|k| (v[k] as f64 + (centre[k] - v[k] as f64) * f) as f32)
    };
    let add = |mesh: &mut Mesh, v: [[f32; 3]; 3]| -> [u32; 3] {
        let first = mesh.positions.len() as u32;
        mesh.positions.extend(v);
        [first, first + 1, first + 2]
    };
    for &p in &moved {
        let v = mesh.triangle(p as usize).map(|c| towards(c, 0.01));
        u.set(p, v).expect("set");
        let t = add(&mut mesh, v);
        mesh.triangles[p as usize] = t;
    }
    let mut inserted = Vec::new();
    for k in 0..2 {
        // Half of a triangle of the first block, about its centroid, moved a little towards
        // the centre: inside the mesh's box, so inside the root cube.
        let t = mesh.triangle(prims_of(0)[k] as usize);
        let c: [f32; 3] = std::array::from_fn(|i| (t[0][i] + t[1][i] + t[2][i]) / 3.0);
        let v = t.map(|p| towards(std::array::from_fn(|i| (p[i] + c[i]) / 2.0), 0.001));
        let p = u.insert(v).expect("insert");
        assert_eq!(
            p as usize,
            mesh.triangles.len(),
            "inserted ids follow the table"
        );
        let t = add(&mut mesh, v);
        mesh.triangles.push(t);
        inserted.push(p);
    }
    let report = u
        .commit(&UpdateOptions {
            block_size: 16384,
            compress: None,
        })
        .expect("commit");
    assert_eq!(
        (report.previous_generation, report.generation),
        (1, 2),
        "{report:?}"
    );
    assert_eq!(
        (report.removed, report.moved, report.inserted),
        (
            removed.len() as u64,
            moved.len() as u64,
            inserted.len() as u64
        ),
        "{report:?}"
    );
    let bytes = std::fs::read(&path).expect("read");
    let edits = UpdateEdits {
        removed,
        moved,
        inserted,
    };
    (mesh, bytes, edits)
}
