#!/usr/bin/env python3
"""The Python binding against the CLI and against two Python peers, on the same rays, in one run.

    tools/py_bench.sh [ARGS...]                  # the whole thing: venv, installs, build, run
    target/bench-venv/bin/python tools/py_bench.py [--reps 5] [--json OUT] [...]

Run it with the Python of ``target/bench-venv`` (made by ``tools/py_bench.sh``: a venv of its own
holding a RELEASE build of oavm, ``pip install ./python``, and ``python/requirements-bench.txt``:
embreex, open3d-cpu, trimesh, numpy). Not ``target/python-venv``: that one is the tests' and may
hold a debug build at any moment. The header prints where ``oavm._native`` was loaded from.

For each ray set of the mesh (``PREFIX.{primary,random,shadow}.rays``, RAYS.md; made with
``cargo run --release --features tools --example rays -- MESH PREFIX`` when missing), with its query (closest hit
for primary and random rays, any hit for shadow rays; ``--query both`` does both on every set):

1. ``oavm-trace FILE --rays R --hits|--occluded OUT --json`` (the CLI's batch mode, a new process
   per run) against ``oavm.open(FILE)`` + ``Scene.intersect`` / ``.occluded`` on the same rays:
   tracing time only on both sides (the CLI's own ``seconds``, which excludes reading the rays
   and writing the answers; the call alone in Python), and wall time (the CLI process from exec
   to exit, writing its answers; in Python ``np.fromfile`` + ``oavm.open`` + the call). Both open
   the file afresh each run; repetitions alternate CLI and Python (CLI first on even reps).
   Also the binding on a scene kept open (warm), the figure set against the peers.
2. embreex (Embree 4, ``EmbreeScene.run``) and Open3D's ``RaycastingScene``: time to first
   answer from mesh arrays in memory (add the mesh, then the first cast of the whole batch,
   which is where both build their BVH), then rays/s over the repetitions on that scene; oavm's
   time to first answer is ``oavm.open`` + the first call (packing, done before, reported
   apart). Their answers are checked against oavm's by RAYS.md's rule (both miss, or both hit
   with |t1 - t2| <= 1e-4 * bounding-box diagonal; any hit: the same answer).

Every figure is measured in this run; ``--json OUT`` writes them all (every repetition too).
Medians are given with their min-max over the repetitions.

Ray extents (RAYS.md: per-ray tmin and tmax) and the peers:
* embreex's ``run`` sets tnear = 0 for every ray and takes a per-ray tfar (``dists``): a nonzero
  tmin is emulated by moving the origin to ``o + tmin * d`` with tfar = tmax - tmin (and adding
  tmin back to the hit distance), which is exact but for float rounding.
* Open3D's ``cast_rays`` takes no tnear/tfar: tmin as above, tmax by dropping hits beyond it
  (exact for a closest hit). ``test_occlusions`` takes ONE tnear and tfar for all rays: passed
  as they are when every ray of the set has the same (the dragon's shadow rays do), otherwise
  emulated by moving origins and scaling directions so that tfar = 1.
The report says, per set and peer, which of these was used ("native", "uniform", "emulated").

Threads: oavm (CLI and binding) uses its default (one per core); Open3D ``nthreads=0``
(automatic: all cores); embreex's ``run`` traces on the calling thread only, but releases the
GIL, so this splits the batch into chunks traced by ``--embreex-threads`` Python threads (default:
one per core). Embree's and Open3D's BVH builds use TBB's default (all cores).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MISS = 0xFFFFFFFF
RAY_SETS = ("primary", "random", "shadow")
DEFAULT_QUERY = {"primary": "closest", "random": "closest", "shadow": "any"}


def now() -> float:
    return time.perf_counter()


def log(msg: str) -> None:
    print(f"py_bench: {msg}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------------------
# Files of RAYS.md


def _header(path: Path, magic: bytes, record: int) -> int:
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(16)
    if len(head) != 16 or head[:4] != magic:
        raise ValueError(f"{path}: not a {magic.decode()} file")
    version = int.from_bytes(head[4:8], "little")
    count = int.from_bytes(head[8:16], "little")
    if version != 1:
        raise ValueError(f"{path}: version {version}, expected 1")
    if size != 16 + count * record:
        raise ValueError(f"{path}: {size} bytes, expected 16 + {count} * {record}")
    return count


def read_rays(path: Path) -> np.ndarray:
    """The ``(N, 8)`` float32 records of a RAYS file (origin, tmin, direction, tmax)."""
    n = _header(path, b"RAYS", 32)
    return np.fromfile(path, dtype="<f4", offset=16).reshape(n, 8)


def read_hits(path: Path) -> Tuple[np.ndarray, np.ndarray]:
    n = _header(path, b"HITS", 8)
    rec = np.fromfile(path, dtype=np.dtype([("t", "<f4"), ("prim", "<u4")]), offset=16)
    assert len(rec) == n
    return rec["t"].copy(), rec["prim"].copy()


def read_occl(path: Path) -> np.ndarray:
    n = _header(path, b"OCCL", 1)
    a = np.fromfile(path, dtype=np.uint8, offset=16)
    assert len(a) == n
    return a.astype(bool)


# ---------------------------------------------------------------------------------------------
# Statistics and comparisons


def summary(values: List[float]) -> Dict[str, Any]:
    if not values:
        return {"median": None, "min": None, "max": None, "values": []}
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "values": values}


def agree_closest(ref: Tuple[np.ndarray, np.ndarray], other: Tuple[np.ndarray, np.ndarray],
                  diag: float) -> Dict[str, Any]:
    """RAYS.md's rule: both miss, or both hit with |t1 - t2| <= 1e-4 * diagonal."""
    t1, p1 = ref
    t2, p2 = other
    hit1 = p1 != MISS
    hit2 = p2 != MISS
    tol = 1e-4 * diag
    with np.errstate(invalid="ignore"):  # inf - inf on misses
        close = np.abs(t1.astype(np.float64) - t2.astype(np.float64)) <= tol
    ok = (~hit1 & ~hit2) | (hit1 & hit2 & close)
    both = hit1 & hit2
    n = len(t1)
    return {
        "rays": n,
        "agree": int(ok.sum()),
        "agree_fraction": float(ok.sum()) / n if n else 1.0,
        "disagree": int(n - ok.sum()),
        "hits_ref": int(hit1.sum()),
        "hits_other": int(hit2.sum()),
        "same_prim_of_both_hit": float((p1[both] == p2[both]).sum()) / max(1, int(both.sum())),
        "tolerance": tol,
    }


