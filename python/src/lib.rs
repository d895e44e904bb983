//! `oavm._native`: the Python bindings' compiled half. It holds no logic of its own: it hands
//! numpy buffers to the `oavm` library and its errors back to Python. The Python half
//! (`python/oavm/__init__.py`) checks and converts arguments, so everything that arrives here
//! is a C-contiguous array of the expected dtype and shape; this half still checks shapes and
//! never trusts them with an index.
//!
//! Every call that traces, packs or verifies releases the GIL and runs on a rayon pool of the
//! threads asked for (one pool per thread count, made on first use and kept). Calls on one
//! scene from several Python threads take turns (see `NativeScene::busy`). A long batch is
//! traced in slices of [`SLICE`] rays, taking the GIL back between slices to let Python deliver
//! signals: Ctrl-C interrupts it with `KeyboardInterrupt`.

use std::collections::HashMap;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use oavm::logical::{BlockReads, ClosestPoint, IO_THREADS_PER_CORE, Order, SceneOptions, Walk};
use oavm::mesh::Mesh;
use oavm::pack::update::{UpdateOptions, Updater};
use oavm::pack::{BuildOptions, LeafKind, PackOptions, PackReport};
use oavm::physical::BlockOptions;
use oavm::physical::DEFAULT_BLOCK_SIZE;
use oavm::physical::format::{FLAG_CLUSTERS, FLAG_COMPRESSED, FLAG_MERGED, VERSION};
use oavm::rays::{Bounds, Camera};
use oavm::{Error, Hit, HitAttributes, Ray, Scene};
use pyo3::create_exception;
use pyo3::exceptions::{
    PyException, PyFileNotFoundError, PyOSError, PyPermissionError, PyValueError,
};
use pyo3::prelude::*;

create_exception!(
    oavm,
    OavmError,
    PyException,
    "An error of the oavm library (its message names the file and the place)."
);
create_exception!(
    oavm,
    FormatError,
    OavmError,
    "A .oavm file that breaks the format (corrupt, truncated, of another version) or that \
     changed while it was read."
);
create_exception!(
    oavm,
    MeshError,
    OavmError,
    "A mesh file or mesh arrays that cannot be read or packed."
);

/// Rays per call into the library when the scene is held whole in memory: their answers (at
/// most 28 bytes each) fit in the cache before they are copied into the numpy arrays.
const PIECE: usize = 1 << 16;

/// Rays traced per release of the GIL: about a second of work, so Ctrl-C answers quickly
/// while the hand-out and (under a budget) the sort by block stay amortised.
const SLICE: usize = 1 << 22;

/// The command-line spelling of an option in the library's messages, and the keyword argument
/// that sets it here.
const OPTION_NAMES: [(&str, &str); 6] = [
    ("--max-depth", "max_depth"),
    ("--leaf-size", "leaf_size"),
    ("--block-size", "block_size"),
    ("--compress", "compress"),
    ("--mem-budget", "mem_budget"),
    ("--threads", "threads"),
];

/// The library's error as a Python exception, with the whole chain of causes in its message
/// (as `oavm-trace` prints it).
fn to_py(e: Error) -> PyErr {
    let mut msg = e.to_string();
    for cause in e.causes() {
        msg.push_str(&format!(": {cause}"));
    }
    if matches!(e, Error::Invalid(_) | Error::Budget { .. }) {
        // The library names its options as the command-line tools spell them.
        for (flag, arg) in OPTION_NAMES {
            msg = msg.replace(flag, arg);
        }
    }
    let io_kind = match &e {
        Error::Io { source, .. } => Some(source.kind()),
        Error::Mesh(oavm::error::MeshError::Io { source, .. }) => Some(source.kind()),
        _ => None,
    };
    match (io_kind, &e) {
        (Some(std::io::ErrorKind::NotFound), _) => PyFileNotFoundError::new_err(msg),
        (Some(std::io::ErrorKind::PermissionDenied), _) => PyPermissionError::new_err(msg),
        (Some(_), _) | (None, Error::Output { .. }) => PyOSError::new_err(msg),
        (None, Error::Format { .. } | Error::Changed { .. }) => FormatError::new_err(msg),
        (None, Error::Mesh(_)) => MeshError::new_err(msg),
        (None, Error::Invalid(_) | Error::Budget { .. }) => PyValueError::new_err(msg),
        (None, _) => OavmError::new_err(msg),
    }
}

/// The cores of this machine.
fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Thread pools kept at once.
const MAX_POOLS: usize = 4;

/// The most threads a call may ask for.
const MAX_THREADS: usize = 1024;

/// A rayon pool of `threads` threads (at most [`MAX_THREADS`]), made on first use and kept.
fn pool(threads: usize) -> PyResult<Arc<rayon::ThreadPool>> {
    let threads = threads.clamp(1, MAX_THREADS);
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<rayon::ThreadPool>>>> = OnceLock::new();
    let mut pools = POOLS
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    if let Some(p) = pools.get(&threads) {
        return Ok(p.clone());
    }
    // A program that asks for many different counts keeps a few pools, not one per count
    // (a pool still in use lives on in its callers' handles and ends with the last of them).
    if pools.len() >= MAX_POOLS {
        pools.clear();
    }
    let p = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("oavm-{i}"))
        .build()
        .map_err(|e| OavmError::new_err(format!("cannot start {threads} threads: {e}")))?;
    let p = Arc::new(p);
    pools.insert(threads, p.clone());
    Ok(p)
}

/// The rays of a `(N, 8)` float32 array, in place when it is aligned for them (numpy's arrays
/// are), else copied.
fn rays_of<'a>(a: &'a PyReadonlyArray2<'_, f32>) -> PyResult<std::borrow::Cow<'a, [Ray]>> {
    if a.shape()[1] != 8 {
        return Err(PyValueError::new_err(format!(
            "rays: expected shape (N, 8), got ({}, {})",
            a.shape()[0],
            a.shape()[1]
        )));
    }
    let flat = a
        .as_slice()
        .map_err(|e| PyValueError::new_err(format!("rays: {e}")))?;
    Ok(match bytemuck::try_cast_slice::<f32, Ray>(flat) {
        Ok(rays) => std::borrow::Cow::Borrowed(rays),
        Err(_) => std::borrow::Cow::Owned(
            flat.chunks_exact(8)
                .map(|c| Ray::new([c[0], c[1], c[2]], [c[4], c[5], c[6]], c[3], c[7]))
                .collect(),
        ),
    })
}

