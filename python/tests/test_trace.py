"""Answers of the Python API against `oavm-trace`'s HITS and OCCL files (byte for byte), and
against an f64 brute force that shares no code with the library."""

from __future__ import annotations

import json
import pickle
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import oavm
from conftest import REPO, hits_bytes, occl_bytes, ray_sets, run, write_records


def _meshes(shared: Path) -> dict:
    return {
        "bunny": REPO / "data" / "bunny.ply",
        "dragon_res2": shared / "scenes" / "dragon" / "dragon_vrip_res2.ply",
    }


@pytest.fixture(scope="module")
def packed(tmp_path_factory, shared, oavm_pack):
    """Each mesh packed by `oavm.pack` and by `oavm-pack`: the files must be the same bytes."""
    out = {}
    d = tmp_path_factory.mktemp("packed")
    for name, mesh in _meshes(shared).items():
        assert mesh.is_file(), f"missing test mesh {mesh}"
        py = d / f"{name}.oavm"
        report = oavm.pack(mesh, py, progress=False)
        assert report["input_triangles"] > 40000 and report["file_bytes"] == py.stat().st_size
        cli = d / f"{name}.cli.oavm"
        run(oavm_pack, mesh, cli)
        assert py.read_bytes() == cli.read_bytes(), f"{name}: oavm.pack and oavm-pack wrote different files"
        out[name] = py
    return out


@pytest.mark.parametrize("mesh", ["bunny", "dragon_res2"])
def test_answers_equal_the_cli_byte_for_byte(packed, mesh, oavm_trace, tmp_path):
    path = packed[mesh]
    with oavm.open(path) as scene:
        info = scene.info
        sets = ray_sets(info["mesh_min"], info["mesh_max"], 20000, seed=7)
        for name, rays in sets.items():
            rays_file = tmp_path / f"{name}.rays"
            write_records(rays_file, b"RAYS", rays)
            run(oavm_trace, path, "--rays", rays_file, "--hits", tmp_path / "cli.hits")
            run(oavm_trace, path, "--rays", rays_file, "--occluded", tmp_path / "cli.occl")
            t, prim = scene.intersect(rays)
            assert t.dtype == np.float32 and prim.dtype == np.uint32 and t.shape == prim.shape == (len(rays),)
            hit = prim != oavm.MISS
            if name != "odd":
                # The sets are made to hit: agreement on misses alone proves nothing.
                assert hit.mean() > 0.3, f"{mesh}/{name}: only {hit.mean():.1%} hit"
            else:
                assert not hit[:32].any(), "rays with NaN, a zero direction or tmin > tmax must miss"
            assert np.all(np.isinf(t[~hit])) and np.all(np.isfinite(t[hit]))
            assert hits_bytes(t, prim) == (tmp_path / "cli.hits").read_bytes(), f"{mesh}/{name}: HITS differ"
            occluded = scene.occluded(rays)
            assert occluded.dtype == np.bool_
            assert occl_bytes(occluded) == (tmp_path / "cli.occl").read_bytes(), f"{mesh}/{name}: OCCL differ"
            # Any hit within [tmin, tmax] exactly when a closest hit exists.
            assert np.array_equal(occluded, hit)
            # The attributes do not change t or prim.
            a = scene.intersect(rays, attributes=True)
            assert np.array_equal(a.t, t) and np.array_equal(a.prim, prim)


def _grid_mesh(seed: int):
    """A rough height field (a 70 x 70 grid) under a floating octahedron: shared edges and
    vertices, triangles in both windings."""
    rng = np.random.default_rng(seed)
    n = 70
    x, y = np.meshgrid(np.linspace(0, 10, n), np.linspace(0, 10, n), indexing="ij")
    z = rng.normal(scale=0.3, size=(n, n))
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    octa = np.array([[5, 5, 3.5], [5, 5, 1.5], [6, 5, 2.5], [4, 5, 2.5], [5, 6, 2.5], [5, 4, 2.5]], float)
    of = np.array([[0, 2, 4], [0, 4, 3], [0, 3, 5], [0, 5, 2], [1, 4, 2], [1, 3, 4], [1, 5, 3], [1, 2, 5]]) + len(v)
    return np.concatenate([v, octa]), np.concatenate([f, of])


