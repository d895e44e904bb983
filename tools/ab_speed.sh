#!/usr/bin/env bash
# A/B speed of two oavm-trace binaries on the same file and ray sets, in one run: repetitions
# interleaved (A, B, A, B, ...) so that the machine's noise falls on both, the median of each
# side per set, and the ratio B/A. The answers of both must be byte-identical (their HITS/OCCL
# files are compared every time); any difference fails the run.
#
#   tools/ab_speed.sh OLD/oavm-trace NEW/oavm-trace FILE.oavm RAYS_PREFIX [REPS] [-- ARGS...]
#
# RAYS_PREFIX names the sets made by `cargo run --release --features tools --example rays -- MESH PREFIX`:
# PREFIX.random.rays and PREFIX.primary.rays (closest hit), PREFIX.shadow.rays (any hit). ARGS
# are passed to both binaries (e.g. --threads 1). Prints one line per set and a JSON summary.
#
# With AB_TOGETHER=1, A and B run at the same time, each with one thread pinned to its own core
# (cores swapped every repetition), and the ratio is the median of the per-pair ratios: on a
# virtual machine whose speed drifts by tens of percent within seconds (ours), the drift then
# falls on both sides of every pair. Needs two cores; ARGS must not set --threads.
set -euo pipefail
[ $# -ge 4 ] || { sed -n '2,12p' "$0"; exit 2; }
a=$1 b=$2 file=$3 prefix=$4 reps=${5:-5}
shift 4; [ $# -gt 0 ] && [ "$1" != "--" ] && shift
[ "${1:-}" = "--" ] && shift
extra=("$@")
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
for set in primary random shadow; do
  rays=$prefix.$set.rays
  [ -f "$rays" ] || { echo "missing $rays" >&2; exit 1; }
  if [ $set = shadow ]; then flag=--occluded; else flag=--hits; fi
  for ((i = 0; i < reps; i++)); do
    if [ "${AB_TOGETHER:-0}" = 1 ]; then
      for side in a b; do
        bin=${!side}
        [ $side = a ] && core=$((i % 2)) || core=$(((i + 1) % 2))
        taskset -c $core "$bin" "$file" --rays "$rays" $flag "$tmp/$side.out" --json --threads 1 \
          "${extra[@]}" > "$tmp/$side.json" &
      done
      wait
      for side in a b; do
        python3 -c 'import json,sys; print(json.load(sys.stdin)["mrays_per_s"])' \
          < "$tmp/$side.json" >> "$tmp/$set.$side"
      done
    else
      for side in a b; do
        bin=${!side}
        "$bin" "$file" --rays "$rays" $flag "$tmp/$side.out" --json "${extra[@]}" \
          | python3 -c 'import json,sys; print(json.load(sys.stdin)["mrays_per_s"])' >> "$tmp/$set.$side"
      done
    fi
    cmp -s "$tmp/a.out" "$tmp/b.out" || { echo "$set: the answers differ" >&2; exit 1; }
  done
done
python3 - "$tmp" "$reps" <<'EOF'
import json, statistics, sys
tmp, reps = sys.argv[1], int(sys.argv[2])
out = {}
for s in ["primary", "random", "shadow"]:
    a = [float(x) for x in open(f"{tmp}/{s}.a")]
    b = [float(x) for x in open(f"{tmp}/{s}.b")]
    ma, mb = statistics.median(a), statistics.median(b)
    pairs = statistics.median(y / x for x, y in zip(a, b))
    out[s] = {"a_mrays_per_s": ma, "b_mrays_per_s": mb, "ratio_b_over_a": mb / ma,
              "median_pair_ratio": pairs, "a_runs": a, "b_runs": b}
    print(f"{s:8} A {ma:7.3f}  B {mb:7.3f} Mrays/s  B/A {mb / ma:.3f}, median of pair ratios "
          f"{pairs:.3f}  ({reps} runs each, medians)")
print(json.dumps(out))
EOF
