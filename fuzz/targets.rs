//! The bodies of the fuzz targets: one plain function per target, taking the input bytes.
//!
//! Compiled into the fuzz binaries (`fuzz/fuzz_targets/*.rs`, as module `targets`) and into the
//! stable test `tests/integration/fuzz_corpus.rs` (`#[path = "../fuzz/targets.rs"] mod targets;`), so the
//! committed corpus and regressions are replayed through exactly the code that fuzzed them.
//!
//! Every input is untrusted: each function returns normally whatever the bytes are (an `Err`
//! from the library is a fine outcome). A panic, abort, hang or unbounded allocation is a bug.
//! Uses only `oavm`, `rayon`, `xxhash-rust` and `zstd`, which are dependencies of the main crate
//! (so the test can use them) and of the fuzz crate.

#![allow(dead_code)] // each fuzz binary uses one of the functions

use std::sync::OnceLock;

use oavm::logical::{BlockReads, SceneOptions, Walk};
use oavm::physical::AlignedBytes;
use oavm::{Hit, Ray, Scene};
use xxhash_rust::xxh3::xxh3_64;

/// A target: its name and its body.
pub type Target = (&'static str, fn(&[u8]));

/// The targets, by name: the names of `fuzz/fuzz_targets/*.rs`, of `fuzz/corpus/<name>/` and of
/// `fuzz/regressions/<name>/`.
pub const TARGETS: &[Target] = &[
    ("ply", ply),
    ("obj", obj),
    ("stl", stl),
    ("off", off),
    ("gltf", gltf),
    ("aff", aff),
    ("rays", rays),
    ("oavm", oavm_file),
    ("oavm_fixed", oavm_fixed),
    ("pack", pack),
];

// ---------------------------------------------------------------------------------------------
// Meshes

/// PLY: ascii, binary little- and big-endian (the header says which).
pub fn ply(data: &[u8]) {
    let _ = oavm::mesh::parse_ply(data, "fuzz.ply");
}

/// OBJ (through `tobj`, with the crate's own checks around it).
pub fn obj(data: &[u8]) {
    let _ = oavm::mesh::parse_obj(data, "fuzz.obj");
}

/// STL, binary (by its exact length) and ASCII.
pub fn stl(data: &[u8]) {
    let _ = oavm::mesh::parse_stl(data, "fuzz.stl");
}

/// OFF and its variants (COFF, NOFF, STOFF...).
pub fn off(data: &[u8]) {
    let _ = oavm::mesh::parse_off(data, "fuzz.off");
}

/// glTF 2.0, JSON or GLB: no buffer files are read (no directory given: a deterministic run
/// that cannot read the machine's files); the mesh capped at 64 MiB, as a small budget would.
pub fn gltf(data: &[u8]) {
    let _ = oavm::mesh::parse_gltf(data, "fuzz.glb", None, 64 << 20);
}

/// BART AFF, the single-file parser: includes are answered "not found" (no disk access, so a
/// run is deterministic and cannot read the machine's files). Parsed at the scene's default
/// time, then, if that succeeded, again at a time picked from the input's hash among values
/// that exercise the keyframe code: before, between and after keys, and extreme ones.
pub fn aff(data: &[u8]) {
    let path = std::path::Path::new("fuzz/scene.aff");
    let mut no_includes = |p: &std::path::Path| -> std::io::Result<Vec<u8>> {
        Err(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            format!("{}: includes are not read while fuzzing", p.display()),
        ))
    };
    if oavm::mesh::parse_aff_with(data, path, None, &mut no_includes).is_err() {
        return;
    }
    const TIMES: [f64; 10] = [
        -1.0,
        0.0,
        0.25,
        1.0,
        2.5,
        7.0,
        1e-300,
        -1e300,
        1e300,
        f64::MAX,
    ];
    let h = xxh3_64(data);
    let time = if h & 1 == 0 {
        TIMES[(h >> 1) as usize % TIMES.len()]
    } else {
        // A time in [-2, 20), in steps of 1/64.
        ((h >> 1) % (22 * 64)) as f64 / 64.0 - 2.0
    };
    let _ = oavm::mesh::parse_aff_with(data, path, Some(time), &mut no_includes);
}

/// Most triangles [`pack`] builds a tree of (building is the slow part).
pub const PACK_MAX_TRIANGLES: usize = 512;

