"""oavm.trimesh.RayMeshIntersector against trimesh's own numpy intersector
(``trimesh.ray.ray_triangle``, float64, not watertight) on the same meshes and rays: first hits,
any hits, every hit with its location, containment; the cache directory; trimesh's conventions.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_triangle import RayMeshIntersector as Reference

import oavm
from oavm.trimesh import RayMeshIntersector
from conftest import brute_distance


def _rays(mesh, n, seed):
    """Origins around the mesh's box, directions uniform, not normalised."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    o = lo - 0.2 * (hi - lo) + 1.4 * (hi - lo) * rng.random((n, 3))
    d = rng.normal(size=(n, 3)) * rng.uniform(0.1, 10.0, size=(n, 1))
    return o, d


@pytest.fixture(scope="module")
def bunny(shared):
    return trimesh.load(shared / "scenes" / "bunny" / "bun_zipper.ply", process=False)


def test_first_and_any_hits_are_trimesh_s(bunny, tmp_path):
    o, d = _rays(bunny, 1500, 1)
    ours, ref = RayMeshIntersector(bunny, cache_dir=tmp_path), Reference(bunny)
    first, want = ours.intersects_first(o, d), ref.intersects_first(o, d)
    assert first.dtype == np.int64 and (first >= -1).all()
    hits = (want >= 0).sum()
    assert hits > 300, f"only {hits} rays hit the bunny"
    differ = np.flatnonzero(first != want)
    # Either triangle of a shared edge, or a ray grazing one: the hit points still agree.
    assert len(differ) <= 3, f"{len(differ)} rays differ: {differ[:10]}"
    assert (ours.intersects_any(o, d) == ref.intersects_any(o, d)).all()
    loc, ray, tri = ours.intersects_location(o, d, multiple_hits=False)
    assert (np.sort(ray) == np.flatnonzero(want >= 0)).all()
    ref_loc, ref_ray, _ = ref.intersects_location(o, d, multiple_hits=False)
    order = np.argsort(ref_ray)
    assert np.allclose(loc[np.argsort(ray)], ref_loc[order], atol=1e-5 * bunny.scale)


def test_every_hit_is_trimesh_s(bunny, tmp_path):
    o, d = _rays(bunny, 1500, 2)
    ours, ref = RayMeshIntersector(bunny, cache_dir=tmp_path), Reference(bunny)
    tri, ray, loc = ours.intersects_id(o, d, multiple_hits=True, return_locations=True)
    ref_tri, ref_ray, ref_loc = ref.intersects_id(o, d, multiple_hits=True, return_locations=True)
    n = len(o)
    counts, ref_counts = np.bincount(ray, minlength=n), np.bincount(ref_ray, minlength=n)
    assert (counts >= 2).sum() > 150, "too few rays cross the bunny twice for this to test much"
    differ = np.flatnonzero(counts != ref_counts)
    # ray_triangle keeps both triangles of an edge a ray passes within its tolerance (1e-8 in
    # barycentrics) of, where oavm counts the crossing once: only such rays may differ.
    assert len(differ) <= 3, f"{len(differ)} rays differ in their number of hits: {differ[:10]}"
    same = np.setdiff1d(np.arange(n), differ)
    pairs = lambda r, t: set(zip(r.tolist(), t.tolist()))  # noqa: E731
    keep, ref_keep = np.isin(ray, same), np.isin(ref_ray, same)
    assert pairs(ray[keep], tri[keep]) == pairs(ref_ray[ref_keep], ref_tri[ref_keep])
    # Each ray's hits in order of distance, at trimesh's locations.
    dist = np.einsum("ij,ij->i", loc - o[ray], d[ray] / np.linalg.norm(d[ray], axis=1)[:, None])
    for r in same[:500]:
        assert (np.diff(dist[ray == r]) >= 0).all()
    key = lambda r, t: np.lexsort((t, r))  # noqa: E731
    a, b = key(ray[keep], tri[keep]), key(ref_ray[ref_keep], ref_tri[ref_keep])
    assert np.allclose(loc[keep][a], ref_loc[ref_keep][b], atol=1e-5 * bunny.scale)
    # max_hits keeps each ray's nearest.
    t2, r2 = ours.intersects_id(o, d, max_hits=2)
    assert (np.bincount(r2, minlength=n) == np.minimum(counts, 2)).all()