def _brute_force(v, f, rays):
    """Closest hit of every ray by an f64 Moller-Trumbore over every triangle (edges
    inclusive): t, prim (MISS where none)."""
    v0, v1, v2 = (v[f[:, k]].astype(np.float64) for k in range(3))
    e1, e2 = v1 - v0, v2 - v0
    best_t = np.full(len(rays), np.inf)
    best_p = np.full(len(rays), oavm.MISS, dtype=np.uint64)
    for j, r in enumerate(rays.astype(np.float64)):
        o, tmin, d, tmax = r[0:3], r[3], r[4:7], r[7]
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = o - v0
            u = np.einsum("ij,ij->i", s, p) * inv
            q = np.cross(s, e1)
            w = (q @ d) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
            ok = (det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t >= tmin) & (t <= tmax)
        if ok.any():
            k = np.flatnonzero(ok)[np.argmin(t[ok])]
            best_t[j], best_p[j] = t[k], k
    return best_t, best_p


def test_closest_hits_and_attributes_against_brute_force(tmp_path):
    v, f = _grid_mesh(seed=11)
    path = tmp_path / "grid.oavm"
    report = oavm.pack((v, f), path, progress=False, leaf_size=16)
    assert report["input_triangles"] == len(f)
    with oavm.open(path) as scene:
        info = scene.info
        diag = float(np.linalg.norm(np.subtract(info["mesh_max"], info["mesh_min"])))
        rays = ray_sets(info["mesh_min"], info["mesh_max"], 600, seed=5)["random"]
        h = scene.intersect(rays, attributes=True)
    ref_t, ref_p = _brute_force(v, f, rays)
    ref_hit = np.isfinite(ref_t)
    hit = h.prim != oavm.MISS
    assert ref_hit.mean() > 0.5
    # RAYS.md: both miss, or both hit with |t1 - t2| <= 1e-4 * diagonal.
    with np.errstate(invalid="ignore"):  # inf - inf on rays both miss
        agree = (hit == ref_hit) & (~hit | (np.abs(h.t.astype(np.float64) - ref_t) <= 1e-4 * diag))
    assert agree.mean() >= 0.999, f"{(~agree).sum()} of {len(rays)} rays disagree with brute force"
    # The attributes describe the triangle hit: the barycentric point is the point at t, and the
    # normal is that of the triangle's corners as given.
    rays64 = rays[hit].astype(np.float64)
    point = rays64[:, 0:3] + h.t[hit, None].astype(np.float64) * rays64[:, 4:7]
    tri = v[f[h.prim[hit].astype(np.int64)]]
    u, w = h.u[hit, None].astype(np.float64), h.v[hit, None].astype(np.float64)
    assert np.all((u >= 0) & (w >= 0) & (u + w <= 1 + 1e-6))
    bary = (1 - u - w) * tri[:, 0] + u * tri[:, 1] + w * tri[:, 2]
    assert np.max(np.linalg.norm(bary - point, axis=1)) <= 1e-4 * diag
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    assert np.max(np.abs(h.normal[hit] - n)) <= 1e-5
    assert np.isnan(h.u[~hit]).all() and np.isnan(h.normal[~hit]).all()


def test_occluded_against_brute_force(tmp_path):
    v, f = _grid_mesh(seed=12)
    path = tmp_path / "grid.oavm"
    oavm.pack((v, f), path, progress=False)
    rays = ray_sets(v.min(0), v.max(0), 600, seed=9)["segments"]
    ref_t, _ = _brute_force(v, f, rays)
    with oavm.open(path) as scene:
        occluded = scene.occluded(rays)
    ref = np.isfinite(ref_t)
    assert 0.1 < ref.mean() < 0.9, "the segments must be a mix of occluded and free"
    assert (occluded == ref).mean() >= 0.999