/// A PLY mesh (any bytes), packed as `oavm-pack` would: parsed, built with options picked from
/// the input's hash (depth 2 to 6, or 10 for at most 32 triangles; leaf size 1 to 8; merged or
/// not), encoded in 4 KiB blocks raw or compressed, opened and verified. Mesh bytes are
/// untrusted, so the builder must give an error or a file, and **a file our own builder wrote
/// must verify clean**: a defect panics (it is a bug of the builder, the writer or verify).
/// Then the probe rays are traced, closest and any hit, and compared with the f64 brute force
/// of `oavm::geom::reference`, which shares no code with the tracer's f32 triangle test: they
/// must agree by `RAYS.md`'s rule ([`agree`]) unless the ray is one where an f32 tracer and the
/// f64 reference may both be right ([`excused`]): it grazes an edge, or it meets a triangle
/// within the f32 test's rounding error of its range's ends. Anything else panics: a triangle
/// the traversal skipped, a false hit, closest and any hit disagreeing. Meshes of more than
/// [`PACK_MAX_TRIANGLES`] are not built.
pub fn pack(data: &[u8]) {
    use oavm::geom::reference;
    use oavm::pack::encode_with;
    use oavm::physical::BlockOptions;
    let Ok(mesh) = oavm::mesh::parse_ply(data, "fuzz.ply") else {
        return;
    };
    if mesh.triangles.len() > PACK_MAX_TRIANGLES {
        return;
    }
    let h = xxh3_64(data);
    let opts = oavm::BuildOptions {
        max_depth: if mesh.triangles.len() <= 32 && h & 3 == 0 {
            10
        } else {
            2 + 2 * ((h >> 2) % 3) as u32
        },
        leaf_size: 1 << ((h >> 4) % 4),
        merge: h >> 6 & 1 == 0,
        leaf: if h >> 8 & 1 == 0 {
            oavm::pack::LeafKind::Cluster
        } else {
            oavm::pack::LeafKind::List
        },
    };
    let blocks = BlockOptions {
        block_size: 4096,
        compress: (h >> 7 & 1 == 0).then_some(1),
        chunk_groups: 1 + (h >> 8 & 15) as u32,
        lean: h >> 7 & 1 == 1 && h >> 12 & 1 == 1,
    };
    pool().install(|| {
        let Ok((parts, _)) = oavm::pack::build(&mesh, &opts, &oavm::pack::Quiet) else {
            return;
        };
        let Ok(file) = encode_with(&parts, &blocks) else {
            return;
        };
        let scene = Scene::from_bytes(file, "fuzz.oavm").unwrap_or_else(|e| {
            panic!("a file the builder wrote ({opts:?}, {blocks:?}) does not open: {e}")
        });
        match scene.verify() {
            Ok(report) => assert!(
                report.is_ok(),
                "a file the builder wrote ({opts:?}, {blocks:?}) has defects: {:?}",
                report.defects
            ),
            Err(e) => panic!("verifying a file the builder wrote fails: {e}"),
        }
        let h = scene.file().header();
        let rays = probe_rays(h.mesh_min, h.mesh_max);
        let mut hits = vec![Hit::MISS; rays.len()];
        let mut occluded = vec![0u8; rays.len()];
        scene
            .intersect_batch(&rays, &mut hits)
            .and_then(|_| scene.occluded_batch(&rays, &mut occluded))
            .unwrap_or_else(|e| panic!("tracing a file the builder wrote fails: {e}"));
        let tris: Vec<[[f32; 3]; 3]> = (0..mesh.triangles.len())
            .map(|i| mesh.triangle(i))
            .collect();
        let (lo, hi) = (h.mesh_min, h.mesh_max);
        let diagonal = (0..3)
            .map(|k| (f64::from(hi[k]) - f64::from(lo[k])).powi(2))
            .sum::<f64>()
            .sqrt();
        let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (f64::from(lo[k]) + f64::from(hi[k])));
        for (i, ray) in rays.iter().enumerate() {
            let (got, got_occluded) = (hits[i], occluded[i] != 0);
            assert_eq!(
                got.is_hit(),
                got_occluded,
                "probe ray {i} {ray:?} ({opts:?}, {blocks:?}): closest hit {got:?}, any hit \
                 {got_occluded}"
            );
            // Known limit, not checked: an origin more than 2^28 mesh diagonals away loses hits
            // in deep trees (the walk's plane crossings are `t = plane * inv - o * inv` in f64,
            // which cancels when `o` is that far; see fuzz/README.md).
            let far = (0..3).any(|k| {
                (f64::from(ray.origin[k]) - centre[k]).abs() > FAR_ORIGIN * diagonal.max(1e-30)
            });
            if far {
                continue;
            }
            let want = reference::closest(&tris, ray);
            let want_occluded = reference::occluded(&tris, ray);
            if (agree(&got, &want, ray, diagonal) || within_rounding(&tris, ray, &got, &want))
                && got_occluded == want_occluded
            {
                continue;
            }
            assert!(
                excused(&tris, ray),
                "probe ray {i} {ray:?} ({opts:?}, {blocks:?}): oavm {got:?} occluded \
                 {got_occluded}, the f64 reference {want:?} occluded {want_occluded}"
            );
        }
    });
}

