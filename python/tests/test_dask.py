"""oavm.dask: a dask array of rays traced by the workers of a cluster, with the same answers as
one process."""

from __future__ import annotations

import os

import dask
import dask.array as da
import numpy as np
import pytest
from distributed import Client, LocalCluster

import oavm
import oavm.dask
from conftest import ray_sets


@pytest.fixture(scope="module")
def dragon(tmp_path_factory, shared):
    path = tmp_path_factory.mktemp("dask") / "dragon_res2.oavm"
    oavm.pack(shared / "scenes" / "dragon" / "dragon_vrip_res2.ply", path, progress=False)
    return path


@pytest.fixture(scope="module")
def rays(dragon):
    with oavm.open(dragon) as s:
        info = s.info
    sets = ray_sets(info["mesh_min"], info["mesh_max"], 40000, seed=21)
    return np.concatenate([sets["random"], sets["segments"]])


@pytest.fixture(scope="module")
def expected(dragon, rays):
    with oavm.open(dragon) as s:
        h = s.intersect(rays, attributes=True)
        occluded = s.occluded(rays)
    assert (h.prim != oavm.MISS).mean() > 0.3
    return h, occluded


def test_a_local_cluster_of_two_worker_processes_gives_the_same_answers(dragon, rays, expected):
    h, occluded = expected
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=40) as cluster, Client(cluster) as client:
        r = da.from_array(rays, chunks=(5000, 8))
        assert r.numblocks[0] == 16
        t, prim = oavm.dask.intersect(dragon, r)
        t, prim = dask.compute(t, prim)
        assert np.array_equal(t, h.t) and np.array_equal(prim, h.prim)
        a = dask.compute(*oavm.dask.intersect(dragon, r, attributes=True))
        for got, want in zip(a, h):
            assert np.array_equal(got, want, equal_nan=True)
        assert np.array_equal(oavm.dask.occluded(dragon, r).compute(), occluded)
        # Both workers traced, each in its own process, and each opened the file once for all
        # three computations.
        infos = client.run(oavm.dask.cache_info)
        assert len(infos) == 2
        pids = {i["pid"] for i in infos.values()}
        assert len(pids) == 2 and os.getpid() not in pids
        for info in infos.values():
            assert info["opens"] == 1, infos
            assert info["files"] == [os.path.realpath(dragon)]


@pytest.mark.parametrize("scheduler", ["synchronous", "threads", "processes"])
def test_local_schedulers(dragon, rays, expected, scheduler):
    h, occluded = expected
    r = da.from_array(rays, chunks=(20000, 8))
    t, prim = dask.compute(*oavm.dask.intersect(dragon, r), scheduler=scheduler)
    assert np.array_equal(t, h.t) and np.array_equal(prim, h.prim)
    assert np.array_equal(oavm.dask.occluded(dragon, r).compute(scheduler=scheduler), occluded)


def test_numpy_input_and_chunking(dragon, rays, expected):
    h, _ = expected
    t, prim = oavm.dask.intersect(dragon, rays, chunk=7000)
    assert t.numblocks == (12,)
    assert np.array_equal(t.compute(scheduler="threads"), h.t)
    # Chunked across the eight columns: rechunked to whole rays.
    r = da.from_array(rays, chunks=(9000, 3))
    assert np.array_equal(oavm.dask.intersect(dragon, r).prim.compute(), h.prim)


def test_a_file_packed_again_is_opened_again(tmp_path, shared):
    path = tmp_path / "scene.oavm"
    oavm.pack(shared / "scenes" / "dragon" / "dragon_vrip_res4.ply", path, progress=False)
    with oavm.open(path) as s:
        rays = ray_sets(s.info["mesh_min"], s.info["mesh_max"], 3000, seed=5)["random"]
    before = oavm.dask.intersect(path, rays).prim.compute(scheduler="synchronous")
    opens = oavm.dask.cache_info()["opens"]
    assert np.array_equal(oavm.dask.intersect(path, rays).prim.compute(scheduler="synchronous"), before)
    assert oavm.dask.cache_info()["opens"] == opens, "the cached scene should have been reused"
    oavm.pack(shared / "scenes" / "dragon" / "dragon_vrip_res3.ply", path, progress=False)
    after = oavm.dask.intersect(path, rays).prim.compute(scheduler="synchronous")
    assert oavm.dask.cache_info()["opens"] == opens + 1
    with oavm.open(path) as s:
        assert np.array_equal(after, s.intersect(rays).prim)
    assert not np.array_equal(after, before)


def test_errors_arrive_at_the_client(tmp_path, rays):
    with pytest.raises(FileNotFoundError):
        oavm.dask.intersect(tmp_path / "missing.oavm", rays)
    with pytest.raises(ValueError, match=r"expected shape \(N, 8\)"):
        oavm.dask.intersect(tmp_path / "x.oavm", da.zeros((10, 7)))


def test_camera_rays_made_on_the_workers(dragon):
    with oavm.open(dragon) as s:
        want = s.camera_rays(200, 150, fov=30)
    r = oavm.dask.camera_rays(dragon, 200, 150, chunk=7000, fov=30)
    assert r.shape == (30000, 8) and r.numblocks == (5, 1)
    assert np.array_equal(r.compute(scheduler="processes"), want)
    with pytest.raises(ValueError, match="camera"):
        oavm.dask.camera_rays(dragon, 20, 20, fov=0)


def test_a_signed_distance_grid_on_a_local_cluster(dragon):
    with oavm.open(dragon) as s:
        lo, hi = np.array(s.info["mesh_min"]), np.array(s.info["mesh_max"])
        axes = [np.linspace(lo[k] - 0.05 * (hi[k] - lo[k]), hi[k] + 0.05 * (hi[k] - lo[k]), 24) for k in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float32)
        want = s.signed_distance(grid)
        inside = s.occupancy(grid)
    assert (want < 0).sum() > 100 and (want > 0).sum() > 100 and ((want < 0) == inside).all()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=40) as cluster, Client(cluster):
        g = da.from_array(grid, chunks=(2000, 3))
        got = oavm.dask.signed_distance(dragon, g).compute()
        assert np.array_equal(got, want)
        assert np.array_equal(oavm.dask.occupancy(dragon, g).compute(), inside)
        assert np.array_equal(oavm.dask.distance(dragon, grid, chunk=5000).compute(), np.abs(want))