def test_forms_of_the_arguments_give_the_same_answers(packed):
    with oavm.open(packed["bunny"]) as scene:
        info = scene.info
        rays = ray_sets(info["mesh_min"], info["mesh_max"], 5000, seed=3)["segments"]
        t, prim = scene.intersect(rays)
        assert (prim != oavm.MISS).mean() > 0.2
        # origins, directions, tmin, tmax as separate arrays (per ray and scalar)
        assert np.array_equal(scene.intersect(rays[:, 0:3], rays[:, 4:7], rays[:, 3], rays[:, 7]).t, t)
        free = scene.intersect(rays[:, 0:3], rays[:, 4:7])
        expect = scene.intersect(np.hstack([rays[:, 0:3], np.zeros((len(rays), 1)), rays[:, 4:7],
                                            np.full((len(rays), 1), np.inf)]))
        assert np.array_equal(free.t, expect.t) and np.array_equal(free.prim, expect.prim)
        # float64, lists, Fortran order, strided views: converted, same answers
        assert np.array_equal(scene.intersect(rays.astype(np.float64)).t, t)
        assert np.array_equal(scene.intersect(rays[:50].tolist()).t, t[:50])
        assert np.array_equal(scene.intersect(np.asfortranarray(rays)).prim, prim)
        wide = np.zeros((len(rays), 16), np.float32)
        wide[:, ::2] = rays
        assert not wide[:, ::2].flags.c_contiguous
        assert np.array_equal(scene.intersect(wide[:, ::2]).prim, prim)
        every_other = np.repeat(rays, 2, axis=0)[::2]
        assert np.array_equal(scene.occluded(every_other), scene.occluded(rays))
        big_endian = rays.astype(">f4")
        assert np.array_equal(scene.intersect(big_endian).t, t)
        # threads: any count, same answers
        for n in (1, 2, 3):
            assert np.array_equal(scene.intersect(rays, threads=n).t, t)
        # a budget smaller than the file pages blocks in and out: same answers
    with oavm.open(packed["bunny"], mem_budget="1M") as small:
        assert small.info["fits_in_budget"] is False
        assert np.array_equal(small.intersect(rays).t, t)


def test_empty_batches(packed):
    with oavm.open(packed["bunny"]) as scene:
        for empty in (np.zeros((0, 8), np.float32), np.zeros((0, 8)), []):
            if isinstance(empty, list):
                empty = np.zeros((0, 8), np.float32)
            h = scene.intersect(empty)
            assert h.t.shape == (0,) and h.t.dtype == np.float32 and h.prim.dtype == np.uint32
            a = scene.intersect(empty, attributes=True)
            assert a.normal.shape == (0, 3)
            o = scene.occluded(empty)
            assert o.shape == (0,) and o.dtype == np.bool_
        assert scene.intersect(np.zeros((0, 3)), np.zeros((0, 3))).t.shape == (0,)


def test_contiguous_float32_rays_are_not_copied(packed):
    """numpy reports its allocations to tracemalloc: tracing 2^20 contiguous float32 rays
    (32 MiB) must not allocate a numpy copy of them (only the answers); a strided view must
    (so the check can fail)."""
    with oavm.open(packed["bunny"]) as scene:
        info = scene.info
        rays = np.tile(ray_sets(info["mesh_min"], info["mesh_max"], 1024, seed=1)["random"], (1024, 1))
        strided = np.repeat(rays, 2, axis=0)[::2]
        scene.intersect(rays[:10])

        def peak(a):
            tracemalloc.start()
            scene.intersect(a)
            scene.occluded(a)
            _, p = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            return p

        # The answers (8 bytes a ray: t and prim) are numpy's own allocations; a copy of the
        # rays would add 32 bytes a ray.
        assert peak(rays) < rays.nbytes // 2, "the contiguous float32 rays were copied"
        assert peak(strided) > rays.nbytes, "a strided view should have been copied (the check is blind)"