/// An opened `.oavm` file (`oavm.Scene` wraps it).
#[pyclass(frozen, module = "oavm._native")]
struct NativeScene {
    scene: Scene,
    /// Held while a batch traces: the pager is sized for `scene.threads()` threads at once, and
    /// each batch may use them all, so batches of several Python threads take turns (each
    /// would use every core anyway).
    busy: Mutex<()>,
}

impl NativeScene {
    /// The threads to trace on: the ones asked for, lowered to what the budget holds, or the
    /// tracer's default for this machine and budget (as `oavm-trace`).
    fn threads(&self, threads: Option<usize>) -> PyResult<usize> {
        match threads {
            Some(0) => Err(PyValueError::new_err("threads must be at least 1")),
            Some(n) => Ok(n.min(self.scene.threads())),
            None => Ok(self.scene.default_threads(cores())),
        }
    }

    /// Answers `rays` with `answer`, piece by piece into a buffer of `fill`s that stays in
    /// the cache, each piece's answers handed to `sink` with the index of its first ray (to
    /// copy them into the numpy arrays); the GIL is released for each slice of [`SLICE`] rays.
    /// A scene that pages traces whole slices at once instead of pieces, so that
    /// [`Order::Blocks`] sorts as many rays together as it can.
    fn traced<T: Send + Sync + Copy>(
        &self,
        py: Python<'_>,
        rays: &[Ray],
        threads: Option<usize>,
        fill: T,
        answer: impl Fn(&Scene, &[Ray], &mut [T], Order) -> Result<(), Error> + Sync,
        mut sink: impl FnMut(usize, &[T]) + Send,
    ) -> PyResult<()> {
        let pool = pool(self.threads(threads)?)?;
        let order = self.scene.default_order();
        let piece = if self.scene.fits_in_budget() {
            PIECE
        } else {
            SLICE
        };
        let mut buf = vec![fill; piece.min(rays.len())];
        for (i, slice) in rays.chunks(SLICE).enumerate() {
            py.detach(|| {
                let _turn = self.busy.lock().unwrap_or_else(|e| e.into_inner());
                pool.install(|| {
                    for (j, rays) in slice.chunks(piece).enumerate() {
                        let out = &mut buf[..rays.len()];
                        answer(&self.scene, rays, out, order)?;
                        sink(i * SLICE + j * piece, out);
                    }
                    Ok(())
                })
            })
            .map_err(to_py)?;
            py.check_signals()?;
        }
        Ok(())
    }
}

/// The points of a `(N, 3)` float32 array.
fn points_of(a: &PyReadonlyArray2<'_, f32>) -> PyResult<Vec<[f32; 3]>> {
    if a.shape()[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "points: expected shape (N, 3), got ({}, {})",
            a.shape()[0],
            a.shape()[1]
        )));
    }
    let flat = a
        .as_slice()
        .map_err(|e| PyValueError::new_err(format!("points: {e}")))?;
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

impl NativeScene {
    /// `answer` on `points` into `out`, slice by slice with the GIL released for each.
    fn per_slice<T: Send>(
        &self,
        py: Python<'_>,
        points: &[[f32; 3]],
        out: &mut [T],
        threads: Option<usize>,
        answer: impl Fn(&Scene, &[[f32; 3]], &mut [T]) -> Result<(), Error> + Sync,
    ) -> PyResult<()> {
        let pool = pool(self.threads(threads)?)?;
        for (p, o) in points.chunks(SLICE).zip(out.chunks_mut(SLICE)) {
            py.detach(|| {
                let _turn = self.busy.lock().unwrap_or_else(|e| e.into_inner());
                pool.install(|| answer(&self.scene, p, o))
            })
            .map_err(to_py)?;
            py.check_signals()?;
        }
        Ok(())
    }
}

impl NativeScene {
    /// One answer per ray of `rays` by `answer`, as an `(N,)` numpy array ([`Self::traced`]).
    fn column<'py, T: numpy::Element + Send + Sync + Copy>(
        &self,
        py: Python<'py>,
        rays: &[Ray],
        threads: Option<usize>,
        fill: T,
        answer: impl Fn(&Scene, &[Ray], &mut [T], Order) -> Result<(), Error> + Sync,
    ) -> PyResult<Bound<'py, PyAny>> {
        let out = zeros::<T>(py, [rays.len(), 1]);
        {
            let mut w = out.readwrite();
            let dst = slice_mut(&mut w)?;
            self.traced(py, rays, threads, fill, answer, |at, a| {
                dst[at..at + a.len()].copy_from_slice(a)
            })?;
        }
        flat(out)
    }
}

/// A C-ordered numpy array of zeros (`calloc`: pages the kernel zeroes as they are first
/// written, so the answers are written once).
fn zeros<'py, T: numpy::Element>(py: Python<'py>, dims: [usize; 2]) -> Bound<'py, PyArray2<T>> {
    PyArray2::<T>::zeros(py, dims, false)
}

/// The contents of a freshly made (so contiguous) array, to fill.
fn slice_mut<'a, T: numpy::Element>(
    a: &'a mut numpy::PyReadwriteArray<'_, T, numpy::Ix2>,
) -> PyResult<&'a mut [T]> {
    a.as_slice_mut()
        .map_err(|e| OavmError::new_err(format!("answer array: {e}")))
}

/// An `(n, 1)` array as the `(n,)` array of its column (a view, no copy).
fn flat<'py, T: numpy::Element>(a: Bound<'py, PyArray2<T>>) -> PyResult<Bound<'py, PyAny>> {
    let n = a.shape()[0];
    Ok(a.reshape([n])?.into_any())
}