def agree_any(ref: np.ndarray, other: np.ndarray) -> Dict[str, Any]:
    ok = ref == other
    n = len(ref)
    return {
        "rays": n,
        "agree": int(ok.sum()),
        "agree_fraction": float(ok.sum()) / n if n else 1.0,
        "disagree": int(n - ok.sum()),
        "occluded_ref": int(ref.sum()),
        "occluded_other": int(other.sum()),
    }


def identical(ref: Any, other: Any, query: str) -> Dict[str, Any]:
    """Bit-for-bit equality (the CLI against the binding: the same library, the same answers)."""
    if query == "closest":
        t1, p1 = ref
        t2, p2 = other
        same = (t1.view(np.uint32) == t2.view(np.uint32)) & (p1 == p2)
    else:
        same = ref == other
    return {"rays": len(same), "identical": int(same.sum()), "all_identical": bool(same.all())}


# ---------------------------------------------------------------------------------------------
# Engines. Each has `prepare(rays)` (outside the timing: the rays in its own layout), `build()`,
# `closest(prep)` -> (t float32, prim uint32 with MISS), `any(prep)` -> bool.


class Oavm:
    name = "oavm"

    def __init__(self, oavm_mod: Any, path: Path):
        self.oavm = oavm_mod
        self.path = path
        self.scene = None

    def build(self) -> None:
        self.scene = self.oavm.open(self.path)

    def prepare(self, rays: np.ndarray) -> Tuple[np.ndarray, Dict[str, str]]:
        return rays, {"extent": "native (per-ray tmin and tmax)"}

    def closest(self, rays: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        h = self.scene.intersect(rays)
        return h.t, h.prim

    def any(self, rays: np.ndarray) -> np.ndarray:
        return self.scene.occluded(rays)

    def threads(self) -> Dict[str, Any]:
        return {"trace": self.scene.info["threads"]}


def _shift(rays: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """Origins moved to o + tmin * d where tmin != 0: (origins, directions, tmin, tmax, moved)."""
    o = np.ascontiguousarray(rays[:, 0:3], dtype=np.float32)
    d = np.ascontiguousarray(rays[:, 4:7], dtype=np.float32)
    tmin = np.ascontiguousarray(rays[:, 3], dtype=np.float32)
    tmax = np.ascontiguousarray(rays[:, 7], dtype=np.float32)
    moved = bool(np.any(tmin != 0))
    if moved:
        o = (o.astype(np.float64) + tmin[:, None].astype(np.float64) * d).astype(np.float32)
    return o, d, tmin, tmax, moved


class Embreex:
    name = "embreex"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int):
        from embreex import mesh_construction, rtcore_scene  # noqa: F401

        self.rtcore_scene = rtcore_scene
        self.mesh_construction = mesh_construction
        self.vertices = vertices
        self.faces = faces
        self.nthreads = threads
        self.pool = ThreadPoolExecutor(threads) if threads > 1 else None
        self.scene = None
        self.mesh = None

    def build(self) -> None:
        # The BVH itself is built (rtcCommitScene) by the first `run`, not here.
        self.scene = self.rtcore_scene.EmbreeScene()
        self.mesh = self.mesh_construction.TriangleMesh(self.scene, self.vertices, self.faces)

    def prepare(self, rays: np.ndarray) -> Tuple[Dict[str, Any], Dict[str, str]]:
        o, d, tmin, tmax, moved = _shift(rays)
        tfar = (tmax - tmin) if moved else tmax
        extent = ("emulated: no tnear in run(); origins moved by tmin, tfar = tmax - tmin"
                  if moved else "native (tmin = 0 for every ray; tmax as per-ray tfar, `dists`)")
        return {"o": o, "d": d, "tfar": np.ascontiguousarray(tfar, dtype=np.float32), "tmin": tmin,
                "moved": moved}, {"extent": extent}

    def _chunks(self, n: int) -> List[Tuple[int, int]]:
        if self.pool is None:
            return [(0, n)]
        k = max(1, min(self.nthreads * 8, n // 4096 or 1))
        b = np.linspace(0, n, k + 1).astype(np.int64)
        return [(int(x), int(y)) for x, y in zip(b[:-1], b[1:]) if y > x]

    def _run(self, p: Dict[str, Any], query: str, output: Optional[int]) -> List[Any]:
        o, d, tfar = p["o"], p["d"], p["tfar"]

        def one(ab: Tuple[int, int]) -> Any:
            a, b = ab
            # `run` writes its answers into `dists`: a fresh copy for every call.
            return self.scene.run(o[a:b], d[a:b], dists=tfar[a:b].copy(), query=query, output=output)

        chunks = self._chunks(len(o))
        if self.pool is None:
            return [one(c) for c in chunks]
        if self.scene is not None and not getattr(self, "_committed", False):
            # The first `run` commits (builds) the scene while holding the GIL; the other
            # threads wait for it. Run the first chunk alone to keep that plain.
            first = [one(chunks[0])]
            self._committed = True
            return first + list(self.pool.map(one, chunks[1:]))
        return list(self.pool.map(one, chunks))

    def closest(self, p: Dict[str, Any]) -> Tuple[np.ndarray, np.ndarray]:
        parts = self._run(p, "INTERSECT", 1)
        prim = np.concatenate([r["primID"] for r in parts]).view(np.uint32)  # -1 -> MISS
        t = np.concatenate([r["tfar"] for r in parts])
        miss = prim == MISS
        if p["moved"]:
            t = t + p["tmin"]
        t = np.where(miss, np.float32(np.inf), t).astype(np.float32)
        return t, prim

    def any(self, p: Dict[str, Any]) -> np.ndarray:
        parts = self._run(p, "OCCLUDED", None)
        # embreex 4: 0 when occluded, -1 otherwise (older ones: the geometry id or -1).
        return np.concatenate(parts) != -1

    def new_scene(self) -> None:
        self._committed = False

    def close(self) -> None:
        self.scene = None
        self.mesh = None
        if self.pool is not None:
            self.pool.shutdown()

    def threads(self) -> Dict[str, Any]:
        return {"trace": f"{self.nthreads} Python threads over chunks (run() is single-threaded, "
                         "releases the GIL)" if self.nthreads > 1 else "1 (run() is single-threaded)",
                "trace_threads": self.nthreads,
                "build": f"TBB default ({os.cpu_count()} cores)"}


class Open3d:
    name = "open3d"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, nthreads: int):
        import open3d as o3d

        self.o3d = o3d
        self.vertices = vertices
        self.faces = faces
        self.nthreads = nthreads
        self.scene = None

    def build(self) -> None:
        # add_triangles copies the arrays; the BVH is built (committed) by the first query.
        o3d = self.o3d
        self.scene = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        self.scene.add_triangles(o3d.core.Tensor.from_numpy(self.vertices),
                                 o3d.core.Tensor.from_numpy(self.faces))

    def prepare(self, rays: np.ndarray) -> Tuple[Dict[str, Any], Dict[str, str]]:
        o, d, tmin, tmax, moved = _shift(rays)
        p: Dict[str, Any] = {"tmin": tmin, "tmax": tmax, "moved": moved}
        finite = np.isfinite(tmax)
        p["cut"] = bool(finite.any())
        p["rays6"] = np.ascontiguousarray(np.concatenate([o, d], axis=1))
        p["t_rays6"] = self.o3d.core.Tensor.from_numpy(p["rays6"])
        closest = []
        if moved:
            closest.append("tmin emulated (no tnear in cast_rays: origins moved by tmin)")
        if p["cut"]:
            closest.append("tmax emulated (no tfar in cast_rays: hits beyond tmax dropped)")
        # test_occlusions: one tnear and one tfar for all rays.
        t0, t1 = rays[:, 3], rays[:, 7]
        if np.all(t0 == t0[0]) and np.all(t1 == t1[0]):
            raw6 = np.ascontiguousarray(np.concatenate([rays[:, 0:3], rays[:, 4:7]], axis=1), dtype=np.float32)
            p["raw6"] = raw6  # origins as given: tnear does the work
            p["occ"] = ("uniform", float(t0[0]), float(t1[0]), self.o3d.core.Tensor.from_numpy(raw6))
            any_extent = (f"uniform: every ray has tmin {float(t0[0]):.9g}, tmax {float(t1[0]):.9g},"
                          " passed as test_occlusions' tnear/tfar")
        else:
            # Origins at o + tmin d; rays with a finite tmax get d * (tmax - tmin) and tfar 1.
            scale = np.where(finite, tmax - tmin, 1.0).astype(np.float32)
            r6 = np.concatenate([o, d * scale[:, None]], axis=1).astype(np.float32)
            groups = []
            for mask, tfar in ((finite, 1.0), (~finite, float("inf"))):
                idx = np.nonzero(mask)[0]
                if len(idx):
                    groups.append((idx, self.o3d.core.Tensor.from_numpy(np.ascontiguousarray(r6[idx])), tfar))
            p["occ"] = ("emulated", groups)
            any_extent = ("emulated: per-ray tmin/tmax not supported by test_occlusions (one tnear/tfar "
                          "for all); origins moved by tmin, directions scaled by tmax - tmin, tfar = 1")
        return p, {"extent_closest": "; ".join(closest) or "native (tmin = 0, tmax = inf for every ray)",
                   "extent_any": any_extent}

    def closest(self, p: Dict[str, Any]) -> Tuple[np.ndarray, np.ndarray]:
        c = self.scene.cast_rays(p["t_rays6"], nthreads=self.nthreads)
        t = c["t_hit"].numpy()
        prim = c["primitive_ids"].numpy().astype(np.uint32, copy=False)
        if p["moved"]:
            t = t + p["tmin"]
        if p["cut"]:
            beyond = t > p["tmax"]
            t = np.where(beyond, np.float32(np.inf), t)
            prim = np.where(beyond, np.uint32(MISS), prim)
        return t.astype(np.float32, copy=False), prim

    def any(self, p: Dict[str, Any]) -> np.ndarray:
        occ = p["occ"]
        if occ[0] == "uniform":
            return self.scene.test_occlusions(occ[3], tnear=occ[1], tfar=occ[2],
                                              nthreads=self.nthreads).numpy().astype(bool)
        out = np.zeros(len(p["tmin"]), dtype=bool)
        for idx, t6, tfar in occ[1]:
            out[idx] = self.scene.test_occlusions(t6, tnear=0.0, tfar=tfar,
                                                  nthreads=self.nthreads).numpy().astype(bool)
        return out

    def threads(self) -> Dict[str, Any]:
        return {"trace": "nthreads=0 (automatic: all cores)" if self.nthreads == 0 else self.nthreads,
                "trace_threads": self.nthreads or os.cpu_count(),
                "build": f"TBB default ({os.cpu_count()} cores)"}


# ---------------------------------------------------------------------------------------------
# Setup


def sh(cmd: List[str]) -> subprocess.CompletedProcess:
    """A build step; its output goes to stderr (stdout is the report's)."""
    return subprocess.run(cmd, cwd=ROOT, check=True, stdout=sys.stderr)


def git_head() -> Dict[str, Any]:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True,
                               text=True, check=True).stdout.strip() != ""
        return {"commit": head, "dirty": dirty}
    except Exception as e:  # not a git checkout
        return {"commit": None, "error": str(e)}


def cpu_model() -> Optional[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def version_of(dist: str) -> Optional[str]:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def ensure_rays(mesh: Path, prefix: Path, sets: List[str]) -> Dict[str, Path]:
    paths = {s: Path(f"{prefix}.{s}.rays") for s in sets}
    missing = [p for p in paths.values() if not p.exists()]
    if missing:
        prefix.parent.mkdir(parents=True, exist_ok=True)
        log(f"making {', '.join(map(str, missing))}: cargo run --release --features tools --example rays -- {mesh} {prefix}")
        sh(["nice", "-n", "19", "cargo", "run", "--release", "--features", "tools", "--example", "rays", "--", str(mesh), str(prefix)])
    return paths


def load_mesh(mesh: Path) -> Tuple[np.ndarray, np.ndarray, Dict[str, Any]]:
    """Vertices (float32) and faces (uint32, in file order: the face index is the primitive id)."""
    import trimesh

    t = now()
    m = trimesh.load(str(mesh), process=False, maintain_order=True, force="mesh")
    v = np.ascontiguousarray(m.vertices, dtype=np.float32)
    f = np.ascontiguousarray(m.faces, dtype=np.uint32)
    seconds = now() - t
    lo = v.astype(np.float64).min(axis=0)
    hi = v.astype(np.float64).max(axis=0)
    return v, f, {"reader": f"trimesh {version_of('trimesh')} (process=False)", "seconds": seconds,
                  "vertices": len(v), "faces": len(f), "bbox_min": lo.tolist(), "bbox_max": hi.tolist(),
                  "bbox_diagonal": float(np.linalg.norm(hi - lo))}


# ---------------------------------------------------------------------------------------------
# The benchmark of one ray set and query


def run_cli(cli: Path, oavm_file: Path, rays_path: Path, query: str, out: Path) -> Dict[str, Any]:
    flag = "--hits" if query == "closest" else "--occluded"
    cmd = [str(cli), str(oavm_file), "--rays", str(rays_path), flag, str(out), "--json"]
    t = now()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = now() - t
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: exit {p.returncode}: {p.stderr.strip()}")
    j = json.loads(p.stdout)
    return {"trace_s": j["seconds"], "wall_s": wall, "mrays_per_s_cli": j["mrays_per_s"],
            "threads": j["threads"], "open_ms": j["open_ms"],
            "start_to_first_ray_ms": j["start_to_first_ray_ms"], "rays": j["rays"],
            "peak_rss_bytes": j.get("peak_rss_bytes")}


def run_py_fresh(oavm_mod: Any, oavm_file: Path, rays_path: Path, query: str) -> Tuple[Dict[str, Any], Any]:
    t0 = now()
    rays = read_rays(rays_path)
    t1 = now()
    scene = oavm_mod.open(oavm_file)
    t2 = now()
    if query == "closest":
        h = scene.intersect(rays)
        ans: Any = (h.t, h.prim)
    else:
        ans = scene.occluded(rays)
    t3 = now()
    threads = scene.info["threads"]
    scene.close()
    return {"read_s": t1 - t0, "open_s": t2 - t1, "trace_s": t3 - t2, "wall_s": t3 - t0,
            "threads": threads}, ans


def bench_set(ctx: Dict[str, Any], name: str, rays_path: Path, query: str) -> Dict[str, Any]:
    oavm_mod = ctx["oavm"]
    oavm_file: Path = ctx["oavm_file"]
    reps: int = ctx["reps"]
    t = now()
    rays = read_rays(rays_path)
    read_s = now() - t
    n = len(rays)
    res: Dict[str, Any] = {"set": name, "query": query, "rays_file": str(rays_path), "rays": n,
                           "read_rays_s": read_s, "engines": {}, "agreement": {}, "notes": []}
    log(f"{name} ({n} rays, {query} hit)")

    # -- time to first answer (each engine on a scene of its own, kept for the repetitions) --
    engines: List[Any] = []
    preps: Dict[str, Any] = {}
    ref = None
    eng = Oavm(oavm_mod, oavm_file)
    t0 = now()
    eng.build()
    t1 = now()
    ref = eng.closest(rays) if query == "closest" else eng.any(rays)
    t2 = now()
    res["engines"]["oavm-py-warm"] = {
        "label": "oavm Python (scene kept open)", "threads": eng.threads(),
        "first_answer": {"open_s": t1 - t0, "first_call_s": t2 - t1, "total_s": t2 - t0,
                         "pack_s": ctx["pack_s"]},
        "extent": "native (per-ray tmin and tmax)",
    }
    engines.append(("oavm-py-warm", eng))
    preps["oavm-py-warm"] = rays

    for key, make in ctx["peer_makers"]:
        try:
            peer = make()
            t0 = now()
            prep, extent = peer.prepare(rays)
            prep_s = now() - t0
            if hasattr(peer, "new_scene"):
                peer.new_scene()
            t0 = now()
            peer.build()
            t1 = now()
            ans = peer.closest(prep) if query == "closest" else peer.any(prep)
            t2 = now()
        except Exception as e:  # a peer that cannot run: said, never a number
            res["engines"][key] = {"label": key, "error": f"{type(e).__name__}: {e}"}
            log(f"  {key}: cannot run: {type(e).__name__}: {e}")
            continue
        ext = extent.get("extent") or extent.get("extent_closest" if query == "closest" else "extent_any")
        res["engines"][key] = {
            "label": key, "threads": peer.threads(), "extent": ext,
            "first_answer": {"prepare_rays_s": prep_s, "add_mesh_s": t1 - t0,
                             "first_cast_s": t2 - t1, "total_s": t2 - t0,
                             "mesh_read_s": ctx["mesh_info"]["seconds"]},
        }
        res["agreement"][key] = agree_closest(ref, ans, ctx["diag"]) if query == "closest" else agree_any(ref, ans)
        engines.append((key, peer))
        preps[key] = prep

    # -- repetitions: CLI and binding (fresh open) alternated, then the warm scene and the peers --
    cli_runs: List[Dict[str, Any]] = []
    py_runs: List[Dict[str, Any]] = []
    warm: Dict[str, List[float]] = {k: [] for k, _ in engines}
    out = ctx["work"] / f"cli.{name}.{'hits' if query == 'closest' else 'occl'}"
    for w in range(ctx["warmup"]):
        run_cli(ctx["cli"], oavm_file, rays_path, query, out)
        run_py_fresh(oavm_mod, oavm_file, rays_path, query)
    checked = False
    for r in range(reps):
        order = ("cli", "py") if r % 2 == 0 else ("py", "cli")
        for which in order:
            if which == "cli":
                cli_runs.append(run_cli(ctx["cli"], oavm_file, rays_path, query, out))
                if not checked:
                    cli_ans = read_hits(out) if query == "closest" else read_occl(out)
                    res["agreement"]["oavm-trace CLI (bitwise)"] = identical(ref, cli_ans, query)
                    checked = True
            else:
                fig, py_ans = run_py_fresh(oavm_mod, oavm_file, rays_path, query)
                py_runs.append(fig)
                if len(py_runs) == 1:
                    res["agreement"]["oavm Python fresh open (bitwise)"] = identical(ref, py_ans, query)
        for key, e in engines:
            t0 = now()
            e.closest(preps[key]) if query == "closest" else e.any(preps[key])
            warm[key].append(now() - t0)
        log(f"  rep {r + 1}/{reps}: CLI {cli_runs[-1]['trace_s']:.4f} s, Python {py_runs[-1]['trace_s']:.4f} s"
            + "".join(f", {k} {v[-1]:.4f} s" for k, v in warm.items()))

    def rate(s: Dict[str, Any]) -> Dict[str, Any]:
        return {"median": n / s["median"] / 1e6, "min": n / s["max"] / 1e6, "max": n / s["min"] / 1e6}

    cli_trace = summary([x["trace_s"] for x in cli_runs])
    py_trace = summary([x["trace_s"] for x in py_runs])
    res["engines"]["oavm-trace"] = {
        "label": "oavm-trace CLI (new process per run)",
        "threads": {"trace": cli_runs[0]["threads"]},
        "trace_s": cli_trace, "mrays_per_s": rate(cli_trace),
        "wall_s": summary([x["wall_s"] for x in cli_runs]),
        "open_ms": summary([x["open_ms"] for x in cli_runs]),
        "start_to_first_ray_ms": summary([x["start_to_first_ray_ms"] for x in cli_runs]),
        "runs": cli_runs,
    }
    res["engines"]["oavm-py-fresh"] = {
        "label": "oavm Python (oavm.open per run)",
        "threads": {"trace": py_runs[0]["threads"]},
        "trace_s": py_trace, "mrays_per_s": rate(py_trace),
        "wall_s": summary([x["wall_s"] for x in py_runs]),
        "read_s": summary([x["read_s"] for x in py_runs]),
        "open_s": summary([x["open_s"] for x in py_runs]),
        "runs": py_runs,
    }
    pair = [p["trace_s"] / c["trace_s"] for p, c in zip(py_runs, cli_runs)]
    res["binding_vs_cli"] = {
        "python_over_cli_trace_time": py_trace["median"] / cli_trace["median"],
        "python_over_cli_rays_per_s": cli_trace["median"] / py_trace["median"],
        "overhead_percent": 100.0 * (py_trace["median"] / cli_trace["median"] - 1.0),
        "paired_ratio_trace_time": summary(pair),
        "python_over_cli_wall_time": (statistics.median([x["wall_s"] for x in py_runs])
                                      / statistics.median([x["wall_s"] for x in cli_runs])),
        "target_overhead_percent": 5.0,
    }
    for key, _ in engines:
        s = summary(warm[key])
        e = res["engines"][key]
        e["trace_s"] = s
        e["mrays_per_s"] = rate(s)
        e["first_answer"]["first_cast_minus_median_s"] = e["first_answer"].get(
            "first_call_s", e["first_answer"].get("first_cast_s")) - s["median"]
    for key, e in engines:
        if key == "oavm-py-warm":
            e.scene.close()
        elif hasattr(e, "close"):
            e.close()
        else:
            e.scene = None
    return res


# ---------------------------------------------------------------------------------------------
# Report


def fmt_s(s: Dict[str, Any]) -> str:
    if s["median"] is None:
        return "-"
    if len(s["values"]) == 1:
        return f"{s['median']:.4f}"
    return f"{s['median']:.4f} [{s['min']:.4f}-{s['max']:.4f}]"


def fmt_r(r: Dict[str, Any]) -> str:
    return f"{r['median']:.2f} [{r['min']:.2f}-{r['max']:.2f}]"


def print_report(rep: Dict[str, Any]) -> None:
    h = rep["header"]
    w = print
    w("=" * 100)
    w(f"oavm Python binding benchmark  commit {h['git']['commit']}{' (+ uncommitted changes)' if h['git'].get('dirty') else ''}"
      f"  format {h['oavm_format_version']}  {h['date']}")
    w(f"CPU: {h['cpu_model']}, {h['cpus']} cores   Python {h['python']}   " +
      ", ".join(f"{k} {v}" for k, v in h["versions"].items()))
    w(f"oavm._native: {h['oavm_native']}")
    m = rep["mesh"]
    w(f"mesh {m['path']}: {m['faces']} triangles, bbox diagonal {m['bbox_diagonal']:.6g}"
      + (f"; {m['vertices']} vertices read for the peers in {m['seconds']:.3f} s ({m['reader']})" if m["reader"] else ""))
    p = rep["pack"]
    w(f"oavm.pack -> {p['file']}: {p['seconds']:.3f} s" if p["seconds"] is not None else f"pack: reused {p['file']}")
    w(f"repetitions: {rep['reps']} (+{rep['warmup']} warm-up of CLI and fresh Python), medians [min-max]")
    for s in rep["sets"]:
        w("-" * 100)
        w(f"{s['set']}: {s['rays']} rays, {s['query']} hit   ({s['rays_file']})")
        w(f"  {'engine':<36} {'threads':>7}  {'trace s':<26} {'Mrays/s':<22} wall s")
        for key in ("oavm-trace", "oavm-py-fresh", "oavm-py-warm", "embreex", "open3d"):
            e = s["engines"].get(key)
            if e is None:
                continue
            if "error" in e:
                w(f"  {key:<36} cannot run: {e['error']}")
                continue
            th = e["threads"].get("trace_threads", e["threads"]["trace"])
            wall = fmt_s(e["wall_s"]) if "wall_s" in e else ""
            w(f"  {e['label'][:36]:<36} {str(th):>7}  {fmt_s(e['trace_s']):<26} {fmt_r(e['mrays_per_s']):<22} {wall}")
        b = s["binding_vs_cli"]
        pr = b["paired_ratio_trace_time"]
        w(f"  binding / CLI, tracing time: {b['python_over_cli_trace_time']:.4f} (overhead {b['overhead_percent']:+.2f} %,"
          f" target < 5 %; per-rep pairs {pr['median']:.4f} [{pr['min']:.4f}-{pr['max']:.4f}]);"
          f" wall time: {b['python_over_cli_wall_time']:.3f}")
        cli = s["engines"]["oavm-trace"]
        py = s["engines"]["oavm-py-fresh"]
        w(f"  CLI wall = exec + open ({cli['open_ms']['median']:.2f} ms) + read rays + trace + write answers"
          f" (first ray at {cli['start_to_first_ray_ms']['median']:.1f} ms);"
          f" Python wall = np.fromfile ({py['read_s']['median'] * 1e3:.1f} ms) + oavm.open"
          f" ({py['open_s']['median'] * 1e3:.2f} ms) + call")
        w("  time to first answer (from arrays/file in memory or on disk, build included):")
        for key in ("oavm-py-warm", "embreex", "open3d"):
            e = s["engines"].get(key)
            if e is None or "error" in e:
                continue
            f = e["first_answer"]
            if key == "oavm-py-warm":
                w(f"    oavm     open {f['open_s'] * 1e3:8.2f} ms + first call {f['first_call_s']:.4f} s"
                  f" = {f['total_s']:.4f} s   (pack beforehand: {ctx_pack(f['pack_s'])})")
            else:
                w(f"    {key:<8} add mesh {f['add_mesh_s']:.4f} s + first cast (builds the BVH) {f['first_cast_s']:.4f} s"
                  f" = {f['total_s']:.4f} s   (BVH build ~ {f['first_cast_minus_median_s']:.4f} s;"
                  f" rays to its layout {f['prepare_rays_s']:.4f} s; PLY read {f['mesh_read_s']:.3f} s)")
        w("  agreement with oavm (RAYS.md rule):")
        for key, a in s["agreement"].items():
            if "identical" in a:
                w(f"    {key:<36} {a['identical']}/{a['rays']} identical")
            else:
                extra = (f", same primitive on {100 * a['same_prim_of_both_hit']:.3f} % of common hits,"
                         f" hits {a['hits_ref']} vs {a['hits_other']}" if "hits_ref" in a
                         else f", occluded {a['occluded_ref']} vs {a['occluded_other']}")
                w(f"    {key:<36} {100 * a['agree_fraction']:.4f} % ({a['disagree']} disagree){extra}")
        for key in ("embreex", "open3d"):
            e = s["engines"].get(key)
            if e and "extent" in e:
                w(f"  {key} ray extent: {e['extent']}")
        for key in ("embreex", "open3d"):
            e = s["engines"].get(key)
            if e and "threads" in e:
                w(f"  {key} threads: trace {e['threads']['trace']}; build {e['threads']['build']}")
    for note in rep["notes"]:
        w(f"note: {note}")
    w("=" * 100)


def ctx_pack(p: Optional[float]) -> str:
    return f"{p:.3f} s" if p is not None else "reused file, not timed"


# ---------------------------------------------------------------------------------------------


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", type=Path, default=ROOT / ".." / "shared" / "scenes" / "dragon" / "dragon_vrip.ply",
                    help="the mesh (default ../shared/scenes/dragon/dragon_vrip.ply beside the repository)")
    ap.add_argument("--rays-prefix", type=Path, default=None,
                    help="ray files PREFIX.{primary,random,shadow}.rays (default target/py-bench/MESHSTEM);"
                         " made with `cargo run --release --features tools --example rays` when missing")
    ap.add_argument("--work", type=Path, default=ROOT / "target" / "py-bench",
                    help="where the .oavm file and the CLI's answers go (default target/py-bench)")
    ap.add_argument("--cli", type=Path, default=ROOT / "target" / "release" / "oavm-trace")
    ap.add_argument("--sets", default=",".join(RAY_SETS), help="ray sets (default primary,random,shadow)")
    ap.add_argument("--query", choices=("auto", "closest", "any", "both"), default="auto",
                    help="auto: closest hit for primary/random, any hit for shadow")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=1, help="untimed CLI + Python runs per set first")
    ap.add_argument("--peers", default="embreex,open3d", help="comma list, or 'none'")
    ap.add_argument("--embreex-threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--open3d-threads", type=int, default=0, help="0: Open3D's automatic (all cores)")
    ap.add_argument("--no-pack", action="store_true", help="reuse an existing .oavm file")
    ap.add_argument("--json", type=Path, default=None, help="write every figure here")
    a = ap.parse_args()

    import oavm

    mesh = a.mesh.resolve()
    work = a.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    prefix = a.rays_prefix.resolve() if a.rays_prefix else work / mesh.stem
    sets = [s for s in a.sets.split(",") if s]
    cli = a.cli.resolve()
    if not cli.exists():
        log(f"{cli} is missing: building it (nice -n 19 cargo build --release --bin oavm-trace)")
        sh(["nice", "-n", "19", "cargo", "build", "--release", "--bin", "oavm-trace"])
    notes: List[str] = []
    if "bench-venv" not in sys.prefix:
        notes.append(f"running in {sys.prefix}, not target/bench-venv: make sure its oavm is a release build")

    versions = {"numpy": np.__version__, "oavm": getattr(oavm, "__version__", None),
                "embreex": version_of("embreex"), "open3d": None, "trimesh": version_of("trimesh")}
    peers = [] if a.peers == "none" else [p for p in a.peers.split(",") if p]
    if "open3d" in peers:
        try:
            import open3d

            versions["open3d"] = open3d.__version__ + (" (open3d-cpu)" if version_of("open3d-cpu") else "")
        except Exception as e:
            versions["open3d"] = f"unavailable: {type(e).__name__}: {e}"

    header = {
        "git": git_head(), "oavm_format_version": oavm.FORMAT_VERSION, "cpu_model": cpu_model(),
        "cpus": os.cpu_count(), "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "python": platform.python_version(), "python_prefix": sys.prefix, "versions": versions,
        "oavm_native": getattr(oavm._native, "__file__", None), "cli": str(cli),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }

    ray_paths = ensure_rays(mesh, prefix, sets)

    oavm_file = work / f"{mesh.stem}.oavm"
    pack_report = None
    if a.no_pack and oavm_file.exists():
        pack_s = None
    else:
        log(f"packing {mesh} -> {oavm_file}")
        t = now()
        pack_report = oavm.pack(mesh, oavm_file, progress=False)
        pack_s = now() - t

    with oavm.open(oavm_file) as sc:
        info = sc.info
    if peers:
        v, f, mesh_info = load_mesh(mesh)
    else:  # no peer: no arrays; the diagonal from the file's header
        lo, hi = np.array(info["mesh_min"], dtype=np.float64), np.array(info["mesh_max"], dtype=np.float64)
        v = f = np.zeros((0, 3))
        mesh_info = {"reader": None, "seconds": None, "vertices": None, "faces": info["input_triangles"],
                     "bbox_min": lo.tolist(), "bbox_max": hi.tolist(),
                     "bbox_diagonal": float(np.linalg.norm(hi - lo))}
    mesh_info["path"] = str(mesh)
    if peers and info["input_triangles"] != len(f):
        notes.append(f"the peers' mesh has {len(f)} triangles, the .oavm file {info['input_triangles']}:"
                     " primitive ids will not match")

    peer_makers: List[Tuple[str, Callable[[], Any]]] = []
    for p in peers:
        if p == "embreex":
            peer_makers.append(("embreex", lambda: Embreex(v, f, a.embreex_threads)))
        elif p == "open3d":
            peer_makers.append(("open3d", lambda: Open3d(v, f, a.open3d_threads)))
        else:
            ap.error(f"unknown peer {p!r} (embreex, open3d)")

    ctx = {"oavm": oavm, "oavm_file": oavm_file, "reps": a.reps, "warmup": a.warmup, "cli": cli,
           "work": work, "pack_s": pack_s, "mesh_info": mesh_info, "diag": mesh_info["bbox_diagonal"],
           "peer_makers": peer_makers}
    results = []
    for s in sets:
        queries = {"auto": [DEFAULT_QUERY.get(s, "closest")], "closest": ["closest"], "any": ["any"],
                   "both": ["closest", "any"]}[a.query]
        for q in queries:
            results.append(bench_set(ctx, s, ray_paths[s], q))

    report = {"header": header, "mesh": mesh_info, "oavm_file_info": info,
              "pack": {"file": str(oavm_file), "seconds": pack_s, "report": pack_report},
              "reps": a.reps, "warmup": a.warmup, "sets": results, "notes": notes}
    print_report(report)
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(report, indent=1))
        log(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
