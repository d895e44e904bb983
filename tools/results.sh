#!/usr/bin/env bash
# Regenerates docs/results.md (and docs/kitchen.png): the OAVM paper's comparison on our scenes.
#
#   tools/results.sh [--reps N] [--random N] ...   # extra flags go to every oavm-bench run
#
# Runs `oavm-bench --json` over the seven scenes (all five structures, 1 and 2 threads), with
# OAVM's leaves as lists (the paper's structure) and as clusters (the default), then
# over the dragon's decimations for build-time scaling, renders the kitchen from its own
# viewpoint, and writes the page with tools/results.py. The JSON is kept in target/results/
# (not in git). About 40 minutes on a 2-core machine.
set -euo pipefail
cd "$(dirname "$0")/.."
S=../shared/scenes
OUT=target/results
mkdir -p "$OUT" docs
cargo build --release --bin oavm-bench --bin oavm-pack --bin oavm-trace
BIN=target/release

SCENES=(
  "$S/bunny/bun_zipper.ply"
  "$S/dragon/dragon_vrip.ply"
  "$S/bart/kitchen/kitchen.aff"
  "$S/bart/robot/Robot.aff"
  "$S/bart/museum/museum5.aff"
  "$S/sibenik/sibenik.obj"
  "$S/cornell_box/CornellBox-Original.obj"
)
"$BIN/oavm-bench" --json --leaf list "$@" "${SCENES[@]}" > "$OUT/bench.json.tmp"
mv "$OUT/bench.json.tmp" "$OUT/bench.json"
"$BIN/oavm-bench" --json --leaf cluster "$@" "${SCENES[@]}" > "$OUT/clusters.json.tmp"
mv "$OUT/clusters.json.tmp" "$OUT/clusters.json"

# Build times against size: few rays, one run, one thread (only the builds matter here).
"$BIN/oavm-bench" --json --leaf list --reps 1 --threads 1 --random 1000 --width 32 --height 24 \
  "$S/dragon/dragon_vrip_res4.ply" "$S/dragon/dragon_vrip_res3.ply" \
  "$S/dragon/dragon_vrip_res2.ply" "$S/dragon/dragon_vrip.ply" > "$OUT/scaling.json.tmp"
mv "$OUT/scaling.json.tmp" "$OUT/scaling.json"

# The threaded KD-tree paper's Table 1: every KD-tree traversal and OAVM's two leaf-to-leaf
# walks on its scenes (primary and shadow rays; the random set is kept small, it is not shown),
# then OAVM's two walks again with leaf lists.
T1=(kdtree:stack kdtree:restart kdtree:pushdown kdtree:shortstack kdtree:splitstack kdtree:ropes
    kdtree:popov oavm:morton oavm:ropes)
T1_SCENES=("$S/bart/kitchen/kitchen.aff" "$S/bart/robot/Robot.aff"
           "$S/cornell_box/CornellBox-Original.obj")
"$BIN/oavm-bench" --json --leaf cluster --random 1000 "$@" \
  --structure "$(IFS=,; echo "${T1[*]}")" "${T1_SCENES[@]}" > "$OUT/stackless.json.tmp"
mv "$OUT/stackless.json.tmp" "$OUT/stackless.json"
"$BIN/oavm-bench" --json --leaf list --random 1000 "$@" --structure oavm:morton,oavm:ropes \
  "${T1_SCENES[@]}" > "$OUT/stackless_lists.json.tmp"
mv "$OUT/stackless_lists.json.tmp" "$OUT/stackless_lists.json"

"$BIN/oavm-pack" "$S/bart/kitchen/kitchen.aff" "$OUT/kitchen.oavm" > /dev/null
"$BIN/oavm-trace" "$OUT/kitchen.oavm" --view "$S/bart/kitchen/kitchen.aff" -o docs/kitchen.png

commit=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)
git diff --quiet HEAD -- src Cargo.toml 2>/dev/null || commit="$commit-dirty"
python3 tools/results.py "$OUT/bench.json" --clusters "$OUT/clusters.json" \
  --scaling "$OUT/scaling.json" --stackless "$OUT/stackless.json" \
  --stackless-lists "$OUT/stackless_lists.json" --kitchen-png kitchen.png --commit "$commit" \
  --command "tools/results.sh $*" > docs/results.md.tmp
mv docs/results.md.tmp docs/results.md
echo "wrote docs/results.md and docs/kitchen.png"
