"""An Open3D-shaped interface: ``oavm.open3d.RaycastingScene`` answers the calls of
``open3d.t.geometry.RaycastingScene`` over an ``.oavm`` file.

Open3D's scene lives in memory only (it cannot be saved, copied or pickled) and builds its BVH
again in every process. This one packs the meshes added to it into an ``.oavm`` file in a cache
directory on first query (named by a hash of the meshes, so the next run opens it), or opens a
file packed before (:meth:`RaycastingScene.open`); it pickles (by the file's path).

Arguments are numpy arrays, Open3D tensors or anything with ``.numpy()``; rays have any leading
shape ``(..., 6)`` (origin, direction; the direction's length is the unit of ``t_hit``). Answers
come back as numpy arrays of Open3D's dtypes and shapes, with a ``.numpy()`` method that returns
them as plain arrays, so code written for Open3D (``ans['t_hit'].numpy()``) runs unchanged.
Misses are Open3D's: ``t_hit`` inf, ids ``INVALID_ID``, uvs and normals 0.

Several meshes: each :meth:`~RaycastingScene.add_triangles` returns its geometry id (0, 1, ...),
and hits name the geometry and the triangle's index within it, as Open3D's do.
"""

from __future__ import annotations

import math
import os
from typing import Any, List, Optional, Tuple, Union

import numpy as np

from . import Scene, _mesh_object
from . import _cache, _native
from . import open as open_scene

__all__ = ["RaycastingScene", "INVALID_ID"]

#: The id of no geometry and no primitive (Open3D's ``RaycastingScene.INVALID_ID``).
INVALID_ID = 0xFFFFFFFF


class _Array(np.ndarray):
    """A numpy array that also answers ``.numpy()`` (as an Open3D tensor does)."""

    def numpy(self) -> np.ndarray:
        return self.view(np.ndarray)


def _answer(a: np.ndarray) -> _Array:
    return np.asarray(a).view(_Array)


def _numpy(name: str, x: Any) -> np.ndarray:
    if hasattr(x, "numpy") and not isinstance(x, np.ndarray):
        x = x.numpy()
    try:
        return np.asarray(x)
    except Exception as e:
        raise ValueError(f"{name}: cannot be read as an array: {e}") from None