def test_contains_points_on_closed_meshes(tmp_path):
    rng = np.random.default_rng(3)
    for mesh, inside in [
        (trimesh.creation.icosphere(subdivisions=3, radius=2.0),
         lambda p: np.linalg.norm(p, axis=1) < 2.0 * np.cos(np.pi / 40)),
        (trimesh.creation.box(extents=(2.0, 3.0, 4.0)),
         lambda p: (np.abs(p) < np.array([1.0, 1.5, 2.0])).all(axis=1)),
    ]:
        p = rng.uniform(-2.5, 2.5, size=(20000, 3))
        # Also the mesh's own vertices moved off the surface, and points on the axes (rays
        # through vertices and edges of the box's and sphere's grids).
        p = np.concatenate([p, mesh.vertices * 0.999, mesh.vertices * 1.001,
                            np.stack([np.linspace(-2.4, 2.4, 97), np.zeros(97), np.zeros(97)], axis=1)])
        got = RayMeshIntersector(mesh, cache_dir=tmp_path).contains_points(p)
        # Away from the surface the answer is known; near it, trimesh's own must agree.
        far = np.abs(np.linalg.norm(p, axis=1) - 2.0) > 0.05 if len(mesh.faces) > 12 else \
            np.min(np.abs(np.abs(p) - np.array([1.0, 1.5, 2.0])), axis=1) > 1e-3
        assert (got[far] == inside(p[far])).all()
        assert got.sum() > 1000
        ref = Reference(mesh).contains_points(p)
        assert (got == ref).mean() > 0.999


def test_the_cache_directory_is_reused_and_follows_the_mesh(bunny, tmp_path):
    o, d = _rays(bunny, 200, 4)
    first = RayMeshIntersector(bunny, cache_dir=tmp_path).intersects_first(o, d)
    files = list(tmp_path.glob("*.oavm"))
    assert len(files) == 1
    stamp = files[0].stat().st_mtime_ns
    # Another intersector (another process would do the same) opens the file packed before.
    again = RayMeshIntersector(bunny.copy(), cache_dir=tmp_path)
    assert (again.intersects_first(o, d) == first).all()
    assert list(tmp_path.glob("*.oavm")) == files and files[0].stat().st_mtime_ns == stamp
    assert again.scene.path == str(files[0])
    # A changed mesh is packed anew, and answered as it now is.
    moved = bunny.copy()
    ours = RayMeshIntersector(moved, cache_dir=tmp_path)
    ours.intersects_first(o, d)
    moved.vertices = moved.vertices + np.array([10.0, 0.0, 0.0])
    assert (ours.intersects_first(o, d) == -1).sum() > (first == -1).sum()
    # (Stored around its centre, a mesh moved whole is the same file.)
    assert len(list(tmp_path.glob("*.oavm"))) == 1
    moved.vertices = moved.vertices * 2.0
    assert (ours.intersects_first(o, d) != first).any()
    assert len(list(tmp_path.glob("*.oavm"))) == 2
    # A damaged file in the cache is packed again, not trusted.
    files[0].write_bytes(files[0].read_bytes()[:1000])
    assert (RayMeshIntersector(bunny, cache_dir=tmp_path).intersects_first(o, d) == first).all()
    # Pickled, it reopens the file where it is unpickled.
    clone = pickle.loads(pickle.dumps(RayMeshIntersector(bunny, cache_dir=tmp_path)))
    assert (clone.intersects_first(o, d) == first).all()


def test_trimesh_conventions(tmp_path):
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    ours = RayMeshIntersector(box, cache_dir=tmp_path)
    o = np.array([[0.0, 0.0, -5.0], [0.0, 0.0, -5.0], [0.0, 0.0, -5.0], [3.0, 3.0, -5.0]])
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 7.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    first = ours.intersects_first(o, d)
    assert (first[:2] >= 0).all() and first[2] == -1 and first[3] == -1
    loc, ray, tri = ours.intersects_location(o, d)
    # Unnormalised directions are normalised: the same hits at the same points.
    assert ray.tolist() == [0, 0, 1, 1]
    assert np.allclose(loc, [[0, 0, -1], [0, 0, 1], [0, 0, -1], [0, 0, 1]])
    with pytest.raises(ValueError):
        ours.intersects_first(o, d[:2])
    # A mesh far from the origin keeps its precision (it is stored around its centre).
    far = box.copy()
    far.vertices = far.vertices + 1.0e6
    hits = RayMeshIntersector(far, cache_dir=tmp_path).intersects_location(o + 1.0e6, d)[0]
    assert np.allclose(hits, loc + 1.0e6, atol=1e-6)
    assert oavm.MISS == 0xFFFFFFFF


