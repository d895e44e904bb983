"""Shared fixtures: the repository, the test meshes of ../shared, the command-line tools, and
ray files in the format of ../shared/RAYS.md.

Run by `cargo test` (python/tests/pytest.rs lays out the package with the extension cargo built, and passes
the tools' paths in OAVM_PACK and OAVM_TRACE). Run alone, after `cargo build --release`:

    target/python-venv/bin/python -m pytest python/tests

Missing test data or tools fail the tests; they are never skipped.
"""

from __future__ import annotations

import os
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


def _shared() -> Path:
    return Path(os.environ.get("OAVM_SHARED", REPO.parent / "shared"))


def _tool(name: str) -> Path:
    env = os.environ.get("OAVM_" + name.split("-")[1].upper())
    candidates = [Path(env)] if env else [REPO / "target" / p / name for p in ("release", "debug")]
    for c in candidates:
        if c.is_file():
            return c
    pytest.fail(f"{name} not found (tried {', '.join(map(str, candidates))}): run `cargo build --release`, "
                f"or the tests through `cargo test`, which sets OAVM_{name.split('-')[1].upper()}")


@pytest.fixture(scope="session")
def shared() -> Path:
    s = _shared()
    if not (s / "scenes").is_dir():
        pytest.fail(f"the test data is missing: {s}/scenes (CI provides ../shared beside the checkout)")
    return s


@pytest.fixture(scope="session")
def oavm_trace() -> Path:
    return _tool("oavm-trace")


@pytest.fixture(scope="session")
def oavm_pack() -> Path:
    return _tool("oavm-pack")


def run(*args) -> subprocess.CompletedProcess:
    """Runs a tool; its failure fails the test with its stderr."""
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if p.returncode != 0:
        pytest.fail(f"{' '.join(map(str, args))} exited with {p.returncode}:\n{p.stderr}")
    return p


def write_records(path: Path, magic: bytes, records: np.ndarray) -> None:
    """A RAYS / HITS / OCCL file (RAYS.md): magic, version 1, count, then the records."""
    with open(path, "wb") as f:
        f.write(magic + struct.pack("<IQ", 1, len(records)))
        f.write(np.ascontiguousarray(records).tobytes())


def hits_bytes(t: np.ndarray, prim: np.ndarray) -> bytes:
    """The bytes of the HITS file of these answers."""
    rec = np.empty(len(t), dtype=[("t", "<f4"), ("prim", "<u4")])
    rec["t"], rec["prim"] = t, prim
    return b"HITS" + struct.pack("<IQ", 1, len(t)) + rec.tobytes()


def occl_bytes(occluded: np.ndarray) -> bytes:
    return b"OCCL" + struct.pack("<IQ", 1, len(occluded)) + occluded.astype(np.uint8).tobytes()


def ray_sets(lo, hi, n: int, seed: int) -> dict:
    """Ray sets around a box [lo, hi], as (N, 8) float32 arrays: `random` (origins around and
    inside the box, aimed at points inside it: most hit), `axis` (parallel to the axes, with
    zero direction components), `segments` (finite [tmin, tmax], for any-hit) and `odd`
    (non-unit directions, rays that must miss: NaN, zero direction, tmin > tmax)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ext = hi - lo
    o = lo + ext * rng.uniform(-0.6, 1.6, size=(n, 3))
    target = lo + ext * rng.uniform(0.15, 0.85, size=(n, 3))
    d = target - o
    random = np.zeros((n, 8), np.float32)
    random[:, 0:3], random[:, 4:7], random[:, 7] = o, d / np.linalg.norm(d, axis=1)[:, None], np.inf
    axis = np.zeros((n, 8), np.float32)
    k = rng.integers(0, 3, size=n)
    axis[:, 0:3] = lo + ext * rng.uniform(0.1, 0.9, size=(n, 3))
    axis[np.arange(n), k] = lo[k] - 0.5 * ext[k]
    axis[np.arange(n), 4 + k] = 1.0
    axis[:, 7] = np.inf
    seg = random.copy()
    seg[:, 3] = rng.uniform(0, 0.5, size=n) * np.linalg.norm(ext)
    seg[:, 7] = seg[:, 3] + rng.uniform(0, 1.0, size=n) * np.linalg.norm(ext)
    seg[:, 4:7] *= rng.uniform(0.25, 4.0, size=(n, 1))  # t in units of the direction
    odd = random[:64].copy()
    odd[0:8, 0] = np.nan
    odd[8:16, 4:7] = 0.0
    odd[16:24, 3], odd[16:24, 7] = 2.0, 1.0
    odd[24:32, 6] = np.inf
    return {"random": random, "axis": axis, "segments": seg, "odd": odd}


def brute_distance(tri: np.ndarray, p: np.ndarray) -> float:
    """Distance from `p` to the nearest of triangles `tri` (f64): to a plane where `p`
    projects inside the triangle, else to its nearest edge."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    h = np.einsum("ij,ij->i", p - a, n) / nn
    proj = p - h[:, None] * n
    inside = np.ones(len(tri), bool)
    for x, y in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(y - x, proj - x), n) >= 0

    def seg(x, y):
        d = y - x
        t = np.clip(np.einsum("ij,ij->i", p - x, d) / np.einsum("ij,ij->i", d, d), 0, 1)
        return np.linalg.norm(p - (x + t[:, None] * d), axis=1)

    return float(np.where(inside, np.abs(h) * np.sqrt(nn), np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a))).min())