#[pymethods]
impl NativeScene {
    /// Closest hits: `(t, prim)`, or with `attributes` `(t, prim, u, v, normal)`.
    #[pyo3(signature = (rays, threads=None, attributes=false))]
    fn intersect<'py>(
        &self,
        py: Python<'py>,
        rays: PyReadonlyArray2<'py, f32>,
        threads: Option<usize>,
        attributes: bool,
    ) -> PyResult<Vec<Bound<'py, PyAny>>> {
        let rays = rays_of(&rays)?;
        let n = rays.len();
        let (t, prim) = (zeros::<f32>(py, [n, 1]), zeros::<u32>(py, [n, 1]));
        let (mut tw, mut pw) = (t.readwrite(), prim.readwrite());
        let (ts, ps) = (slice_mut(&mut tw)?, slice_mut(&mut pw)?);
        if !attributes {
            self.traced(
                py,
                &rays,
                threads,
                Hit::MISS,
                |s, r, o, order| s.intersect_batch_ordered(r, o, order).map(drop),
                |at, hits| {
                    for (k, h) in hits.iter().enumerate() {
                        ts[at + k] = h.t;
                        ps[at + k] = h.prim;
                    }
                },
            )?;
            drop((tw, pw));
            return Ok(vec![flat(t)?, flat(prim)?]);
        }
        let (u, v, normal) = (
            zeros::<f32>(py, [n, 1]),
            zeros::<f32>(py, [n, 1]),
            zeros::<f32>(py, [n, 3]),
        );
        let (mut uw, mut vw, mut nw) = (u.readwrite(), v.readwrite(), normal.readwrite());
        let (us, vs, ns) = (
            slice_mut(&mut uw)?,
            slice_mut(&mut vw)?,
            slice_mut(&mut nw)?,
        );
        self.traced(
            py,
            &rays,
            threads,
            HitAttributes::MISS,
            |s, r, o, order| s.intersect_attributes_ordered(r, o, order).map(drop),
            |at, hits| {
                for (k, h) in hits.iter().enumerate() {
                    let i = at + k;
                    (ts[i], ps[i], us[i], vs[i]) = (h.t, h.prim, h.u, h.v);
                    ns[3 * i..3 * i + 3].copy_from_slice(&h.normal);
                }
            },
        )?;
        drop((tw, pw, uw, vw, nw));
        Ok(vec![
            flat(t)?,
            flat(prim)?,
            flat(u)?,
            flat(v)?,
            normal.into_any(),
        ])
    }

    /// Open3D's `cast_rays` in one pass over `(N, 8)` rays (`RAYS.md`; `oavm.open3d` makes
    /// them from Open3D's with `six_rays`): returns `t_hit`, `geometry_ids` and
    /// `primitive_ids` (the index within the geometry, from the file's geometry table),
    /// `primitive_uvs` `(N, 2)` and `primitive_normals` `(N, 3)`, misses as Open3D gives them
    /// (`inf`, `u32::MAX` ids, zero uvs and normals). What `oavm.open3d` would otherwise
    /// assemble in numpy.
    #[pyo3(signature = (rays, threads=None))]
    fn cast_rays<'py>(
        &self,
        py: Python<'py>,
        rays: PyReadonlyArray2<'py, f32>,
        threads: Option<usize>,
    ) -> PyResult<Vec<Bound<'py, PyAny>>> {
        let rays = rays_of(&rays)?;
        let n = rays.len();
        let t = zeros::<f32>(py, [n, 1]);
        let (geom, prim) = (zeros::<u32>(py, [n, 1]), zeros::<u32>(py, [n, 1]));
        let (uv, normal) = (zeros::<f32>(py, [n, 2]), zeros::<f32>(py, [n, 3]));
        {
            let (mut tw, mut gw, mut pw) = (t.readwrite(), geom.readwrite(), prim.readwrite());
            let (mut uw, mut nw) = (uv.readwrite(), normal.readwrite());
            let (ts, gs, ps) = (
                slice_mut(&mut tw)?,
                slice_mut(&mut gw)?,
                slice_mut(&mut pw)?,
            );
            let (us, ns) = (slice_mut(&mut uw)?, slice_mut(&mut nw)?);
            let scene = &self.scene;
            self.traced(
                py,
                &rays,
                threads,
                HitAttributes::MISS,
                |s, r, o, order| s.intersect_attributes_ordered(r, o, order).map(drop),
                |at, hits| {
                    for (k, h) in hits.iter().enumerate() {
                        let i = at + k;
                        ts[i] = h.t;
                        // Misses stay as `zeros` made them but for the ids.
                        match scene.locate(h.prim) {
                            Some((g, local)) => {
                                (gs[i], ps[i]) = (g, local as u32);
                                (us[2 * i], us[2 * i + 1]) = (h.u, h.v);
                                ns[3 * i..3 * i + 3].copy_from_slice(&h.normal);
                            }
                            None => (gs[i], ps[i]) = (u32::MAX, u32::MAX),
                        }
                    }
                },
            )?;
        }
        Ok(vec![
            flat(t)?,
            flat(geom)?,
            flat(prim)?,
            uv.into_any(),
            normal.into_any(),
        ])
    }

    /// Any-hit answers, as a uint8 array of 0 and 1 (viewed as bool by the Python half).
    #[pyo3(signature = (rays, threads=None))]
    fn occluded<'py>(
        &self,
        py: Python<'py>,
        rays: PyReadonlyArray2<'py, f32>,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyAny>> {
        self.column(py, &rays_of(&rays)?, threads, 0u8, |s, r, o, order| {
            s.occluded_batch_ordered(r, o, order).map(drop)
        })
    }

    /// How many triangles each ray hits, as a uint32 array.
    #[pyo3(signature = (rays, threads=None))]
    fn count_intersections<'py>(
        &self,
        py: Python<'py>,
        rays: PyReadonlyArray2<'py, f32>,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyAny>> {
        self.column(py, &rays_of(&rays)?, threads, 0u32, |s, r, o, _| {
            s.count_intersections(r, o).map(drop)
        })
    }

    /// Every hit of each ray: `(splits, t, prim, uv)`, ray `i`'s hits at
    /// `splits[i]..splits[i + 1]` (uint64, N + 1), in order of `t`; `uv` is `(H, 2)`.
    #[pyo3(signature = (rays, threads=None))]
    fn list_intersections<'py>(
        &self,
        py: Python<'py>,
        rays: PyReadonlyArray2<'py, f32>,
        threads: Option<usize>,
    ) -> PyResult<Vec<Bound<'py, PyAny>>> {
        let rays = rays_of(&rays)?;
        let pool = pool(self.threads(threads)?)?;
        let mut splits: Vec<u64> = Vec::with_capacity(rays.len() + 1);
        splits.push(0);
        let mut hits = Vec::new();
        for slice in rays.chunks(SLICE) {
            let (all, _) = py
                .detach(|| {
                    let _turn = self.busy.lock().unwrap_or_else(|e| e.into_inner());
                    pool.install(|| self.scene.list_intersections(slice))
                })
                .map_err(to_py)?;
            let base = splits[splits.len() - 1];
            splits.extend(all.splits[1..].iter().map(|s| s + base));
            hits.extend_from_slice(&all.hits);
            py.check_signals()?;
        }
        let n = hits.len();
        let (t, prim, uv) = (
            zeros::<f32>(py, [n, 1]),
            zeros::<u32>(py, [n, 1]),
            zeros::<f32>(py, [n, 2]),
        );
        {
            let (mut tw, mut pw, mut uw) = (t.readwrite(), prim.readwrite(), uv.readwrite());
            let (ts, ps, us) = (
                slice_mut(&mut tw)?,
                slice_mut(&mut pw)?,
                slice_mut(&mut uw)?,
            );
            for (i, h) in hits.iter().enumerate() {
                (ts[i], ps[i], us[2 * i], us[2 * i + 1]) = (h.t, h.prim, h.u, h.v);
            }
        }
        let splits = PyArray1::from_vec(py, splits).into_any();
        Ok(vec![splits, flat(t)?, flat(prim)?, uv.into_any()])
    }

    /// The closest point of the surface to each point within `max_distance`: `(points (N,
    /// 3), distance, prim, uv (N, 2), normal (N, 3))`.
    #[pyo3(signature = (points, max_distance=f32::INFINITY, threads=None))]
    fn closest_points<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f32>,
        max_distance: f32,
        threads: Option<usize>,
    ) -> PyResult<Vec<Bound<'py, PyAny>>> {
        let pts = points_of(&points)?;
        let n = pts.len();
        let mut found = vec![ClosestPoint::NONE; n];
        self.per_slice(py, &pts, &mut found, threads, |s, p, o| {
            s.closest_points(p, max_distance, o).map(drop)
        })?;
        let (pt, d, prim, uv, nrm) = (
            zeros::<f32>(py, [n, 3]),
            zeros::<f32>(py, [n, 1]),
            zeros::<u32>(py, [n, 1]),
            zeros::<f32>(py, [n, 2]),
            zeros::<f32>(py, [n, 3]),
        );
        {
            let (mut a, mut b, mut c, mut e, mut f) = (
                pt.readwrite(),
                d.readwrite(),
                prim.readwrite(),
                uv.readwrite(),
                nrm.readwrite(),
            );
            let (a, b, c, e, f) = (
                slice_mut(&mut a)?,
                slice_mut(&mut b)?,
                slice_mut(&mut c)?,
                slice_mut(&mut e)?,
                slice_mut(&mut f)?,
            );
            for (i, r) in found.iter().enumerate() {
                a[3 * i..3 * i + 3].copy_from_slice(&r.point);
                (b[i], c[i], e[2 * i], e[2 * i + 1]) = (r.distance, r.prim, r.u, r.v);
                f[3 * i..3 * i + 3].copy_from_slice(&r.normal);
            }
        }
        Ok(vec![
            pt.into_any(),
            flat(d)?,
            flat(prim)?,
            uv.into_any(),
            nrm.into_any(),
        ])
    }

    /// Whether each point is inside (1) or not (0), by a vote of three rays.
    #[pyo3(signature = (points, threads=None))]
    fn occupancy<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f32>,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let pts = points_of(&points)?;
        let mut occ = vec![0u8; pts.len()];
        self.per_slice(py, &pts, &mut occ, threads, |s, p, o| {
            s.occupancy(p, o).map(drop)
        })?;
        let out = zeros::<u8>(py, [pts.len(), 1]);
        slice_mut(&mut out.readwrite())?.copy_from_slice(&occ);
        flat(out)
    }

    /// Checks every byte, checksum and invariant; the report as JSON (`ok`, `defects`, ...).
    fn verify(&self, py: Python<'_>) -> PyResult<String> {
        let pool = pool(cores())?;
        let t = std::time::Instant::now();
        let report = py
            .detach(|| {
                let _turn = self.busy.lock().unwrap_or_else(|e| e.into_inner());
                pool.install(|| self.scene.verify())
            })
            .map_err(to_py)?;
        Ok(serde_json::json!({
            "path": self.scene.path(),
            "ok": report.is_ok(),
            "seconds": t.elapsed().as_secs_f64(),
            "bytes_checked": report.bytes_checked,
            "sections_checked": report.sections_checked,
            "defects": report.defects,
        })
        .to_string())
    }

    /// The header, the counts and the tracing set-up, as JSON.
    /// The geometry table (format-spec §8.8): `(name, first_primitive, primitive_count,
    /// transform)` each, the transform row-major 3x4; empty for a file of one mesh.
    fn geometries(&self) -> Vec<GeometryTuple> {
        self.scene.geometries().iter().map(geometry_tuple).collect()
    }

    fn info(&self) -> String {
        let h = self.scene.file().header();
        let s = self.scene.info();
        serde_json::json!({
            "path": self.scene.path(),
            "format_version": h.version,
            "file_bytes": s.file_bytes,
            "leaf": if h.flags & FLAG_CLUSTERS != 0 { "cluster" } else { "list" },
            "merged": h.flags & FLAG_MERGED != 0,
            "compressed": h.flags & FLAG_COMPRESSED != 0,
            "input_triangles": h.input_triangles,
            "stored_triangles": h.stored_triangles,
            "block_triangles": h.block_triangles,
            "mesh_min": h.mesh_min,
            "mesh_max": h.mesh_max,
            "root_min": h.root_min,
            "root_size": h.root_size,
            "levels": h.level_count,
            "max_depth": h.max_depth,
            "leaf_size": h.leaf_size,
            "solid_leaves": h.solid_leaves,
            "empty_leaves": h.empty_leaves,
            "blocks": h.block_count,
            "max_block_raw_len": h.max_block_raw_len,
            "decoded_bytes": self.scene.decoded_bytes(),
            "mem_budget": self.scene.budget(),
            "fits_in_budget": self.scene.fits_in_budget(),
            "threads": self.scene.default_threads(cores()),
            "max_threads": self.scene.threads(),
            "pager_peak_resident_bytes": s.pager_peak_resident_bytes,
        })
        .to_string()
    }
}

