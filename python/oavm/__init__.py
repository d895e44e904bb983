"""oavm: a ray-tracing acceleration structure that lives in a file.

Pack a mesh once, then open the file (in well under a millisecond, whatever its size) and trace
numpy arrays of rays against it, from any number of processes or machines::

    import numpy as np, oavm
    oavm.pack("bunny.ply", "bunny.oavm")
    with oavm.open("bunny.oavm") as scene:
        t, prim = scene.intersect(origins, directions)
        blocked = scene.occluded(origins, directions, tmax=1.0)

Rays are the records of ``RAYS.md``: a ``(N, 8)`` float32 array of origin (3), tmin, direction
(3), tmax; directions are used as given (``t`` is in units of the direction). Closest hits come
back as ``t`` (float32, ``inf`` on a miss) and ``prim`` (uint32, the triangle's index in the
mesh, ``0xFFFFFFFF`` on a miss); any-hit answers as a bool array. ``oavm.dask`` traces a dask
array of rays on a cluster.

Every call that traces, packs or verifies releases the GIL and runs on the library's threads.
Errors of the library arrive as exceptions carrying its message (the file and the place):
``FileNotFoundError`` / ``OSError`` for files that cannot be read or written, ``FormatError``
for a file that is not a sound ``.oavm`` file, ``MeshError`` for a mesh that cannot be packed,
``ValueError`` for bad arguments.
"""

from __future__ import annotations

import json
import os
import re
from typing import Any, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from ._native import FORMAT_VERSION, FormatError, MeshError, OavmError

__all__ = [
    "FORMAT_VERSION",
    "MISS",
    "VOTE_DIRECTIONS",
    "ClosestPoints",
    "FormatError",
    "Geometry",
    "Hits",
    "HitsWithAttributes",
    "MeshError",
    "OavmError",
    "Scene",
    "open",
    "pack",
    "update",
    "compact",
    "load_mesh",
    "rays",
]

#: The primitive id of a miss.
MISS = 0xFFFFFFFF

#: The three directions (float32, ``(3, 3)``, each of length about 1) along which
#: :meth:`Scene.occupancy` counts crossings: a point is inside when most of the three counts
#: are odd.
VOTE_DIRECTIONS = np.array(_native.VOTE_DIRECTIONS, dtype=np.float32)
VOTE_DIRECTIONS.setflags(write=False)

PathLike = Union[str, "os.PathLike[str]"]


class Hits(NamedTuple):
    """Closest hits: ``t`` (float32, ``inf`` on a miss) and ``prim`` (uint32, ``MISS``)."""

    t: np.ndarray
    prim: np.ndarray


class ClosestPoints(NamedTuple):
    """Closest points of the surface: ``point`` ``(N, 3)``, ``distance``, ``prim`` (uint32,
    ``MISS`` for none), ``uv`` ``(N, 2)`` (the point is ``(1-u-v) v0 + u v1 + v v2``) and the
    triangle's unit ``normal`` ``(N, 3)``."""

    point: np.ndarray
    distance: np.ndarray
    prim: np.ndarray
    uv: np.ndarray
    normal: np.ndarray


class HitsWithAttributes(NamedTuple):
    """Closest hits with their surface attributes.

    ``u``, ``v``: barycentric coordinates, the hit point being ``(1-u-v) v0 + u v1 + v v2`` for
    the triangle's corners as the mesh lists them (Embree's convention); ``normal``: ``(N, 3)``
    unit geometric normal ``(v1-v0) x (v2-v0)``, following the corners' winding. All NaN on a
    miss.
    """

    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray


class Geometry(NamedTuple):
    """One of the meshes a file was made of (format-spec §8.8): the file's primitives
    ``first_primitive .. first_primitive + primitive_count``, its ``name`` (cut to 48 bytes),
    and the ``transform`` that placed its vertices before they were stored (``(3, 4)`` float64,
    row-major: ``world = transform[:, :3] @ p + transform[:, 3]``; the identity when none)."""

    name: str
    first_primitive: int
    primitive_count: int
    transform: np.ndarray


_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([KMGT]?)(?:i?B)?\s*$", re.IGNORECASE)