def test_scene_is_a_picklable_context_manager(packed):
    path = packed["bunny"]
    scene = oavm.open(path, mem_budget="64M")
    info = scene.info
    for key in ("format_version", "input_triangles", "blocks", "mesh_min", "mesh_max", "leaf", "mem_budget"):
        assert key in info
    assert info["format_version"] == oavm.FORMAT_VERSION and info["mem_budget"] == 64 << 20
    assert info["input_triangles"] == 69451
    rays = ray_sets(info["mesh_min"], info["mesh_max"], 1000, seed=2)["random"]
    t = scene.intersect(rays).t
    clone = pickle.loads(pickle.dumps(scene))
    assert clone.path == str(path) and clone.info["mem_budget"] == 64 << 20
    assert np.array_equal(clone.intersect(rays).t, t)
    assert scene.verify()["ok"] is True
    with scene as s:
        assert s is scene
    assert scene.closed
    with pytest.raises(ValueError, match="closed"):
        scene.intersect(rays)
    assert "closed" in repr(scene)


def test_camera_rays(packed, oavm_trace, tmp_path):
    with oavm.open(packed["bunny"]) as scene:
        r = scene.camera_rays(160, 120)
        assert r.shape == (160 * 120, 8) and r.dtype == np.float32
        assert np.allclose(np.linalg.norm(r[:, 4:7], axis=1), 1, atol=1e-6)
        assert np.all(r[:, 0:3] == r[0, 0:3]) and np.all(r[:, 3] == 0) and np.all(np.isinf(r[:, 7]))
        assert np.array_equal(scene.camera_rays(160, 120, start=1000, stop=1500), r[1000:1500])
        # The default camera frames the mesh: the centre of the image sees it.
        t, prim = scene.intersect(r)
        centre = prim.reshape(120, 160)[40:80, 60:100]
        assert (centre != oavm.MISS).mean() > 0.5
        # Same rays, same answers as oavm-trace's benchmark of its own primary rays (hit count).
        p = run(oavm_trace, packed["bunny"], "--primary", "160x120", "--json")
        assert json.loads(p.stdout)["sets"][0]["hits"] == int((prim != oavm.MISS).sum())
        # A camera looking along -z from above the mesh, narrower.
        top = scene.camera_rays(8, 8, eye=(0, 1, 0), target=(0, 0, 0), up=(0, 0, -1), fov=10)
        assert np.allclose(top[:, 0:3], [0, 1, 0]) and np.all(top[:, 5] < -0.99)
        for bad in (dict(eye=(0, 0, 0), target=(0, 0, 0)), dict(fov=0), dict(fov=200), dict(up=(0, 1, 0), eye=(0, 1, 0), target=(0, 0, 0))):
            with pytest.raises(ValueError, match="camera"):
                scene.camera_rays(8, 8, **bad)
        with pytest.raises(ValueError, match="pixels"):
            scene.camera_rays(8, 8, start=10, stop=100)
        with pytest.raises(ValueError, match="width"):
            scene.camera_rays(0, 8)


def test_python_threads_share_a_scene(packed):
    """Eight Python threads trace one scene at once, under a budget that makes it page: the
    GIL is released (they overlap) and every thread gets the single-threaded answers."""
    from concurrent.futures import ThreadPoolExecutor

    with oavm.open(packed["dragon_res2"], mem_budget="2M") as scene:
        info = scene.info
        assert not info["fits_in_budget"]
        rays = ray_sets(info["mesh_min"], info["mesh_max"], 20000, seed=31)["random"]
        want = scene.intersect(rays, threads=1)
        with ThreadPoolExecutor(8) as ex:
            got = list(ex.map(lambda k: scene.intersect(rays[k::3]) if k % 2 else scene.occluded(rays[k::3]), range(24)))
        for k, g in enumerate(got):
            if k % 2:
                assert np.array_equal(g.t, want.t[k::3]) and np.array_equal(g.prim, want.prim[k::3])
            else:
                assert np.array_equal(g, want.prim[k::3] != oavm.MISS)