/// Whether the tracer's closest hit `got` and the reference's `want` differ only by the f32
/// test's rounding of `t` ([`t_rounding`], which grows as 1 / det: rays nearly along a
/// triangle's plane): the reference hits `got`'s triangle too, at a `t` within that rounding
/// of `got.t`, and no further beyond `want.t` than the two triangles' roundings together (the
/// f32 test could have put `want`'s triangle behind it).
pub fn within_rounding(tris: &[[[f32; 3]; 3]], ray: &Ray, got: &Hit, want: &Hit) -> bool {
    use oavm::geom::reference;
    let (Some(g), Some(w)) = (tris.get(got.prim as usize), tris.get(want.prim as usize)) else {
        return false;
    };
    let Some(t_exact) = reference::hit_t(g, ray) else {
        return false;
    };
    let (rg, rw) = (t_rounding(g, ray), t_rounding(w, ray));
    got.is_hit()
        && want.is_hit()
        && (f64::from(got.t) - t_exact).abs() <= rg
        && t_exact - f64::from(want.t) <= rg + rw
}

/// Whether `ray` is one on which the f32 tracer and the f64 reference may disagree with both
/// right: it grazes an edge or a corner (`reference::grazes`), or its line meets a triangle
/// (inside or on its edges) at a `t` within [`t_rounding`] of `tmin` or `tmax`, where the f32
/// test may put the hit on either side of the range's end.
pub fn excused(tris: &[[[f32; 3]; 3]], ray: &Ray) -> bool {
    use oavm::geom::reference;
    reference::grazes(tris, ray)
        || tris.iter().any(|tri| {
            let Some(m) = reference::meet(tri, ray) else {
                return false;
            };
            let slack = t_rounding(tri, ray);
            m.margin() >= -reference::GRAZING
                && [ray.tmin, ray.tmax]
                    .iter()
                    .any(|&end| (m.t - f64::from(end)).abs() <= slack)
        })
}

/// How far the f32 watertight test's `t` may lie from the exact one: pbrt-v4's bound on the
/// rounding error of that test (Pharr, Jakob, Humphreys, *Physically Based Rendering*, 4th ed.,
/// "Robust Triangle Intersections"), evaluated here in f64 on the ray and triangle (not by the
/// tracer's code), and the error of gradual underflow, which that bound (relative errors only)
/// leaves out; with a factor 4 to spare, plus the smallest normal f32: a `t` below it is
/// subnormal (a direction near `f32::MAX`), where f32 keeps no relative precision.
///
/// Underflow: an f32 operation whose result is subnormal errs by up to half the smallest
/// subnormal, 2^-150, absolutely, whatever its relative error. The scaled `t`, `u * az +
/// v * bz + w * cz` with `az = sz * a.z` and so on, underflows when the direction is huge
/// (`sz = 1 / d.z` tiny) and the triangle small: its three `z`, three products and two sums err
/// by up to 2^-150 more, the `z` weighed by the edge functions, and the edge functions' own
/// three operations each by the `z`. Divided by the determinant, that is an error of `t` the
/// relative bound does not see: a direction of (1e30, -1e30, 1e30) on a triangle 1e-4 across,
/// `t` = 5.5e-36, scaled `t` -1.7e-43 (118 steps of the smallest subnormal), `t` off by 0.4 %
/// (`regressions/pack/huge_direction_subnormal_t_scaled`).
pub fn t_rounding(tri: &[[f32; 3]; 3], ray: &Ray) -> f64 {
    let d = ray.dir.map(f64::from);
    // The dominant axis, the first of equal ones as the watertight test picks it: the bound
    // is that of the shear the tracer used (for a direction of (1e30, -1e30, 1e30) the last
    // axis's bound is 1e-5 of the first's).
    let kz = (0..3).fold(0, |m, k| if d[k].abs() > d[m].abs() { k } else { m });
    let (kx, ky) = ((kz + 1) % 3, (kz + 2) % 3);
    let (sx, sy, sz) = (-d[kx] / d[kz], -d[ky] / d[kz], 1.0 / d[kz]);
    let sheared = tri.map(|p| {
        let r: [f64; 3] = std::array::from_fn(|k| f64::from(p[k]) - f64::from(ray.origin[k]));
        [r[kx] + sx * r[kz], r[ky] + sy * r[kz], sz * r[kz]]
    });
    let max = |k: usize| sheared.iter().fold(0.0f64, |m, p| m.max(p[k].abs()));
    let (mx, my, mz) = (max(0), max(1), max(2));
    let e: [f64; 3] = std::array::from_fn(|i| {
        let (a, b) = (sheared[(i + 1) % 3], sheared[(i + 2) % 3]);
        a[0] * b[1] - a[1] * b[0]
    });
    let det = e.iter().sum::<f64>().abs();
    let me = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let gamma = |n: f64| {
        let eps = f64::from(f32::EPSILON) * 0.5;
        n * eps / (1.0 - n * eps)
    };
    let dz = gamma(3.0) * mz;
    let dx = gamma(5.0) * (mx + mz);
    let dy = gamma(5.0) * (my + mz);
    let de = 2.0 * (gamma(2.0) * mx * my + dy * mx + dx * my);
    let bound = 3.0 * (gamma(3.0) * me * mz + de * mz + dz * me) / det;
    let tiny = (-150f64).exp2();
    let underflow = (3.0 * me * tiny + 5.0 * tiny + 9.0 * mz * tiny) / det;
    4.0 * (bound + underflow) + f64::from(f32::MIN_POSITIVE)
}

