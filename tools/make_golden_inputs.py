#!/usr/bin/env python3
"""Makes the inputs of the golden files (tests/golden/README.md): a small generated mesh and a
ray set aimed at its awkward places.

    python3 tools/make_golden_inputs.py [OUT_DIR]      (default tests/golden)

writes OUT_DIR/mesh.ply (ascii PLY, 487 triangles after fan triangulation) and OUT_DIR/rays.rays
(RAYS.md, version 1). Deterministic: SplitMix64 with fixed seeds, and only +, -, *, / and sqrt
(correctly rounded in IEEE arithmetic, so any Python 3 gives the same bytes); no trigonometry,
no `random` module. The mesh's coordinates are written with 6 decimals and the rays are aimed at
the coordinates as written, so aiming at a vertex means that vertex's parsed value.

The mesh, in primitive-id order (fan triangulation, RAYS.md):
  A   0..    a radius-1 icosphere (icosahedron subdivided twice, 320 faces) around the origin with
             a hole: the faces whose centroid points within ~25 degrees of +z are left out, so
             rays through the hole see the inside of the shell
  B          a radius-0.3 icosphere (subdivided once, 80 faces) inside A, seen through the hole
  C          a radius-0.1 icosphere (subdivided once) far from A: a dense cluster, a deep subtree
  D          an axis-aligned box as 6 quads (12 triangles by fan), corners on multiples of 1/4
  E          a floor quad (2 triangles) at y = -1.25 under everything: large triangles in many cells
  F          a tetrahedron far from everything else: large merged empty volumes between
  G          a vertical pentagon (3 triangles by fan)
  H          two degenerate triangles (a repeated vertex; three collinear vertices): they keep
             their ids and are never hit
"""
import os
import struct
import sys

out_dir = sys.argv[1] if len(sys.argv) > 1 else "tests/golden"
os.makedirs(out_dir, exist_ok=True)


class SplitMix64:
    """The same generator as oavm::rays::SplitMix64."""

    def __init__(self, seed):
        self.s = seed & 0xFFFFFFFFFFFFFFFF

    def next_u64(self):
        m = 0xFFFFFFFFFFFFFFFF
        self.s = (self.s + 0x9E3779B97F4A7C15) & m
        z = self.s
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & m
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & m
        return z ^ (z >> 31)

    def next_f64(self):
        return (self.next_u64() >> 11) * (1.0 / (1 << 53))

    def uniform(self, lo, hi):
        return lo + (hi - lo) * self.next_f64()

    def unit_vector(self):
        # Rejection sampling in the cube: uniform on the sphere without trigonometry.
        while True:
            v = [self.uniform(-1.0, 1.0) for _ in range(3)]
            n2 = sum(c * c for c in v)
            if 1e-6 < n2 <= 1.0:
                n = n2 ** 0.5
                return [c / n for c in v]


def q(x):
    """A coordinate as the PLY file stores it (6 decimals), parsed back."""
    return float("%.6f" % x)


# ---- mesh -----------------------------------------------------------------------------------

verts = []  # written coordinates (already rounded)
faces = []  # vertex index lists (3 or more: the reader fans them)
pieces = {}  # name -> (first face index, face count) for aiming rays


def add_vertex(p):
    verts.append([q(c) for c in p])
    return len(verts) - 1


