#!/usr/bin/env python3
"""Makes data/bunny.ply, the project's bundled mesh, from the Stanford bunny.

Reads ../shared/scenes/bunny/bun_zipper.ply (ascii; x y z confidence intensity per vertex) and
writes the same vertices (x y z only) and faces as binary little-endian PLY. The geometry is
unchanged: the f32 values parsed from the ascii text are written as they are.

    python3 tools/make_bundled_bunny.py [SRC] [DST]
"""
import struct
import sys

src = sys.argv[1] if len(sys.argv) > 1 else "../shared/scenes/bunny/bun_zipper.ply"
dst = sys.argv[2] if len(sys.argv) > 2 else "data/bunny.ply"

with open(src) as f:
    lines = f.read().splitlines()
end = lines.index("end_header")
header = lines[:end]
nv = next(int(l.split()[2]) for l in header if l.startswith("element vertex"))
nf = next(int(l.split()[2]) for l in header if l.startswith("element face"))
body = lines[end + 1:]
verts = [tuple(float(x) for x in body[i].split()[:3]) for i in range(nv)]
faces = [tuple(int(x) for x in body[nv + i].split()) for i in range(nf)]

out = bytearray()
out += (
    "ply\nformat binary_little_endian 1.0\n"
    "comment Stanford Bunny, Stanford University Computer Graphics Laboratory\n"
    "comment converted from bun_zipper.ply by tools/make_bundled_bunny.py\n"
    f"element vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
    f"element face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
).encode()
for v in verts:
    out += struct.pack("<3f", *v)
for fc in faces:
    n = fc[0]
    assert n == len(fc) - 1
    out += struct.pack("<B", n) + struct.pack(f"<{n}i", *fc[1:])
with open(dst, "wb") as f:
    f.write(out)
print(f"{dst}: {nv} vertices, {nf} faces, {len(out)} bytes")
