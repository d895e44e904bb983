#!/usr/bin/env python3
"""A signed-distance grid of a packed file, in one process or over a Dask LocalCluster, timed.

    python tools/sdf_grid.py FILE.oavm --n 64 --mem-budget 1200M [--dask WORKERS] [--json OUT]

The grid: ``n^3`` points over the file's mesh box grown by 5 % a side, in C order; each point's
signed distance (``Scene.signed_distance``: the closest point by a best-first descent of the wide
nodes, the sign by a vote of three exact rays), within ``--mem-budget`` per process (a file
larger than memory pages). With ``--dask W``: a ``LocalCluster`` of ``W`` worker processes of one
thread, the grid cut into ``--chunk`` points (``oavm.dask.signed_distance``), checked equal to
the one-process answers when both are run (``--both``). Run it inside a memory cgroup
(``tools/ooc.sh 1.5G -- python tools/sdf_grid.py ...``) for an honest out-of-core figure.
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np

import oavm


def grid(scene: oavm.Scene, n: int) -> np.ndarray:
    lo, hi = np.array(scene.info["mesh_min"]), np.array(scene.info["mesh_max"])
    pad = 0.05 * (hi - lo)
    axes = [np.linspace(lo[k] - pad[k], hi[k] + pad[k], n) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float32)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file")
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--mem-budget", default="1200M")
    ap.add_argument("--dask", type=int, default=0, help="worker processes (0: one process, no Dask)")
    ap.add_argument("--worker-budget", default="400M")
    ap.add_argument("--chunk", type=int, default=16384)
    ap.add_argument("--both", action="store_true", help="one process, then Dask, compared")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    out: dict = {"file": args.file, "n": args.n, "points": args.n ** 3}
    with oavm.open(args.file, mem_budget=args.mem_budget) as s:
        out["triangles"] = s.info["input_triangles"]
        pts = grid(s, args.n)
        single = None
        if not args.dask or args.both:
            t = time.perf_counter()
            single = s.signed_distance(pts)
            out["one_process"] = {"seconds": time.perf_counter() - t, "mem_budget": args.mem_budget,
                                  "inside": int((single < 0).sum())}
            print(f"one process: {args.n}^3 points in {out['one_process']['seconds']:.1f} s, "
                  f"{out['one_process']['inside']} inside", flush=True)
    if args.dask:
        import dask.array as da
        from oavm import dask as oavm_dask
        from distributed import Client, LocalCluster
        with LocalCluster(n_workers=args.dask, threads_per_worker=1, processes=True,
                          dashboard_address=None, silence_logs=40) as cluster, Client(cluster):
            g = da.from_array(pts, chunks=(args.chunk, 3))
            t = time.perf_counter()
            got = oavm_dask.signed_distance(args.file, g, mem_budget=args.worker_budget).compute()
            out["dask"] = {"seconds": time.perf_counter() - t, "workers": args.dask,
                           "worker_budget": args.worker_budget, "chunks": g.numblocks[0],
                           "inside": int((got < 0).sum())}
            if single is not None:
                out["dask"]["equal_to_one_process"] = bool(np.array_equal(got, single))
            print(f"dask: {args.dask} workers, {g.numblocks[0]} chunks, {out['dask']['seconds']:.1f} s"
                  + (f", equal to one process: {out['dask']['equal_to_one_process']}" if single is not None else ""),
                  flush=True)
    out["peak_rss_bytes_this_process"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
