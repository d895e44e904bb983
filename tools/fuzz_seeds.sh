#!/usr/bin/env bash
# Writes the seed inputs of every fuzz target into fuzz/work/seeds/<target>/ (not committed: the
# committed corpus, fuzz/corpus/<target>/, is what fuzzing kept of them, minimised).
#
#   tools/fuzz_seeds.sh
#
# Meshes are cut from ../shared/scenes or written by hand (tools/fuzz_seeds.py); ray, hit and
# occlusion files and the .oavm files are made by the project's own release binaries from those
# cuts. Each .oavm seed stays under 24 KB (fuzz.sh's -max_len for the oavm targets is 32768):
# small inputs mutate faster and keep the committed corpus small; several blocks (4 KiB target
# size), compressed and raw, deep trees and unmerged volumes fit in that. Both kinds of solid
# leaf (format-spec.md §2 flag CLUSTERS): clusters, the default (§7.1, §7.2), and leaf lists
# (`--leaf list`, §6, §7; the seeds named *_list); files with the primitive table (*_upd, §8.6)
# and of generation 2 (*_gen2, §2.1: updated in place by oavm-update). Format version 7; the
# seeds of clusters cut their groups into chunks of 8 (§8.3), so that blocks have several
# (but for the deep one and the updated one, in the default chunks, to stay under 24 KB).
#
# The binaries are built in $CARGO_TARGET_DIR if it is set (else target/).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
scenes=$root/../shared/scenes
seeds=$root/fuzz/work/seeds
rm -rf "$seeds"
mkdir -p "$seeds"/{ply,obj,aff,rays,oavm,oavm_fixed,pack}
python3 tools/fuzz_seeds.py meshes "$scenes" "$seeds"

nice -n 19 cargo build --release --quiet --bins --features tools --example rays
bin=${CARGO_TARGET_DIR:-$root/target}/release
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