def _mesh_arrays(mesh: Any) -> Tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of an Open3D tensor or legacy mesh, a trimesh mesh, a meshio
    mesh (its triangle cells) or a ``(vertices, triangles)`` pair."""
    arrays = _mesh_object(mesh)
    if isinstance(arrays, (tuple, list)) and len(arrays) == 2:
        return _numpy("vertices", arrays[0]), _numpy("triangles", arrays[1])
    raise ValueError(f"mesh: expected an Open3D, trimesh or meshio mesh or (vertices, triangles), got {type(mesh).__name__}")


def _rays(rays: Any) -> Tuple[np.ndarray, Tuple[int, ...]]:
    """The ``(N, 6)`` float32 rays of ``(..., 6)`` and the leading shape."""
    r = _numpy("rays", rays)
    if r.ndim < 1 or r.shape[-1] != 6:
        raise ValueError(f"rays: expected shape (..., 6) (origin, direction), got {r.shape}")
    if r.dtype.kind not in "fiu":
        raise ValueError(f"rays: dtype {r.dtype} is not a real number type")
    lead = r.shape[:-1]
    return r.reshape(-1, 6).astype(np.float32, copy=False), lead


def _points(points: Any) -> Tuple[np.ndarray, Tuple[int, ...]]:
    p = _numpy("query_points", points)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"query_points: expected shape (..., 3), got {p.shape}")
    return p.reshape(-1, 3).astype(np.float32, copy=False), p.shape[:-1]


def _threads(nthreads: int) -> Optional[int]:
    n = int(nthreads)
    if n < 0:
        raise ValueError(f"nthreads: {n} is negative (0: automatic)")
    return n or None


class RaycastingScene:
    """Open3D's ``RaycastingScene`` over an ``.oavm`` file.

    ``cache_dir``: where the file packed from the added meshes is kept (default
    ``$OAVM_CACHE_DIR``, else ``~/.cache/oavm``); ``mem_budget``: see :func:`oavm.open`."""

    INVALID_ID = INVALID_ID

    def __init__(self, nthreads: int = 0, *, cache_dir: Union[None, str, "os.PathLike[str]"] = None,
                 mem_budget: Union[None, int, str] = None):
        self._threads = _threads(nthreads)
        self._cache_dir = cache_dir
        self._mem_budget = mem_budget
        self._vertices: List[np.ndarray] = []
        self._triangles: List[np.ndarray] = []
        self._normals: Optional[np.ndarray] = None
        self._scene: Optional[Scene] = None
        self._path: Optional[str] = None

    @classmethod
    def open(cls, path: Union[str, "os.PathLike[str]"], *, mem_budget: Union[None, int, str] = None,
             nthreads: int = 0) -> "RaycastingScene":
        """A scene over a file packed before (:func:`oavm.pack`), which may be larger than
        memory: nothing is read but its header and top tree until rays come. Its geometries are
        those of the file's geometry table (one, id 0, for a file packed from one mesh)."""
        s = cls(nthreads, mem_budget=mem_budget)
        s._scene = open_scene(path, mem_budget=mem_budget)
        s._path = os.fspath(path)
        return s

    def add_triangles(self, vertex_positions: Any, triangle_indices: Any = None) -> int:
        """Adds a mesh (``vertex_positions`` ``(V, 3)`` and ``triangle_indices`` ``(F, 3)``, or
        one mesh object) and returns its geometry id."""
        if self._path is not None:
            raise ValueError(f"{self._path}: a scene opened from a file takes no more meshes")
        v, f = (_mesh_arrays(vertex_positions) if triangle_indices is None
                else (_numpy("vertex_positions", vertex_positions), _numpy("triangle_indices", triangle_indices)))
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"expected (V, 3) vertex positions and (F, 3) triangle indices, got {v.shape} and {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ValueError(f"triangle_indices: indices must be in 0..{len(v) - 1}")
        base = sum(len(x) for x in self._vertices)
        self._vertices.append(v.astype(np.float32))
        self._triangles.append(f.astype(np.int64) + base)
        self._scene, self._normals = None, None
        return len(self._triangles) - 1

    def _opened(self) -> Scene:
        if self._scene is None:
            if not self._triangles:
                raise ValueError("the scene has no geometry: add_triangles first")
            v = np.concatenate(self._vertices)
            f = np.concatenate(self._triangles).astype(np.uint32)
            # Several meshes are stored with the file's geometry table, so the file opened
            # later on its own (RaycastingScene.open) names them too.
            geoms = ([(f"geometry {i}", len(t), None) for i, t in enumerate(self._triangles)]
                     if len(self._triangles) > 1 else None)
            self._scene = _cache.opened(v, f, self._cache_dir, self._mem_budget, geometries=geoms)
        return self._scene

    def _ids(self, prim: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Geometry ids and primitive ids within them of the file's primitive ids ``prim``
        (``INVALID_ID`` stays), from the file's geometry table."""
        return self._opened().locate(prim)

    def _ray_array(self, r6: np.ndarray, tnear: float = 0.0, tfar: float = math.inf) -> np.ndarray:
        return _native.six_rays(np.ascontiguousarray(r6), float(tnear), float(tfar), self._threads)

    def cast_rays(self, rays: Any, nthreads: int = 0) -> dict:
        """The first hit of each ray: ``t_hit``, ``geometry_ids``, ``primitive_ids``,
        ``primitive_uvs`` ``(..., 2)``, ``primitive_normals`` ``(..., 3)`` (unit, following
        the triangle's winding)."""
        r6, lead = _rays(rays)
        t, geom, prim, uv, normal = self._opened()._scene().cast_rays(
            self._ray_array(r6), threads=_threads(nthreads) or self._threads)
        return {
            "t_hit": _answer(t.reshape(lead)),
            "geometry_ids": _answer(geom.reshape(lead)),
            "primitive_ids": _answer(prim.reshape(lead)),
            "primitive_uvs": _answer(uv.reshape(lead + (2,))),
            "primitive_normals": _answer(normal.reshape(lead + (3,))),
        }

    def test_occlusions(self, rays: Any, tnear: float = 0.0, tfar: float = math.inf, nthreads: int = 0) -> _Array:
        """Whether each ray hits anything with ``tnear <= t <= tfar`` (bool, shape ``(...)``)."""
        r6, lead = _rays(rays)
        occ = self._opened().occluded(self._ray_array(r6, tnear, tfar), threads=_threads(nthreads) or self._threads)
        return _answer(occ.reshape(lead))

    def count_intersections(self, rays: Any, nthreads: int = 0) -> _Array:
        """How many triangles each ray hits (int32, shape ``(...)``); exact on shared edges and
        corners (one hit where a ray passes through one)."""
        r6, lead = _rays(rays)
        n = self._opened().count_intersections(self._ray_array(r6), threads=_threads(nthreads) or self._threads)
        return _answer(n.astype(np.int32).reshape(lead))

    def list_intersections(self, rays: Any, nthreads: int = 0) -> dict:
        """Every hit of every ray: ``ray_splits`` (uint32, ``N + 1``), ``ray_ids``,
        ``geometry_ids``, ``primitive_ids``, ``primitive_uvs`` ``(H, 2)``, ``t_hit``; each ray's
        hits in order of ``t`` (Open3D's come in the order Embree finds them)."""
        r6, _ = _rays(rays)
        lists = self._opened().list_intersections(self._ray_array(r6), threads=_threads(nthreads) or self._threads)
        geom, local = self._ids(lists["primitive_ids"])
        return {
            "ray_splits": _answer(lists["ray_splits"].astype(np.uint32)),
            "ray_ids": _answer(lists["ray_ids"]),
            "geometry_ids": _answer(geom),
            "primitive_ids": _answer(local),
            "primitive_uvs": _answer(lists["primitive_uvs"]),
            "t_hit": _answer(lists["t_hit"]),
        }

    def compute_closest_points(self, query_points: Any, nthreads: int = 0) -> dict:
        """The closest point of the surface to each query point (``(..., 3)``): ``points``,
        ``geometry_ids``, ``primitive_ids``, ``primitive_uvs`` ``(..., 2)``,
        ``primitive_normals`` ``(..., 3)``."""
        p, lead = _points(query_points)
        c = self._opened().closest_points(p, threads=_threads(nthreads) or self._threads)
        geom, local = self._ids(c.prim)
        return {
            "points": _answer(c.point.reshape(lead + (3,))),
            "geometry_ids": _answer(geom.reshape(lead)),
            "primitive_ids": _answer(local.reshape(lead)),
            "primitive_uvs": _answer(c.uv.reshape(lead + (2,))),
            "primitive_normals": _answer(c.normal.reshape(lead + (3,))),
        }

    def compute_distance(self, query_points: Any, nthreads: int = 0) -> _Array:
        """The distance from each query point to the surface (float32, shape ``(...)``)."""
        p, lead = _points(query_points)
        d = self._opened().closest_points(p, threads=_threads(nthreads) or self._threads).distance
        return _answer(d.reshape(lead))

    def compute_occupancy(self, query_points: Any, nthreads: int = 0, nsamples: int = 1) -> _Array:
        """1.0 where a query point is inside, else 0.0 (float32, shape ``(...)``). Inside is
        decided by a vote of three rays whose crossings are counted exactly (a ray through an
        edge or a corner crosses once), whatever ``nsamples`` (taken for Open3D's signature;
        it must be odd, as there)."""
        if int(nsamples) < 1 or int(nsamples) % 2 == 0:
            raise ValueError(f"nsamples: {nsamples} is not a positive odd number")
        p, lead = _points(query_points)
        occ = self._opened().occupancy(p, threads=_threads(nthreads) or self._threads)
        return _answer(occ.astype(np.float32).reshape(lead))

    def compute_signed_distance(self, query_points: Any, nthreads: int = 0, nsamples: int = 1) -> _Array:
        """The distance to the surface, negative inside (:meth:`compute_occupancy`)."""
        occ = self.compute_occupancy(query_points, nthreads, nsamples).numpy()
        d = self.compute_distance(query_points, nthreads).numpy()
        return _answer(np.where(occ > 0, -d, d).astype(np.float32))

    @staticmethod
    def create_rays_pinhole(*args: Any, **kwargs: Any) -> _Array:
        """The ``(height_px, width_px, 6)`` rays of a pinhole camera, as Open3D makes them:
        ``create_rays_pinhole(intrinsic_matrix, extrinsic_matrix, width_px, height_px)`` (a
        3x3 ``K`` and the 4x4 world-to-camera matrix: each pixel's ray from the camera's
        centre through the pixel's centre, direction ``R^T K^-1 (x + 0.5, y + 0.5, 1)``, not
        normalised, so ``t_hit`` is the depth along the camera's axis), or
        ``create_rays_pinhole(fov_deg, center, eye, up, width_px, height_px)`` (``fov_deg`` the
        HORIZONTAL field of view; Open3D's camera of this form has its x axis to the left and
        its y axis up, so row 0 of the image is at the bottom and column 0 at the right, a
        picture turned by 180 degrees; kept for the same rays)."""
        return _answer(_pinhole(*args, **kwargs))

    def __reduce__(self):
        if self._path is not None:
            return (_reopen, (self._path, self._mem_budget, self._threads or 0))
        state = (self._vertices, self._triangles, self._cache_dir, self._mem_budget, self._threads or 0)
        return (_rebuild, state)


def _reopen(path: str, mem_budget: Any, nthreads: int) -> RaycastingScene:
    return RaycastingScene.open(path, mem_budget=mem_budget, nthreads=nthreads)


def _rebuild(vertices, triangles, cache_dir, mem_budget, nthreads) -> RaycastingScene:
    s = RaycastingScene(nthreads, cache_dir=cache_dir, mem_budget=mem_budget)
    base = 0
    for v, f in zip(vertices, triangles):
        s.add_triangles(v, f - base)
        base += len(v)
    return s


def _pinhole(*args: Any, **kwargs: Any) -> np.ndarray:
    names_k = ("intrinsic_matrix", "extrinsic_matrix", "width_px", "height_px")
    names_f = ("fov_deg", "center", "eye", "up", "width_px", "height_px")
    given = dict(zip(names_k if len(args) == 4 or "intrinsic_matrix" in kwargs else names_f, args))
    given.update(kwargs)
    w, h = int(given["width_px"]), int(given["height_px"])
    if w <= 0 or h <= 0:
        raise ValueError(f"width_px and height_px must be positive, got {w} x {h}")
    if "intrinsic_matrix" in given:
        k = _numpy("intrinsic_matrix", given["intrinsic_matrix"]).astype(np.float64).reshape(3, 3)
        e = _numpy("extrinsic_matrix", given["extrinsic_matrix"]).astype(np.float64).reshape(4, 4)
        rot, t = e[:3, :3], e[:3, 3]
    else:
        fov = float(given["fov_deg"])
        if not 0.0 < fov < 180.0:
            raise ValueError(f"fov_deg: {fov} is not between 0 and 180 degrees")
        center, eye, up = (_numpy(n, given[n]).astype(np.float64).reshape(3) for n in ("center", "eye", "up"))
        fwd = center - eye
        x = np.cross(up, fwd)
        if np.linalg.norm(fwd) == 0 or np.linalg.norm(x) == 0:
            raise ValueError("center, eye, up: the view direction is zero or parallel to up")
        fwd, x = fwd / np.linalg.norm(fwd), x / np.linalg.norm(x)
        y = np.cross(fwd, x)
        rot = np.stack([x, y, fwd])  # world to camera
        t = -rot @ eye
        f = 0.5 * w / math.tan(math.radians(fov) / 2.0)
        k = np.array([[f, 0.0, 0.5 * w], [0.0, f, 0.5 * h], [0.0, 0.0, 1.0]])
    px, py = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    pix = np.stack([px, py, np.ones_like(px)], axis=-1)
    cam = pix @ np.linalg.inv(k).T
    dirs = cam @ rot  # R^T applied to each row vector
    origin = -rot.T @ t
    out = np.empty((h, w, 6), dtype=np.float32)
    out[..., 0:3] = origin
    out[..., 3:6] = dirs
    return out
