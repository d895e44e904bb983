"""A drop-in for trimesh's ray intersectors: ``mesh.ray = oavm.trimesh.RayMeshIntersector(mesh)``.

trimesh's own (``trimesh.ray.ray_pyembree``, over embreex, on one thread; or
``trimesh.ray.ray_triangle``, numpy) build their structure again in every process. This one packs
the mesh into an ``.oavm`` file in a cache directory on first use, named by a hash of the mesh,
and opens that file on every later use, in this process or another; it traces on every core, and
its multiple hits are exact (every triangle a ray crosses, once each, a ray through a shared edge
or corner counting once) where trimesh's re-cast loop over Embree may miss or repeat hits.

Conventions are trimesh's: float64 in and out, directions normalised (so a hit's distance is in
units of length), rays starting at their origins (hits at ``t >= 0``), ``-1`` for a miss in
:meth:`RayMeshIntersector.intersects_first`. The mesh is stored in float32, moved so that the
centre of its bounding box is at the origin (rays are moved alike, in float64, before they are
rounded), which keeps float32's relative precision for meshes far from the origin. See
``docs/python.md`` ("Coming from trimesh or Open3D") for the differences that remain.

Only ``mesh.vertices``, ``mesh.faces`` and (for :meth:`~RayMeshIntersector.contains_points`)
``mesh.bounds`` are read; trimesh itself is not imported.
"""

from __future__ import annotations

import os
from typing import Any, Optional, Tuple, Union

import numpy as np

from . import Scene
from . import _cache, _native

__all__ = ["RayMeshIntersector", "ProximityQuery"]

#: The direction of trimesh's ``contains_points`` rays (``trimesh.ray.ray_util``).
_CONTAINS_DIRECTION = np.array([0.4395064455, 0.617598629942, 0.652231566745])
#: A second direction, for the points whose two rays disagree (an open mesh).
_SECOND_DIRECTION = np.array([-0.5773502691896258, 0.5773502691896258, -0.5773502691896258])


