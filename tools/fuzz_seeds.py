#!/usr/bin/env python3
"""Seed inputs of the fuzz targets, for tools/fuzz_seeds.sh.

    tools/fuzz_seeds.py meshes SCENES OUT    mesh seeds cut from the scenes or written by hand,
                                             into OUT/ply, OUT/obj, OUT/aff
    tools/fuzz_seeds.py cuts SCENES DIR      DIR/dragon20.ply, DIR/dragon200.ply: the first 20
                                             and 200 triangles of the dragon, to pack
    tools/fuzz_seeds.py zmark OUT FILE...    for each raw .oavm FILE, OUT/<name>_zmark.oavm
                                             (see zmark below)
    tools/fuzz_seeds.py moved IN OUT         the ascii PLY IN with its last 6 faces dropped
                                             and its first face's corners moved a tenth of
                                             the way to the mesh's centre: what oavm-update
                                             makes generation 2 of a seed from

SCENES is ../shared/scenes. The ray files and .oavm seeds are made by the project's own binaries
(tools/fuzz_seeds.sh). Seeds are small on purpose: libFuzzer mutates small inputs much faster,
and the parsers' paths do not depend on a file's length.
"""

import os
import re
import struct
import sys



def dragon_cuts(scenes, out):
    text = open(f"{scenes}/dragon/dragon_vrip_res4.ply").read()
    head, body = text.split("end_header\n", 1)
    rows = body.splitlines()
    nv = int(re.search(r"element vertex (\d+)", head).group(1))
    verts, faces = rows[:nv], [list(map(int, r.split()[1:])) for r in rows[nv:]]
    for n in (20, 200):
        part = faces[:n]
        used = {}
        for f in part:
            for i in f:
                used.setdefault(i, len(used))
        order = sorted(used, key=used.get)
        lines = ["ply", "format ascii 1.0", f"element vertex {len(order)}", "property float x",
                 "property float y", "property float z", f"element face {len(part)}",
                 "property list uchar int vertex_indices", "end_header"]
        lines += [verts[i].strip() for i in order]
        lines += ["3 " + " ".join(str(used[i]) for i in f) for f in part]
        with open(f"{out}/dragon{n}.ply", "w") as fh:
            fh.write("\n".join(lines) + "\n")


def zmark(out, paths):
    """Raw .oavm files with every block marked zstd (codec 1) and the header flagged COMPRESSED.

    The oavm_fixed target's fix-up compresses such blocks before opening (fuzz/targets.rs,
    fix_checksums), so mutations reach the decoded contents of compressed blocks. Laid out again
    (format-spec.md version 7, §2, §3, §8.2, §8.6) with every block, primitive chunk and section
    at the next multiple of 64 (what §8.2 asks of compressed blocks), not of 4096, to keep them
    small: header slot 0, slot 1 (zero: generation 1 only), the data region from 4096 (the
    blocks in directory order, then the primitive chunks, if the file has the table), ending at
    the next multiple of 64, where the directory starts, then the other sections in table
    order; the fix-up recomputes the checksums."""
    up = lambda x: (x + 63) // 64 * 64
    entry = lambda i: 256 + 48 * i  # §3: section entry i of slot 0
    for path in paths:
        with open(path, "rb") as fh:
            b = fh.read()
        assert not any(b[2048:4096]), f"{path}: zmark lays out files of generation 1"
        flags = struct.unpack_from("<I", b, 12)[0]
        kinds = (list(range(1, 8)) + [10, 11] * bool(flags & 4) + [8] * bool(flags & 8)
                 + [9] * bool(flags & 32))
        sec = [struct.unpack_from("<QQ", b, entry(i) + 8) for i in range(len(kinds))]
        new = bytearray(b[:4096])
        struct.pack_into("<I", new, 12, flags | 2)  # §2: COMPRESSED
        directory = bytearray(b[sec[1][0]:sec[1][0] + sec[1][1]])
        for e in range(0, len(directory), 64):  # §8.2: each block, 64-aligned
            off, stored = struct.unpack_from("<QQ", directory, e)
            new += bytes(up(len(new)) - len(new))
            struct.pack_into("<Q", directory, e, len(new))
            struct.pack_into("<I", directory, e + 24, 1)  # codec: zstd
            new += b[off:off + stored]
        chunks = bytearray()
        if 9 in kinds:  # §8.6: each chunk of 36-byte records, 64-aligned
            at, length = sec[kinds.index(9)]
            chunks = bytearray(b[at:at + length])
            for e in range(0, len(chunks), 32):
                off, count = struct.unpack_from("<QQ", chunks, e)
                new += bytes(up(len(new)) - len(new))
                struct.pack_into("<Q", chunks, e, len(new))
                new += b[off:off + 36 * count]
        new += bytes(up(len(new)) - len(new))  # §3: the directory starts where the region ends
        struct.pack_into("<QQ", new, entry(0) + 8, 4096, len(new) - 4096)
        for i, kind in enumerate(kinds[1:], start=1):
            new += bytes(up(len(new)) - len(new))
            struct.pack_into("<Q", new, entry(i) + 8, len(new))
            new += {2: directory, 9: chunks}.get(kind, b[sec[i][0]:sec[i][0] + sec[i][1]])
        struct.pack_into("<Q", new, 32, len(new))  # §2: file_size
        name = os.path.basename(path).replace(".oavm", "_zmark.oavm")
        with open(os.path.join(out, name), "wb") as fh:
            fh.write(new)