/// Units in the last place of `t` that [`agree`] allows beyond RAYS.md's tolerance.
pub const T_ULPS: f64 = 4.0;

/// Rays of [`pack`] whose origin is more than this many mesh diagonals from the mesh's box are
/// not compared with brute force (a known precision limit of the tracer, see [`pack`]).
pub const FAR_ORIGIN: f64 = (1u64 << 28) as f64;

/// `RAYS.md`'s agreement rule (`Hit::agrees`) with the distance along the ray (`t` times the
/// direction's length: the probe rays' directions are not unit) in place of `t`, plus
/// [`T_ULPS`] units in the last place of the larger `t`: a ray starting a million diagonals
/// away has `t` values an f32 cannot resolve to `1e-4` of the diagonal, and two triangles
/// meeting at an edge give `t`s an ulp apart.
fn agree(a: &Hit, b: &Hit, ray: &Ray, diagonal: f64) -> bool {
    let len = ray
        .dir
        .iter()
        .map(|&d| f64::from(d).powi(2))
        .sum::<f64>()
        .sqrt();
    let ulps = T_ULPS * f64::from(f32::EPSILON) * f64::from(a.t.abs().max(b.t.abs()));
    a.agrees(b, diagonal / len)
        || (a.is_hit() && b.is_hit() && (f64::from(a.t) - f64::from(b.t)).abs() <= ulps)
}

// ---------------------------------------------------------------------------------------------
// Ray, hit and occlusion files (`../shared/RAYS.md`)

/// The three batch files: the magic picks which parse gets past the header.
pub fn rays(data: &[u8]) {
    let _ = oavm::rays::parse_records::<Ray>(data, b"RAYS");
    let _ = oavm::rays::parse_records::<Hit>(data, b"HITS");
    let _ = oavm::rays::parse_records::<u8>(data, b"OCCL");
}

// ---------------------------------------------------------------------------------------------
// `.oavm` files

/// An `.oavm` file as given: open, verify, trace [`probe_rays`] (closest and any hit); then
/// opened again under a memory budget of one byte with block checks off (so that raw blocks are
/// paged in without their checksum and their contents reach the tracer even in this target),
/// traced in block order and as given.
pub fn oavm_file(data: &[u8]) {
    open_verify_trace(data);
}

/// An `.oavm` file whose checksums are recomputed first ([`fix_checksums`]), so that mutations
/// get past the header, section and block checksums into the structural checks, `verify` and
/// the tracer; then as [`oavm_file`].
pub fn oavm_fixed(data: &[u8]) {
    let mut bytes = AlignedBytes::from_slice(data);
    fix_checksums(bytes.as_mut_slice());
    open_verify_trace(bytes.as_ref());
}

fn open_verify_trace(data: &[u8]) {
    pool().install(|| {
        if let Ok(scene) = Scene::from_bytes(AlignedBytes::from_slice(data), "fuzz.oavm") {
            let _ = scene.verify();
            trace(&scene, false);
        }
        let tiny = SceneOptions {
            mem_budget: Some(1),
            threads: 1,
            check_blocks: false,
            block_reads: BlockReads::Auto,
            walk: Walk::Auto,
            // Chunked where the file stores chunks (format-spec §8.3): the chunk table and
            // chunks' checksums are read on that path only.
            chunks: true,
        };
        if let Ok(scene) =
            Scene::from_bytes_with(AlignedBytes::from_slice(data), "fuzz.oavm", &tiny)
        {
            trace(&scene, true);
        }
        // The leaf-to-leaf walks, by Morton codes and by ropes (spec §8.4), whatever the leaves.
        for walk in [Walk::Neighbours, Walk::Ropes] {
            let opts = SceneOptions {
                walk,
                ..SceneOptions::default()
            };
            if let Ok(scene) =
                Scene::from_bytes_with(AlignedBytes::from_slice(data), "fuzz.oavm", &opts)
            {
                trace(&scene, false);
            }
        }
    });
}

/// One thread: fuzzing wants runs that are deterministic and cost one core.
fn pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("a one-thread rayon pool")
    })
}