python3 tools/fuzz_seeds.py cuts "$scenes" "$tmp"
cp "$seeds/ply/dragon60_ascii.ply" "$tmp/dragon60.ply"
# pack builds PLY meshes: the PLY seeds and the cuts.
cp "$seeds"/ply/* "$tmp"/dragon20.ply "$tmp"/dragon200.ply "$seeds/pack/"
cp "$scenes/cornell_box/CornellBox-Original.obj" "$tmp/cornell.obj"
cp "$seeds/aff/museum_block.aff" "$seeds/aff/keys_only.aff" "$tmp/"

# Ray files: random, primary and shadow rays of a small mesh; hits and occlusion answers of them.
(cd "$tmp" && "$bin/examples/rays" dragon60.ply dragon --random 16 --width 4 --height 3 >/dev/null)
for s in random primary shadow; do
    cp "$tmp/dragon.$s.rays" "$seeds/rays/"
done
printf 'RAYS\1\0\0\0\0\0\0\0\0\0\0\0' >"$seeds/rays/empty.rays"

pack() { # NAME MESH ARGS...
    local name=$1 mesh=$2
    shift 2
    "$bin/oavm-pack" "$tmp/$mesh" "$tmp/$name.oavm" --threads 1 --chunk-groups "${CG:-8}" "$@" >/dev/null
}
# Clusters. A cluster holds up to 512 triangles by default, so a cut of the dragon is one leaf
# (one wide BVH several nodes deep: dragon200_z); the seeds that want several leaves and blocks
# give a smaller leaf size (clusters of 4 make the 60 triangles 28 KB: 8 is the smallest under
# 24 KB).
pack cornell cornell.obj
pack cornell_z cornell.obj --compress
pack dragon200_z dragon200.ply --compress=1
pack dragon60_4k dragon60.ply --block-size 4K --leaf-size 32
pack dragon200_4k_z dragon200.ply --block-size 4K --leaf-size 32 --compress=1
CG=128 pack dragon20_deep_z dragon20.ply --leaf-size 3 --max-depth 7 --block-size 4K --compress
pack dragon60_leaf8_z dragon60.ply --leaf-size 8 --max-depth 6 --block-size 4K --compress
pack dragon20_nomerge_z dragon20.ply --block-size 4K --no-merge --leaf-size 4 --compress
pack museum_block museum_block.aff --block-size 4K
pack keys_t keys_only.aff --time 0.5
# Leaf lists: the seeds of format 3, with the options they had.
pack cornell_list cornell.obj --leaf list
pack cornell_z_list cornell.obj --leaf list --compress
pack dragon60_4k_list dragon60.ply --leaf list --block-size 4K
pack dragon200_4k_z_list dragon200.ply --leaf list --block-size 4K --compress=1
pack dragon20_deep_z_list dragon20.ply --leaf list --leaf-size 3 --max-depth 8 --block-size 4K --compress
pack dragon60_leaf4_z_list dragon60.ply --leaf list --leaf-size 4 --max-depth 6 --block-size 4K --compress
pack dragon20_nomerge_z_list dragon20.ply --leaf list --block-size 4K --no-merge --leaf-size 4 --compress
pack museum_block_list museum_block.aff --leaf list --block-size 4K
pack keys_t_list keys_only.aff --leaf list --time 0.5
# With the primitive table (`--updatable`, format-spec.md §8.6: chunks after the blocks, a last
# section); and small compressed ones updated in place by oavm-update to the cut with 6 faces
# removed and one moved (tools/fuzz_seeds.py moved): generation 2, in header slot 1, its data
# region holding generation 1's blocks and sections as well as its own (§2.1). An update
# appends from the next multiple of 4096, so generation 2 of dragon60_4k_upd would be 40 KB.
pack dragon60_4k_upd dragon60.ply --block-size 4K --leaf-size 32 --updatable
pack dragon60_4k_upd_list dragon60.ply --leaf list --block-size 4K --updatable
python3 tools/fuzz_seeds.py moved "$tmp/dragon20.ply" "$tmp/dragon20_moved.ply"
CG=128 pack dragon20_upd_z dragon20.ply --block-size 4K --leaf-size 4 --updatable --compress=1
pack dragon20_upd_z_list dragon20.ply --leaf list --block-size 4K --leaf-size 4 --updatable \
    --compress=1
for s in dragon20_upd_z dragon20_upd_z_list; do
    cp "$tmp/$s.oavm" "$tmp/${s}_gen2.oavm"
    "$bin/oavm-update" "$tmp/${s}_gen2.oavm" "$tmp/dragon20_moved.ply" --block-size 4096 \
        --threads 1 >/dev/null
done
over=0
for f in "$tmp"/*.oavm; do
    size=$(stat -c %s "$f")
    if [ "$size" -gt 24576 ]; then
        echo "fuzz_seeds.sh: $(basename "$f") is $size bytes, over 24 KB" >&2
        over=1
    fi
    cp "$f" "$seeds/oavm/"
    cp "$f" "$seeds/oavm_fixed/"
done
[ "$over" = 0 ] || exit 1
for s in primary random; do
    "$bin/oavm-trace" "$tmp/dragon60_4k.oavm" --rays "$tmp/dragon.$s.rays" \
        --hits "$seeds/rays/dragon.$s.hits" >/dev/null
    "$bin/oavm-trace" "$tmp/dragon60_4k.oavm" --rays "$tmp/dragon.$s.rays" \
        --occluded "$seeds/rays/dragon.$s.occl" >/dev/null
done

# Raw files with every block marked zstd, for oavm_fixed (see zmark in tools/fuzz_seeds.py). They
# are not compressed: dragon20_nomerge's clusters are of 8 (of 4, as in dragon20_nomerge_z, the
# file is 38 KB, past fuzz.sh's -max_len).
pack dragon200_4k dragon200.ply --block-size 4K --leaf-size 32
pack dragon20_nomerge dragon20.ply --block-size 4K --no-merge --leaf-size 8
pack dragon200_4k_list dragon200.ply --leaf list --block-size 4K
pack dragon20_nomerge_list dragon20.ply --leaf list --block-size 4K --no-merge --leaf-size 4
python3 tools/fuzz_seeds.py zmark "$seeds/oavm_fixed" \
    "$tmp"/cornell.oavm "$tmp"/dragon200_4k.oavm "$tmp"/museum_block.oavm "$tmp"/dragon20_nomerge.oavm \
    "$tmp"/cornell_list.oavm "$tmp"/dragon200_4k_list.oavm "$tmp"/museum_block_list.oavm \
    "$tmp"/dragon20_nomerge_list.oavm "$tmp"/dragon60_4k_upd.oavm "$tmp"/dragon60_4k_upd_list.oavm

for t in "$seeds"/*; do
    printf '%-11s %3d files %7d bytes\n' "$(basename "$t")" "$(ls "$t" | wc -l)" "$(cat "$t"/* | wc -c)"
done
