"""Traces one camera frame of a packed file on a Dask LocalCluster and writes the image.

    python python/examples/dask_frame.py FILE.oavm [--width 1920 --height 1080] [--workers 2]
        [--chunk 262144] [--frames 2] [--out frame.png] [--check]

Every worker process opens the file itself (once: `oavm.dask` keeps it) and makes and traces
its own chunks of the frame's primary rays; only the camera goes to the workers and only the
answers come back. The image is shaded by the angle between the ray and the surface normal.
With --check, the same rays are traced and shaded again in this process alone, and the
answers (t, primitive ids, grey levels) must be identical, bit for bit.

The README's figures for the 130-million-triangle mesh come from:

    cargo run --release --features tools --example make_copies -- ../shared/scenes/dragon/dragon_vrip.ply 150 big.ply
    cargo run --release --bin oavm-pack -- big.ply big.oavm --mem-budget 4G
    python python/examples/dask_frame.py big.oavm --check
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import time
import zlib

import dask
import numpy as np
from distributed import Client, LocalCluster

import oavm
import oavm.dask


def write_png(path: str, grey: np.ndarray) -> None:
    """An 8-bit greyscale PNG (the standard library's zlib; no imaging package needed)."""
    h, w = grey.shape
    raw = b"".join(b"\x00" + grey[y].tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


def shade(rays: np.ndarray, t: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Grey levels of a chunk of pixels: by the cosine between ray and normal; background dark."""
    hit = np.isfinite(t.reshape(-1))
    cos = np.abs(np.einsum("ij,ij->i", np.nan_to_num(normal), rays[:, 4:7]))
    return np.where(hit, 40 + 215 * cos, 16).astype(np.uint8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--threads-per-worker", type=int, default=1, help="dask threads per worker (default 1)")
    ap.add_argument("--threads", type=int, default=None,
                    help="threads each task traces on (default: this machine's cores / workers, at least 1)")
    ap.add_argument("--chunk", type=int, default=1 << 18, help="rays per task (default 262144)")
    ap.add_argument("--mem-budget", default=None, help="per worker, e.g. 4G (default: half the free memory)")
    ap.add_argument("--out", default="frame.png")
    ap.add_argument("--frames", type=int, default=2,
                    help="trace the frame this many times (the first with cold workers; default 2)")
    ap.add_argument("--check", action="store_true", help="trace again in this process and compare")
    ap.add_argument("--json", default=None, help="write the figures to this file")
    a = ap.parse_args()

    w, h = a.width, a.height
    threads = a.threads or max(1, (os.cpu_count() or 1) // a.workers)
    with oavm.open(a.file) as scene:
        info = scene.info
    print(f"{a.file}: {info['input_triangles']:,} triangles, {info['file_bytes'] / 1e9:.2f} GB, "
          f"{info['blocks']:,} blocks, format {info['format_version']}")

    t0 = time.perf_counter()
    with LocalCluster(n_workers=a.workers, threads_per_worker=a.threads_per_worker, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        t_start = time.perf_counter() - t0
        rays = oavm.dask.camera_rays(a.file, w, h, chunk=a.chunk, mem_budget=a.mem_budget)
        hits = oavm.dask.intersect(a.file, rays, attributes=True, mem_budget=a.mem_budget, threads=threads)
        # Shaded on the workers too: only the grey levels, t and the primitive ids come back.
        grey = rays.map_blocks(shade, hits.t[:, None], hits.normal, dtype=np.uint8, drop_axis=1,
                               meta=np.empty((0,), np.uint8))
        walls = []
        for _ in range(a.frames):
            t1 = time.perf_counter()
            image, t, prim = dask.compute(grey, hits.t, hits.prim)
            walls.append(time.perf_counter() - t1)
        grey = image
        opens = client.run(oavm.dask.cache_info)
    n = w * h
    print(f"LocalCluster: {a.workers} worker processes x {a.threads_per_worker} dask threads, each task "
          f"tracing on {threads} threads (started in {t_start:.1f} s); {rays.numblocks[0]} chunks of up to "
          f"{a.chunk:,} rays")
    for k, wall in enumerate(walls):
        print(f"frame {k + 1}: {n:,} rays in {wall:.2f} s ({n / wall / 1e6:.2f} Mrays/s, wall: making the rays, "
              f"tracing, shading, gathering t, ids and grey levels){'; workers cold: opening the file, first touch of its pages' if k == 0 else '; workers warm'}")
    print(f"{np.isfinite(t).mean():.1%} of the rays hit")
    for addr, c in sorted(opens.items()):
        print(f"  worker {addr} (pid {c['pid']}): opened the file {c['opens']} time(s)")
    write_png(a.out, grey.reshape(h, w))
    print(f"wrote {a.out}")

    figures = dict(file=a.file, triangles=info["input_triangles"], width=w, height=h, workers=a.workers,
                   threads_per_worker=a.threads_per_worker, trace_threads=threads, chunks=int(rays.numblocks[0]), chunk=a.chunk,
                   wall_seconds=walls, mrays_per_s=[n / w_ / 1e6 for w_ in walls], hit_fraction=float(np.isfinite(t).mean()),
                   opens={k: v["opens"] for k, v in opens.items()})
    if a.check:
        with oavm.open(a.file, mem_budget=a.mem_budget) as scene:
            singles = []
            for _ in range(a.frames):
                t2 = time.perf_counter()
                r1 = scene.camera_rays(w, h)
                single = scene.intersect(r1, attributes=True)
                grey1 = shade(r1, single.t, single.normal)
                singles.append(time.perf_counter() - t2)
        same = (np.array_equal(single.t, t) and np.array_equal(single.prim, prim) and np.array_equal(grey1, grey))
        for k, single_s in enumerate(singles):
            print(f"one process ({(os.cpu_count() or 1)} threads), frame {k + 1}: {single_s:.2f} s "
                  f"({n / single_s / 1e6:.2f} Mrays/s, the same work)")
        print(f"t, primitive ids and grey levels identical to the cluster's: {same}")
        single_s = singles
        figures.update(single_process_seconds=single_s, identical=bool(same))
        if not same:
            raise SystemExit("the cluster's answers differ from one process's")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(figures, f, indent=2)


if __name__ == "__main__":
    main()
