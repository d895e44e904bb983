#!/usr/bin/env bash
# Regenerates docs/results.md (and docs/kitchen.png): the OAVM paper's comparison on our scenes.
#
#   tools/results.sh [--reps N] [--random N] ...   # extra flags go to every oavm-bench run
#   tools/results.sh --shadow-only [--reps N] ...  # only the shadow-ray runs (below)
#   tools/results.sh --anim-only                   # only the animation runs (Table 3, below)
#
# Runs `oavm-bench --json` (the binary of the workspace crate oavm-compare, crates/oavm-compare,
# at target/release/oavm-bench) over the seven scenes (all five structures, 1 and 2 threads), with
# OAVM's leaves as lists (the paper's structure) and as clusters (the default), then
# over the dragon's decimations for build-time scaling, the shadow-ray walks (standard, SATO,
# multi-index tree) over four scenes, renders the kitchen from its own viewpoint, and writes the
# page with tools/results.py. The JSON is kept in target/results/ (not in git; RESULTS_DIR=DIR
# puts it elsewhere). With --reps 2, about 35 minutes in all on a 2-core AMD EPYC at format 6
# (commit 2848123), the shadow rays and the animations (Table 3, with 2 GB of Rain frames in
# RESULTS_DIR/rain, made once and kept) included; the first run adds the frames' making.
#
# --anim-only runs just the animation benchmark (tools/anim_bench.rs) into RESULTS_DIR/anim*.json
# and writes docs/results.md again from the JSON already in RESULTS_DIR (so that a page measured
# in parts at one commit is whole); extra flags are not passed to it.
#
# --shadow-only runs just the shadow-ray benchmark (flags given override its defaults, e.g.
# `--width 128 --height 96 --frames 2 --reps 1` for a quick look) and writes RESULTS_DIR/shadow.json
# and that section alone to RESULTS_DIR/shadow.md; docs/results.md is left as it is.
set -euo pipefail
cd "$(dirname "$0")/.."
S=../shared/scenes
OUT=${RESULTS_DIR:-target/results}
SHADOW_ONLY=0
ANIM_ONLY=0
ARGS=()
for a in "$@"; do
  case $a in
    --shadow-only) SHADOW_ONLY=1 ;;
    --anim-only) ANIM_ONLY=1 ;;
    *) ARGS+=("$a") ;;
  esac
done
set -- ${ARGS[@]+"${ARGS[@]}"}
mkdir -p "$OUT"
BIN=target/release
commit=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)
git diff --quiet HEAD -- src crates Cargo.toml 2>/dev/null || commit="$commit-dirty"

# Whether flag $1 is among the rest (as `--flag value` or `--flag=value`).
given() {
  local flag=$1 a
  shift
  for a in "$@"; do
    [[ $a == "$flag" || $a == "$flag="* ]] && return 0
  done
  return 1
}

