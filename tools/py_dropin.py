#!/usr/bin/env python3
"""oavm's drop-ins (``oavm.trimesh``, ``oavm.open3d``) against what they replace, in one process,
on the same meshes, rays and points: agreement, and speed as a ratio.

    tools/py_bench.sh --no-run && target/bench-venv/bin/python tools/py_dropin.py [--meshes ...]

(``tools/py_bench.sh`` makes ``target/bench-venv``: a release build of oavm and the pinned peers
of ``python/requirements-bench.txt``, Open3D, embreex, trimesh; this tool also needs ``rtree``
for trimesh's numpy intersector, installed there by ``tools/py_bench.sh`` too.)

Per mesh (default: the dragon, the BART kitchen, Sibenik; read by ``oavm.load_mesh``, the same
triangles for everyone):

* Agreement with Open3D's ``RaycastingScene`` (Embree 4 inside) on ``--rays`` random rays
  (origins around the mesh's box, uniform directions): first hits (hit or miss, ``t`` within
  1e-4 of the box's diagonal, the same triangle), hit counts, and every listed hit; and with
  trimesh's own numpy intersector (``ray_triangle``, float64) on ``--trimesh-rays`` of them
  (it takes seconds a thousand rays). Every disagreement is listed with its explanation: the
  ray's smallest barycentric margin (f64) on the triangles involved, 0 for a ray through an
  edge; a ray whose margin is above 1e-6 is an unexplained disagreement. Closest points and
  distances against Open3D's on ``--points / 4`` points in the box, and the sign of the
  signed distance on those and on as many points near the surface (1e-5 to 1e-2 of the
  diagonal off it), each disagreement explained by twelve rays traced in f64 by brute force.
* Speed: each call timed ``--reps`` times (median, min-max) on the same inputs, after one
  untimed call each (Open3D and embreex build their BVH then; oavm opens its file, packed
  before), ours against theirs: ``intersects_first``, ``intersects_location`` (multiple hits)
  and ``contains_points`` against trimesh with embreex; ``cast_rays``, ``test_occlusions``,
  ``count_intersections`` and ``list_intersections`` against Open3D (``nthreads=0``, all
  cores). Ratios are their time over ours (above 1: oavm is faster).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Dict, List

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / ".." / "shared" / "scenes"
MESHES = {
    "dragon": SCENES / "dragon" / "dragon_vrip.ply",
    "kitchen": SCENES / "bart" / "kitchen" / "kitchen.aff",
    "sibenik": SCENES / "sibenik" / "sibenik.obj",
    "bunny": SCENES / "bunny" / "bun_zipper.ply",
}


def timed(f: Callable[[], Any], reps: int) -> Dict[str, Any]:
    f()  # untimed: builds, page faults
    ts = []
    for _ in range(reps):
        # A pause first: TBB's workers (Open3D's) spin for a while after a call, and would take
        # the cores from the next call timed.
        time.sleep(0.2)
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return {"median_s": statistics.median(ts), "min_s": min(ts), "max_s": max(ts)}


def margin(v: np.ndarray, f: np.ndarray, tri: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Smallest barycentric coordinate (f64) of where each ray's line meets its triangle."""
    a, b, c = (v[f[tri, k]].astype(np.float64) for k in range(3))
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    s = o - a
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.einsum("ij,ij->i", s, p) / det
        q = np.cross(s, e1)
        w = np.einsum("ij,ij->i", d, q) / det
    return np.minimum(np.minimum(u, w), 1.0 - u - w)


