"""Tracing a dask array of rays: one packed file, traced by every worker of a cluster.

A packed file is read-only and opens in well under a millisecond, so each worker process maps
the same file (from a shared file system, or its own copy at the same path) and traces the
chunks of rays it is given::

    import dask.array as da, oavm.dask
    rays = da.from_array(ray_array, chunks=(1_000_000, 8))      # (N, 8), RAYS.md order
    t, prim = oavm.dask.intersect("scene.oavm", rays)           # dask arrays, lazy
    t, prim = dask.compute(t, prim)                              # one trace per chunk

Works with a ``dask.distributed`` cluster and with dask's local schedulers (threads,
processes, synchronous). Each process opens a file once and keeps it open for later chunks and
later calls, keyed by its real path, modification time, size and inode, and the memory budget:
a file re-packed in place is opened again, never traced stale.
"""

from __future__ import annotations

import os
import threading
from typing import Any, Dict, Optional, Union

import numpy as np

try:
    import dask.array as da
except ImportError as e:  # pragma: no cover - depends on the environment
    raise ImportError("oavm.dask needs dask: pip install 'oavm[dask]' (or dask[array])") from e

from . import Hits, HitsWithAttributes, Scene, _bytes, _count
from . import open as _open

__all__ = ["camera_rays", "intersect", "occluded", "distance", "signed_distance", "occupancy", "scene",
           "cache_info", "HIT_DTYPE", "ATTRIBUTES_DTYPE"]

#: The record of one closest hit (the ``HITS`` record of RAYS.md).
HIT_DTYPE = np.dtype([("t", "<f4"), ("prim", "<u4")])
#: A closest hit with its barycentric coordinates and geometric normal.
ATTRIBUTES_DTYPE = np.dtype([("t", "<f4"), ("prim", "<u4"), ("u", "<f4"), ("v", "<f4"), ("normal", "<f4", (3,))])

#: Rays per chunk when a numpy array (not a dask array) is given.
DEFAULT_CHUNK = 1 << 20

_LOCK = threading.Lock()
_SCENES: Dict[tuple, Scene] = {}
_OPENS = 0


def _key(path: str, mem_budget: Optional[int]) -> tuple:
    real = os.path.realpath(path)
    st = os.stat(real)
    return (real, st.st_mtime_ns, st.st_size, st.st_ino, mem_budget)


def scene(path: Union[str, "os.PathLike[str]"], mem_budget: Optional[int] = None) -> Scene:
    """This process's opened scene of ``path``: opened on first use, kept, and opened again
    when the file has changed (another modification time, size or inode) since."""
    global _OPENS
    key = _key(os.fspath(path), mem_budget)
    with _LOCK:
        s = _SCENES.get(key)
        if s is None:
            # Older versions of the same file with the same budget are dropped (a call still
            # tracing with one keeps its own reference until it returns).
            for k in [k for k in _SCENES if k[0] == key[0] and k[4] == mem_budget]:
                _SCENES.pop(k).close()
            s = _open(key[0], mem_budget=mem_budget)
            _SCENES[key] = s
            _OPENS += 1
        return s


def cache_info() -> dict:
    """What this process's cache holds: ``opens`` (files opened so far) and ``files`` (the
    real paths open now). For a cluster: ``client.run(oavm.dask.cache_info)``."""
    with _LOCK:
        return {"pid": os.getpid(), "opens": _OPENS, "files": sorted({k[0] for k in _SCENES})}


def _intersect_block(block: np.ndarray, path: str, mem_budget: Optional[int], threads: Optional[int],
                     attributes: bool) -> np.ndarray:
    hits = scene(path, mem_budget).intersect(block, threads=threads, attributes=attributes)
    out = np.empty(len(block), dtype=ATTRIBUTES_DTYPE if attributes else HIT_DTYPE)
    for name, column in zip(hits._fields, hits):
        out[name] = column
    return out


def _occluded_block(block: np.ndarray, path: str, mem_budget: Optional[int], threads: Optional[int]) -> np.ndarray:
    return scene(path, mem_budget).occluded(block, threads=threads)


def _as_rows(name: str, arr: Any, width: int, chunk: Optional[int], what: str) -> "da.Array":
    """``arr`` as a dask array of rows of ``width`` numbers, chunked along the rows only (a numpy
    array cut into ``chunk`` rows)."""
    if not isinstance(arr, da.Array):
        a = np.asarray(arr)
        size = _count("chunk", chunk, 1, 1 << 40) or DEFAULT_CHUNK
        arr = da.from_array(a, chunks=(size,) + a.shape[1:])
    elif chunk is not None:
        arr = arr.rechunk((_count("chunk", chunk, 1, 1 << 40), -1))
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(f"{name}: expected shape (N, {width}){what}, got {arr.shape}")
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{name}: dtype {arr.dtype} is not a real number type (expected float32)")
    if len(arr.chunks[1]) != 1:
        arr = arr.rechunk({1: -1})  # a chunk must hold whole rows
    return arr


def _as_rays(rays: Any, chunk: Optional[int]) -> "da.Array":
    return _as_rows("rays", rays, 8, chunk, " (origin, tmin, direction, tmax per ray)")


def _check_file(path: str) -> str:
    # Fail now, on the client, for a file that is missing or not an .oavm file, rather than
    # in every task; workers open it again (the path must name the same file there).
    path = os.fspath(path)
    with _open(path):
        pass
    return path