/// A geometry as Python sees it: `(name, first_primitive, primitive_count, transform)`, the
/// transform's 12 numbers row-major.
type GeometryTuple = (String, u64, u64, Vec<f64>);

fn geometry_tuple(g: &oavm::mesh::Geometry) -> GeometryTuple {
    (
        g.name.clone(),
        g.first_primitive,
        g.primitive_count,
        g.transform.as_flattened().to_vec(),
    )
}

/// A geometry as Python gives it: `(name, primitive_count, transform)`.
type GivenGeometry = (String, u64, Option<Vec<f64>>);

/// Geometries from Python's `(name, primitive_count, transform)` triples (a transform of 12
/// numbers, row-major 3x4, or none for the identity), one after another from primitive 0.
fn geometries_of(given: Option<Vec<GivenGeometry>>) -> PyResult<Vec<oavm::mesh::Geometry>> {
    let mut first = 0u64;
    let mut out = Vec::new();
    for (name, count, transform) in given.unwrap_or_default() {
        let transform = match transform {
            None => oavm::mesh::Geometry::IDENTITY,
            Some(t) if t.len() == 12 => {
                std::array::from_fn(|r| std::array::from_fn(|c| t[4 * r + c]))
            }
            Some(t) => {
                return Err(PyValueError::new_err(format!(
                    "geometry {name:?}: a transform of {} numbers, expected 12 (3x4, row-major)",
                    t.len()
                )));
            }
        };
        out.push(oavm::mesh::Geometry {
            name,
            first_primitive: first,
            primitive_count: count,
            transform,
        });
        first = first.saturating_add(count);
    }
    Ok(out)
}