# Shadow rays: the multi-index tree of Liang and Huang (2019) against the standard walk and SATO
# order, on each structure oavm-bench has them for, over the frames of a camera orbit. One run
# per scene (each needs its own camera or box), merged into $OUT/shadow.json with each scene's
# arguments. The defaults are the table's; the same flags given to this script replace them.
SHADOW_SCENES=(
  "$S/bart/kitchen/kitchen.aff"
  "$S/bart/robot/Robot.aff"
  "$S/sibenik/sibenik.obj --eye=-17,-10,0 --target=10,-9,0 --fov 60 --light-at=3,-3,2"
  "$S/dragon/dragon_vrip.ply --closed-box"
)
shadow_runs() {
  local defaults=(--width 1024 --height 768 --frames 8 --orbit-step 1 --tile 16 --threads 1,2
                  --light point)
  local common=() merge=() scene entry i n=0
  for ((i = 0; i < ${#defaults[@]}; i += 2)); do
    given "${defaults[i]}" "$@" || common+=("${defaults[i]}" "${defaults[i + 1]}")
  done
  for entry in "${SHADOW_SCENES[@]}"; do
    read -ra scene <<< "$entry"
    n=$((n + 1))
    "$BIN/oavm-bench" --json --shadow-variant standard,sato,multi "${common[@]}" "$@" \
      "${scene[@]}" > "$OUT/shadow_$n.json.tmp"
    merge+=("$OUT/shadow_$n.json.tmp" "$entry")
  done
  python3 - "$OUT/shadow.json.tmp" "${merge[@]}" <<'EOF'
import json, sys
out, rest = sys.argv[1], sys.argv[2:]
merged = None
for path, args in zip(rest[::2], rest[1::2]):
    d = json.load(open(path))
    opts = {k: v for k, v in d["shadow"].items() if k != "closed_box"}  # per scene
    if merged is None:
        merged = {"format_version": d["format_version"], "shadow": opts, "scenes": []}
    elif (d["format_version"], opts) != (merged["format_version"], merged["shadow"]):
        sys.exit(f"results.sh: {path} has other shadow options or format version")
    for sc in d["scenes"]:
        sc["args"] = args
        merged["scenes"].append(sc)
json.dump(merged, open(out, "w"), indent=1)
EOF
  rm -f "$OUT"/shadow_[0-9]*.json.tmp
  mv "$OUT/shadow.json.tmp" "$OUT/shadow.json"
}

# Dynamic scenes: the OAVM paper's Table 3. Rain frames by tools/rain.rs (seed 1; kept in
# $OUT/rain between runs: the same arguments write the same bytes), then anim_bench: the three
# BART scenes and Rain at 10^5 balls over 10 frames at the paper's three sizes, Rain at 10^6 over
# 3 frames, and the update cost alone (--steps-only) for Rain at 10^6 (3 steps) and 10^7 (80 M
# triangles, 2 steps; 3 frames of 1.8 GB each; every pack of it streams within 8 GiB, as
# `oavm-pack --mem-budget 8G`, its time including reading the PLY: built in memory it would take
# most of this machine's 24 GiB beside the update's file and frames).
anim_runs() {
  cargo build --release --features tools --example anim_bench --example rain
  local R=$OUT/rain n last
  for n in 100000:10 1000000:3 10000000:2; do
    last=${n#*:}; n=${n%:*}
    [[ -f $R/$n/rain_$(printf %05d "$last").ply ]] ||
      "$BIN/examples/rain" --balls "$n" --seed 1 --frames "0..=$last" --out "$R/$n" > /dev/null
  done
  local A=("$BIN/examples/anim_bench" --out "$OUT" --work "$OUT/anim_work")
  "${A[@]}" --frames 10 --name anim kitchen="$S/bart/kitchen/kitchen.aff" \
    robots="$S/bart/robot/Robot.aff" museum="$S/bart/museum/museum5.aff" \
    "rain 10^5"="$R/100000" > /dev/null
  "${A[@]}" --frames 3 --name anim_rain6 "rain 10^6"="$R/1000000" > /dev/null
  "${A[@]}" --steps-only --frames 3 --name anim_steps6 "rain 10^6"="$R/1000000" > /dev/null
  "${A[@]}" --steps-only --frames 2 --name anim_steps7 --mem-budget 8G "rain 10^7"="$R/10000000" > /dev/null
  rm -rf "$OUT/anim_work"
}

# The page, from every JSON in $OUT (a part not measured is left out).
write_page() {
  local opt=() f
  [[ -f $OUT/shadow.json ]] && opt+=(--shadow "$OUT/shadow.json")
  local anim=() steps=()
  for f in anim anim_rain6; do [[ -f $OUT/$f.json ]] && anim+=("$OUT/$f.json"); done
  for f in anim_steps6 anim_steps7; do [[ -f $OUT/$f.json ]] && steps+=("$OUT/$f.json"); done
  ((${#anim[@]})) && opt+=(--anim "$(IFS=,; echo "${anim[*]}")")
  ((${#steps[@]})) && opt+=(--anim-steps "$(IFS=,; echo "${steps[*]}")")
  python3 tools/results.py "$OUT/bench.json" --clusters "$OUT/clusters.json" \
    --scaling "$OUT/scaling.json" --stackless "$OUT/stackless.json" \
    --stackless-lists "$OUT/stackless_lists.json" ${opt[@]+"${opt[@]}"} \
    --kitchen-png kitchen.png --commit "$commit" \
    --command "tools/results.sh $*" > docs/results.md.tmp
  mv docs/results.md.tmp docs/results.md
  echo "wrote docs/results.md"
}

if ((ANIM_ONLY)); then
  anim_runs
  write_page --anim-only
  exit 0
fi

if ((SHADOW_ONLY)); then
  cargo build --release -p oavm-compare --bin oavm-bench
  shadow_runs "$@"
  python3 tools/results.py --shadow "$OUT/shadow.json" --commit "$commit" > "$OUT/shadow.md.tmp"
  mv "$OUT/shadow.md.tmp" "$OUT/shadow.md"
  echo "wrote $OUT/shadow.json and $OUT/shadow.md"
  exit 0
fi

mkdir -p docs
cargo build --release -p oavm-compare --bin oavm-bench
cargo build --release -p oavm --bin oavm-pack --bin oavm-trace

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

shadow_runs "$@"

"$BIN/oavm-pack" "$S/bart/kitchen/kitchen.aff" "$OUT/kitchen.oavm" > /dev/null
"$BIN/oavm-trace" "$OUT/kitchen.oavm" --view "$S/bart/kitchen/kitchen.aff" --shade -o docs/kitchen.png

anim_runs
write_page "$@"
echo "and docs/kitchen.png"