def icosphere(centre, radius, subdivisions):
    phi = (1.0 + 5.0 ** 0.5) / 2.0
    base = [
        (-1, phi, 0), (1, phi, 0), (-1, -phi, 0), (1, -phi, 0),
        (0, -1, phi), (0, 1, phi), (0, -1, -phi), (0, 1, -phi),
        (phi, 0, -1), (phi, 0, 1), (-phi, 0, -1), (-phi, 0, 1),
    ]
    tris = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]

    def unit(p):
        n = sum(c * c for c in p) ** 0.5
        return tuple(c / n for c in p)

    pts = [unit(p) for p in base]
    for _ in range(subdivisions):
        mid = {}

        def midpoint(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                pts.append(unit(tuple((x + y) / 2.0 for x, y in zip(pts[a], pts[b]))))
                mid[key] = len(pts) - 1
            return mid[key]

        new = []
        for a, b, c in tris:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        tris = new
    return [tuple(centre[k] + radius * p[k] for k in range(3)) for p in pts], tris


def add_piece(name, points, polys, keep=lambda pts: True):
    idx = [add_vertex(p) for p in points]
    first = len(faces)
    for poly in polys:
        if keep([points[i] for i in poly]):
            faces.append([idx[i] for i in poly])
    pieces[name] = (first, len(faces) - first)


def outside_hole(pts):
    c = [sum(p[k] for p in pts) / 3.0 for k in range(3)]
    n = sum(x * x for x in c) ** 0.5
    return c[2] / n < 0.9  # cos 25.8 degrees


add_piece("A", *icosphere((0.0, 0.0, 0.0), 1.0, 2), keep=outside_hole)
add_piece("B", *icosphere((0.0, 0.0, 0.0), 0.3, 1))
add_piece("C", *icosphere((-1.5, 0.75, 1.0), 0.1, 1))

x0, x1, y0, y1, z0, z1 = 1.5, 2.25, -0.5, 0.25, -0.25, 0.5
box = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]  # index = 4x + 2y + z
add_piece("D", box, [
    (0, 1, 3, 2), (4, 6, 7, 5),  # x = x0, x = x1
    (0, 4, 5, 1), (2, 3, 7, 6),  # y = y0, y = y1
    (0, 2, 6, 4), (1, 5, 7, 3),  # z = z0, z = z1
])
add_piece("E", [(-2.0, -1.25, -2.0), (2.5, -1.25, -2.0), (2.5, -1.25, 2.0), (-2.0, -1.25, 2.0)],
          [(0, 1, 2, 3)])
add_piece("F", [(-3.0, 1.5, -1.0), (-2.5, 1.5, -1.5), (-2.75, 2.0, -1.25), (-2.5, 1.25, -0.75)],
          [(0, 1, 2), (0, 3, 1), (1, 3, 2), (2, 3, 0)])
add_piece("G", [(-2.0, -0.5, 0.0), (-2.0, -0.5, 0.5), (-2.0, 0.0, 0.75), (-2.0, 0.5, 0.5),
                (-2.0, 0.5, 0.0)], [(0, 1, 2, 3, 4)])
add_piece("H", [(0.5, 1.5, 0.5), (1.0, 1.5, 0.5), (0.75, 1.75, 0.5), (1.25, 1.5, 0.5)],
          [(0, 1, 1), (0, 1, 3)])  # (0, 1, 1) repeats a vertex; 0, 1, 3 are collinear


def fan(poly):
    return [(poly[0], poly[i], poly[i + 1]) for i in range(1, len(poly) - 1)]


triangles = [t for f in faces for t in fan(f)]

with open(os.path.join(out_dir, "mesh.ply"), "w", newline="\n") as f:
    f.write("ply\nformat ascii 1.0\n")
    f.write("comment oavm golden mesh, made by tools/make_golden_inputs.py\n")
    f.write("element vertex %d\nproperty float x\nproperty float y\nproperty float z\n" % len(verts))
    f.write("element face %d\nproperty list uchar int vertex_indices\nend_header\n" % len(faces))
    for v in verts:
        f.write("%.6f %.6f %.6f\n" % tuple(v))
    for p in faces:
        f.write("%d %s\n" % (len(p), " ".join(str(i) for i in p)))

# ---- rays -----------------------------------------------------------------------------------

lo = [min(v[k] for v in verts) for k in range(3)]
hi = [max(v[k] for v in verts) for k in range(3)]
centre = [(lo[k] + hi[k]) / 2.0 for k in range(3)]
diag = sum((hi[k] - lo[k]) ** 2 for k in range(3)) ** 0.5
INF = float("inf")
NAN = float("nan")
rays = []  # (origin, tmin, dir, tmax)