/// Opens a file, O(1) in its size: the header, section table and top tree's level table.
#[pyfunction]
#[pyo3(signature = (path, mem_budget=None, walk="auto"))]
fn open(
    py: Python<'_>,
    path: PathBuf,
    mem_budget: Option<u64>,
    walk: &str,
) -> PyResult<NativeScene> {
    let walk = match walk {
        "auto" => Walk::Auto,
        "wide" => Walk::Wide,
        "topdown" => Walk::TopDown,
        "neighbours" => Walk::Neighbours,
        "ropes" => Walk::Ropes,
        other => {
            return Err(PyValueError::new_err(format!(
                "walk must be 'auto', 'wide', 'topdown', 'neighbours' or 'ropes', not {other:?}"
            )));
        }
    };
    let opts = SceneOptions {
        mem_budget,
        // As `oavm-trace`: room for the reader threads a budget smaller than the file wants;
        // each call traces on `Scene::default_threads` of them unless told otherwise.
        threads: cores() * IO_THREADS_PER_CORE,
        check_blocks: true,
        block_reads: BlockReads::Auto,
        walk,
        chunks: false,
    };
    let scene = py
        .detach(|| Scene::open_with(&path, &opts))
        .map_err(to_py)?;
    Ok(NativeScene {
        scene,
        busy: Mutex::new(()),
    })
}

/// The pack options from the keyword arguments.
#[allow(clippy::too_many_arguments)]
fn pack_options(
    leaf: &str,
    leaf_size: Option<u32>,
    max_depth: Option<u32>,
    compress: Option<i32>,
    mem_budget: Option<u64>,
    block_size: Option<u64>,
    ropes: bool,
    updatable: bool,
    bounds: Option<([f32; 3], [f32; 3])>,
) -> PyResult<PackOptions> {
    let leaf = match leaf {
        "cluster" => LeafKind::Cluster,
        "list" => LeafKind::List,
        other => {
            return Err(PyValueError::new_err(format!(
                "leaf must be 'cluster' or 'list', not {other:?}"
            )));
        }
    };
    let opts = PackOptions {
        build: BuildOptions {
            max_depth: max_depth.unwrap_or(oavm::pack::DEFAULT_MAX_DEPTH),
            leaf_size: leaf_size.unwrap_or(leaf.default_leaf_size()),
            leaf,
            merge: true,
        },
        blocks: BlockOptions {
            block_size: block_size.unwrap_or(DEFAULT_BLOCK_SIZE),
            compress,
            ..BlockOptions::default()
        },
        time: None,
        mem_budget,
        ropes,
        occluders: false,
        updatable,
        bounds,
    };
    opts.validate().map_err(to_py)?;
    Ok(opts)
}

/// Runs a pack with the GIL released and a progress bar on a terminal's stderr.
fn run_pack(
    py: Python<'_>,
    progress: bool,
    threads: Option<usize>,
    pack: impl FnOnce(&dyn oavm::pack::Progress) -> Result<PackReport, Error> + Send,
) -> PyResult<String> {
    let pool = pool(threads.unwrap_or_else(cores).max(1))?;
    let report = py
        .detach(|| {
            let bar = oavm::progress::Bar::new(progress && std::io::stderr().is_terminal());
            let r = pool.install(|| pack(&bar));
            bar.finish();
            r
        })
        .map_err(to_py)?;
    serde_json::to_string(&report)
        .map_err(|e| OavmError::new_err(format!("cannot write the report: {e}")))
}