def moved(src, dst):
    """See the module's documentation: the new geometry of an update of a seed."""
    with open(src) as fh:
        head, body = fh.read().split("end_header\n", 1)
    nv = int(re.search(r"element vertex (\d+)", head).group(1))
    nf = int(re.search(r"element face (\d+)", head).group(1))
    rows = body.splitlines()
    verts = [[float(x) for x in r.split()] for r in rows[:nv]]
    faces = rows[nv:nv + nf - 6]
    centre = [sum(v[k] for v in verts) / nv for k in range(3)]
    for i in map(int, faces[0].split()[1:]):
        verts[i] = [c + (m - c) / 10 for c, m in zip(verts[i], centre)]
    head = re.sub(r"element face \d+", f"element face {len(faces)}", head)
    with open(dst, "w") as fh:
        fh.write(head + "end_header\n")
        fh.write("".join(" ".join(repr(c) for c in v) + "\n" for v in verts))
        fh.write("".join(f + "\n" for f in faces))


if sys.argv[1] == "cuts":
    dragon_cuts(sys.argv[2], sys.argv[3])
    sys.exit(0)
if sys.argv[1] == "zmark":
    zmark(sys.argv[2], sys.argv[3:])
    sys.exit(0)
if sys.argv[1] == "moved":
    moved(sys.argv[2], sys.argv[3])
    sys.exit(0)
assert sys.argv[1] == "meshes", __doc__
SCENES, OUT = sys.argv[2], sys.argv[3]


