#!/usr/bin/env bash
# Digests of what the binaries produce, to show that a refactor changes no answer and no byte:
# packed files (every kind of file pack writes), the ray sets of the `rays` example, the HITS and
# OCCL answers of every walk and order (in memory and paged within a small budget), the walks'
# work counters, renders, an update and the comparison structures' answers. Run it with two
# builds and compare the outputs line by line:
#
#     tools/digests.sh --bin DIR_A --work /tmp/a > a.txt
#     tools/digests.sh --bin DIR_B --work /tmp/b > b.txt
#     diff a.txt b.txt              # empty: the same bytes and answers
#
# DIR holds oavm-pack, oavm-trace, oavm-update, oavm-inspect and the `rays` example (default:
# target/release, with examples/rays; build them with
# `cargo build --release --bins --examples --features oavm/tools`, which at the top of the workspace builds oavm-bench too, the binary of the crate oavm-compare);
# `--compare BIN` names oavm-bench (default: DIR/oavm-bench). The meshes come from
# ../shared/scenes (dragon, Sibenik, the BART kitchen) and data/bunny.ply (the streaming pack reads binary PLY). About five minutes on
# two cores; the work directory takes about 1.5 GB.
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
bin="$root/target/release"
work=""
bench=""
while [ $# -gt 0 ]; do
    case "$1" in
        --bin) bin="$(cd "$2" && pwd)"; shift 2 ;;
        --work) work="$2"; shift 2 ;;
        --compare) bench="$2"; shift 2 ;;
        *) echo "usage: tools/digests.sh [--bin DIR] [--work DIR] [--compare OAVM_BENCH]" >&2; exit 2 ;;
    esac
done
[ -n "$work" ] || work="$(mktemp -d)"
[ -n "$bench" ] || bench="$bin/oavm-bench"
rays_bin="$bin/examples/rays"
[ -x "$rays_bin" ] || rays_bin="$bin/rays"
scenes="$root/../shared/scenes"
for f in "$scenes/dragon/dragon_vrip.ply" "$scenes/sibenik/sibenik.obj" \
    "$scenes/bart/kitchen/kitchen.aff"; do
    [ -e "$f" ] || { echo "digests.sh: $f is missing (../shared/scenes)" >&2; exit 1; }
done
mkdir -p "$work"
cd "$work"

pack="$bin/oavm-pack"
trace="$bin/oavm-trace"
digest() { sha256sum "$1" | cut -c1-16; }
say() { printf '%-58s %s\n' "$1" "$2"; }
# The walk's counters of a --json report: those that do not depend on threads or timing.
counters() {
    python3 -c '
import json, sys
r = json.load(open(sys.argv[1]))
keys = ["rays", "hits", "occluded", "nodes_visited", "leaves_visited", "volumes_crossed",
        "leaves_culled", "links_culled", "top_nodes_culled", "triangles_tested",
        "clusters_entered", "cluster_nodes_visited", "boxes_tested", "groups_tested",
        "ropes_followed", "promoted_tested"]
print(" ".join(f"{k}={r[k]}" for k in keys if k in r))' "$1"
}

# Packs: every kind of file.
p() {
    local name=$1 mesh=$2
    shift 2
    "$pack" "$mesh" "$name.oavm" "$@" > /dev/null
    say "pack $name ($*)" "$(digest "$name.oavm")"
}
p dragon "$scenes/dragon/dragon_vrip.ply"
p dragon-list "$scenes/dragon/dragon_vrip.ply" --leaf list
p dragon-ropes "$scenes/dragon/dragon_vrip.ply" --ropes
p dragon-list-ropes "$scenes/dragon/dragon_vrip.ply" --leaf list --ropes
p dragon-occl "$scenes/dragon/dragon_vrip.ply" --occluders
p dragon-zstd "$scenes/dragon/dragon_vrip.ply" --compress --block-size 64K
p dragon-upd "$scenes/dragon/dragon_vrip.ply" --updatable
p sibenik "$scenes/sibenik/sibenik.obj"
p sibenik-list "$scenes/sibenik/sibenik.obj" --leaf list
p sibenik-occl "$scenes/sibenik/sibenik.obj" --occluders
p bunny "$root/data/bunny.ply"
p bunny-stream "$root/data/bunny.ply" --mem-budget 16M
p kitchen "$scenes/bart/kitchen/kitchen.aff"

# The ray sets.
for s in bunny:"$root/data/bunny.ply" dragon:"$scenes/dragon/dragon_vrip.ply" sibenik:"$scenes/sibenik/sibenik.obj" \
    kitchen:"$scenes/bart/kitchen/kitchen.aff"; do
    name=${s%%:*}
    "$rays_bin" "${s#*:}" "$name" > /dev/null
    for set in random primary shadow; do
        say "rays $name.$set" "$(digest "$name.$set.rays")"
    done
done