def random_rays(v: np.ndarray, n: int, seed: int):
    rng = np.random.default_rng(seed)
    lo, hi = v.min(axis=0).astype(np.float64), v.max(axis=0).astype(np.float64)
    o = lo - 0.1 * (hi - lo) + 1.2 * (hi - lo) * rng.random((n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d


def agree_open3d(v, f, o, d, ours, theirs, diag) -> Dict[str, Any]:
    r = np.concatenate([o, d], axis=1).astype(np.float32)
    o32, d32 = r[:, :3].astype(np.float64), r[:, 3:].astype(np.float64)
    a, b = ours.cast_rays(r), theirs.cast_rays(r)
    ta, tb = a["t_hit"].numpy(), b["t_hit"].numpy()
    pa, pb = a["primitive_ids"].numpy(), b["primitive_ids"].numpy()
    ha, hb = np.isfinite(ta), np.isfinite(tb)
    out: Dict[str, Any] = {"rays": len(r), "hits_oavm": int(ha.sum()), "hits_open3d": int(hb.sum())}
    miss_differs = np.flatnonzero(ha != hb)
    both = ha & hb
    t_differs = np.flatnonzero(both & (np.abs(ta - tb) > 1e-4 * diag))
    prim_differs = np.flatnonzero(both & (np.abs(ta - tb) <= 1e-4 * diag) & (pa != pb))
    # Explain: the margin of the triangle(s) the disagreeing rays hit, on each side.
    def explain(idx, prims):
        if not len(idx):
            return []
        m = margin(v, f, prims[idx], o32[idx], d32[idx])
        return [float(x) for x in m]
    hit_side = np.where(ha[miss_differs], pa[miss_differs], pb[miss_differs])
    hm = margin(v, f, hit_side, o32[miss_differs], d32[miss_differs]) if len(miss_differs) else np.zeros(0)
    out["first_hit_or_miss_differs"] = {"rays": len(miss_differs), "margins": [float(x) for x in hm[:20]],
                                        "unexplained": int((np.abs(hm) > 1e-6).sum())}
    out["first_t_differs"] = {"rays": len(t_differs),
                              "margins_oavm": explain(t_differs, pa)[:20], "margins_open3d": explain(t_differs, pb)[:20]}
    # The same t, another triangle: a tie (an edge, or coincident triangles); RAYS.md takes
    # either id.
    out["first_same_t_other_triangle"] = {"rays": len(prim_differs)}
    # Counts; each ray where they differ explained, or not: (a) the hits oavm lists beyond
    # Open3D's lie within RAYS.md's tolerance (1e-4 of the diagonal) of another of its hits
    # (coincident or nearly coincident triangles: Open3D's filter skips a hit next to the one
    # before, oavm and the f64 brute force count each triangle); (b) the hits Open3D lists beyond oavm's pass an edge within f32 rounding
    # (64 ulps of the coordinates, in length); else unexplained.
    ca, cb = ours.count_intersections(r).numpy(), theirs.count_intersections(r).numpy()
    cd = np.flatnonzero(ca != cb)
    la, lb = ours.list_intersections(r[cd]), theirs.list_intersections(r[cd])
    scale = float(np.abs(v).max())
    reasons = {"coincident_triangles": 0, "edge_within_f32": 0, "unexplained": 0}
    unexplained = []
    for k, i in enumerate(cd):
        sa, sb = la["ray_splits"].numpy(), lb["ray_splits"].numpy()
        pa_, ta_ = la["primitive_ids"].numpy()[sa[k]:sa[k + 1]], la["t_hit"].numpy()[sa[k]:sa[k + 1]]
        pb_ = lb["primitive_ids"].numpy()[sb[k]:sb[k + 1]]
        extra_a = [j for j, p in enumerate(pa_) if p not in set(pb_.tolist())]
        extra_b = np.array([p for p in pb_ if p not in set(pa_.tolist())], dtype=np.int64)
        same_t = all(np.sum(np.abs(ta_ - ta_[j]) <= 1e-4 * diag) >= 2 for j in extra_a)
        edge = True
        if len(extra_b):
            m = margin(v, f, extra_b, np.repeat(o32[i:i + 1], len(extra_b), 0), np.repeat(d32[i:i + 1], len(extra_b), 0))
            tri = v[f[extra_b]].astype(np.float64)
            size = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
            edge = bool(np.all(np.abs(m) * size <= 64 * 2.0 ** -24 * scale))
        if extra_a and same_t and not len(extra_b):
            reasons["coincident_triangles"] += 1
        elif len(extra_b) and edge and not extra_a:
            reasons["edge_within_f32"] += 1
        else:
            reasons["unexplained"] += 1
            unexplained.append(int(i))
    out["counts"] = {"hits_oavm": int(ca.sum()), "hits_open3d": int(cb.sum()),
                     "rays_crossing_twice_or_more": int((cb >= 2).sum()), "rays_differ": len(cd),
                     **reasons, "unexplained_rays": unexplained[:10]}
    return out


def odd_crossings(v: np.ndarray, f: np.ndarray, p: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Whether the ray from each point along each direction crosses the mesh an odd number of
    times, ``(len(p), len(dirs))``: float64 Moller-Trumbore against every triangle (brute force,
    no code shared with either side). Crossings counted, as both sides' signs count them (not a
    winding number: the scenes' triangles are not consistently oriented)."""
    a, b, c = (v[f[:, k]].astype(np.float64) for k in range(3))
    e1, e2 = b - a, c - a
    odd = np.zeros((len(p), len(dirs)), dtype=bool)
    for i, q in enumerate(p.astype(np.float64)):
        s = q - a
        qv = np.cross(s, e1)
        t_num = np.einsum("ij,ij->i", e2, qv)
        for j, d in enumerate(dirs):
            h = np.cross(d, e2)
            det = np.einsum("ij,ij->i", e1, h)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / det
                u = np.einsum("ij,ij->i", s, h) * inv
                w = (qv @ d) * inv
                n = np.count_nonzero((det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t_num * inv > 0))
            odd[i, j] = n & 1
    return odd


def near_points(v: np.ndarray, f: np.ndarray, n: int, diag: float, seed: int) -> np.ndarray:
    """Points near the surface: a uniform point of a random triangle (by area) moved along the
    triangle's normal by a distance from 1e-5 to 1e-2 of the diagonal (log-uniform), either way."""
    rng = np.random.default_rng(seed)
    a, b, c = (v[f[:, k]].astype(np.float64) for k in range(3))
    nrm = np.cross(b - a, c - a)
    area = np.linalg.norm(nrm, axis=1)
    ok = area > 0
    t = rng.choice(np.flatnonzero(ok), size=n, p=area[ok] / area[ok].sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    on = (1 - s)[:, None] * a[t] + (s * (1 - r2))[:, None] * b[t] + (s * r2)[:, None] * c[t]
    off = diag * 10.0 ** rng.uniform(-5, -2, n) * rng.choice([-1.0, 1.0], n)
    return (on + (nrm[t] / area[t, None]) * off[:, None]).astype(np.float32)


def sign_agreement(v, f, pts, sa, sb, dist, diag, explain: int = 200) -> Dict[str, Any]:
    """Where the two signs differ, each disagreement explained by rays traced in float64
    (``odd_crossings``; up to ``explain`` of them, evenly spaced, when there are more): nine
    random directions and oavm's three. A point within 1e-6 of the diagonal of the surface (f32
    rounding of the coordinates decides); a point whose twelve rays do not all agree (it sees
    through a hole: inside is not defined there, and neither sign is wrong); else the side the
    twelve take. Also counted: whether oavm's answer is the vote of its three rays traced in f64
    (its crossings are exact, so it should always be)."""
    differ = np.flatnonzero((sa < 0) != (sb < 0))
    out: Dict[str, Any] = {"points": len(pts), "inside_oavm": int((sa < 0).sum()),
                           "inside_open3d": int((sb < 0).sum()), "differ": len(differ)}
    pick = differ[np.linspace(0, len(differ) - 1, min(explain, len(differ))).astype(np.int64)] if len(differ) else differ
    on_surface = np.abs(dist[pick]) <= 1e-6 * diag
    rest = pick[~on_surface]
    rng = np.random.default_rng(4)
    dirs = rng.normal(size=(9, 3))
    # oavm's sign is the parity of most of its three rays' crossings, counted exactly.
    import oavm
    vote_dirs = np.asarray(oavm.VOTE_DIRECTIONS, dtype=np.float64)
    dirs = np.concatenate([dirs / np.linalg.norm(dirs, axis=1)[:, None], vote_dirs])
    odd = odd_crossings(v, f, pts[rest], dirs)
    unanimous = odd.all(axis=1) | (~odd).all(axis=1)
    inside_ref = odd.all(axis=1)
    vote = odd[:, 9:].sum(axis=1) >= 2
    with_oavm = unanimous & (inside_ref == (sa[rest] < 0))
    with_o3d = unanimous & (inside_ref == (sb[rest] < 0))
    out.update(explained=len(pick), on_surface=int(on_surface.sum()), sees_a_hole=int((~unanimous).sum()),
               rays_side_with_oavm=int(with_oavm.sum()), rays_side_with_open3d=int(with_o3d.sum()),
               oavm_is_its_vote_in_f64=int((vote == (sa[rest] < 0)).sum()),
               open3d_right_examples=pts[rest[with_o3d][:5]].tolist())
    return out


def agree_distance(v, f, pts, near, ours, theirs, diag, explain: int) -> Dict[str, Any]:
    """Closest points and distances against Open3D's on the same points (within 1e-6 of the
    diagonal), and the sign on the same points (uniform in the box: most far from the surface)
    and on points near it, every disagreement explained by twelve f64 rays
    (``sign_agreement``). Open3D's sign is one ray's parity; oavm's is exact crossings voted
    over three rays (``oavm.VOTE_DIRECTIONS``)."""
    a, b = ours.compute_closest_points(pts), theirs.compute_closest_points(pts)
    da = np.linalg.norm(a["points"].numpy() - pts, axis=1)
    db = np.linalg.norm(b["points"].numpy() - pts, axis=1)
    out: Dict[str, Any] = {"points": len(pts), "distance_differs": int((np.abs(da - db) > 1e-6 * diag).sum()),
                           "max_distance_difference_over_diagonal": float(np.max(np.abs(da - db)) / diag),
                           "other_triangle_at_same_distance": int((a["primitive_ids"].numpy() != b["primitive_ids"].numpy()).sum())}
    for name, p in (("sign_in_the_box", pts), ("sign_near_the_surface", near)):
        sa, sb = ours.compute_signed_distance(p).numpy(), theirs.compute_signed_distance(p).numpy()
        out[name] = sign_agreement(v, f, p, sa, sb, np.abs(sb), diag, explain)
    return out


def agree_trimesh(mesh_t, o, d, ours) -> Dict[str, Any]:
    from trimesh.ray.ray_triangle import RayMeshIntersector as Reference
    ref = Reference(mesh_t)
    t = time.perf_counter()
    fa, fb = ours.intersects_first(o, d), ref.intersects_first(o, d)
    ia, ra = ours.intersects_id(o, d)
    ib, rb = ref.intersects_id(o, d)
    ca, cb = np.bincount(ra, minlength=len(o)), np.bincount(rb, minlength=len(o))
    return {"rays": len(o), "first_differs": int((fa != fb).sum()), "first_hits": int((fb >= 0).sum()),
            "count_differs": int((ca != cb).sum()), "hits_oavm": int(ca.sum()), "hits_trimesh": int(cb.sum()),
            "seconds": time.perf_counter() - t}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", default="dragon,kitchen,sibenik")
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--points", type=int, default=200_000, help="points for contains_points")
    ap.add_argument("--trimesh-rays", type=int, default=1000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--explain", type=int, default=200,
                    help="sign disagreements explained by f64 rays, per point set (evenly spaced)")
    ap.add_argument("--cache-dir", type=Path, default=ROOT / "target" / "py-dropin-cache")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    import open3d as o3d
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector as EmbreeIntersector

    import oavm
    import oavm.open3d
    import oavm.trimesh

    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    report: Dict[str, Any] = {"commit": commit, "format_version": oavm.FORMAT_VERSION,
                              "open3d": o3d.__version__, "trimesh": trimesh.__version__, "meshes": {}}
    print(f"commit {commit}, format {oavm.FORMAT_VERSION}, open3d {o3d.__version__}, trimesh {trimesh.__version__}")
    for name in args.meshes.split(","):
        v, f = oavm.load_mesh(MESHES[name])
        diag = float(np.linalg.norm(v.max(axis=0).astype(np.float64) - v.min(axis=0)))
        mesh_t = trimesh.Trimesh(v.astype(np.float64), f.astype(np.int64), process=False)
        o, d = random_rays(v, args.rays, 1)
        r6 = np.concatenate([o, d], axis=1).astype(np.float32)
        lo, hi = v.min(axis=0), v.max(axis=0)
        pts = lo + (hi - lo) * np.random.default_rng(2).random((args.points, 3))
        p32 = pts.astype(np.float32)
        t = time.perf_counter()
        ours_o3d = oavm.open3d.RaycastingScene(cache_dir=args.cache_dir)
        ours_o3d.add_triangles(v, f)
        ours_o3d.cast_rays(r6[:1])
        first_use = time.perf_counter() - t
        theirs_o3d = o3d.t.geometry.RaycastingScene()
        theirs_o3d.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f))
        ours_tm = oavm.trimesh.RayMeshIntersector(mesh_t, cache_dir=args.cache_dir)
        theirs_tm = EmbreeIntersector(mesh_t)
        rep: Dict[str, Any] = {"triangles": len(f), "rays": len(o), "first_use_s": first_use}
        print(f"\n{name}: {len(f)} triangles, {len(o)} rays; first use (pack or open) {first_use:.2f} s")
        rep["agree_open3d"] = agree_open3d(v, f, o, d, ours_o3d, theirs_o3d, diag)
        print("  against Open3D:", json.dumps(rep["agree_open3d"]))
        near = near_points(v, f, args.points // 4, diag, 3)
        rep["agree_distance"] = agree_distance(v, f, p32[: args.points // 4], near, ours_o3d, theirs_o3d, diag, args.explain)
        print("  distances against Open3D:", json.dumps(rep["agree_distance"]))
        k = args.trimesh_rays
        rep["agree_trimesh"] = agree_trimesh(mesh_t, o[:k], d[:k], ours_tm)
        print("  against trimesh ray_triangle:", json.dumps(rep["agree_trimesh"]))
        calls = [
            ("intersects_first", lambda: ours_tm.intersects_first(o, d), lambda: theirs_tm.intersects_first(o, d)),
            ("intersects_location (multiple hits)", lambda: ours_tm.intersects_location(o, d),
             lambda: theirs_tm.intersects_location(o, d)),
            ("contains_points", lambda: ours_tm.contains_points(pts), lambda: theirs_tm.contains_points(pts)),
            ("cast_rays", lambda: ours_o3d.cast_rays(r6), lambda: theirs_o3d.cast_rays(r6)),
            ("test_occlusions", lambda: ours_o3d.test_occlusions(r6), lambda: theirs_o3d.test_occlusions(r6)),
            ("count_intersections", lambda: ours_o3d.count_intersections(r6),
             lambda: theirs_o3d.count_intersections(r6)),
            ("list_intersections", lambda: ours_o3d.list_intersections(r6),
             lambda: theirs_o3d.list_intersections(r6)),
            ("compute_closest_points", lambda: ours_o3d.compute_closest_points(p32),
             lambda: theirs_o3d.compute_closest_points(p32)),
            ("compute_distance", lambda: ours_o3d.compute_distance(p32), lambda: theirs_o3d.compute_distance(p32)),
            ("compute_signed_distance", lambda: ours_o3d.compute_signed_distance(p32),
             lambda: theirs_o3d.compute_signed_distance(p32)),
        ]
        rep["speed"] = {}
        for call, mine, peer in calls:
            time.sleep(0.5)
            a = timed(mine, args.reps)
            time.sleep(0.5)
            b = timed(peer, args.reps)
            peer_name = "trimesh+embreex" if call in ("intersects_first", "contains_points") or "location" in call else "Open3D"
            ratio = b["median_s"] / a["median_s"]
            rep["speed"][call] = {"oavm": a, peer_name: b, "ratio": ratio}
            print(f"  {call:38s} oavm {a['median_s']:.3f} s ({a['min_s']:.3f}-{a['max_s']:.3f}), "
                  f"{peer_name} {b['median_s']:.3f} s ({b['min_s']:.3f}-{b['max_s']:.3f}): {ratio:.2f}x")
        report["meshes"][name] = rep
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
