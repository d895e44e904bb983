"""Bad arguments and bad inputs: a Python exception naming the problem, never a crash."""

from __future__ import annotations

import os

import numpy as np
import pytest

import oavm
from conftest import REPO, ray_sets


@pytest.fixture(scope="module")
def bunny(tmp_path_factory):
    path = tmp_path_factory.mktemp("bunny") / "bunny.oavm"
    oavm.pack(REPO / "data" / "bunny.ply", path, progress=False)
    return path


@pytest.fixture(scope="module")
def scene(bunny):
    with oavm.open(bunny) as s:
        yield s


@pytest.mark.parametrize("shape", [(10, 7), (10, 9), (8,), (2, 4, 8), (10, 3), ()])
def test_wrong_shapes(scene, shape):
    with pytest.raises(ValueError, match=r"rays: expected shape \(N, 8\)"):
        scene.intersect(np.zeros(shape, np.float32))
    with pytest.raises(ValueError, match=r"rays: expected shape \(N, 8\)"):
        scene.occluded(np.zeros(shape, np.float32))


def test_wrong_shapes_of_origins_and_directions(scene):
    with pytest.raises(ValueError, match=r"origins: expected shape \(N, 3\)"):
        scene.intersect(np.zeros((5, 4)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="5 against 6 rays"):
        scene.intersect(np.zeros((5, 3)), np.zeros((6, 3)))
    with pytest.raises(ValueError, match=r"tmax: expected a number or shape \(5,\)"):
        scene.intersect(np.zeros((5, 3)), np.ones((5, 3)), tmax=np.ones(4))
    with pytest.raises(ValueError, match="tmin and tmax go with origins"):
        scene.intersect(np.zeros((5, 8)), tmax=1.0)


@pytest.mark.parametrize("bad", [np.zeros((4, 8), complex), np.array([["a"] * 8] * 4), np.zeros((4, 8), object),
                                 np.zeros((4, 8), "datetime64[s]"), [[1, 2, 3], [4]]])
def test_wrong_dtypes(scene, bad):
    with pytest.raises(ValueError, match="rays"):
        scene.intersect(bad)


def test_integer_and_bool_like_rays_convert_or_refuse(scene):
    # Integers are numbers: converted. Booleans are not a real number type: refused.
    assert scene.intersect(np.zeros((3, 8), np.int32)).t.shape == (3,)
    with pytest.raises(ValueError, match="dtype bool"):
        scene.intersect(np.zeros((3, 8), bool))


def test_bad_thread_counts(scene):
    rays = np.zeros((3, 8), np.float32)
    for bad in (0, -1, 1.5, "2", 5000):
        with pytest.raises(ValueError, match="threads"):
            scene.intersect(rays, threads=bad)


def test_missing_and_corrupt_files(tmp_path, bunny):
    with pytest.raises(FileNotFoundError, match="nothing.oavm"):
        oavm.open(tmp_path / "nothing.oavm")
    with pytest.raises(oavm.FormatError, match="not an .oavm file"):
        (tmp_path / "text.oavm").write_text("hello, world\n" * 100)
        oavm.open(tmp_path / "text.oavm")
    data = bunny.read_bytes()
    (tmp_path / "truncated.oavm").write_bytes(data[: len(data) // 2])
    with pytest.raises(oavm.FormatError, match="truncated.oavm"):
        oavm.open(tmp_path / "truncated.oavm")
    (tmp_path / "empty.oavm").write_bytes(b"")
    with pytest.raises(oavm.FormatError, match="empty.oavm"):
        oavm.open(tmp_path / "empty.oavm")
    with pytest.raises(OSError):
        oavm.open(tmp_path)  # a directory


def test_a_damaged_block_is_an_error_not_a_crash(tmp_path, bunny):
    """A flipped byte in the middle of the blocks: opening reads only the header and top tree,
    so it opens; verify() finds the damage, and tracing into the block raises FormatError."""
    data = bytearray(bunny.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad = tmp_path / "damaged.oavm"
    bad.write_bytes(bytes(data))
    with oavm.open(bad) as scene:
        with pytest.raises(oavm.FormatError, match="damaged.oavm: verification failed"):
            scene.verify()
        info = scene.info
        rays = ray_sets(info["mesh_min"], info["mesh_max"], 20000, seed=4)["random"]
        with pytest.raises(oavm.FormatError, match="damaged.oavm.*block"):
            scene.intersect(rays)
        with pytest.raises(oavm.FormatError, match="damaged.oavm"):
            scene.occluded(rays)
    assert issubclass(oavm.FormatError, oavm.OavmError)


def test_budget_too_small(bunny):
    with pytest.raises(ValueError, match=r"too small for this file.*\(mem_budget\)"):
        oavm.open(bunny, mem_budget=4096)
    for bad in ("lots", -5, 0, 2.5, True):
        with pytest.raises(ValueError, match="mem_budget"):
            oavm.open(bunny, mem_budget=bad)


def test_bad_meshes(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                   "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                   "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(oavm.MeshError, match=r"bad.ply: line 13: face 0 refers to vertex 7"):
        oavm.pack(bad, tmp_path / "out.oavm", progress=False)
    assert not (tmp_path / "out.oavm").exists(), "no partial output"
    with pytest.raises(FileNotFoundError, match="absent.ply"):
        oavm.pack(tmp_path / "absent.ply", tmp_path / "out.oavm")
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    with pytest.raises(oavm.MeshError, match="triangle 0 refers to vertex 5"):
        oavm.pack((v, [[0, 1, 5]]), tmp_path / "out.oavm")
    with pytest.raises(oavm.MeshError, match="negative vertex index"):
        oavm.pack((v, [[0, 1, -1]]), tmp_path / "out.oavm")
    with pytest.raises(oavm.MeshError, match="non-finite"):
        oavm.pack((np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), [[0, 1, 2]]), tmp_path / "out.oavm")
    with pytest.raises(oavm.MeshError, match="non-finite"):
        oavm.pack((np.array([[0, 0, 0], [1, 0, 0], [0, 1e300, 0]]), [[0, 1, 2]]), tmp_path / "out.oavm")
    with pytest.raises(oavm.MeshError, match="no triangles"):
        oavm.pack((v, np.zeros((0, 3), int)), tmp_path / "out.oavm")
    with pytest.raises(ValueError, match=r"faces: expected shape \(F, 3\)"):
        oavm.pack((v, [[0, 1, 2, 0]]), tmp_path / "out.oavm")
    with pytest.raises(ValueError, match="faces: the indices are not whole numbers"):
        oavm.pack((v, [[0, 1, 1.5]]), tmp_path / "out.oavm")
    with pytest.raises(ValueError, match="mesh: expected a path, a mesh object"):
        oavm.pack(42, tmp_path / "out.oavm")
    assert not (tmp_path / "out.oavm").exists()


def test_bad_pack_options_and_outputs(tmp_path):
    mesh = REPO / "data" / "bunny.ply"
    with pytest.raises(ValueError, match="leaf must be"):
        oavm.pack(mesh, tmp_path / "o.oavm", leaf="tree")
    with pytest.raises(ValueError, match="compress"):
        oavm.pack(mesh, tmp_path / "o.oavm", compress=99)
    with pytest.raises(ValueError, match="max_depth"):
        oavm.pack(mesh, tmp_path / "o.oavm", max_depth=-1)
    with pytest.raises(ValueError, match="^max_depth 40 is too deep"):
        oavm.pack(mesh, tmp_path / "o.oavm", max_depth=40)
    with pytest.raises(ValueError, match="^block_size 100 must be between"):
        oavm.pack(mesh, tmp_path / "o.oavm", block_size=100)
    with pytest.raises(OSError, match="directory"):
        oavm.pack(mesh, tmp_path)
    with pytest.raises(OSError):
        oavm.pack(mesh, mesh)  # the input itself
    assert not (tmp_path / "o.oavm").exists()


def test_pack_options_take_effect(tmp_path):
    mesh = REPO / "data" / "bunny.ply"
    raw = oavm.pack(mesh, tmp_path / "raw.oavm", progress=False, leaf="list", leaf_size=8, max_depth=9)
    z = oavm.pack(mesh, tmp_path / "z.oavm", progress=False, compress=True, block_size="64K")
    assert raw["options"]["leaf_size"] == 8 and raw["options"]["max_depth"] == 9 and raw["depth"] <= 9
    with oavm.open(tmp_path / "raw.oavm") as a, oavm.open(tmp_path / "z.oavm") as b:
        assert a.info["leaf"] == "list" and b.info["compressed"] is True and b.info["leaf"] == "cluster"
        assert b.info["blocks"] > a.info["blocks"] // 4
        rays = ray_sets(a.info["mesh_min"], a.info["mesh_max"], 3000, seed=8)["random"]
        ha, hb = a.intersect(rays), b.intersect(rays)
        assert (ha.prim != oavm.MISS).mean() > 0.3
        assert np.array_equal(ha.prim != oavm.MISS, hb.prim != oavm.MISS)
        assert b.verify()["ok"]
    assert os.path.getsize(tmp_path / "z.oavm") < os.path.getsize(tmp_path / "raw.oavm")