def test_ropes_from_python_give_every_walks_answers(packed, oavm_trace, tmp_path):
    """`oavm.pack(..., ropes=True)` writes the file `oavm-pack --ropes` writes, and every walk of
    it (`walk=` of `oavm.open`) answers every ray set exactly as the default walk of the file
    without ropes; a file without ropes refuses the rope walk."""
    mesh = REPO / "data" / "bunny.ply"
    roped = tmp_path / "roped.oavm"
    report = oavm.pack(mesh, roped, progress=False, ropes=True)
    assert report["ropes"]["ropes"] > 0 and report["file_bytes"] == roped.stat().st_size
    assert report["file_bytes"] > packed["bunny"].stat().st_size
    with oavm.open(packed["bunny"]) as plain:
        info = plain.info
        sets = ray_sets(info["mesh_min"], info["mesh_max"], 5000, seed=11)
        want = {name: (plain.intersect(r).t, plain.occluded(r)) for name, r in sets.items()}
    assert want["random"][0][np.isfinite(want["random"][0])].size > 1000
    for walk in ("auto", "topdown", "neighbours", "ropes"):
        with oavm.open(roped, walk=walk) as scene:
            assert scene.verify()["ok"] is True
            for name, rays in sets.items():
                t = scene.intersect(rays).t
                assert np.array_equal(t.view(np.uint32), want[name][0].view(np.uint32)), (walk, name)
                assert np.array_equal(scene.occluded(rays), want[name][1]), (walk, name)
    with pytest.raises(ValueError, match="no ropes"):
        oavm.open(packed["bunny"], walk="ropes")
    with pytest.raises(ValueError, match="walk"):
        oavm.open(packed["bunny"], walk="sideways")


def _crossings(v: np.ndarray, f: np.ndarray, p: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Triangles the ray from each point along `d` crosses (t > 0): float64 Moller-Trumbore."""
    a, b, c = (v[f[:, k]] for k in range(3))
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    s = p[:, None, :] - a[None]
    u = np.einsum("ptj,tj->pt", s, h) / det
    q = np.cross(s, e1[None])
    w = (q @ d) / det
    t = np.einsum("ptj,tj->pt", q, e2) / det
    return ((u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)).sum(axis=1)


def test_occupancy_is_the_vote_of_the_exported_directions(tmp_path):
    # A cube with its +y and +z faces open: a point near them sees out along some directions and
    # not others, so the vote depends on which three rays it takes.
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    quads = {"-x": (0, 1, 3, 2), "+x": (4, 6, 7, 5), "-y": (0, 4, 5, 1), "-z": (0, 2, 6, 4)}
    f = np.array([t for a, b, c, d in quads.values() for t in ((a, b, c), (a, c, d))], dtype=np.uint32)
    path = tmp_path / "open_box.oavm"
    oavm.pack((corners.astype(np.float32), f), path, progress=False)
    d = oavm.VOTE_DIRECTIONS
    assert d.shape == (3, 3) and d.dtype == np.float32 and not d.flags.writeable
    assert np.allclose(np.linalg.norm(d, axis=1), 1, atol=1e-3)
    # The same float32 points for the scene and (widened exactly) for the reference.
    pts = np.random.default_rng(7).uniform(0.05, 0.95, size=(400, 3)).astype(np.float32)
    p64 = pts.astype(np.float64)
    vote = lambda dirs: sum(_crossings(corners, f.astype(np.int64), p64, x) % 2 for x in dirs) >= 2  # noqa: E731
    want = vote(d.astype(np.float64))
    # The check can fail: both answers occur, and other directions vote otherwise somewhere.
    assert want.any() and not want.all()
    assert (vote(-d.astype(np.float64)) != want).any()
    with oavm.open(path) as scene:
        got = scene.occupancy(pts)
    assert np.array_equal(got, want), f"{(got != want).sum()} of {len(pts)} points differ"