def _bytes(name: str, value: Union[None, int, str]) -> Optional[int]:
    """A size in bytes from an int or a string such as ``"4G"`` or ``"512 MiB"`` (binary units)."""
    if value is None:
        return None
    if isinstance(value, bool):
        raise ValueError(f"{name}: expected a size in bytes (an int or a string like '4G'), got {value!r}")
    if isinstance(value, (int, np.integer)):
        n = int(value)
    elif isinstance(value, str):
        m = _SIZE.match(value)
        if not m:
            raise ValueError(f"{name}: cannot read {value!r} as a size (e.g. 1073741824, '512M', '4G')")
        unit = m.group(2).upper()
        n = int(float(m.group(1)) * (1024 ** ("KMGT".index(unit) + 1) if unit else 1))
    else:
        raise ValueError(f"{name}: expected a size in bytes (an int or a string like '4G'), got {type(value).__name__}")
    if n <= 0 or n >= 2**64:
        raise ValueError(f"{name}: {value!r} is not a positive size below 2^64 bytes")
    return n


def _count(name: str, value: Optional[int], lo: int, hi: int) -> Optional[int]:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name}: expected an int, got {type(value).__name__}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{name}: {int(value)} is not between {lo} and {hi}")
    return int(value)


def _real_array(name: str, a: Any) -> np.ndarray:
    """``a`` as an array of real numbers (no copy when it is one already)."""
    try:
        arr = np.asarray(a)
    except Exception as e:  # a ragged list, an object that is not array-like
        raise ValueError(f"{name}: cannot be read as an array: {e}") from None
    if arr.dtype.kind not in "fiu":
        raise ValueError(
            f"{name}: dtype {arr.dtype} is not a real number type (expected float32; "
            "other float and integer types are converted)"
        )
    return arr


def _mesh_arrays(mesh: Any) -> "tuple[np.ndarray, np.ndarray]":
    """A ``(vertices, faces)`` pair checked and converted as the native code takes it: float32
    ``(V, 3)`` and uint32 ``(F, 3)``, C-contiguous (face indices must be whole numbers in
    0..2^32-2; the native side checks them against V)."""
    v = _real_array("vertices", mesh[0])
    f = _real_array("faces", mesh[1])
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices: expected shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces: expected shape (F, 3) (triangles), got {f.shape}")
    if f.dtype.kind == "f":
        if f.size and not np.array_equal(f, np.round(f)):
            raise ValueError("faces: the indices are not whole numbers")
    if f.size:
        lo, hi = f.min(), f.max()
        if lo < 0:
            face = int(np.argwhere(f < 0)[0][0])
            raise MeshError(f"arrays: face {face} holds the negative vertex index {int(f[face].min())}")
        if hi > 0xFFFFFFFE:
            raise MeshError(f"arrays: vertex index {int(hi)} does not fit in 32 bits")
    v32 = _float32_c(v)
    f32 = np.require(f, dtype=np.uint32, requirements=["C_CONTIGUOUS", "ALIGNED"])
    return v32, f32