fn trace(scene: &Scene<AlignedBytes>, blocks_order: bool) {
    let h = scene.file().header();
    let rays = probe_rays(h.mesh_min, h.mesh_max);
    let mut hits = vec![Hit::MISS; rays.len()];
    let mut occluded = vec![0u8; rays.len()];
    if blocks_order {
        let _ = scene.intersect_batch_ordered(&rays, &mut hits, oavm::logical::Order::Blocks);
    } else {
        let _ = scene.intersect_batch(&rays, &mut hits);
    }
    let _ = scene.occluded_batch(&rays, &mut occluded);
}

/// Number of rays of [`probe_rays`] spread over the mesh's box (the degenerate ones follow).
pub const SPREAD_RAYS: usize = 64;

/// A fixed set of rays for a file whose header gives the mesh box `lo..hi`: [`SPREAD_RAYS`]
/// deterministic rays from points around and inside the box towards points in the box (some
/// with finite `tmax`, some axis-aligned), then degenerate ones: along the box's edges and
/// faces, starting on a corner, invalid (NaN, infinite, zero direction, `tmin > tmax`), and with
/// tiny and huge directions. The box comes from the file, so it may be anything; arithmetic is
/// in f64 and rounded to f32 (infinities make invalid rays, which must miss).
pub fn probe_rays(lo: [f32; 3], hi: [f32; 3]) -> Vec<Ray> {
    let lo = lo.map(f64::from);
    let hi = hi.map(f64::from);
    let ext: [f64; 3] = std::array::from_fn(|k| hi[k] - lo[k]);
    let diag = ext.iter().map(|e| e * e).sum::<f64>().sqrt().max(1e-3);
    let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let mut state = 0x0a5f_17e5_u64;
    let mut unit = move || {
        // SplitMix64 (Steele, Lea, Flood 2014), uniform in [0, 1).
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    };
    let f = |v: [f64; 3]| v.map(|c| c as f32);
    let mut rays = Vec::with_capacity(SPREAD_RAYS + 32);
    for i in 0..SPREAD_RAYS {
        // From a point in the box grown by half its diagonal on every side (inside or out)...
        let origin: [f64; 3] =
            std::array::from_fn(|k| lo[k] - 0.5 * diag + (ext[k] + diag) * unit());
        // ... towards a point of the box.
        let target: [f64; 3] = std::array::from_fn(|k| lo[k] + ext[k] * unit());
        let mut dir: [f64; 3] = std::array::from_fn(|k| target[k] - origin[k]);
        if i % 8 == 7 {
            // Axis-aligned: exact ties with cell faces.
            let k = i / 8 % 3;
            dir = [0.0; 3];
            dir[k] = if i % 16 == 7 { 1.0 } else { -1.0 };
        }
        let tmax = if i % 4 == 3 { 0.5 } else { f64::INFINITY };
        rays.push(Ray::new(f(origin), f(dir), 0.0, tmax as f32));
    }
    let inf = f32::INFINITY;
    let (l, h, c) = (f(lo), f(hi), f(centre));
    let x = [1.0, 0.0, 0.0];
    let d = [1.0, 1.0, 1.0];
    rays.extend([
        // Along the box's edges and faces, and from its corners.
        Ray::new(l, x, 0.0, inf),
        Ray::new(l, [0.0, 1.0, 0.0], 0.0, inf),
        Ray::new(l, [0.0, 0.0, 1.0], 0.0, inf),
        Ray::new(h, [-1.0, 0.0, 0.0], 0.0, inf),
        Ray::new(l, d, 0.0, inf),
        Ray::new(h, [-1.0, -1.0, -1.0], 0.0, inf),
        Ray::new([l[0], c[1], c[2]], [-1.0, 0.0, 0.0], -inf, inf),
        Ray::new(c, [1.0, 1.0, 0.0], 0.0, inf),
        // From the centre: a point, zero length, negative range, tiny and huge directions.
        Ray::new(c, d, 0.0, 0.0),
        Ray::new(c, d, 1.0, 1.0),
        Ray::new(c, d, -inf, -1.0),
        Ray::new(c, [1e-30, 1e-30, 1e-30], 0.0, inf),
        Ray::new(c, [1e-45, 0.0, 0.0], 0.0, inf),
        Ray::new(c, [1e30, -1e30, 1e30], 0.0, inf),
        Ray::new(c, [-3.4e38, 3.4e38, 1.0], 0.0, inf),
        // Invalid: must miss.
        Ray::new(c, [0.0; 3], 0.0, inf),
        Ray::new([f32::NAN; 3], d, 0.0, inf),
        Ray::new(c, [f32::NAN, 1.0, 1.0], 0.0, inf),
        Ray::new(c, [inf, 1.0, 1.0], 0.0, inf),
        Ray::new([inf, 0.0, 0.0], d, 0.0, inf),
        Ray::new(c, d, 2.0, 1.0),
        Ray::new(c, d, f32::NAN, inf),
        Ray::new(c, d, 0.0, f32::NAN),
        // Far away, towards the box, and with tmin beyond the box.
        Ray::new(
            f([centre[0] - 1e6 * diag, centre[1], centre[2]]),
            x,
            0.0,
            inf,
        ),
        Ray::new(
            f([centre[0] - 1e6 * diag, centre[1], centre[2]]),
            x,
            1e12,
            inf,
        ),
        Ray::new(f([-3e38, centre[1], centre[2]]), x, 0.0, inf),
    ]);
    rays
}

