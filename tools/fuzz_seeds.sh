#!/usr/bin/env bash
# Writes the seed inputs of every fuzz target into fuzz/work/seeds/<target>/ (not committed: the
# committed corpus, fuzz/corpus/<target>/, is what fuzzing kept of them, minimised).
#
#   tools/fuzz_seeds.sh
#
# Meshes are cut from ../shared/scenes (tools/fuzz_seeds.py); ray, hit and occlusion files and
# the .oavm files are made by the project's own release binaries from those cuts: each .oavm seed
# stays under ~100 KB (fuzz.sh's -max_len for the oavm targets is 131072).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
scenes=$root/../shared/scenes
seeds=$root/fuzz/work/seeds
rm -rf "$seeds"
mkdir -p "$seeds"/{ply,obj,aff,rays,oavm,oavm_fixed}
python3 tools/fuzz_seeds.py "$scenes" "$seeds"

nice -n 19 cargo build --release --quiet --bins --example rays
bin=$root/target/release
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# A bigger cut of the bunny, for files of several blocks.
python3 - "$scenes" "$tmp" <<'EOF'
import sys
scenes, tmp = sys.argv[1], sys.argv[2]
text = open(f"{scenes}/bunny/bun_zipper.ply").read()
head, body = text.split("end_header\n", 1)
rows = body.splitlines()
nv = 35947
verts, faces = rows[:nv], [list(map(int, r.split()[1:])) for r in rows[nv:]]
faces = faces[:600]
used = {}
for f in faces:
    for i in f:
        used.setdefault(i, len(used))
order = sorted(used, key=used.get)
out = ["ply", "format ascii 1.0", f"element vertex {len(order)}", "property float x",
       "property float y", "property float z", f"element face {len(faces)}",
       "property list uchar int vertex_indices", "end_header"]
out += [" ".join(verts[i].split()[:3]) for i in order]
out += ["3 " + " ".join(str(used[i]) for i in f) for f in faces]
open(f"{tmp}/bunny600.ply", "w").write("\n".join(out) + "\n")
EOF
cp "$seeds/ply/dragon60_ascii.ply" "$tmp/dragon60.ply"
cp "$scenes/cornell_box/CornellBox-Original.obj" "$tmp/cornell.obj"
cp "$seeds/aff/museum_block.aff" "$seeds/aff/keys_only.aff" "$tmp/"

# Ray files: random, primary and shadow rays of a small mesh; hits and occlusion answers of them.
(cd "$tmp" && "$bin/examples/rays" dragon60.ply dragon --random 16 --width 4 --height 3 >/dev/null)
pack() { # NAME MESH ARGS...
    local name=$1 mesh=$2
    shift 2
    "$bin/oavm-pack" "$tmp/$mesh" "$tmp/$name.oavm" --threads 1 "$@" >/dev/null
}
pack cornell cornell.obj
pack cornell_z cornell.obj --compress
pack dragon60_4k dragon60.ply --block-size 4K
pack dragon60_leaf2 dragon60.ply --leaf-size 2 --max-depth 6 --block-size 16K
pack dragon60_leaf1_z dragon60.ply --leaf-size 1 --max-depth 7 --compress
pack bunny600_4k bunny600.ply --block-size 4K
pack bunny600_4k_z bunny600.ply --block-size 4K --compress=1
pack dragon60_nomerge dragon60.ply --block-size 4K --no-merge --leaf-size 4
pack museum_block museum_block.aff --block-size 4K
pack keys_t keys_only.aff --time 0.5
for s in random primary shadow; do
    cp "$tmp/dragon.$s.rays" "$seeds/rays/"
done
for s in primary random; do
    "$bin/oavm-trace" "$tmp/dragon60_4k.oavm" --rays "$tmp/dragon.$s.rays" \
        --hits "$seeds/rays/dragon.$s.hits" >/dev/null
    "$bin/oavm-trace" "$tmp/dragon60_4k.oavm" --rays "$tmp/dragon.$s.rays" \
        --occluded "$seeds/rays/dragon.$s.occl" >/dev/null
done
printf 'RAYS\1\0\0\0\0\0\0\0\0\0\0\0' >"$seeds/rays/empty.rays"

for f in "$tmp"/*.oavm; do
    size=$(stat -c %s "$f")
    if [ "$size" -gt 102400 ]; then
        echo "fuzz_seeds.sh: $(basename "$f") is $size bytes, over 100 KB" >&2
        exit 1
    fi
    cp "$f" "$seeds/oavm/"
    cp "$f" "$seeds/oavm_fixed/"
done
# For oavm_fixed: raw files whose blocks are all marked zstd (codec 1) and the header flagged
# COMPRESSED; the target's fix-up compresses such blocks before opening (fuzz/targets.rs,
# fix_checksums), so mutations reach the decoded contents of compressed blocks.
python3 - "$seeds/oavm_fixed" "$tmp"/cornell.oavm "$tmp"/bunny600_4k.oavm "$tmp"/museum_block.oavm <<'EOF'
import os, struct, sys
out = sys.argv[1]
for path in sys.argv[2:]:
    b = bytearray(open(path, "rb").read())
    flags = struct.unpack_from("<I", b, 12)[0]
    struct.pack_into("<I", b, 12, flags | 2)            # §2 flags: COMPRESSED
    dir_off, dir_len = struct.unpack_from("<QQ", b, 256 + 48 + 8)  # §3 entry 1: directory
    for e in range(dir_off, dir_off + dir_len, 48):
        struct.pack_into("<I", b, e + 24, 1)            # §8.2 codec: zstd
    name = os.path.basename(path).replace(".oavm", "_zmark.oavm")
    open(os.path.join(out, name), "wb").write(b)
EOF
for t in "$seeds"/*; do
    printf '%-11s %3d files %7d bytes\n' "$(basename "$t")" "$(ls "$t" | wc -l)" "$(cat "$t"/* | wc -c)"
done