def _mesh_object(mesh: Any) -> Any:
    """A trimesh, Open3D (legacy or tensor) or meshio mesh as its ``(vertices, faces)`` arrays;
    anything else as it is."""
    if isinstance(mesh, (str, bytes, os.PathLike, tuple, list)):
        return mesh
    if hasattr(mesh, "vertex") and hasattr(mesh, "triangle"):  # open3d.t.geometry.TriangleMesh
        return (mesh.vertex.positions.numpy(), mesh.triangle.indices.numpy())
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):  # trimesh.Trimesh
        return (np.asarray(mesh.vertices), np.asarray(mesh.faces))
    if hasattr(mesh, "vertices") and hasattr(mesh, "triangles"):  # open3d.geometry.TriangleMesh
        return (np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    if hasattr(mesh, "points") and hasattr(mesh, "cells"):  # meshio.Mesh: its triangle cells
        tris = [c.data for c in mesh.cells if c.type == "triangle"]
        if not tris:
            raise ValueError("mesh: a meshio mesh without triangle cells")
        return (np.asarray(mesh.points)[:, :3], np.concatenate(tris))
    return mesh


def _is_trimesh_scene(mesh: Any) -> bool:
    return hasattr(mesh, "graph") and hasattr(mesh, "geometry") and hasattr(mesh.graph, "nodes_geometry")


def _is_pair(mesh: Any) -> bool:
    """Whether ``mesh`` is one ``(vertices, faces)`` pair of arrays (not a list of meshes)."""
    if not isinstance(mesh, (tuple, list)) or len(mesh) != 2:
        return False
    for x in mesh:
        if hasattr(x, "numpy") and not hasattr(x, "vertices"):  # an Open3D tensor
            continue
        if isinstance(x, (str, bytes, os.PathLike)):
            return False
        try:
            a = np.asarray(x)
        except Exception:
            return False
        if a.dtype.kind not in "biuf" or a.ndim != 2:
            return False
    return True


#: A part of a mesh made of several: float32 vertices, uint32 faces, and its geometries as the
#: native code takes them, ``(name, face count, 12 transform numbers or None)``.
_Part = Tuple[np.ndarray, np.ndarray, list]


def _parts(mesh: Any) -> Optional[List[_Part]]:
    """The meshes of ``mesh`` when it is several (a list or dict of meshes, a ``trimesh.Scene``),
    each with its geometries; ``None`` when it is one mesh."""
    if _is_trimesh_scene(mesh):
        parts = []
        for node in mesh.graph.nodes_geometry:
            matrix, name = mesh.graph[node]
            g = mesh.geometry[name]
            if not hasattr(g, "faces"):  # a path or a point cloud: no triangles
                continue
            m = np.asarray(matrix, dtype=np.float64)
            v = np.asarray(g.vertices, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]
            v32, f32 = _mesh_arrays((v, np.asarray(g.faces)))
            parts.append((v32, f32, [(str(node), len(f32), m[:3, :4].reshape(-1).tolist())]))
        if not parts:
            raise ValueError("mesh: a trimesh.Scene without triangle meshes")
        return parts
    if isinstance(mesh, dict):
        items = [(str(k), m) for k, m in mesh.items()]
    elif isinstance(mesh, (list, tuple)) and not _is_pair(mesh):
        items = [(None, m) for m in mesh]
    else:
        return None
    if not items:
        raise ValueError("mesh: an empty list of meshes")
    parts = []
    for i, (name, m) in enumerate(items):
        if isinstance(m, (str, bytes, os.PathLike)):
            v, f, geoms = _native.load_mesh(os.fsdecode(m), None)
            label = name or os.path.basename(os.fsdecode(m))
            if geoms:  # a glTF scene: its nodes, named within the file's name
                parts.append((v, f, [(f"{label}/{g[0]}", g[2], g[3]) for g in geoms]))
            else:
                parts.append((v, f, [(label, len(f), None)]))
            continue
        inner = _parts(m) if _is_trimesh_scene(m) or isinstance(m, dict) else None
        if inner is not None:
            label = name or f"scene {i}"
            for v, f, geoms in inner:
                parts.append((v, f, [(f"{label}/{g[0]}", g[1], g[2]) for g in geoms]))
            continue
        label = name
        if label is None:
            meta = getattr(m, "metadata", None)
            label = str(meta.get("name")) if isinstance(meta, dict) and meta.get("name") else f"mesh {i}"
        v32, f32 = _mesh_arrays(_mesh_object(m))
        parts.append((v32, f32, [(label, len(f32), None)]))
    return parts


def _joined(parts: List[_Part]) -> "tuple[np.ndarray, np.ndarray, list]":
    """One vertex and one face array of several parts, and their geometries in order."""
    base = np.cumsum([0] + [len(v) for v, _, _ in parts])
    if base[-1] > 2**32:
        raise MeshError(f"arrays: {base[-1]} vertices in all, more than 32-bit indices reach")
    v = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3), np.float32)
    f = np.concatenate([p[1].astype(np.int64) + b for p, b in zip(parts, base)])
    geoms = [g for p in parts for g in p[2]]
    return _float32_c(v), np.require(f, dtype=np.uint32, requirements=["C_CONTIGUOUS", "ALIGNED"]), geoms


def _float32_c(arr: np.ndarray) -> np.ndarray:
    """C-contiguous, aligned, native-order float32: ``arr`` itself when it already is."""
    with np.errstate(over="ignore"):  # beyond the float32 range: inf, which the library refuses
        return np.require(arr, dtype=np.float32, requirements=["C_CONTIGUOUS", "ALIGNED"])