/// The triangles of a mesh file (PLY, OBJ, STL, OFF, glTF/GLB, AFF posed at `time`) as oavm reads
/// them: `(V, 3)` float32 vertices and `(F, 3)` uint32 faces, face `i` being primitive `i`.
#[pyfunction]
#[pyo3(signature = (mesh, time=None))]
fn load_mesh<'py>(
    py: Python<'py>,
    mesh: PathBuf,
    time: Option<f64>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>, Vec<GeometryTuple>)> {
    let m = py
        .detach(|| oavm::mesh::load_at(&mesh, time))
        .map_err(|e| to_py(e.into()))?;
    let v = PyArray1::from_vec(py, m.positions.as_flattened().to_vec())
        .reshape([m.positions.len(), 3])?;
    let f = PyArray1::from_vec(py, m.triangles.as_flattened().to_vec())
        .reshape([m.triangles.len(), 3])?;
    let g = m.geometries.iter().map(geometry_tuple).collect();
    Ok((v.into_any(), f.into_any(), g))
}

/// Packs a mesh file (PLY, OBJ, STL, OFF, glTF/GLB, AFF); the report as JSON.
#[pyfunction]
#[pyo3(signature = (mesh, out, leaf="cluster", leaf_size=None, max_depth=None, compress=None,
                    mem_budget=None, block_size=None, progress=true, threads=None, ropes=false,
                    updatable=false, bounds=None))]
#[allow(clippy::too_many_arguments)]
fn pack_file(
    py: Python<'_>,
    mesh: PathBuf,
    out: PathBuf,
    leaf: &str,
    leaf_size: Option<u32>,
    max_depth: Option<u32>,
    compress: Option<i32>,
    mem_budget: Option<u64>,
    block_size: Option<u64>,
    progress: bool,
    threads: Option<usize>,
    ropes: bool,
    updatable: bool,
    bounds: Option<([f32; 3], [f32; 3])>,
) -> PyResult<String> {
    let opts = pack_options(
        leaf, leaf_size, max_depth, compress, mem_budget, block_size, ropes, updatable, bounds,
    )?;
    run_pack(py, progress, threads, |bar| {
        oavm::pack::pack(&mesh, &out, &opts, bar)
    })
}

/// Packs a mesh given as a `(V, 3)` float32 vertex array and a `(F, 3)` uint32 face array
/// (with `geometries`, several meshes one after another: `(name, faces, transform)` each);
/// the report as JSON.
#[pyfunction]
#[pyo3(signature = (vertices, faces, out, leaf="cluster", leaf_size=None, max_depth=None,
                    compress=None, block_size=None, progress=true, threads=None, ropes=false,
                    updatable=false, bounds=None, geometries=None))]
#[allow(clippy::too_many_arguments)]
fn pack_arrays(
    py: Python<'_>,
    vertices: PyReadonlyArray2<'_, f32>,
    faces: PyReadonlyArray2<'_, u32>,
    out: PathBuf,
    leaf: &str,
    leaf_size: Option<u32>,
    max_depth: Option<u32>,
    compress: Option<i32>,
    block_size: Option<u64>,
    progress: bool,
    threads: Option<usize>,
    ropes: bool,
    updatable: bool,
    bounds: Option<([f32; 3], [f32; 3])>,
    geometries: Option<Vec<GivenGeometry>>,
) -> PyResult<String> {
    let opts = pack_options(
        leaf, leaf_size, max_depth, compress, None, block_size, ropes, updatable, bounds,
    )?;
    let (mut mesh, name) = arrays_mesh(&vertices, &faces)?;
    mesh.geometries = geometries_of(geometries)?;
    run_pack(py, progress, threads, |bar| {
        // The options were checked above: what is invalid now is the mesh (an index out of
        // range, a non-finite corner, no triangles), reported as for a mesh file.
        oavm::pack::pack_mesh(mesh, &name, &out, &opts, bar).map_err(|e| match e {
            Error::Invalid(what) => {
                Error::Mesh(oavm::error::MeshError::Arrays(format!("{name}: {what}")))
            }
            e => e,
        })
    })
}

