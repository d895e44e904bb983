"""Updates from Python: a file packed with ``updatable=True`` follows new geometry given as
arrays (face i is primitive i) or as a BART scene at a time; it then answers exactly as a fresh
pack of the same triangles; a scene opened before an update keeps answering as before it; a file
without the primitive table is refused with a message that says how to pack it."""

import numpy as np
import pytest

import oavm


def _grid(n: int, lift: float = 0.0):
    """n*n unit quads in the z=0 plane (two triangles each), those with x > n/2 lifted."""
    verts, faces = [], []
    for i in range(n):
        for j in range(n):
            z = lift if i > n // 2 else 0.0
            b = len(verts)
            verts += [(i, j, z), (i + 0.9, j, z), (i + 0.9, j + 0.9, z), (i, j + 0.9, z)]
            faces += [(b, b + 1, b + 2), (b, b + 2, b + 3)]
    return np.array(verts, dtype=np.float32), np.array(faces, dtype=np.uint32)


def _answers(scene, origins, dirs):
    t, prim = scene.intersect(origins, dirs)
    occ = scene.occluded(origins, dirs)
    return t.tobytes() + prim.tobytes() + np.asarray(occ).tobytes()


def test_update_from_arrays_answers_as_a_fresh_pack(tmp_path):
    v0, f = _grid(24)
    v1, _ = _grid(24, lift=0.5)
    path = tmp_path / "grid.oavm"
    oavm.pack((v0, f), path, updatable=True, bounds=((0, 0, -1), (25, 25, 1)), progress=False)
    rng = np.random.default_rng(3)
    origins = np.column_stack([rng.uniform(0, 24, 4000), rng.uniform(0, 24, 4000), np.full(4000, 5.0)])
    dirs = np.tile([0.0, 0.0, -1.0], (4000, 1))
    before_scene = oavm.open(path)
    before = _answers(before_scene, origins, dirs)
    report = oavm.update(path, (v1, f))
    assert report["moved"] > 0 and report["blocks_rebuilt"] >= 1, report
    assert report["generation"] == 2
    # The scene opened before answers as before; a new one as a fresh pack of the new grid.
    assert _answers(before_scene, origins, dirs) == before
    fresh = tmp_path / "fresh.oavm"
    oavm.pack((v1, f), fresh, progress=False)
    after = _answers(oavm.open(path), origins, dirs)
    assert after == _answers(oavm.open(fresh), origins, dirs)
    assert after != before
    # Hits must happen: half the rays hit the lifted half at z = 0.5.
    t, _ = oavm.open(path).intersect(origins, dirs)
    assert np.sum(np.isclose(t, 4.5)) > 1000 and np.sum(np.isclose(t, 5.0)) > 1000
    assert oavm.open(path).verify()["ok"]
    c = oavm.compact(path)
    assert c["generation"] == 2 and c["bytes_after"] < c["bytes_before"]
    assert _answers(oavm.open(path), origins, dirs) == after


def test_update_refuses_files_without_the_table(tmp_path):
    v, f = _grid(4)
    path = tmp_path / "plain.oavm"
    oavm.pack((v, f), path, progress=False)
    with pytest.raises(ValueError, match="updatable"):
        oavm.update(path, (v, f))
    with pytest.raises(ValueError):
        oavm.pack((v, f), path, updatable=True, bounds=((0, 0), (1, 1)), progress=False)


def test_update_checks_arrays_as_pack_does(tmp_path):
    """Faces given as floats must be whole numbers, and indices non-negative, for an update as
    for a pack (an update once cast 0.5 to 0), and the file is left as it was."""
    v, f = _grid(4)
    path = tmp_path / "grid.oavm"
    oavm.pack((v, f), path, updatable=True, progress=False)
    before = path.read_bytes()
    half = f.astype(np.float64)
    half[0, 0] = 0.5
    with pytest.raises(ValueError, match="whole numbers"):
        oavm.update(path, (v, half))
    negative = f.astype(np.int64)
    negative[1, 2] = -1
    with pytest.raises(oavm.MeshError, match="face 1 holds the negative vertex index -1"):
        oavm.update(path, (v, negative))
    assert path.read_bytes() == before


def test_update_from_a_bart_scene(tmp_path, shared):
    scene = shared / "scenes/bart/kitchen/kitchen.aff"
    path = tmp_path / "k.oavm"
    oavm.pack(scene, path, updatable=True, progress=False)
    r = oavm.update(path, scene, time=8.0)
    assert r["moved"] > 0 and r["blocks_rebuilt"] < r["blocks_before"], r