def _points(points: Any) -> np.ndarray:
    p = _real_array("points", points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {p.shape}")
    return _float32_c(p)


def rays(origins: Any, directions: Any, tmin: Any = 0.0, tmax: Any = np.inf) -> np.ndarray:
    """The ``(N, 8)`` float32 ray array (``RAYS.md`` order) of ``origins`` and ``directions``
    (``(N, 3)`` each, or one of them ``(3,)`` for all rays) and ``tmin``, ``tmax`` (scalars or
    ``(N,)``)."""
    o = _real_array("origins", origins)
    d = _real_array("directions", directions)
    for name, x in (("origins", o), ("directions", d)):
        if x.ndim not in (1, 2) or x.shape[-1] != 3:
            raise ValueError(f"{name}: expected shape (N, 3) or (3,), got {x.shape}")
    n = max(o.shape[0] if o.ndim == 2 else 1, d.shape[0] if d.ndim == 2 else 1)
    if o.ndim == 1 and d.ndim == 1:
        n = 1
    for name, x in (("origins", o), ("directions", d)):
        if x.ndim == 2 and x.shape[0] != n:
            raise ValueError(f"origins and directions: {o.shape[0] if o.ndim == 2 else 1} against "
                             f"{d.shape[0] if d.ndim == 2 else 1} rays")
    out = np.empty((n, 8), dtype=np.float32)
    out[:, 0:3] = o
    out[:, 4:7] = d
    for name, x, col in (("tmin", tmin, 3), ("tmax", tmax, 7)):
        v = _real_array(name, x)
        if v.ndim > 1 or (v.ndim == 1 and v.shape[0] != n):
            raise ValueError(f"{name}: expected a number or shape ({n},), got shape {v.shape}")
        out[:, col] = v
    return out


def _ray_array(rays_or_origins: Any, directions: Any, tmin: Any, tmax: Any) -> np.ndarray:
    if directions is None:
        if tmin is not None or tmax is not None:
            raise ValueError("tmin and tmax go with origins and directions; a (N, 8) ray array carries its own")
        arr = _real_array("rays", rays_or_origins)
        if arr.ndim != 2 or arr.shape[1] != 8:
            raise ValueError(
                f"rays: expected shape (N, 8) (origin, tmin, direction, tmax per ray), got {arr.shape}"
                + ("; give origins and directions as two arguments" if arr.ndim == 2 and arr.shape[1] == 3 else "")
            )
        return _float32_c(arr)
    return rays(rays_or_origins, directions, 0.0 if tmin is None else tmin, np.inf if tmax is None else tmax)


class Scene:
    """An opened ``.oavm`` file (see :func:`open`). Usable from many threads at once; picklable
    (by path and budget: a worker that unpickles it opens the file itself); a context manager
    that closes (unmaps) the file on exit."""

    def __init__(self, path: PathLike, *, mem_budget: Union[None, int, str] = None,
                 walk: str = "auto"):
        budget = _bytes("mem_budget", mem_budget)
        self._path = os.fspath(path)
        self._native: Optional[_native.NativeScene] = None
        self._native = _native.open(self._path, budget, str(walk))
        self._mem_budget = budget
        self._walk = str(walk)
        self._info: Optional[dict] = None
        self._geometries: "Optional[list[Geometry]]" = None

    def _scene(self) -> "_native.NativeScene":
        s = self._native
        if s is None:
            raise ValueError(f"{self._path}: the scene is closed")
        return s

    @property
    def path(self) -> str:
        """The file's path, as given to :func:`open`."""
        return self._path

    @property
    def info(self) -> dict:
        """The file's header and counts (format version, triangles, leaves, blocks, bounds) and
        how it is traced (memory budget, threads), as a dict."""
        return json.loads(self._scene().info())

    def verify(self) -> dict:
        """Checks every byte, checksum and invariant of the file (reading it whole). Returns the
        report as a dict; raises :class:`FormatError` listing the defects if there are any."""
        report = json.loads(self._scene().verify())
        if not report["ok"]:
            defects = report["defects"]
            raise FormatError(
                f"{self._path}: verification failed ({len(defects)} defects): " + "; ".join(defects[:20])
                + (" ..." if len(defects) > 20 else "")
            )
        return report

    @property
    def geometries(self) -> "list[Geometry]":
        """The meshes the file was made of (its geometry table, format-spec §8.8): one
        :class:`Geometry` each, in the order of their primitives; empty for a file packed from
        one mesh."""
        if self._geometries is None:
            self._geometries = [
                Geometry(name, first, count, np.array(t, dtype=np.float64).reshape(3, 4))
                for name, first, count, t in self._scene().geometries()
            ]
        return self._geometries

    def locate(self, prim: Any) -> "tuple[np.ndarray, np.ndarray]":
        """The geometry holding each primitive id of ``prim`` (what hits and closest points
        return) and the primitive's index within it, as two uint32 arrays; ``MISS`` stays
        ``MISS`` in both. In a file of one mesh, geometry 0 and the id itself."""
        p = np.asarray(prim)
        if p.dtype.kind not in "iu":
            raise ValueError(f"prim: expected integer primitive ids, got {p.dtype}")
        p = p.astype(np.int64)
        miss = (p == MISS) | (p < 0)
        g = self.geometries
        if not g:
            geom = np.zeros(p.shape, dtype=np.int64)
            local = p
        else:
            ends = np.array([x.first_primitive + x.primitive_count for x in g], dtype=np.int64)
            geom = np.searchsorted(ends, p, side="right")
            miss |= geom >= len(g)
            starts = np.array([x.first_primitive for x in g], dtype=np.int64)
            local = p - starts[np.minimum(geom, len(g) - 1)]
        return (np.where(miss, MISS, geom).astype(np.uint32),
                np.where(miss, MISS, local).astype(np.uint32))

    def intersect(
        self,
        rays: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        attributes: bool = False,
        threads: Optional[int] = None,
    ) -> Union[Hits, HitsWithAttributes]:
        """Closest hits of ``rays`` (an ``(N, 8)`` array in ``RAYS.md`` order) or of
        ``origins, directions`` (``(N, 3)`` each; ``tmin`` default 0, ``tmax`` default inf).

        Returns :class:`Hits` ``(t, prim)``, or with ``attributes=True``
        :class:`HitsWithAttributes` ``(t, prim, u, v, normal)``. ``threads``: how many threads
        trace (default: one per core, more when a memory budget makes the tracer read from
        disk). A contiguous float32 ray array is traced in place, not copied; do not write to
        it from another thread meanwhile."""
        arr = _ray_array(rays, directions, tmin, tmax)
        out = self._scene().intersect(arr, _count("threads", threads, 1, 1024), bool(attributes))
        return HitsWithAttributes(*out) if attributes else Hits(*out)

    def occluded(
        self,
        rays: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        threads: Optional[int] = None,
    ) -> np.ndarray:
        """Any-hit answers (a bool array: some triangle is hit with ``tmin <= t <= tmax``), for
        the same arguments as :meth:`intersect`."""
        arr = _ray_array(rays, directions, tmin, tmax)
        return self._scene().occluded(arr, _count("threads", threads, 1, 1024)).view(np.bool_)

    def count_intersections(
        self,
        rays: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        threads: Optional[int] = None,
    ) -> np.ndarray:
        """How many triangles each ray hits with ``tmin <= t <= tmax`` (uint32), for the same
        arguments as :meth:`intersect`: each triangle once, and a ray through an edge or a
        corner shared by several triangles meets one of them, so a ray from outside a closed
        mesh to outside it crosses it an even number of times. Files of clusters; a ray with
        ``tmin < 0`` is an error."""
        arr = _ray_array(rays, directions, tmin, tmax)
        return self._scene().count_intersections(arr, _count("threads", threads, 1, 1024))

    def list_intersections(
        self,
        rays: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        threads: Optional[int] = None,
    ) -> dict:
        """Every hit of each ray (those :meth:`count_intersections` counts), in Open3D's form:
        a dict of ``ray_splits`` (uint64, ``N + 1``: ray ``i``'s hits are
        ``ray_splits[i]:ray_splits[i + 1]``), ``ray_ids`` (uint32, the ray of each hit),
        ``t_hit`` (float32), ``primitive_ids`` (uint32) and ``primitive_uvs`` (float32,
        ``(H, 2)``, :class:`HitsWithAttributes`' convention); each ray's hits in order of
        ``t``, then primitive id."""
        arr = _ray_array(rays, directions, tmin, tmax)
        splits, t, prim, uv = self._scene().list_intersections(arr, _count("threads", threads, 1, 1024))
        ray_ids = np.repeat(np.arange(len(arr), dtype=np.uint32), np.diff(splits).astype(np.int64))
        return {"ray_splits": splits, "ray_ids": ray_ids, "t_hit": t, "primitive_ids": prim,
                "primitive_uvs": uv}

    def closest_points(self, points: Any, *, max_distance: float = float("inf"),
                       threads: Optional[int] = None) -> "ClosestPoints":
        """The closest point of the surface to each of ``points`` (``(N, 3)``), within
        ``max_distance`` of it: :class:`ClosestPoints` ``(point, distance, prim, uv, normal)``
        (float32; ``prim`` uint32, ``MISS`` where no triangle is that near, with NaN points and
        ``inf`` distances). A best-first descent of the file's wide nodes, through the memory
        budget as rays are. Files of clusters."""
        pts = _points(points)
        out = self._scene().closest_points(pts, float(max_distance), _count("threads", threads, 1, 1024))
        return ClosestPoints(*out)

    def occupancy(self, points: Any, *, threads: Optional[int] = None) -> np.ndarray:
        """Whether each point is inside the surface (bool): most of three rays from it (along
        :data:`VOTE_DIRECTIONS`) cross the surface an odd number of times, each crossing counted
        once however the rays pass edges and corners: exact on closed meshes, a vote on meshes
        with holes."""
        pts = _points(points)
        return self._scene().occupancy(pts, _count("threads", threads, 1, 1024)).view(np.bool_)

    def signed_distance(self, points: Any, *, threads: Optional[int] = None) -> np.ndarray:
        """The distance from each point to the surface, negative inside (:meth:`occupancy`),
        float32."""
        d = self.closest_points(points, threads=threads).distance
        return np.where(self.occupancy(points, threads=threads), -d, d).astype(np.float32)

    def camera_rays(
        self,
        width: int,
        height: int,
        *,
        eye: Any = None,
        target: Any = None,
        up: Any = None,
        fov: Optional[float] = None,
        start: int = 0,
        stop: Optional[int] = None,
    ) -> np.ndarray:
        """The primary rays of a ``width`` x ``height`` pinhole camera, one through the centre of
        each pixel, row by row from the top left, as an ``(N, 8)`` float32 array (unit
        directions): bit for bit the rays ``oavm-trace`` renders and benchmarks with. By default
        the camera frames the mesh as ``oavm-trace`` does; ``eye``, ``target``, ``up`` (default
        ``(0, 1, 0)``) and ``fov`` (vertical, degrees, default 40) replace what they name.
        ``start``, ``stop``: only the pixels ``start..stop`` (row-major index), for a slice of
        the image."""
        info = self.info
        vec = lambda name, x: None if x is None else tuple(float(c) for c in _real_array(name, x).reshape(3))
        return _native.camera_rays(
            info["mesh_min"], info["mesh_max"], _count("width", width, 1, 1 << 20),
            _count("height", height, 1, 1 << 20), vec("eye", eye), vec("target", target), vec("up", up),
            None if fov is None else float(fov), _count("start", start, 0, 1 << 40),
            _count("stop", stop, 0, 1 << 40),
        )

    def close(self) -> None:
        """Unmaps the file; the scene cannot trace afterwards. Idempotent."""
        self._native = None

    @property
    def closed(self) -> bool:
        return self._native is None

    def __enter__(self) -> "Scene":
        self._scene()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __reduce__(self):
        return (_reopen, (self._path, self._mem_budget, self._walk))

    def __repr__(self) -> str:
        if self._native is None:
            return f"<oavm.Scene {self._path!r} (closed)>"
        i = self.info
        return (f"<oavm.Scene {self._path!r}: {i['input_triangles']} triangles, "
                f"{i['blocks']} blocks, {i['file_bytes']} bytes, format {i['format_version']}>")


def _reopen(path: str, mem_budget: Optional[int], walk: str = "auto") -> Scene:
    return Scene(path, mem_budget=mem_budget, walk=walk)


def open(path: PathLike, *, mem_budget: Union[None, int, str] = None,  # noqa: A001
         walk: str = "auto") -> Scene:
    """Opens a packed ``.oavm`` file for tracing. Reads only the header, section table and top
    tree: its cost does not grow with the file. ``mem_budget`` (bytes, or a string like
    ``"4G"``): the most decoded blocks kept in memory (default: half of the memory available);
    a file larger than it is traced by paging blocks in and out. ``walk``: ``"auto"`` (the
    fastest for the file), ``"wide"`` or ``"topdown"`` (files of clusters: the 8-wide nodes, or
    the octree's records), ``"neighbours"`` (the OAVM paper's
    leaf-to-leaf walk) or ``"ropes"`` (the same, following the ropes of a file packed with
    ``ropes=True``); the answers are the same."""
    return Scene(path, mem_budget=mem_budget, walk=walk)


def _box(name: str, box: Any) -> Optional[Tuple[Tuple[float, float, float], Tuple[float, float, float]]]:
    """``None``, or a ``(lo, hi)`` pair of three finite numbers each, ``lo <= hi``."""
    if box is None:
        return None
    try:
        lo, hi = box
        lo = tuple(float(c) for c in lo)
        hi = tuple(float(c) for c in hi)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected (lo, hi), two sequences of three numbers, got {box!r}") from None
    if len(lo) != 3 or len(hi) != 3 or not all(np.isfinite(lo + hi)) or any(a > b for a, b in zip(lo, hi)):
        raise ValueError(f"{name}: expected finite corners lo <= hi of three numbers each, got {box!r}")
    return lo, hi  # type: ignore[return-value]


def update(
    path: PathLike,
    mesh: Any,
    *,
    time: Optional[float] = None,
    block_size: Union[None, int, str] = None,
    compress: Union[None, bool, int] = None,
    threads: Optional[int] = None,
) -> dict:
    """Brings the file at ``path`` (packed with ``updatable=True``) to the triangles of
    ``mesh`` in place: a path (an AFF scene posed at ``time``) or a ``(vertices, faces)`` pair
    whose face ``i`` is primitive ``i``. Only the blocks whose triangles moved, appeared or went
    are rebuilt; several meshes (as :func:`pack` takes them) replace the file's geometry table,
    one mesh keeps it (its last geometry ending where the new primitives do). The update is a
    new generation of the file (format-spec §2.1), so a crash
    leaves the previous or the new one, and scenes opened before keep answering as before.
    Returns the report as a dict (primitives moved, inserted, removed; blocks rebuilt; bytes
    written; seconds). ``compress``: a zstd level for the new blocks, ``False`` for raw
    (default: as the file's blocks are)."""
    p = os.fspath(path)
    opts = dict(
        block_size=_bytes("block_size", block_size),
        compress=None if compress in (None, True, False) else _count("compress", compress, -(1 << 17), 22),
        raw=compress is False,
        threads=_count("threads", threads, 1, 1024),
    )
    if compress is True:
        opts["compress"] = 3
    if isinstance(mesh, (str, bytes, os.PathLike)):
        return json.loads(_native.update_file(p, os.fsdecode(mesh), time=time, **opts))
    if time is not None:
        raise ValueError("time poses an AFF scene file, not a mesh given as arrays")
    parts = _parts(mesh)
    if parts is not None:
        v32, f32, geoms = _joined(parts)
        return json.loads(_native.update_arrays(p, v32, f32, geometries=geoms, **opts))
    mesh = _mesh_object(mesh)
    if isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        v32, f32 = _mesh_arrays(mesh)
        return json.loads(_native.update_arrays(p, v32, f32, **opts))
    raise ValueError(f"mesh: expected a path, a mesh object, a (vertices, faces) pair of arrays, or a list, "
                     f"dict or trimesh.Scene of them, got {type(mesh).__name__}")


def load_mesh(path: PathLike, *, time: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray]:
    """The triangles of a mesh file as :func:`pack` reads it (PLY, OBJ, STL, OFF, glTF/GLB, or a BART AFF
    scene posed at ``time``): ``(V, 3)`` float32 vertices and ``(F, 3)`` uint32 faces, face
    ``i`` being primitive ``i`` (polygons fanned into triangles, every object of a scene in
    order)."""
    v, f, _ = _native.load_mesh(os.fspath(path), None if time is None else float(time))
    return v, f


def compact(path: PathLike) -> dict:
    """Rewrites an updated file without the blocks older generations left, atomically, as a
    file of generation 1; scenes opened before keep the old file. Returns the report."""
    return json.loads(_native.compact(os.fspath(path)))


def pack(
    mesh: Any,
    out_path: PathLike,
    *,
    leaf_size: Optional[int] = None,
    max_depth: Optional[int] = None,
    compress: Union[None, bool, int] = None,
    mem_budget: Union[None, int, str] = None,
    progress: bool = True,
    leaf: str = "cluster",
    block_size: Union[None, int, str] = None,
    threads: Optional[int] = None,
    ropes: bool = False,
    updatable: bool = False,
    bounds: Optional[Tuple[Sequence[float], Sequence[float]]] = None,
) -> dict:
    """Packs a triangle mesh into an ``.oavm`` file, written atomically (it appears only when
    complete). Returns the pack report as a dict (triangles, nodes, leaves, volumes, bytes,
    seconds per phase).

    ``mesh``: a path (PLY, OBJ, STL, OFF, glTF/GLB, or a BART AFF scene), a trimesh, Open3D or
    meshio mesh object (its triangles), or a ``(vertices, faces)`` pair of arrays
    (``(V, 3)`` floats and ``(F, 3)`` integer indices: what trimesh's ``mesh.vertices,
    mesh.faces`` and Open3D's ``np.asarray(m.vertices), np.asarray(m.triangles)`` give);
    primitive ids are the face indices. Several meshes: a list of any of these, a dict of them
    by name, or a ``trimesh.Scene`` (each node's mesh placed by its transform); they are
    stored one after another, each a geometry of the file's geometry table
    (:attr:`Scene.geometries`, :meth:`Scene.locate`), as is each node of a glTF file.
    ``leaf_size``: subdivide leaves holding more triangles
    (default 512 for clusters, 32 for lists); ``max_depth``: deepest octree level (default 16,
    at most 21); ``compress``: ``True`` or a zstd level (1-22) to store blocks compressed;
    ``mem_budget``: pack a binary PLY file within about this much memory, streaming it (for
    meshes larger than memory); ``progress``: a progress bar on stderr when it is a terminal;
    ``leaf``: ``"cluster"`` (a wide BVH per leaf, the fastest) or ``"list"`` (the OAVM paper's
    triangle lists); ``block_size``: target size of a block, the unit of paging (default 256K);
    ``threads``: build threads (default one per core; the file is the same for any count);
    ``ropes``: add ropes (format-spec §8.4) for ``oavm.open(..., walk="ropes")``;
    ``updatable``: store the primitive table, which :func:`update` needs (36 bytes a
    triangle); ``bounds``: ``(lo, hi)`` corners of a box the root cube must hold as well as the
    mesh, room for updates to move triangles into."""
    level: Optional[int]
    if compress is None or compress is False:
        level = None
    elif compress is True:
        level = 3
    else:
        level = _count("compress", compress, -(1 << 17), 22)
    opts = dict(
        leaf=str(leaf),
        leaf_size=_count("leaf_size", leaf_size, 1, 2**32 - 1),
        max_depth=_count("max_depth", max_depth, 0, 2**32 - 1),
        compress=level,
        block_size=_bytes("block_size", block_size),
        progress=bool(progress),
        threads=_count("threads", threads, 1, 1024),
        ropes=bool(ropes),
        updatable=bool(updatable),
        bounds=_box("bounds", bounds),
    )
    out = os.fspath(out_path)
    if isinstance(mesh, (str, bytes, os.PathLike)):
        report = _native.pack_file(os.fsdecode(mesh), out, mem_budget=_bytes("mem_budget", mem_budget), **opts)
        return json.loads(report)
    if mem_budget is not None:
        raise ValueError("mem_budget streams one binary PLY file; meshes given as objects, arrays or "
                         "lists are packed in memory")
    parts = _parts(mesh)
    if parts is not None:
        v32, f32, geoms = _joined(parts)
        return json.loads(_native.pack_arrays(v32, f32, out, geometries=geoms, **opts))
    mesh = _mesh_object(mesh)
    if isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        v32, f32 = _mesh_arrays(mesh)
        return json.loads(_native.pack_arrays(v32, f32, out, **opts))
    raise ValueError(
        f"mesh: expected a path, a mesh object, a (vertices, faces) pair of arrays, or a list, dict or "
        f"trimesh.Scene of them, got {type(mesh).__name__}"
    )


try:  # the version of the installed distribution (maturin takes it from Cargo.toml)
    from importlib.metadata import version as _version

    __version__ = _version("oavm")
except Exception:  # pragma: no cover - not installed as a distribution
    __version__ = "unknown"
