"""oavm.open3d.RaycastingScene: Open3D's calls, shapes, dtypes and miss values; several
geometries; the two pinhole forms. (Against Open3D itself: tools/py_dropin.py, which needs the
400 MB Open3D wheel the tests do not install.)"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import trimesh

import oavm
from oavm.open3d import INVALID_ID, RaycastingScene
from conftest import brute_distance


@pytest.fixture(scope="module")
def bunny(shared):
    m = trimesh.load(shared / "scenes" / "bunny" / "bun_zipper.ply", process=False)
    return m.vertices.astype(np.float32), m.faces.astype(np.uint32)


def _rays(v, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = v.min(axis=0), v.max(axis=0)
    o = lo - 0.2 * (hi - lo) + 1.4 * (hi - lo) * rng.random((n, 3))
    d = rng.normal(size=(n, 3))
    return np.concatenate([o, d], axis=1).astype(np.float32)


def test_cast_rays_shapes_dtypes_and_misses(bunny, tmp_path):
    v, f = bunny
    s = RaycastingScene(cache_dir=tmp_path)
    assert s.add_triangles(v, f) == 0
    rays = _rays(v, 4 * 5 * 50, 1).reshape(4, 5, 50, 6)
    ans = s.cast_rays(rays)
    want = {"t_hit": ((4, 5, 50), np.float32), "geometry_ids": ((4, 5, 50), np.uint32),
            "primitive_ids": ((4, 5, 50), np.uint32), "primitive_uvs": ((4, 5, 50, 2), np.float32),
            "primitive_normals": ((4, 5, 50, 3), np.float32)}
    assert set(ans) == set(want)
    for k, (shape, dtype) in want.items():
        a = ans[k].numpy()
        assert type(a) is np.ndarray and a.shape == shape and a.dtype == dtype, k
    t = ans["t_hit"].numpy()
    miss = ~np.isfinite(t)
    assert 100 < (~miss).sum() < t.size
    assert (ans["geometry_ids"].numpy()[miss] == INVALID_ID).all()
    assert (ans["primitive_ids"].numpy()[miss] == INVALID_ID).all()
    assert (ans["primitive_uvs"].numpy()[miss] == 0).all() and (ans["primitive_normals"].numpy()[miss] == 0).all()
    # The same answers as oavm's own call.
    flat = rays.reshape(-1, 6)
    with oavm.open(s._opened().path) as scene:
        h = scene.intersect(flat[:, :3], flat[:, 3:], attributes=True)
    assert (h.t == t.reshape(-1)).all() and (h.prim == ans["primitive_ids"].numpy().reshape(-1)).all()
    hit = ~miss.reshape(-1)
    assert np.allclose(np.linalg.norm(ans["primitive_normals"].numpy().reshape(-1, 3)[hit], axis=1), 1.0, atol=1e-5)
    # Occlusion within tnear..tfar; counts and lists agree with each other and with cast_rays.
    occ = s.test_occlusions(rays).numpy()
    assert occ.dtype == np.bool_ and (occ == ~miss).all()
    short = s.test_occlusions(rays, tnear=0.0, tfar=1e-6).numpy()
    assert short.sum() < occ.sum()
    n = s.count_intersections(rays).numpy()
    assert n.dtype == np.int32 and n.shape == (4, 5, 50) and ((n > 0) == ~miss).all()
    lx = s.list_intersections(rays)
    splits = lx["ray_splits"].numpy()
    assert splits.dtype == np.uint32 and (np.diff(splits) == n.reshape(-1)).all()
    first = splits[:-1][hit]
    assert (lx["t_hit"].numpy()[first] == t.reshape(-1)[hit]).all()
    assert (lx["ray_ids"].numpy() == np.repeat(np.arange(flat.shape[0]), n.reshape(-1))).all()


def test_several_geometries_name_their_hits(bunny, tmp_path):
    v, f = bunny
    shift = np.float32([1.0, 0.0, 0.0])
    s = RaycastingScene(cache_dir=tmp_path)
    s.add_triangles(v, f)
    assert s.add_triangles(trimesh.Trimesh(v + shift, f, process=False)) == 1
    rays = _rays(v, 3000, 2)
    one = RaycastingScene(cache_dir=tmp_path)
    one.add_triangles(v, f)
    a = one.cast_rays(rays)
    # The same rays moved onto the second copy, whose hits then name geometry 1 and the same
    # triangles (the first copy is behind or beside them, never between: 1.0 apart along x,
    # the bunny is 0.16 wide; rays moved by +1 along x still may pass the first copy, so only
    # rays whose first hit in `two` is in geometry 1 are compared).
    moved = rays.copy()
    moved[:, 0] += 1.0
    b = s.cast_rays(moved)
    g, p = b["geometry_ids"].numpy(), b["primitive_ids"].numpy()
    second = g == 1
    assert second.sum() > 300
    assert (p[second] == a["primitive_ids"].numpy()[second]).all()
    assert np.allclose(b["t_hit"].numpy()[second], a["t_hit"].numpy()[second], rtol=1e-3, atol=1e-5)
    assert set(np.unique(g)) <= {0, 1, INVALID_ID}
    lx = s.list_intersections(moved)
    assert set(np.unique(lx["geometry_ids"].numpy())) == {0, 1} or (lx["geometry_ids"].numpy() == 1).all()
    assert (lx["primitive_ids"].numpy() < len(f)).all()
    # Pickled (by its meshes), it answers the same.
    c = pickle.loads(pickle.dumps(s)).cast_rays(moved)
    assert (c["geometry_ids"].numpy() == g).all()
    # The file it packed holds the geometry table: opened on its own, it names them too.
    f2 = RaycastingScene.open(s._opened().path).cast_rays(moved)
    assert (f2["geometry_ids"].numpy() == g).all() and (f2["primitive_ids"].numpy() == p).all()


def test_a_packed_file_opens_as_a_scene(bunny, tmp_path):
    v, f = bunny
    oavm.pack((v, f), tmp_path / "b.oavm", progress=False)
    s = RaycastingScene.open(tmp_path / "b.oavm")
    ans = s.cast_rays(_rays(v, 500, 3))
    assert np.isfinite(ans["t_hit"].numpy()).sum() > 50
    assert set(np.unique(ans["geometry_ids"].numpy())) <= {0, INVALID_ID}
    with pytest.raises(ValueError):
        s.add_triangles(v, f)
    assert (pickle.loads(pickle.dumps(s)).cast_rays(_rays(v, 500, 3))["t_hit"].numpy() == ans["t_hit"].numpy()).all()


def test_pinhole_rays():
    # Intrinsics and extrinsics: each ray projects back onto its pixel's centre.
    k = np.array([[300.0, 0.0, 3.5], [0.0, 310.0, 2.5], [0.0, 0.0, 1.0]])
    c, s_ = np.cos(0.3), np.sin(0.3)
    e = np.eye(4)
    e[:3, :3] = [[c, 0, s_], [0, 1, 0], [-s_, 0, c]]
    e[:3, 3] = [0.1, -0.2, 0.3]
    r = RaycastingScene.create_rays_pinhole(k, e, 7, 5).numpy()
    assert r.shape == (5, 7, 6) and r.dtype == np.float32
    p = r[..., :3] + r[..., 3:]
    cam = p.reshape(-1, 3) @ e[:3, :3].T + e[:3, 3]
    pix = cam @ k.T
    pix = pix[:, :2] / pix[:, 2:]
    ys, xs = np.mgrid[0:5, 0:7]
    assert np.allclose(pix, np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], axis=1), atol=1e-3)
    # The field-of-view form, as Open3D 0.20 gives it (its output for these arguments, copied):
    # x to the left, y up, the horizontal field of view.
    r = RaycastingScene.create_rays_pinhole(fov_deg=90, center=[0, 0, -1], eye=[0, 0, 0], up=[0, 1, 0],
                                            width_px=4, height_px=2).numpy()
    want = np.array([[0.75, -0.25, -1], [0.25, -0.25, -1], [-0.25, -0.25, -1], [-0.75, -0.25, -1],
                     [0.75, 0.25, -1], [0.25, 0.25, -1], [-0.25, 0.25, -1], [-0.75, 0.25, -1]])
    assert np.allclose(r.reshape(-1, 6)[:, 3:], want) and (r[..., :3] == 0).all()


def test_bad_arguments_are_value_errors(bunny, tmp_path):
    v, f = bunny
    s = RaycastingScene(cache_dir=tmp_path)
    with pytest.raises(ValueError, match="no geometry"):
        s.cast_rays(np.zeros((1, 6), np.float32))
    with pytest.raises(ValueError):
        s.add_triangles(v, f[:, :2])
    with pytest.raises(ValueError):
        s.add_triangles(v, f + len(v))
    s.add_triangles(v, f)
    with pytest.raises(ValueError, match=r"\(\.\.\., 6\)"):
        s.cast_rays(np.zeros((3, 5), np.float32))
    with pytest.raises(ValueError):
        s.cast_rays(np.zeros((3, 6)), nthreads=-1)


def test_closest_points_and_signed_distance(bunny, tmp_path):
    v, f = bunny
    s = RaycastingScene(cache_dir=tmp_path)
    s.add_triangles(v, f)
    rng = np.random.default_rng(5)
    lo, hi = v.min(axis=0), v.max(axis=0)
    q = (lo - 0.1 * (hi - lo) + 1.2 * (hi - lo) * rng.random((4, 50, 3))).astype(np.float32)
    c = s.compute_closest_points(q)
    assert c["points"].numpy().shape == (4, 50, 3) and c["primitive_ids"].numpy().dtype == np.uint32
    d = s.compute_distance(q).numpy()
    assert d.shape == (4, 50) and d.dtype == np.float32
    assert np.allclose(np.linalg.norm(c["points"].numpy() - q, axis=-1), d, atol=1e-6)
    # Against a brute force over every triangle (numpy, f64, conftest) on some of the points.
    tri = v[f].astype(np.float64)
    for p, dist in zip(q.reshape(-1, 3)[:40].astype(np.float64), d.reshape(-1)[:40]):
        assert abs(brute_distance(tri, p) - dist) <= 1e-6, (p, dist)
    # The sign on a closed mesh: an icosphere's inside is known.
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    t = RaycastingScene(cache_dir=tmp_path)
    t.add_triangles(sphere)
    pts = rng.uniform(-1.5, 1.5, size=(3000, 3)).astype(np.float32)
    r = np.linalg.norm(pts, axis=1)
    clear = np.abs(r - 1.0) > 0.02
    sd = t.compute_signed_distance(pts).numpy()
    occ = t.compute_occupancy(pts).numpy()
    assert ((sd < 0) == (r < 1))[clear].all() and ((occ == 1.0) == (r < 1))[clear].all()
    assert (occ == 1.0).sum() > 300
    with pytest.raises(ValueError):
        t.compute_occupancy(pts, nsamples=2)