def write(target, name, data):
    d = os.path.join(OUT, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


# --- PLY -------------------------------------------------------------------------------------


def read_ascii_ply(path):
    """Header lines, vertex rows (lists of floats) and faces (lists of ints) of an ascii PLY."""
    with open(path, "rb") as f:
        text = f.read().decode()
    head, body = text.split("end_header\n", 1)
    lines = head.splitlines()
    nv = int(re.search(r"element vertex (\d+)", head).group(1))
    nf = int(re.search(r"element face (\d+)", head).group(1))
    rows = body.splitlines()
    verts = [[float(x) for x in r.split()] for r in rows[:nv]]
    faces = [[int(x) for x in r.split()[1:]] for r in rows[nv:nv + nf]]
    return lines, verts, faces


def cut(verts, faces, count):
    """The first `count` faces and the vertices they use, renumbered in order of first use."""
    faces = faces[:count]
    used = {}
    for f in faces:
        for i in f:
            used.setdefault(i, len(used))
    order = sorted(used, key=used.get)
    return [verts[i] for i in order], [[used[i] for i in f] for f in faces]


def ply_header(fmt, props, nv, nf, extra=""):
    h = ["ply", f"format {fmt} 1.0", "comment cut for fuzzing", f"element vertex {nv}"]
    h += [f"property {t} {n}" for t, n in props]
    h += [f"element face {nf}", "property list uchar int vertex_indices"]
    if extra:
        h.append(extra)
    h.append("end_header")
    return ("\n".join(h) + "\n").encode()


def ply_ascii(props, verts, faces):
    out = ply_header("ascii", props, len(verts), len(faces))
    body = "".join(" ".join(repr(x) if isinstance(x, float) else str(x) for x in v) + "\n"
                   for v in verts)
    body += "".join(f"{len(f)} " + " ".join(map(str, f)) + "\n" for f in faces)
    return out + body.encode()


def ply_binary(props, verts, faces, big):
    e = ">" if big else "<"
    fmt = "binary_big_endian" if big else "binary_little_endian"
    out = bytearray(ply_header(fmt, props, len(verts), len(faces)))
    codes = {"float": "f", "double": "d", "uchar": "B", "int": "i", "short": "h"}
    vfmt = e + "".join(codes[t] for t, _ in props)
    for v in verts:
        out += struct.pack(vfmt, *[int(x) if codes[t] in "Bih" else x
                                   for x, (t, _) in zip(v, props)])
    for f in faces:
        out += struct.pack(e + "B" + "i" * len(f), len(f), *f)
    return bytes(out)


bunny_lines, bunny_v, bunny_f = read_ascii_ply(f"{SCENES}/bunny/bun_zipper.ply")
bunny_props = [("float", "x"), ("float", "y"), ("float", "z"), ("float", "confidence"),
               ("float", "intensity")]
dragon_lines, dragon_v, dragon_f = read_ascii_ply(f"{SCENES}/dragon/dragon_vrip_res4.ply")
xyz = [("float", "x"), ("float", "y"), ("float", "z")]

v, f = cut(bunny_v, bunny_f, 40)
write("ply", "bunny40_ascii.ply", ply_ascii(bunny_props, v, f))
write("ply", "bunny40_le.ply", ply_binary(bunny_props, v, f, big=False))
v, f = cut(dragon_v, dragon_f, 60)
write("ply", "dragon60_ascii.ply", ply_ascii(xyz, v, f))
write("ply", "dragon60_be.ply", ply_binary(xyz, v, f, big=True))
write("ply", "dragon60_le.ply", ply_binary(xyz, v, f, big=False))
dv = [[float(c) for c in p] for p in v]
write("ply", "dragon60_double_le.ply",
      ply_binary([("double", "x"), ("double", "y"), ("double", "z")], dv, f, big=False))
# The header alone of the whole bunny (counts that the body does not back).
with open(f"{SCENES}/bunny/bun_zipper.ply", "rb") as fh:
    write("ply", "bunny_header_only.ply", fh.read().split(b"end_header\n", 1)[0] + b"end_header\n")
write("ply", "quads_ascii.ply", """ply
format ascii 1.0
comment quads, a pentagon, a degenerate face and a two-corner face
obj_info hand-written
element vertex 6
property float32 x
property float32 y
property float32 z
property uint8 red
element face 4
property list uint8 uint32 vertex_index
element edge 1
property int vertex1
property int vertex2
end_header
0 0 0 255
1 0 0 0
1 1 0 0
0 1 0 0
0.5 2 0.5 7
0 0 1 1
4 0 1 2 3
5 0 1 2 4 3
3 0 0 0
2 1 5
0 1
""")
write("ply", "crlf_types.ply", (
    "ply\r\nformat ascii 1.0\r\nelement vertex 3\r\nproperty double x\r\nproperty double y\r\n"
    "property double z\r\nproperty short s\r\nproperty ushort us\r\nproperty char c\r\n"
    "element face 1\r\nproperty uchar flags\r\nproperty list ushort short vertex_indices\r\n"
    "property list uchar float texcoord\r\nend_header\r\n"
    "0 0 0 -1 2 -3\r\n1e0 0 0 1 2 3\r\n0 1.5e-3 0 4 5 6\r\n9 3 0 1 2 2 0.5 0.5\r\n"))
write("ply", "face_first.ply", """ply
format ascii 1.0
element face 1
property list uchar int vertex_indices
element vertex 3
property float z
property float y
property float x
end_header
3 0 1 2
0 0 0
0 1 0
1 0 0
""")

# --- OBJ -------------------------------------------------------------------------------------

with open(f"{SCENES}/cornell_box/CornellBox-Original.obj", "rb") as fh:
    write("obj", "cornell_box.obj", fh.read())
with open(f"{SCENES}/sibenik/sibenik.obj") as fh:
    sib = fh.read().splitlines()
sv = [l for l in sib if l.startswith("v ")]
sf = [[int(x) - 1 for x in l.split()[1:]] for l in sib if l.startswith("f ")]
for name, first, count in [("sibenik_a.obj", 0, 120), ("sibenik_b.obj", 40000, 150)]:
    faces = sf[first:first + count]
    used = {}
    for fc in faces:
        for i in fc:
            used.setdefault(i, len(used))
    order = sorted(used, key=used.get)
    text = "# cut from sibenik.obj for fuzzing\n" + "".join(sv[i] + "\n" for i in order)
    text += "".join("f " + " ".join(str(used[i] + 1) for i in fc) + "\n" for fc in faces)
    write("obj", name, text)
write("obj", "forms.obj", """# every index form, groups, objects, materials, lines, points
mtllib missing.mtl
o first
v 0 0 0
v 1 0 0 1.0
v 1 1 0 0.5 0.5 0.5
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vn 0 0 1
g one two
usemtl red
f 1/1/1 2/2/1 3/3/1
f 1//1 3//1 4//1
s off
usemtl blue
f -4/-3 -3/-2 -2/-1 -1/-1
o second
v 0 0 1
l 1 2 3
p 4
f 5 1 2 3 4
f 1 2
g
f 1 2 3 4 5 -1
""")
write("obj", "continuation.obj", "v 0 0 0\nv 1 \\\n 0 0\nv 0 1 0\nf 1 2 \\\n 3\n")
write("obj", "crlf_negative.obj", "v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf -3 -2 -1\r\nf 1 2 3\r\n")

# --- AFF -------------------------------------------------------------------------------------

bart = f"{SCENES}/bart"
for rel in ["museum/block.aff", "museum/room.aff", "museum/paintings.aff", "museum/camera.aff",
            "kitchen/cupboard_door_large.aff", "kitchen/fridge_handle.aff", "kitchen/roof.aff",
            "robot/lu_leg.aff", "robot/color8.aff"]:
    with open(f"{bart}/{rel}", "rb") as fh:
        write("aff", rel.replace("/", "_"), fh.read())


def without_includes(path):
    with open(path) as fh:
        return "".join(l for l in fh if not re.match(r"\s*i\s", l))


write("aff", "museum5_no_includes.aff", without_includes(f"{bart}/museum/museum5.aff"))
write("aff", "kitchen_no_includes.aff", without_includes(f"{bart}/kitchen/kitchen.aff"))
write("aff", "robot_no_includes.aff", without_includes(f"{bart}/robot/Robot.aff"))
with open(f"{bart}/museum/animart5.aff") as fh:
    art = fh.read()
# The first few `tpa` statements of the animated art.
starts = [m.start() for m in re.finditer(r"(?m)^\s*tpa ", art)]
write("aff", "animart5_head.aff", art[:starts[4]])
write("aff", "statements.aff", """% every statement kind, by hand
b 0.1 0.2 0.3
v
from 0 1 -5
at 0 0 0
up 0 1 0
angle 45
hither 0.01
resolution 64 48
am 0.1 0.1 0.1
l 1 2 3
l 4 5 6 1 1 1
f 1 0 0 0.5 0.5 10 0 1
fm 0.1 0.1 0.1 0.5 0.5 0.5 0.2 0.2 0.2 10 0 1
a 0 2 20
d 1
i 2 not_included.aff
p 3 0 0 0 1 0 0 0 1 0
pp 4 0 0 0 0 0 1 1 0 0 0 0 1 1 1 0 0 0 1 0 1 0 0 0 1
tt tex.ppm 0 0 0 0 0 1 0 0 1 0 0 1 0 0 1
ttp tex.ppm 0 0 1 0 0 1 0 0  1 0 1 0 0 1 1 0  0 1 1 0 0 1 0 1
c 0 0 0 1 0 2 0 0.5
s 0 3 0 0.75
xs 2 2 2 0 1 0 30 1 2 3 {
  s 0 0 0 1
  xs 1 1 1 1 0 0 90 0 0 0 { p 3 0 0 0 1 0 0 0 1 0 }
}
x spin {
  m
  vertices 4
  0 0 0  1 0 0  1 1 0  0 1 0
  normals 4
  0 0 1  0 0 1  0 0 1  0 0 1
  texturecoords 4 t.ppm
  0 0  1 0  1 1  0 1
  triangles 2
  0 1 2  0 1 2  0 1 2
  0 2 3  0 2 3  0 2 3
}
k spin
{
  transl 4
  0 0 0 0  0 0 0
  1 1 0 0  0.5 0 0
  2 1 1 0  0 0.5 0
  3 0 1 1  0 0 0.5
  rot 4
  0 0 1 0 0    0 0 0
  1 0 1 0 90   0 0 0
  2 1 0 0 180  0 0 0
  3 0 0 1 -90  0 0 0
  scale 4
  0 1 1 1  0 0 0
  1 2 2 2  0 0 0
  2 1 1 1  0 0 0
  3 0.5 0.5 0.5 0 0 0
  visibility 3
  0 1
  1 0
  2 1
}
tpa 3
  0
  0 0 0 0 0 1  1 0 0 0 0 1  0 1 0 0 0 1
  1
  0 0 1 0 0 1  1 0 1 0 0 1  0 1 1 0 0 1
  2.5
  0 0 2 0 0 1  1 0 2 0 0 1  0 1 2 0 0 1
""")
write("aff", "keys_only.aff", """k camera {
transl 4
-1 0 0 -5 0 0 0
0 0 0 -4 1 -1 0.5
1 1 1 -3 0 0 0
2 2 0 -2 0 0 0
rot 4
-1 0 1 0 180 0 0 0
0 0 1 0 170 0 0 0
1 1 0 0 10 0 0 0
2 0 0 1 0 0 0 0
}
a -1 2 30
x camera { p 4 0 0 0 1 0 0 1 1 0 0 1 0 }
""")