// ---------------------------------------------------------------------------------------------
// Recomputing an `.oavm` file's checksums (format-spec.md §1-§3, §8.2, §8.3)

// Offsets, from format-spec.md, as the tests state them (a mismatch with the code would only
// make the fuzzing weaker, never wrong: everything here is bounds-checked).
#[path = "../tests/common/layout.rs"]
pub mod layout;
use layout::*;

/// At most this many directory entries are fixed up (each costs a hash of its block).
const MAX_FIXED_BLOCKS: usize = 4096;
/// At most this many chunk table entries of a block are fixed up, and at most this many bytes
/// hashed for them (a table read from garbage may be long, its chunks overlapping).
const MAX_FIXED_CHUNKS: usize = 4096;
const MAX_CHUNK_BYTES_HASHED: usize = 1 << 26;
/// The largest zstd head decoded to recompute its chunk table's checksums (a head that claims
/// more keeps its table as it is; the pager's own limit is the header's `max_block_raw_len`).
const MAX_DECODED_HEAD: usize = 16 << 20;

fn read_u32(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(
        b.get(at..at.checked_add(4)?)?.try_into().ok()?,
    ))
}

fn read_u64(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(
        b.get(at..at.checked_add(8)?)?.try_into().ok()?,
    ))
}

fn write_u64(b: &mut [u8], at: usize, v: u64) {
    if let Some(dst) = at.checked_add(8).and_then(|end| b.get_mut(at..end)) {
        dst.copy_from_slice(&v.to_le_bytes());
    }
}

/// `at..at + len` if it lies inside a buffer of `size` bytes.
fn range(at: u64, len: u64, size: usize) -> Option<std::ops::Range<usize>> {
    let end = at.checked_add(len)?;
    (end <= size as u64).then_some(at as usize..end as usize)
}

/// §8.3: recomputes the checksum of each entry of the chunk table of the decoded head `head`
/// (where its block header places the table, if inside the head) over that chunk's stored
/// bytes, which lie in `chunks` (the block's stored bytes after its head's) at the entry's
/// `offset`, `stored_len` bytes long; entries whose chunk does not lie inside `chunks` are left
/// alone. Returns whether a checksum changed.
fn fix_chunk_table(head: &mut [u8], chunks: &[u8]) -> bool {
    let Some((parts, _)) = block_layout(head) else {
        return false;
    };
    let table = parts[PART_CHUNKS].clone();
    if table.end > head.len() {
        return false;
    }
    let mut changed = false;
    let mut hashed = 0usize;
    for e in table.step_by(CHUNK_ENTRY_LEN).take(MAX_FIXED_CHUNKS) {
        let (Some(offset), Some(len)) = (
            read_u32(head, e + CE_OFFSET),
            read_u32(head, e + CE_STORED_LEN),
        ) else {
            continue;
        };
        let Some(r) = range(u64::from(offset), u64::from(len), chunks.len()) else {
            continue;
        };
        hashed += r.len();
        if hashed > MAX_CHUNK_BYTES_HASHED {
            break;
        }
        let sum = xxh3_64(&chunks[r]);
        if read_u64(head, e + CE_CHECKSUM) != Some(sum) {
            write_u64(head, e + CE_CHECKSUM, sum);
            changed = true;
        }
    }
    changed
}