def intersect(path: Union[str, "os.PathLike[str]"], rays: Any, *, attributes: bool = False,
              mem_budget: Union[None, int, str] = None, threads: Optional[int] = None,
              chunk: Optional[int] = None) -> Union[Hits, HitsWithAttributes]:
    """Closest hits of a ``(N, 8)`` dask array of rays (chunked along the rays; a numpy array
    is cut into chunks of ``chunk`` rays) through the file at ``path``: :class:`oavm.Hits` of
    dask arrays ``(t, prim)``, or with ``attributes=True`` :class:`oavm.HitsWithAttributes`
    ``(t, prim, u, v, normal)``. Compute them together (``dask.compute(*hits)``) to trace
    once. ``mem_budget``, ``threads``: per worker process, as for :func:`oavm.open` and
    :meth:`oavm.Scene.intersect`."""
    rays = _as_rays(rays, chunk)
    path = _check_file(path)
    dtype = ATTRIBUTES_DTYPE if attributes else HIT_DTYPE
    records = rays.map_blocks(
        _intersect_block, path, _bytes("mem_budget", mem_budget), _count("threads", threads, 1, 1024),
        bool(attributes), dtype=dtype, drop_axis=1, meta=np.empty((0,), dtype),
    )
    fields = [records[name] for name in dtype.names]
    return HitsWithAttributes(*fields) if attributes else Hits(*fields)


def occluded(path: Union[str, "os.PathLike[str]"], rays: Any, *, mem_budget: Union[None, int, str] = None,
             threads: Optional[int] = None, chunk: Optional[int] = None) -> "da.Array":
    """Any-hit answers (a bool dask array) of a ``(N, 8)`` dask array of rays, as
    :func:`intersect`."""
    rays = _as_rays(rays, chunk)
    path = _check_file(path)
    return rays.map_blocks(
        _occluded_block, path, _bytes("mem_budget", mem_budget), _count("threads", threads, 1, 1024),
        dtype=bool, drop_axis=1, meta=np.empty((0,), bool),
    )



def _as_points(points: Any, chunk: Optional[int]) -> "da.Array":
    return _as_rows("points", points, 3, chunk, "")


def _points_block(block: np.ndarray, path: str, mem_budget: Optional[int], threads: Optional[int],
                  what: str) -> np.ndarray:
    s = scene(path, mem_budget)
    if what == "distance":
        return s.closest_points(block, threads=threads).distance
    if what == "occupancy":
        return s.occupancy(block, threads=threads)
    return s.signed_distance(block, threads=threads)


def _per_point(path: Any, points: Any, what: str, dtype: Any, mem_budget: Any, threads: Any,
               chunk: Any) -> "da.Array":
    points = _as_points(points, chunk)
    path = _check_file(path)
    return points.map_blocks(
        _points_block, path, _bytes("mem_budget", mem_budget), _count("threads", threads, 1, 1024), what,
        dtype=dtype, drop_axis=1, meta=np.empty((0,), dtype),
    )


def distance(path: Union[str, "os.PathLike[str]"], points: Any, *, mem_budget: Union[None, int, str] = None,
             threads: Optional[int] = None, chunk: Optional[int] = None) -> "da.Array":
    """The distance from each point of a ``(N, 3)`` dask array (or numpy array, cut into
    ``chunk`` points) to the surface in the file at ``path`` (float32), each chunk on a worker
    (:meth:`oavm.Scene.closest_points`)."""
    return _per_point(path, points, "distance", np.float32, mem_budget, threads, chunk)


def signed_distance(path: Union[str, "os.PathLike[str]"], points: Any, *, mem_budget: Union[None, int, str] = None,
                    threads: Optional[int] = None, chunk: Optional[int] = None) -> "da.Array":
    """The signed distance (negative inside, :meth:`oavm.Scene.signed_distance`) of each point,
    as :func:`distance`: a signed-distance grid of a mesh larger than memory, on a cluster."""
    return _per_point(path, points, "signed", np.float32, mem_budget, threads, chunk)


def occupancy(path: Union[str, "os.PathLike[str]"], points: Any, *, mem_budget: Union[None, int, str] = None,
              threads: Optional[int] = None, chunk: Optional[int] = None) -> "da.Array":
    """Whether each point is inside (bool, :meth:`oavm.Scene.occupancy`), as :func:`distance`."""
    return _per_point(path, points, "occupancy", bool, mem_budget, threads, chunk)


def _camera_block(path: str, mem_budget: Optional[int], width: int, height: int, block_info=None,
                  **camera: Any) -> np.ndarray:
    start, stop = block_info[None]["array-location"][0]
    return scene(path, mem_budget).camera_rays(width, height, start=start, stop=stop, **camera)


def camera_rays(path: Union[str, "os.PathLike[str]"], width: int, height: int, *, chunk: Optional[int] = None,
                mem_budget: Union[None, int, str] = None, eye: Any = None, target: Any = None, up: Any = None,
                fov: Optional[float] = None) -> "da.Array":
    """The primary rays of a ``width`` x ``height`` camera framing the file's mesh
    (:meth:`oavm.Scene.camera_rays`), as a lazy ``(width * height, 8)`` dask array of chunks of
    ``chunk`` rays (default 2^20), each made by the worker that traces it: nothing is sent to
    the workers but the camera."""
    _count("width", width, 1, 1 << 20)
    _count("height", height, 1, 1 << 20)
    size = _count("chunk", chunk, 1, 1 << 40) or DEFAULT_CHUNK
    path = _check_file(path)
    n = int(width) * int(height)
    chunks = (tuple(min(size, n - i) for i in range(0, n, size)), (8,))
    camera = {k: v for k, v in dict(eye=eye, target=target, up=up, fov=fov).items() if v is not None}
    # Fail on the client for a camera that cannot be made.
    scene(path, _bytes("mem_budget", mem_budget)).camera_rays(width, height, stop=1, **camera)
    return da.map_blocks(
        _camera_block, path, _bytes("mem_budget", mem_budget), int(width), int(height), chunks=chunks,
        dtype=np.float32, meta=np.empty((0, 8), np.float32), **camera,
    )