# Answers and counters: FILE RAYS-PREFIX TAG [trace options].
t() {
    local file=$1 prefix=$2 tag=$3
    shift 3
    for set in random primary; do
        "$trace" "$file.oavm" --rays "$prefix.$set.rays" --hits "$tag.$set.hits" --json "$@" \
            > "$tag.$set.json"
        say "hits $tag.$set" "$(digest "$tag.$set.hits") $(counters "$tag.$set.json")"
    done
    "$trace" "$file.oavm" --rays "$prefix.shadow.rays" --occluded "$tag.shadow.occl" --json "$@" \
        > "$tag.shadow.json"
    say "occl $tag.shadow" "$(digest "$tag.shadow.occl") $(counters "$tag.shadow.json")"
}
t dragon dragon dragon
t dragon dragon dragon-neighbours --walk neighbours
t dragon dragon dragon-topdown --walk topdown
t dragon dragon dragon-morton --order morton
t dragon dragon dragon-blocks --order blocks
t dragon dragon dragon-stream --order stream
t dragon dragon dragon-paged --mem-budget 8M --threads 2
t dragon dragon dragon-paged-none --mem-budget 8M --order none --block-reads read
t dragon dragon dragon-paged-map --mem-budget 8M --order morton --block-reads map
t dragon-list dragon dragon-list
t dragon-ropes dragon dragon-ropes --walk ropes
t dragon-list-ropes dragon dragon-list-ropes --walk ropes
t dragon-occl dragon dragon-occl
t dragon-zstd dragon dragon-zstd
t dragon-zstd dragon dragon-zstd-paged --mem-budget 6M
t dragon-upd dragon dragon-upd
t bunny bunny bunny
t bunny-stream bunny bunny-stream-packed
t sibenik sibenik sibenik
t sibenik sibenik sibenik-stream --order stream
t sibenik sibenik sibenik-neighbours --walk neighbours
t sibenik-list sibenik sibenik-list
t sibenik-occl sibenik sibenik-occl
t kitchen kitchen kitchen

# Frames (benchmark mode): a frame's primary and shadow rays, in waves and in one stream.
sets() {
    python3 -c '
import json, sys
r = json.load(open(sys.argv[1]))
print(" ".join(s["set"] + "=" + s["answers_xxh3"] for s in r["sets"]))' "$1"
}
for opts in "--wave 65536" "--wave 0" "--order stream" "--mem-budget 8M"; do
    # shellcheck disable=SC2086
    "$trace" dragon.oavm --primary 640x480 --shadow $opts --json > frame.json
    say "frame dragon $opts" "$(sets frame.json) $(counters frame.json)"
done
"$trace" dragon.oavm --random 200000 --seed 7 --json > random.json
say "random dragon --seed 7" "$(sets random.json) $(counters random.json)"

# Renders: the default picture, a shaded scene with its materials and lights.
"$trace" bunny.oavm -o bunny.png > /dev/null
say "render bunny" "$(digest bunny.png)"
"$trace" kitchen.oavm --view "$scenes/bart/kitchen/kitchen.aff" --shade --width 320 --height 240 \
    -o kitchen.png > /dev/null
say "render kitchen --shade 320x240" "$(digest kitchen.png)"

# An update in place, and its answers.
"$pack" "$scenes/bart/kitchen/kitchen.aff" kitchen-upd.oavm --updatable > /dev/null
"$bin/oavm-update" kitchen-upd.oavm "$scenes/bart/kitchen/kitchen.aff" --time 7.5 > /dev/null
say "update kitchen 0 -> 7.5" "$(digest kitchen-upd.oavm)"
t kitchen-upd kitchen kitchen-upd
"$bin/oavm-update" kitchen-upd.oavm --compact > /dev/null
say "compact kitchen" "$(digest kitchen-upd.oavm)"
for f in dragon dragon-list-ropes dragon-occl dragon-zstd kitchen-upd; do
    # The report less its time.
    "$trace" "$f.oavm" --verify | sed 's/; [0-9.]* s)/)/' > verify.txt
    say "verify $f" "$(digest verify.txt)"
done
"$bin/oavm-inspect" dragon-occl.oavm --levels --blocks > inspect.txt
say "inspect dragon-occl --levels --blocks" "$(digest inspect.txt)"

# The comparison structures (oavm-bench), each on the kitchen's ray files.
if [ -x "$bench" ]; then
    for s in grid kdtree octree bvh oavm oavm:morton kdtree:restart kdtree:pushdown \
        kdtree:shortstack kdtree:splitstack kdtree:ropes kdtree:popov; do
        "$bench" "$scenes/bart/kitchen/kitchen.aff" --structure "$s" --rays kitchen.random.rays \
            --hits "cmp.$s.hits" > /dev/null
        "$bench" "$scenes/bart/kitchen/kitchen.aff" --structure "$s" --rays kitchen.shadow.rays \
            --occluded "cmp.$s.occl" > /dev/null
        say "compare $s" "$(digest "cmp.$s.hits") $(digest "cmp.$s.occl")"
    done
    for v in standard sato multi; do
        "$bench" "$scenes/bart/kitchen/kitchen.aff" --structure kdtree --shadow-variant "$v" \
            --rays kitchen.shadow.rays --occluded "cmp.kd-$v.occl" > /dev/null
        "$bench" "$scenes/bart/kitchen/kitchen.aff" --structure oavm --shadow-variant "$v" \
            --rays kitchen.shadow.rays --occluded "cmp.oavm-$v.occl" > /dev/null
        say "compare shadow $v (kdtree, oavm)" \
            "$(digest "cmp.kd-$v.occl") $(digest "cmp.oavm-$v.occl")"
    done
fi