/// A mesh from a `(V, 3)` float32 vertex array and a `(F, 3)` uint32 face array, and its name
/// for reports.
fn arrays_mesh(
    vertices: &PyReadonlyArray2<'_, f32>,
    faces: &PyReadonlyArray2<'_, u32>,
) -> PyResult<(Mesh, String)> {
    let three = |name: &str, shape: &[usize]| {
        if shape[1] == 3 {
            Ok(())
        } else {
            Err(PyValueError::new_err(format!(
                "{name}: expected shape ({}, 3), got ({}, {})",
                if name == "vertices" { "V" } else { "F" },
                shape[0],
                shape[1]
            )))
        }
    };
    three("vertices", vertices.shape())?;
    three("faces", faces.shape())?;
    let v = vertices
        .as_slice()
        .map_err(|e| PyValueError::new_err(format!("vertices: {e}")))?;
    let f = faces
        .as_slice()
        .map_err(|e| PyValueError::new_err(format!("faces: {e}")))?;
    let mesh = Mesh {
        geometries: Vec::new(),
        positions: v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        triangles: f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    };
    let name = format!(
        "arrays ({} vertices, {} faces)",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    Ok((mesh, name))
}

/// Runs an update of the file at `path` to `mesh` (loaded inside, with the GIL released).
fn run_update(
    py: Python<'_>,
    path: PathBuf,
    threads: Option<usize>,
    opts: UpdateOptions,
    mesh: impl FnOnce() -> Result<Mesh, Error> + Send,
) -> PyResult<String> {
    opts.validate().map_err(to_py)?;
    let pool = pool(threads.unwrap_or_else(cores).max(1))?;
    let report = py
        .detach(|| {
            pool.install(|| {
                let mut u = Updater::open(&path)?;
                let mesh = mesh()?;
                u.set_mesh(&mesh)?;
                drop(mesh);
                u.commit(&opts)
            })
        })
        .map_err(to_py)?;
    serde_json::to_string(&report)
        .map_err(|e| OavmError::new_err(format!("cannot write the report: {e}")))
}

fn update_options(block_size: Option<u64>, compress: Option<i32>, raw: bool) -> UpdateOptions {
    UpdateOptions {
        block_size: block_size.unwrap_or(DEFAULT_BLOCK_SIZE),
        compress: if raw { Some(None) } else { compress.map(Some) },
    }
}

/// Updates a file packed with `updatable=True` to the triangles of a mesh file (an AFF scene
/// posed at `time`); the report as JSON.
#[pyfunction]
#[pyo3(signature = (path, mesh, time=None, block_size=None, compress=None, raw=false, threads=None))]
#[allow(clippy::too_many_arguments)]
fn update_file(
    py: Python<'_>,
    path: PathBuf,
    mesh: PathBuf,
    time: Option<f64>,
    block_size: Option<u64>,
    compress: Option<i32>,
    raw: bool,
    threads: Option<usize>,
) -> PyResult<String> {
    let opts = update_options(block_size, compress, raw);
    run_update(py, path, threads, opts, || {
        Ok(oavm::mesh::load_at(&mesh, time)?)
    })
}

/// Updates a file packed with `updatable=True` to a mesh given as arrays (face i is primitive
/// i; `geometries` as for `pack_arrays`, else the file's table kept); the report as JSON.
#[pyfunction]
#[pyo3(signature = (path, vertices, faces, block_size=None, compress=None, raw=false, threads=None,
                    geometries=None))]
#[allow(clippy::too_many_arguments)]
fn update_arrays(
    py: Python<'_>,
    path: PathBuf,
    vertices: PyReadonlyArray2<'_, f32>,
    faces: PyReadonlyArray2<'_, u32>,
    block_size: Option<u64>,
    compress: Option<i32>,
    raw: bool,
    threads: Option<usize>,
    geometries: Option<Vec<GivenGeometry>>,
) -> PyResult<String> {
    let opts = update_options(block_size, compress, raw);
    let (mut mesh, _) = arrays_mesh(&vertices, &faces)?;
    mesh.geometries = geometries_of(geometries)?;
    run_update(py, path, threads, opts, || Ok(mesh))
}

/// Rewrites an updated file without what older generations left; the report as JSON.
#[pyfunction]
fn compact(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    let report = py
        .detach(|| oavm::pack::update::compact(&path, &path))
        .map_err(to_py)?;
    serde_json::to_string(&report)
        .map_err(|e| OavmError::new_err(format!("cannot write the report: {e}")))
}

/// The rays of pixels `start..stop` (row-major from the top left) of a `width` x `height`
/// image, as a `(stop - start, 8)` float32 array: bit for bit `oavm-trace`'s primary rays. The
/// camera frames the box `[mesh_min, mesh_max]` as `oavm-trace` does, then `eye`, `target`,
/// `up`, `fov` (degrees, vertical) replace what they name.
/// An `(rows, width)` array of `T` filled by `fill(first_row, rows)` over chunks of 4096 rows
/// at a time, on the library's threads with the GIL released: the drop-ins' conversions.
fn filled<'py, T: numpy::Element + Send>(
    py: Python<'py>,
    rows: usize,
    width: usize,
    threads: Option<usize>,
    fill: impl Fn(usize, &mut [T]) + Sync,
) -> PyResult<Bound<'py, PyAny>> {
    use rayon::prelude::*;
    const ROWS: usize = 4096;
    let out = zeros::<T>(py, [rows, width]);
    {
        let mut w = out.readwrite();
        let dst = slice_mut(&mut w)?;
        let pool = pool(threads.unwrap_or_else(cores).max(1))?;
        py.detach(|| {
            pool.install(|| {
                dst.par_chunks_mut(width * ROWS)
                    .enumerate()
                    .for_each(|(c, chunk)| fill(c * ROWS, chunk))
            })
        });
    }
    Ok(out.into_any())
}

/// A direction made unit as trimesh makes it, in float64: `d / |d|`, a zero direction left
/// zero (so its ray misses).
fn unit(d: &[f64]) -> [f64; 3] {
    let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    std::array::from_fn(|k| if norm == 0.0 { 0.0 } else { d[k] / norm })
}

/// The contents of a contiguous array, or a `ValueError` naming it.
fn contents<'a, T: numpy::Element, D: numpy::ndarray::Dimension>(
    name: &str,
    a: &'a numpy::PyReadonlyArray<'_, T, D>,
) -> PyResult<&'a [T]> {
    a.as_slice()
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))
}

/// trimesh's hit locations: for each hit `h`, `origins[ray[h]] + unit(directions[ray[h]]) *
/// t[h]` in float64, the unit direction as [`unit_rays`] makes it. An index past the rays is
/// an error.
#[pyfunction]
#[pyo3(signature = (origins, directions, index_ray, t, threads=None))]
fn hit_locations<'py>(
    py: Python<'py>,
    origins: PyReadonlyArray2<'py, f64>,
    directions: PyReadonlyArray2<'py, f64>,
    index_ray: numpy::PyReadonlyArray1<'py, i64>,
    t: numpy::PyReadonlyArray1<'py, f32>,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let (o, d) = (
        contents("origins", &origins)?,
        contents("directions", &directions)?,
    );
    let (rays, t) = (contents("index_ray", &index_ray)?, contents("t", &t)?);
    let n = (o.len() / 3) as i64;
    if o.len() != d.len() || rays.len() != t.len() {
        let what = "origins and directions, index_ray and t: lengths differ";
        return Err(PyValueError::new_err(what));
    }
    if let Some(bad) = rays.iter().find(|&&i| !(0..n).contains(&i)) {
        let what = format!("index_ray: {bad} is not one of the {n} rays");
        return Err(PyValueError::new_err(what));
    }
    filled(py, rays.len(), 3, threads, |first, loc| {
        for (h, p) in loc.chunks_exact_mut(3).enumerate() {
            let (k, t) = (3 * rays[first + h] as usize, t[first + h] as f64);
            let u = unit(&d[k..k + 3]);
            for c in 0..3 {
                p[c] = o[k + c] + u[c] * t;
            }
        }
    })
}

