"""Traces one camera frame of a packed file on a Dask LocalCluster and writes the image.

    python python/examples/dask_frame.py FILE.oavm [--width 1920 --height 1080] [--workers 2]
        [--chunk 65536] [--out frame.png] [--check]

Every worker process opens the file itself (once: `oavm.dask` keeps it) and makes and traces
its own chunks of the frame's primary rays; only the camera goes to the workers and only the
answers come back. The image is shaded by the angle between the ray and the surface normal.
With --check, the same rays are traced again in this process alone, and the answers (t,
primitive ids, normals) must be identical, bit for bit.

The README's figures for the 130-million-triangle mesh come from:

    cargo run --release --example make_copies -- ../shared/scenes/dragon/dragon_vrip.ply 150 big.ply
    cargo run --release --bin oavm-pack -- big.ply big.oavm --mem-budget 4G
    python python/examples/dask_frame.py big.oavm --check
"""

from __future__ import annotations

import argparse
import json
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


def shade(rays: np.ndarray, t: np.ndarray, normal: np.ndarray, width: int, height: int) -> np.ndarray:
    hit = np.isfinite(t)
    cos = np.abs(np.einsum("ij,ij->i", np.nan_to_num(normal), rays[:, 4:7]))
    grey = np.where(hit, 40 + 215 * cos, 16).astype(np.uint8)
    return grey.reshape(height, width)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--threads-per-worker", type=int, default=1,
                    help="dask threads per worker; each task traces on all of the machine's cores")
    ap.add_argument("--chunk", type=int, default=1 << 16, help="rays per task (default 65536)")
    ap.add_argument("--mem-budget", default=None, help="per worker, e.g. 4G (default: half the free memory)")
    ap.add_argument("--out", default="frame.png")
    ap.add_argument("--check", action="store_true", help="trace again in this process and compare")
    ap.add_argument("--json", default=None, help="write the figures to this file")
    a = ap.parse_args()

    w, h = a.width, a.height
    with oavm.open(a.file) as scene:
        info = scene.info
    print(f"{a.file}: {info['input_triangles']:,} triangles, {info['file_bytes'] / 1e9:.2f} GB, "
          f"{info['blocks']:,} blocks, format {info['format_version']}")

    t0 = time.perf_counter()
    with LocalCluster(n_workers=a.workers, threads_per_worker=a.threads_per_worker, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        t_start = time.perf_counter() - t0
        rays = oavm.dask.camera_rays(a.file, w, h, chunk=a.chunk, mem_budget=a.mem_budget)
        hits = oavm.dask.intersect(a.file, rays, attributes=True, mem_budget=a.mem_budget)
        t1 = time.perf_counter()
        r, t, prim, normal = dask.compute(rays, hits.t, hits.prim, hits.normal)
        wall = time.perf_counter() - t1
        opens = client.run(oavm.dask.cache_info)
    n = w * h
    print(f"LocalCluster: {a.workers} worker processes x {a.threads_per_worker} threads (started in "
          f"{t_start:.1f} s); {rays.numblocks[0]} chunks of up to {a.chunk:,} rays")
    print(f"traced {n:,} rays in {wall:.2f} s ({n / wall / 1e6:.2f} Mrays/s, wall, including making the "
          f"rays and gathering the answers); {np.isfinite(t).mean():.1%} hit")
    for addr, c in sorted(opens.items()):
        print(f"  worker {addr} (pid {c['pid']}): opened the file {c['opens']} time(s)")
    write_png(a.out, shade(r, t, normal, w, h))
    print(f"wrote {a.out}")

    figures = dict(file=a.file, triangles=info["input_triangles"], width=w, height=h, workers=a.workers,
                   threads_per_worker=a.threads_per_worker, chunks=int(rays.numblocks[0]), chunk=a.chunk,
                   wall_seconds=wall, mrays_per_s=n / wall / 1e6, hit_fraction=float(np.isfinite(t).mean()),
                   opens={k: v["opens"] for k, v in opens.items()})
    if a.check:
        with oavm.open(a.file, mem_budget=a.mem_budget) as scene:
            t2 = time.perf_counter()
            r1 = scene.camera_rays(w, h)
            single = scene.intersect(r1, attributes=True)
            single_s = time.perf_counter() - t2
        same = (np.array_equal(r1, r) and np.array_equal(single.t, t) and np.array_equal(single.prim, prim)
                and np.array_equal(single.normal, normal, equal_nan=True))
        print(f"one process: {single_s:.2f} s ({n / single_s / 1e6:.2f} Mrays/s); answers identical to "
              f"the cluster's: {same}")
        figures.update(single_process_seconds=single_s, identical=bool(same))
        if not same:
            raise SystemExit("the cluster's answers differ from one process's")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(figures, f, indent=2)


if __name__ == "__main__":
    main()
