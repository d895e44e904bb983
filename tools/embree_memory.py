"""What Embree needs to build a mesh: loads a binary little-endian PLY of the layout
tools/make_copies.rs writes (`vertex`: float x, y, z; `face`: list uchar int), builds an Embree 4
scene of it with embreex (Embree's default build, as py_bench.py uses it), traces one ray so that
the build happens, and prints the peak resident memory of the process and the build time.

    python tools/embree_memory.py MESH.ply [--json]

Run it inside a memory cgroup (tools/ooc.sh LIMIT -- python ...) to see where a mesh too large
for the machine stops: the cgroup reports the peak and the OOM kill. The arrays handed to Embree
(float32 vertices, int32 indices) are the least any caller of Embree holds; Embree copies
neither into its BVH but builds its own nodes and triangle leaves beside them.
"""

import json
import resource
import sys
import time

import numpy as np


def load(path):
    with open(path, "rb") as f:
        head = b""
        while not head.endswith(b"end_header\n"):
            line = f.readline()
            if not line:
                sys.exit(f"{path}: no end_header")
            head += line
    lines = head.decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        sys.exit(f"{path}: not a binary little-endian PLY")
    nv = nf = None
    for ln in lines:
        if ln.startswith("element vertex "):
            nv = int(ln.split()[2])
        elif ln.startswith("element face "):
            nf = int(ln.split()[2])
    expect = ["property float x", "property float y", "property float z",
              "property list uchar int vertex_indices"]
    if nv is None or nf is None or [ln for ln in lines if ln.startswith("property")] != expect:
        sys.exit(f"{path}: not the layout of tools/make_copies.rs")
    raw = np.memmap(path, dtype=np.uint8, mode="r", offset=len(head))
    vertices = np.frombuffer(raw[: nv * 12], dtype="<f4").reshape(nv, 3)
    faces = np.ndarray((nf,), dtype=np.dtype([("n", "u1"), ("i", "<i4", (3,))]),
                       buffer=raw[nv * 12: nv * 12 + nf * 13])
    if not np.all(faces["n"] == 3):
        sys.exit(f"{path}: a face is not a triangle")
    return np.ascontiguousarray(vertices), np.ascontiguousarray(faces["i"])


def peak_bytes():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main():
    path = sys.argv[1]
    as_json = "--json" in sys.argv[2:]
    t0 = time.perf_counter()
    vertices, indices = load(path)
    loaded = time.perf_counter()
    arrays = vertices.nbytes + indices.nbytes
    peak_loaded = peak_bytes()
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, vertices, indices)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    origin = np.array([(lo + hi) / 2 - [0, 0, (hi[2] - lo[2])]], dtype=np.float32)
    direction = np.array([[0, 0, 1]], dtype=np.float32)
    t1 = time.perf_counter()
    scene.run(origin, direction)  # the first query builds the BVH
    built = time.perf_counter()
    out = {
        "mesh": path,
        "vertices": int(len(vertices)),
        "triangles": int(len(indices)),
        "arrays_bytes": int(arrays),
        "peak_rss_after_load_bytes": int(peak_loaded),
        "peak_rss_bytes": int(peak_bytes()),
        "embree_bytes_per_triangle": (peak_bytes() - peak_loaded) / len(indices),
        "load_seconds": loaded - t0,
        "build_seconds": built - t1,
    }
    if as_json:
        print(json.dumps(out, indent=2))
    else:
        for k, v in out.items():
            print(f"{k:28} {v}")


if __name__ == "__main__":
    main()
