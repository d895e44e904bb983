#!/usr/bin/env python3
"""What the drop-ins' Python layer adds to the tracer: each ray call of ``oavm.open3d`` and
``oavm.trimesh`` timed against the ``oavm.Scene`` call it wraps, on the same file and rays.

    target/bench-venv/bin/python tools/binding_cost.py [--mesh dragon] [--rays 500000]

The rays are ``tools/py_dropin.py``'s kind (origins in the mesh's box grown by 20 %, uniform
unit directions, seed 1); the file is packed into ``target/py-dropin-cache`` on first use.
Medians of ``--reps`` timings after one untimed call. Prints, per call, the drop-in's time, the
tracer's, and the difference: the binding's cost (conversions, ids, uvs, locations).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

import oavm
import oavm.open3d
import oavm.trimesh

ROOT = Path(__file__).resolve().parents[1]
MESHES = {
    "dragon": "dragon/dragon_vrip.ply",
    "kitchen": "bart/kitchen/kitchen.aff",
    "sibenik": "sibenik/sibenik.obj",
}


def median_ms(fn, reps: int) -> float:
    fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1000 * float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mesh", default="dragon", choices=sorted(MESHES))
    ap.add_argument("--rays", type=int, default=500_000)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    args = ap.parse_args()
    v, f = oavm.load_mesh(args.shared / "scenes" / MESHES[args.mesh])
    cache = ROOT / "target" / "py-dropin-cache"
    rng = np.random.default_rng(1)
    lo, hi = v.min(axis=0).astype(np.float64), v.max(axis=0).astype(np.float64)
    o = lo - 0.1 * (hi - lo) + 1.2 * (hi - lo) * rng.random((args.rays, 3))
    d = rng.normal(size=(args.rays, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    r6 = np.concatenate([o, d], axis=1).astype(np.float32)

    o3 = oavm.open3d.RaycastingScene(cache_dir=cache)
    o3.add_triangles(v, f)
    scene = o3._opened()
    r8 = oavm.rays(r6[:, :3], r6[:, 3:])
    mesh = trimesh.Trimesh(v.astype(np.float64), f.astype(np.int64), process=False)
    tm = oavm.trimesh.RayMeshIntersector(mesh, cache_dir=cache)
    tm_scene = tm.scene
    tm_rays = tm._ray_array(o, d)
    rows = [
        ("open3d cast_rays", lambda: o3.cast_rays(r6),
         "Scene.intersect(attributes=True)", lambda: scene.intersect(r8, attributes=True)),
        ("open3d test_occlusions", lambda: o3.test_occlusions(r6),
         "Scene.occluded", lambda: scene.occluded(r8)),
        ("trimesh intersects_first", lambda: tm.intersects_first(o, d),
         "Scene.intersect", lambda: tm_scene.intersect(tm_rays)),
        ("trimesh intersects_location", lambda: tm.intersects_location(o, d),
         "Scene.list_intersections", lambda: tm_scene.list_intersections(tm_rays)),
    ]
    print(f"{args.mesh}: {len(f)} triangles, {args.rays} rays, medians of {args.reps}")
    for name, call, inner_name, inner in rows:
        a, b = median_ms(call, args.reps), median_ms(inner, args.reps)
        print(f"  {name:<28} {a:7.1f} ms   {inner_name:<34} {b:7.1f} ms   binding {a - b:6.1f} ms")


if __name__ == "__main__":
    main()