/// Open3D's rays as oavm's: `(N, 6)` float32 (origin, direction) with `tnear`, `tfar` as
/// the `(N, 8)` array of `RAYS.md` (what `oavm.open3d` would otherwise copy column by column
/// in numpy).
#[pyfunction]
#[pyo3(signature = (rays, tnear, tfar, threads=None))]
fn six_rays<'py>(
    py: Python<'py>,
    rays: PyReadonlyArray2<'py, f32>,
    tnear: f32,
    tfar: f32,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    if rays.shape()[1] != 6 {
        return Err(PyValueError::new_err(format!(
            "rays: expected shape (N, 6), got ({}, {})",
            rays.shape()[0],
            rays.shape()[1]
        )));
    }
    let six = contents("rays", &rays)?;
    filled(py, six.len() / 6, 8, threads, |first, out| {
        for (i, r) in out.chunks_exact_mut(8).enumerate() {
            let c = &six[6 * (first + i)..6 * (first + i) + 6];
            r.copy_from_slice(&[c[0], c[1], c[2], tnear, c[3], c[4], c[5], tfar]);
        }
    })
}

/// trimesh's rays as oavm's: float64 `(N, 3)` origins moved by `-shift` and directions made
/// unit in float64 ([`unit`]), as the `(N, 8)` float32 array of `RAYS.md` (tmin 0, tmax
/// inf). What `oavm.trimesh` would otherwise do in numpy, at a fifth of the time of its hits.
#[pyfunction]
#[pyo3(signature = (origins, directions, shift, threads=None))]
fn unit_rays<'py>(
    py: Python<'py>,
    origins: PyReadonlyArray2<'py, f64>,
    directions: PyReadonlyArray2<'py, f64>,
    shift: [f64; 3],
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    if origins.shape()[1] != 3 || origins.shape() != directions.shape() {
        return Err(PyValueError::new_err(format!(
            "ray_origins and ray_directions: expected two (n, 3) arrays, got {:?} and {:?}",
            origins.shape(),
            directions.shape()
        )));
    }
    let (o, d) = (
        contents("ray_origins", &origins)?,
        contents("ray_directions", &directions)?,
    );
    filled(py, o.len() / 3, 8, threads, |first, out| {
        for (i, r) in out.chunks_exact_mut(8).enumerate() {
            let k = 3 * (first + i);
            let u = unit(&d[k..k + 3]);
            r.copy_from_slice(&[
                (o[k] - shift[0]) as f32,
                (o[k + 1] - shift[1]) as f32,
                (o[k + 2] - shift[2]) as f32,
                0.0,
                u[0] as f32,
                u[1] as f32,
                u[2] as f32,
                f32::INFINITY,
            ]);
        }
    })
}

#[pyfunction]
#[pyo3(signature = (mesh_min, mesh_max, width, height, eye=None, target=None, up=None, fov=None,
                    start=0, stop=None))]
#[allow(clippy::too_many_arguments)]
fn camera_rays<'py>(
    py: Python<'py>,
    mesh_min: [f32; 3],
    mesh_max: [f32; 3],
    width: u32,
    height: u32,
    eye: Option<[f64; 3]>,
    target: Option<[f64; 3]>,
    up: Option<[f64; 3]>,
    fov: Option<f64>,
    start: u64,
    stop: Option<u64>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let pixels = width as u64 * height as u64;
    let stop = stop.unwrap_or(pixels);
    if width == 0 || height == 0 || start > stop || stop > pixels {
        return Err(PyValueError::new_err(format!(
            "pixels {start}..{stop} of a {width} x {height} image: need 0 < width, height and \
             start <= stop <= width * height"
        )));
    }
    let framing = Camera::framing(&Bounds {
        min: mesh_min,
        max: mesh_max,
    });
    let camera = Camera::look_at(
        eye.unwrap_or(framing.eye),
        target.unwrap_or(framing.target),
        up.unwrap_or(framing.up),
        fov.unwrap_or(framing.fov_y),
    )
    .map_err(|e| PyValueError::new_err(format!("camera: {e}")))?;
    let view = camera.pixels(width, height);
    let n = (stop - start) as usize;
    let flat: Vec<f32> = py.detach(|| {
        (start..stop)
            .flat_map(|i| {
                let r = view.ray((i % width as u64) as u32, (i / width as u64) as u32);
                bytemuck::cast::<Ray, [f32; 8]>(r)
            })
            .collect()
    });
    PyArray1::from_vec(py, flat).reshape([n, 8])
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<NativeScene>()?;
    m.add_function(wrap_pyfunction!(open, m)?)?;
    m.add_function(wrap_pyfunction!(pack_file, m)?)?;
    m.add_function(wrap_pyfunction!(load_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(pack_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(update_file, m)?)?;
    m.add_function(wrap_pyfunction!(update_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(compact, m)?)?;
    m.add_function(wrap_pyfunction!(camera_rays, m)?)?;
    m.add_function(wrap_pyfunction!(unit_rays, m)?)?;
    m.add_function(wrap_pyfunction!(six_rays, m)?)?;
    m.add_function(wrap_pyfunction!(hit_locations, m)?)?;
    m.add("OavmError", m.py().get_type::<OavmError>())?;
    m.add("FormatError", m.py().get_type::<FormatError>())?;
    m.add("MeshError", m.py().get_type::<MeshError>())?;
    m.add("FORMAT_VERSION", VERSION)?;
    m.add("VOTE_DIRECTIONS", oavm::logical::VOTE_DIRECTIONS.to_vec())?;
    Ok(())
}