/// Rewrites `b` as a tool that edits a file in place would, so that only the structural checks
/// can tell what changed. For each header slot that holds a header (slot 0 always, slot 1 when
/// it starts with the magic; §2.1), the newer generation first, with the flags and the section
/// table of that slot (seven sections, the wide nodes and links with flag `CLUSTERS`, the
/// ropes with `ROPES`, the primitive table with `PRIMS`, §3):
///
/// 1. `file_size` (§2) is set to where the slot's last section ends, if that is inside the
///    buffer, else to the buffer's length (so inserting or removing bytes, or appending them,
///    still gets past the first header check);
/// 2. every directory entry (§8.2, in the directory section as the section table places it)
///    but a free one (all zero) whose stored bytes, and its head's within them, lie in the file
///    gets its checksums: first each chunk's, into the head's chunk table (§8.3: over the
///    chunk's stored bytes, which follow the head's at the entry's `offset`), then the head's,
///    into the directory entry. A raw head's table is fixed in place. A zstd head (one frame)
///    is decoded (up to [`MAX_DECODED_HEAD`] bytes); if a chunk's checksum changed, the head is
///    compressed again and stored with the chunks right behind it, where the block was (as
///    below), if that fits in the block's old bytes (else left as it was). A block marked zstd
///    (codec 1) whose head is a decoded head (it starts with the tag `OBLK`, §8.3) is
///    compressed, its head only, into one frame, its chunks left raw behind it, in place: the
///    rest of its old bytes zeroed, the frame and the chunks written at its offset, or, if the
///    block ended the data region (the region ends where the directory starts, §3, at the next
///    multiple of 64 after its last item), at the last multiple of 64 that keeps it ending
///    there; `offset`, `stored_len`, `raw_len` (the old stored length), `head_stored_len` and
///    `head_raw_len` set (the chunks' offsets in the table, counted from the head's end, stay
///    right). So a seed whose blocks are raw but marked zstd lets the mutator change the
///    *contents* of compressed blocks, which it could not reach through a frame's bytes;
/// 3. every primitive chunk (§8.6, in the chunk directory) whose records lie in the file gets
///    their checksum;
/// 4. every section's checksum but the blocks' (§3), over the range its entry gives;
/// 5. the header checksum (§2): header bytes 0..248, then the section table.
///
/// Ranges that are not inside the buffer are left alone (open or the pager rejects them). A
/// block both generations refer to is compressed for the newer one (the older one's entry
/// then describes bytes that are no longer the block: the fix-up keeps the newest generation
/// sound).
pub fn fix_checksums(b: &mut [u8]) {
    let mut slots = vec![HEADER_SLOTS[0]];
    if b.get(HEADER_SLOTS[1]..HEADER_SLOTS[1] + MAGIC.len()) == Some(&MAGIC[..]) {
        slots.push(HEADER_SLOTS[1]);
    }
    slots.sort_by_key(|&slot| std::cmp::Reverse(read_u64(b, slot + GENERATION_AT)));
    for slot in slots {
        fix_slot(b, slot);
    }
}

/// Step 2 of [`fix_checksums`] for the directory entry at `e` (not free), in a file whose data
/// region ends at `region_end`.
fn fix_block(b: &mut [u8], e: usize, region_end: Option<u64>) {
    let (Some(at), Some(len), Some(codec), Some(head_len)) = (
        read_u64(b, e + DIR_OFFSET),
        read_u64(b, e + DIR_STORED_LEN),
        read_u32(b, e + DIR_CODEC),
        read_u64(b, e + DIR_HEAD_STORED_LEN),
    ) else {
        return;
    };
    let Some(stored) = range(at, len, b.len()) else {
        return;
    };
    let Some(head) = range(at, head_len, b.len()).filter(|h| h.end <= stored.end) else {
        return;
    };
    if codec != CODEC_ZSTD || b[head.clone()].starts_with(BLOCK_TAG) {
        // A decoded head: its table fixed in place.
        let (left, right) = b.split_at_mut(head.end);
        fix_chunk_table(&mut left[head.start..], &right[..stored.end - head.end]);
    }
    // The head to store compressed instead of its stored bytes, decoded: a decoded head marked
    // zstd, or a zstd head (one frame) whose table changed.
    let raw_head = match codec {
        CODEC_ZSTD if b[head.clone()].starts_with(BLOCK_TAG) => b[head.clone()].to_vec(),
        CODEC_ZSTD => {
            let raw_len = read_u64(b, e + DIR_HEAD_RAW_LEN).unwrap_or(0);
            let Some(raw_len) = usize::try_from(raw_len)
                .ok()
                .filter(|&n| n <= MAX_DECODED_HEAD)
            else {
                return set_head_checksum(b, e, head);
            };
            match zstd::bulk::decompress(&b[head.clone()], raw_len) {
                Ok(mut d) if d.len() == raw_len => {
                    if !fix_chunk_table(&mut d, &b[head.end..stored.end]) {
                        return set_head_checksum(b, e, head);
                    }
                    d
                }
                _ => return set_head_checksum(b, e, head),
            }
        }
        _ => return set_head_checksum(b, e, head),
    };
    // A decoded head is compressed if that shrinks it (as a raw-looking block was compressed
    // whole before the chunks); a zstd head whose table changed is stored again if it still
    // fits with the chunks in the block's bytes.
    let Some(frame) = zstd::bulk::compress(&raw_head, 1)
        .ok()
        .filter(|f| f.len() <= head.len())
    else {
        return set_head_checksum(b, e, head);
    };
    let decoded = b[head.clone()].starts_with(BLOCK_TAG);
    let chunks = b[head.end..stored.end].to_vec();
    let total = frame.len() + chunks.len();
    // A block that ended the data region still ends it (§3: the directory starts at the next
    // multiple of 64 after the region's last item).
    let region_end = region_end.and_then(|end| usize::try_from(end).ok());
    let ends_region = region_end.filter(|&end| stored.end.next_multiple_of(ALIGN) == end);
    let (start, limit) = match ends_region {
        Some(end) => (
            (end.saturating_sub(total) / ALIGN * ALIGN).max(stored.start),
            end,
        ),
        None => (stored.start, stored.end),
    };
    if start + total > limit.min(b.len()) {
        return set_head_checksum(b, e, head);
    }
    b[stored.clone()].fill(0);
    b[start..start + frame.len()].copy_from_slice(&frame);
    b[start + frame.len()..start + total].copy_from_slice(&chunks);
    write_u64(b, e + DIR_OFFSET, start as u64);
    write_u64(b, e + DIR_STORED_LEN, total as u64);
    write_u64(b, e + DIR_HEAD_STORED_LEN, frame.len() as u64);
    if decoded {
        // Its stored bytes were the decoded block, its head the decoded head.
        write_u64(b, e + DIR_RAW_LEN, stored.len() as u64);
        write_u64(b, e + DIR_HEAD_RAW_LEN, head.len() as u64);
    }
    set_head_checksum(b, e, start..start + frame.len());
}

