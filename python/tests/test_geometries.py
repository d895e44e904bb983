"""Several meshes in one file (format-spec §8.8): ``oavm.pack`` of a list, a dict, a
``trimesh.Scene`` and mesh files (a glTF scene's nodes among them); ``Scene.geometries`` and
``Scene.locate``; updates that replace the table. Hits are checked against where each mesh is,
computed here, not by the library."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

import oavm


def _down(xy):
    """Rays straight down (-z) from z = 10 over the points ``xy``."""
    xy = np.asarray(xy, dtype=np.float32)
    o = np.column_stack([xy, np.full(len(xy), 10.0, np.float32)])
    d = np.tile(np.float32([0, 0, -1]), (len(xy), 1))
    return o, d


def test_a_list_of_meshes_is_a_table(tmp_path):
    box = trimesh.creation.box()  # 12 triangles, top at z = 0.5
    ball = trimesh.creation.icosphere(subdivisions=2)  # 320 triangles, radius 1
    moved = ball.copy()
    moved.apply_translation([5, 0, 0])
    out = tmp_path / "l.oavm"
    oavm.pack([box, (moved.vertices, moved.faces)], out, progress=False)
    s = oavm.open(out)
    assert [(g.name, g.first_primitive, g.primitive_count) for g in s.geometries] == [
        ("mesh 0", 0, 12), ("mesh 1", 12, 320)]
    assert (s.geometries[1].transform == np.eye(4)[:3]).all()
    o, d = _down([[0, 0], [5, 0], [20, 0]])
    t, prim = s.intersect(o, d)
    assert np.allclose(t[:2], [9.5, 9.0], atol=1e-4) and prim[2] == oavm.MISS
    geom, local = s.locate(prim)
    assert geom.tolist() == [0, 1, oavm.MISS] and local[2] == oavm.MISS
    # The local index is the triangle's in its own mesh: that face of the sphere is under the ray.
    tri = moved.triangles[local[1]]
    assert tri[:, 2].max() > 0.9 and np.abs(tri[:, 0] - 5).max() < 0.3
    # A (vertices, faces) pair is still one mesh, with no table.
    oavm.pack((box.vertices, box.faces), tmp_path / "one.oavm", progress=False)
    one = oavm.open(tmp_path / "one.oavm")
    assert one.geometries == []
    assert one.locate(np.array([3, oavm.MISS], np.uint32))[0].tolist() == [0, oavm.MISS]


def test_a_trimesh_scene_is_placed_by_its_transforms(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box()
    scene.add_geometry(box, node_name="left", transform=trimesh.transformations.translation_matrix([-3, 0, 0]))
    scene.add_geometry(box, node_name="right", geom_name="box",
                       transform=trimesh.transformations.translation_matrix([3, 0, 1]))
    out = tmp_path / "s.oavm"
    oavm.pack(scene, out, progress=False)
    s = oavm.open(out)
    by_name = {g.name: g for g in s.geometries}
    assert set(by_name) == {"left", "right"}
    assert by_name["right"].transform[:, 3].tolist() == [3, 0, 1]
    o, d = _down([[-3, 0], [3, 0], [0, 0]])
    t, prim = s.intersect(o, d)
    # The boxes' tops at z = 0.5 and 1.5 (placed by their nodes), nothing between them.
    assert np.allclose(t[:2], [9.5, 8.5], atol=1e-4) and prim[2] == oavm.MISS
    names = [s.geometries[g].name for g in s.locate(prim)[0][:2]]
    assert names == ["left", "right"]
    # The same scene exported by trimesh as GLB, and packed from the file in a list: a geometry
    # per node, named within the file's name, the same hits.
    glb = tmp_path / "s.glb"
    glb.write_bytes(scene.export(file_type="glb"))
    oavm.pack([glb], tmp_path / "g.oavm", progress=False)
    g = oavm.open(tmp_path / "g.oavm")
    assert sorted(x.name for x in g.geometries) == ["s.glb/left", "s.glb/right"]
    t2, prim2 = g.intersect(o, d)
    assert np.allclose(t2[:2], t[:2], atol=1e-5) and prim2[2] == oavm.MISS
    assert [g.geometries[i].name for i in g.locate(prim2)[0][:2]] == ["s.glb/left", "s.glb/right"]


def test_named_meshes_and_files(tmp_path, shared):
    bunny = shared / "scenes" / "bunny" / "bun_zipper.ply"
    out = tmp_path / "d.oavm"
    oavm.pack({"rabbit": bunny, "box": trimesh.creation.box()}, out, progress=False)
    s = oavm.open(out)
    n = len(oavm.load_mesh(bunny)[1])
    assert [(g.name, g.first_primitive, g.primitive_count) for g in s.geometries] == [
        ("rabbit", 0, n), ("box", n, 12)]
    oavm.pack([bunny], tmp_path / "f.oavm", progress=False)
    assert [g.name for g in oavm.open(tmp_path / "f.oavm").geometries] == ["bun_zipper.ply"]
    with pytest.raises(ValueError, match="empty list"):
        oavm.pack([], tmp_path / "e.oavm", progress=False)


def test_an_update_with_meshes_replaces_the_table(tmp_path):
    box = trimesh.creation.box()
    out = tmp_path / "u.oavm"
    oavm.pack({"a": box, "b": box}, out, progress=False, updatable=True,
              bounds=((-10, -10, -10), (10, 10, 10)))
    far = box.copy()
    far.apply_translation([4, 0, 0])
    r = oavm.update(out, {"a": box, "b": box, "c": far})
    assert r["inserted"] == 12
    s = oavm.open(out)
    assert [(g.name, g.first_primitive) for g in s.geometries] == [("a", 0), ("b", 12), ("c", 24)]
    o, d = _down([[4, 0]])
    t, prim = s.intersect(o, d)
    assert s.locate(prim)[0].tolist() == [2] and np.isclose(t[0], 9.5)
    # One mesh keeps the table, its last geometry ending with the new primitives ("c" empty).
    v = np.concatenate([box.vertices, box.vertices])
    f = np.concatenate([box.faces, box.faces + len(box.vertices)])
    oavm.update(out, (v, f))
    assert [(g.name, g.primitive_count) for g in oavm.open(out).geometries] == [
        ("a", 12), ("b", 12), ("c", 0)]
    with pytest.raises(ValueError, match="give the new mesh's geometries"):
        oavm.update(out, (box.vertices, box.faces[:6]))
    assert json.dumps(oavm.open(out).info)  # still a sound file