class RayMeshIntersector:
    """trimesh's ``RayMeshIntersector`` API over an ``.oavm`` file of ``mesh``.

    ``cache_dir``: where packed files are kept (default ``$OAVM_CACHE_DIR``, else
    ``~/.cache/oavm``); ``mem_budget``: the scene's memory budget (see :func:`oavm.open`);
    ``threads``: tracing threads (default: one per core). The file is packed or opened on
    first use, and again if the mesh changes (trimesh's content hash tells)."""

    def __init__(self, mesh: Any, cache_dir: Union[None, str, "os.PathLike[str]"] = None, *,
                 mem_budget: Union[None, int, str] = None, threads: Optional[int] = None):
        self.mesh = mesh
        self.cache_dir = cache_dir
        self.mem_budget = mem_budget
        self.threads = threads
        self._token: Any = None
        self._scene: Optional[Scene] = None
        self._shift = np.zeros(3)

    @property
    def scene(self) -> Scene:
        """The opened ``.oavm`` scene of the mesh (packed into the cache first if need be)."""
        token = hash(self.mesh)
        if self._scene is None or token != self._token:
            v = np.asarray(self.mesh.vertices, dtype=np.float64)
            f = np.asarray(self.mesh.faces)
            if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
                raise ValueError(f"mesh: expected (V, 3) vertices and (F, 3) faces, got {v.shape} and {f.shape}")
            shift = (v.min(axis=0) + v.max(axis=0)) / 2.0 if len(v) else np.zeros(3)
            v32 = (v - shift).astype(np.float32)
            f32 = f.astype(np.uint32)
            self._scene = _cache.opened(v32, f32, self.cache_dir, self.mem_budget)
            self._shift, self._token = shift, token
        return self._scene

    def _ray_array(self, origins: Any, directions: Any) -> np.ndarray:
        """The ``(N, 8)`` ray array of trimesh's arguments: origins moved to the stored mesh's
        centre and directions made unit in float64 as trimesh does (``d / |d|``, a zero
        direction left zero, so it misses), then float32; natively, on the tracing threads."""
        o = np.ascontiguousarray(origins, dtype=np.float64)
        d = np.ascontiguousarray(directions, dtype=np.float64)
        if o.ndim != 2 or o.shape[1] != 3 or o.shape != d.shape:
            raise ValueError(f"ray_origins and ray_directions: expected two (n, 3) arrays, got {o.shape} and {d.shape}")
        self.scene  # opened first: it sets the shift
        return _native.unit_rays(o, d, tuple(float(x) for x in self._shift), self.threads)

    def intersects_first(self, ray_origins: Any, ray_directions: Any, **kwargs: Any) -> np.ndarray:
        """The index of the first triangle each ray hits (int64), ``-1`` where it hits none."""
        r = self._ray_array(ray_origins, ray_directions)
        _, prim = self.scene.intersect(r, threads=self.threads)
        out = prim.astype(np.int64)
        out[prim == 0xFFFFFFFF] = -1
        return out

    def intersects_any(self, ray_origins: Any, ray_directions: Any, **kwargs: Any) -> np.ndarray:
        """Whether each ray hits any triangle (bool)."""
        r = self._ray_array(ray_origins, ray_directions)
        return self.scene.occluded(r, threads=self.threads)

    def intersects_id(self, ray_origins: Any, ray_directions: Any, multiple_hits: bool = True,
                      max_hits: int = 100, return_locations: bool = False, **kwargs: Any):
        """The triangles hit and the rays that hit them, ``(index_tri, index_ray)`` (int64),
        and with ``return_locations`` the ``(h, 3)`` hit points: every hit of each ray (at
        most ``max_hits`` a ray, the nearest) with ``multiple_hits``, else each ray's first.
        Ray by ray, each ray's hits in order of distance (trimesh's embreex intersector lists
        them depth by depth: every ray's first hit, then every second hit...)."""
        o = np.ascontiguousarray(ray_origins, dtype=np.float64)
        d = np.ascontiguousarray(ray_directions, dtype=np.float64)
        r = self._ray_array(o, d)
        if multiple_hits:
            lists = self.scene.list_intersections(r, threads=self.threads)
            splits = lists["ray_splits"]
            index_ray = lists["ray_ids"].astype(np.int64)
            index_tri = lists["primitive_ids"].astype(np.int64)
            t32 = lists["t_hit"]
            if max_hits is not None and len(index_ray) and np.diff(splits).max() > int(max_hits):
                rank = np.arange(len(index_ray)) - splits[:-1].astype(np.int64)[index_ray]
                keep = rank < int(max_hits)
                index_ray, index_tri, t32 = index_ray[keep], index_tri[keep], t32[keep]
        else:
            t_all, prim = self.scene.intersect(r, threads=self.threads)
            index_ray = np.flatnonzero(prim != 0xFFFFFFFF)
            index_tri = prim[index_ray].astype(np.int64)
            t32 = t_all[index_ray]
        if not return_locations:
            return index_tri, index_ray
        # o + unit(d) * t in float64, as trimesh computes them (natively, on the threads).
        locations = _native.hit_locations(o, d, index_ray, np.ascontiguousarray(t32), self.threads)
        return index_tri, index_ray, locations

    def intersects_location(self, ray_origins: Any, ray_directions: Any, multiple_hits: bool = True,
                            **kwargs: Any):
        """``(locations, index_ray, index_tri)``: where each ray hits the mesh (every hit with
        ``multiple_hits``, else the first), as :meth:`intersects_id`."""
        index_tri, index_ray, locations = self.intersects_id(
            ray_origins, ray_directions, multiple_hits=multiple_hits, return_locations=True, **kwargs)
        return locations, index_ray, index_tri

    def contains_points(self, points: Any) -> np.ndarray:
        """Whether each point is inside the mesh (bool), by the parity of the exact number of
        crossings of a ray from it (trimesh's direction, forward and backward; where those two
        disagree, which only an open mesh makes them do, a third ray in another direction
        settles it). A point outside the mesh's bounding box is outside; a point on the surface
        may go either way (as in trimesh)."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points: expected shape (n, 3), got {p.shape}")
        lo, hi = np.asarray(self.mesh.bounds, dtype=np.float64)
        inside_box = np.all((p >= lo) & (p <= hi), axis=1)
        out = np.zeros(len(p), dtype=bool)
        q = p[inside_box]
        if not len(q):
            return out
        odd = lambda d: self._crossings(q, d) % 2 == 1  # noqa: E731
        forward, backward = odd(_CONTAINS_DIRECTION), odd(-_CONTAINS_DIRECTION)
        result = forward
        split = forward != backward
        if split.any():  # only the points whose two rays disagree take the third
            result[split] = self._crossings(q[split], _SECOND_DIRECTION) % 2 == 1
        out[inside_box] = result
        return out

    def _crossings(self, points: np.ndarray, direction: np.ndarray) -> np.ndarray:
        r = self._ray_array(points, np.broadcast_to(direction, points.shape))
        return self.scene.count_intersections(r, threads=self.threads)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_scene"], state["_token"] = None, None  # reopened from the cache where unpickled
        return state


class ProximityQuery:
    """trimesh's ``mesh.nearest`` (``trimesh.proximity.ProximityQuery``) over the same cached
    ``.oavm`` file as :class:`RayMeshIntersector`: ``mesh.nearest =
    oavm.trimesh.ProximityQuery(mesh)``. trimesh's conventions: float64, and a signed distance
    POSITIVE inside (the opposite of Open3D's and :meth:`oavm.Scene.signed_distance`'s)."""

    def __init__(self, mesh: Any, cache_dir: Union[None, str, "os.PathLike[str]"] = None, *,
                 mem_budget: Union[None, int, str] = None, threads: Optional[int] = None):
        self._rays = RayMeshIntersector(mesh, cache_dir, mem_budget=mem_budget, threads=threads)

    def _points(self, points: Any) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points: expected shape (n, 3), got {p.shape}")
        self._rays.scene  # opened first: it sets the shift
        return (p - self._rays._shift).astype(np.float32)

    def on_surface(self, points: Any) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(closest (n, 3), distance (n,), triangle_id (n,))``: the nearest point of the
        surface to each point, as ``trimesh.proximity.closest_point``."""
        q = self._points(points)
        c = self._rays.scene.closest_points(q, threads=self._rays.threads)
        closest = c.point.astype(np.float64) + self._rays._shift
        return closest, c.distance.astype(np.float64), c.prim.astype(np.int64)

    def signed_distance(self, points: Any) -> np.ndarray:
        """The distance to the surface, POSITIVE inside (trimesh's sign), float64; inside by a
        vote of three rays whose crossings are counted exactly."""
        q = self._points(points)
        s = self._rays.scene
        d = s.closest_points(q, threads=self._rays.threads).distance.astype(np.float64)
        return np.where(s.occupancy(q, threads=self._rays.threads), d, -d)