def test_pack_takes_mesh_objects(bunny, tmp_path):
    oavm.pack(bunny, tmp_path / "t.oavm", progress=False)
    oavm.pack((bunny.vertices, bunny.faces), tmp_path / "a.oavm", progress=False)
    assert (tmp_path / "t.oavm").read_bytes() == (tmp_path / "a.oavm").read_bytes()
    with pytest.raises(ValueError):
        oavm.pack(object(), tmp_path / "x.oavm")


def test_proximity_follows_trimesh_s_conventions(bunny, tmp_path):
    from oavm.trimesh import ProximityQuery
    rng = np.random.default_rng(7)
    lo, hi = bunny.bounds
    p = lo - 0.1 * (hi - lo) + 1.2 * (hi - lo) * rng.random((60, 3))
    closest, dist, tri = ProximityQuery(bunny, cache_dir=tmp_path).on_surface(p)
    assert closest.dtype == np.float64 and tri.dtype == np.int64
    tris = bunny.triangles
    for k in range(len(p)):
        assert abs(dist[k] - brute_distance(tris, p[k])) <= 1e-6 * bunny.scale
        assert abs(np.linalg.norm(closest[k] - p[k]) - dist[k]) <= 1e-6 * bunny.scale
        assert brute_distance(tris[tri[k]:tri[k] + 1], p[k]) <= dist[k] + 1e-6 * bunny.scale
    # trimesh's sign: positive inside.
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    q = rng.uniform(-1.5, 1.5, size=(2000, 3))
    r = np.linalg.norm(q, axis=1)
    clear = np.abs(r - 1.0) > 0.02
    sd = ProximityQuery(sphere, cache_dir=tmp_path).signed_distance(q)
    assert ((sd > 0) == (r < 1))[clear].all() and (sd > 0).sum() > 200
    for k in range(0, 2000, 50):
        assert abs(abs(sd[k]) - brute_distance(sphere.triangles, q[k])) <= 1e-6


def test_rays_and_locations_are_numpy_s_bit_for_bit(bunny, tmp_path):
    # The intersector makes its rays and hit locations natively; they must be the float64
    # arithmetic trimesh does in numpy (d / |d|, a zero direction left zero; o + unit * t),
    # bit for bit, scaled directions and a zero one included.
    ours = RayMeshIntersector(bunny, cache_dir=tmp_path)
    o, d = _rays(bunny, 5000, 7)
    d = d * np.linspace(0.1, 30.0, len(d))[:, None]
    d[3] = 0.0
    norm = np.linalg.norm(d, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = d / norm[:, None]
    unit[norm == 0] = 0.0
    ours.scene  # opened first: it sets the shift
    shift = ours._shift
    assert np.array_equal(ours._ray_array(o, d), oavm.rays(o - shift, unit))
    tri, ray, loc = ours.intersects_id(o, d, multiple_hits=True, return_locations=True)
    lists = ours.scene.list_intersections(oavm.rays(o - shift, unit))
    assert len(ray) > 1000 and (ray == lists["ray_ids"]).all()
    t = lists["t_hit"].astype(np.float64)
    assert np.array_equal(loc, o[ray] + unit[ray] * t[:, None])
    # Open3D's (N, 6) rays become RAYS.md's, tnear and tfar in place.
    r6 = np.concatenate([o, d], axis=1).astype(np.float32)
    want = np.empty((len(r6), 8), np.float32)
    want[:, 0:3], want[:, 3], want[:, 4:7], want[:, 7] = r6[:, 0:3], 0.5, r6[:, 3:6], 9.0
    assert np.array_equal(oavm._native.six_rays(r6, 0.5, 9.0, None), want)
    with pytest.raises(ValueError, match="not one of"):
        oavm._native.hit_locations(o, d, np.array([len(o)], np.int64), np.ones(1, np.float32), None)