/// Writes the checksum of the head's stored bytes `head` into the directory entry at `e`.
fn set_head_checksum(b: &mut [u8], e: usize, head: std::ops::Range<usize>) {
    let sum = xxh3_64(&b[head]);
    write_u64(b, e + DIR_CHECKSUM, sum);
}

/// [`fix_checksums`] for the header slot at offset `slot`.
fn fix_slot(b: &mut [u8], slot: usize) {
    let Some(flags) = read_u32(b, slot + FLAGS_AT) else {
        return;
    };
    let kinds = section_kinds(flags);
    let table = table_range(slot, flags);
    if b.len() < table.end {
        return;
    }
    let entry = |i: usize| table.start + i * ENTRY_LEN;
    let section = |b: &[u8], i: usize| {
        Some((
            read_u64(b, entry(i) + ENTRY_OFFSET)?,
            read_u64(b, entry(i) + ENTRY_LENGTH)?,
        ))
    };
    let last_end = section(b, kinds.len() - 1)
        .and_then(|(at, len)| at.checked_add(len))
        .filter(|&end| end <= b.len() as u64);
    write_u64(b, slot + FILE_SIZE_AT, last_end.unwrap_or(b.len() as u64));
    // The data region's end: where the blocks section ends (the directory's start, §3).
    let region_end = section(b, BLOCKS).and_then(|(at, len)| at.checked_add(len));
    if let Some(dir) = section(b, DIRECTORY).and_then(|(at, len)| range(at, len, b.len())) {
        for i in 0..(dir.len() / DIR_LEN).min(MAX_FIXED_BLOCKS) {
            let e = dir.start + i * DIR_LEN;
            if b[e..e + DIR_LEN].iter().all(|&x| x == 0) {
                continue; // a free entry (§8.2)
            }
            fix_block(b, e, region_end);
        }
    }
    let prims = section_position(flags, KIND_PRIMS).and_then(|i| section(b, i));
    if let Some(chunks) = prims.and_then(|(at, len)| range(at, len, b.len())) {
        for c in 0..(chunks.len() / PRIM_CHUNK_LEN).min(MAX_FIXED_BLOCKS) {
            let e = chunks.start + c * PRIM_CHUNK_LEN;
            let (Some(at), Some(count)) = (read_u64(b, e + PC_OFFSET), read_u64(b, e + PC_COUNT))
            else {
                continue;
            };
            let records = count
                .checked_mul(PRIM_RECORD_LEN as u64)
                .and_then(|len| range(at, len, b.len()));
            if let Some(r) = records {
                let sum = xxh3_64(&b[r]);
                write_u64(b, e + PC_CHECKSUM, sum);
            }
        }
    }
    for i in DIRECTORY..kinds.len() {
        if let Some(r) = section(b, i).and_then(|(at, len)| range(at, len, b.len())) {
            let sum = xxh3_64(&b[r]);
            write_u64(b, entry(i) + ENTRY_CHECKSUM, sum);
        }
    }
    let mut covered = Vec::with_capacity(HEADER_CHECKSUM + table.len());
    covered.extend_from_slice(&b[slot..slot + HEADER_CHECKSUM]);
    covered.extend_from_slice(&b[table]);
    write_u64(b, slot + HEADER_CHECKSUM, xxh3_64(&covered));
}