def ray(o, d, tmin=0.0, tmax=INF):
    rays.append((list(o), tmin, list(d), tmax))


def towards(o, target):
    return [target[k] - o[k] for k in range(3)]


# 1. Random: origins in the bounds enlarged by 10 % of the diagonal, directions uniform.
rng = SplitMix64(20260301)
pad = 0.1 * diag
for _ in range(192):
    ray([rng.uniform(lo[k] - pad, hi[k] + pad) for k in range(3)], rng.unit_vector())

# 2. Random rays cut short: tmin > 0 and finite tmax (any-hit and closest-hit answers differ
#    from the unbounded ray's), directions not unit length.
for _ in range(64):
    o = [rng.uniform(lo[k] - pad, hi[k] + pad) for k in range(3)]
    s = rng.uniform(0.25, 4.0)
    d = [c * s for c in rng.unit_vector()]
    tmin = rng.uniform(0.0, 0.5) / s
    ray(o, d, tmin, tmin + rng.uniform(0.0, 2.0 * diag) / s)

# 3. Aimed from far away at vertices, edge midpoints and centroids of every piece: hits on
#    shared vertices and edges, where a non-watertight test would let the ray through.
tri_list = list(triangles)
for i in range(96):
    t = tri_list[rng.next_u64() % len(tri_list)]
    a, b, c = (verts[j] for j in t)
    kind = i % 3
    if kind == 0:
        target = a
    elif kind == 1:
        target = [(a[k] + b[k]) / 2.0 for k in range(3)]
    else:
        target = [(a[k] + b[k] + c[k]) / 3.0 for k in range(3)]
    u = rng.unit_vector()
    o = [centre[k] + 1.5 * diag * u[k] for k in range(3)]
    ray(o, towards(o, target))

# 4. Axis-parallel rays from each side of the bounds on a grid through exact planes of the box,
#    the floor, the pentagon and the centre (multiples of 1/4, some on faces and edges).
grid = [-2.0, -1.25, -0.5, 0.0, 0.25, 0.5, 1.5, 2.25]
far = 8.0
for axis in range(3):
    u, v = [k for k in range(3) if k != axis]
    for sign in (1.0, -1.0):
        for i, gu in enumerate(grid):
            for j, gv in enumerate(grid):
                if (i + j + axis) % 2:  # a checkerboard: half the grid, 32 per direction
                    continue
                o = [0.0, 0.0, 0.0]
                o[axis], o[u], o[v] = -sign * far, gu, gv
                d = [0.0, 0.0, 0.0]
                d[axis] = sign
                ray(o, d)

# 5. Grazing: in the floor's plane, along the box's edges and in the planes of its faces,
#    tangent to the spheres, through the rim of the hole.
for i in range(8):
    u = rng.unit_vector()
    ray([u[0] * 5.0, -1.25, u[2] * 5.0], [-u[0], 0.0, -u[2]])        # in the floor's plane
ray([x0, y0, -5.0], [0.0, 0.0, 1.0])                                 # along box edges
ray([x1, y1, 5.0], [0.0, 0.0, -1.0])
ray([-5.0, y1, z1], [1.0, 0.0, 0.0])
ray([x0, 5.0, z0], [0.0, -1.0, 0.0])
ray([x0, -0.125, -5.0], [0.0, 0.0, 1.0])                             # in the plane of a face
ray([1.875, y1, -5.0], [0.0, 0.0, 1.0])
ray([-2.0, -0.25, -5.0], [0.0, 0.0, 1.0])                            # in the pentagon's plane
for r, c in ((1.0, (0.0, 0.0, 0.0)), (0.3, (0.0, 0.0, 0.0)), (0.1, (-1.5, 0.75, 1.0))):
    for k in range(3):                       # tangent to each sphere (A: through a vertex)
        o = list(c)
        o[k] += r
        o[(k + 1) % 3] -= 5.0
        d = [0.0, 0.0, 0.0]
        d[(k + 1) % 3] = 1.0
        ray(o, d)
for i in range(12):                                                  # through the hole's rim
    u = rng.unit_vector()
    target = [0.43 * u[0], 0.43 * u[1], 0.9]
    o = [target[0] * 0.2, target[1] * 0.2, 6.0]
    ray(o, towards(o, target))

# 6. From inside: between the two shells, inside the inner one, from a vertex of the box.
for i in range(24):
    o = [0.0, 0.0, 0.6] if i < 12 else [0.05, -0.05, 0.0]
    ray(o, rng.unit_vector())
ray([x0, y0, z0], [1.0, 1.0, 1.0])
ray([x0, y0, z0], [-1.0, -1.0, -1.0])

# 7. At the degenerate triangles (never hit), and ending just short of, or starting just past,
#    the first hit along the axis through the hole (on the inner sphere B, found here in f64).
ray([0.75, 1.5, 5.0], [0.0, 0.0, -1.0])
ray([0.6, 1.5, 5.0], [0.0, 0.0, -1.0])


def hit_t(o, d, tri):
    """Moller-Trumbore in f64: t of the hit of o + t d on triangle tri, or None."""
    a, b, c = (verts[j] for j in tri)
    e1 = [b[k] - a[k] for k in range(3)]
    e2 = [c[k] - a[k] for k in range(3)]
    p = [d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2], d[0] * e2[1] - d[1] * e2[0]]
    det = sum(e1[k] * p[k] for k in range(3))
    if det == 0.0:
        return None
    s = [o[k] - a[k] for k in range(3)]
    u = sum(s[k] * p[k] for k in range(3)) / det
    qv = [s[1] * e1[2] - s[2] * e1[1], s[2] * e1[0] - s[0] * e1[2], s[0] * e1[1] - s[1] * e1[0]]
    v = sum(d[k] * qv[k] for k in range(3)) / det
    t = sum(e2[k] * qv[k] for k in range(3)) / det
    return t if u >= 0.0 and v >= 0.0 and u + v <= 1.0 and t >= 0.0 else None


axis_o, axis_d = [0.01, 0.02, 5.0], [0.0, 0.0, -1.0]  # off the axis: no vertex or edge of B there
first = min(t for t in (hit_t(axis_o, axis_d, tri) for tri in triangles) if t is not None)
ray(axis_o, axis_d, 0.0, first - 1e-3)   # ends just short: a miss, not occluded
ray(axis_o, axis_d, 0.0, first + 1e-3)   # ends just past: hits at first
ray(axis_o, axis_d, first + 1e-3, INF)   # starts just past: the next surface (B's back)
ray(axis_o, [0.0, 0.0, -2.0], 0.0, (first + 1e-3) / 2.0)  # the same with a direction of length 2

# 8. Rays that hit nothing by RAYS.md's rules: non-finite, zero direction, tmin > tmax.
ray([NAN, 0.0, 0.0], [1.0, 0.0, 0.0])
ray([0.0, 0.0, 5.0], [0.0, 0.0, 0.0])
ray([0.0, 0.0, 5.0], [0.0, INF, -1.0])
ray([0.0, 0.0, 5.0], [0.0, 0.0, -1.0], 2.0, 1.0)
ray([0.0, 0.0, 5.0], [0.0, 0.0, -1.0], NAN, INF)
ray([INF, 0.0, 0.0], [-1.0, 0.0, 0.0])

out = bytearray(b"RAYS" + struct.pack("<IQ", 1, len(rays)))
for o, tmin, d, tmax in rays:
    out += struct.pack("<8f", o[0], o[1], o[2], tmin, d[0], d[1], d[2], tmax)
with open(os.path.join(out_dir, "rays.rays"), "wb") as f:
    f.write(out)

print("mesh.ply: %d vertices, %d faces, %d triangles; pieces (first face, faces): %s"
      % (len(verts), len(faces), len(triangles), pieces))
print("rays.rays: %d rays" % len(rays))
