#!/usr/bin/env bash
# tools/ooc_ab.sh: two ways of tracing one file out of core, A/B, interleaved so that the
# machine's drift falls on both: per repetition and per ray set, the page cache is dropped and
# A runs twice in a fresh cgroup (cold, then warm), then B likewise. Prints each run's
# Mrays/s, disk bytes per ray and blocks read, the medians and the ratio B/A of the medians,
# warm and cold; fails if any run's answers differ from the first's.
#
# Usage (as root):
#   tools/ooc_ab.sh FILE.oavm LIMIT BUDGET REPS "A FLAGS" "B FLAGS"
# e.g. tools/ooc_ab.sh /work/big/c150zstd.oavm 1.5G 1G 3 "--order blocks" "--order stream"
#
# A side may be another build on its own file (an older format against the current one):
# A_BIN / B_BIN name its oavm-trace and A_FILE / B_FILE its file (default: this checkout's
# release build, and FILE). The answers must still be the same on both sides.
# e.g. A_BIN=/work/f5-target/release/oavm-trace A_FILE=/work/big/c150-v5.oavm \
#      tools/ooc_ab.sh /work/big/c150.oavm 1.5G 1200M 3 "" "--chunks"
set -euo pipefail
cd "$(dirname "$0")/.."
file=$1 limit=$2 budget=$3 reps=$4 a=$5 b=$6
cargo build --release --bin oavm-trace >&2
bin=$PWD/target/release/oavm-trace
a_bin=${A_BIN:-$bin} b_bin=${B_BIN:-$bin} a_file=${A_FILE:-$file} b_file=${B_FILE:-$file}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for set in primary random; do
    case $set in
        primary) args="--primary 1024x768 --shadow" ;;
        random) args="--random 1000000" ;;
    esac
    for ((i = 0; i < reps; i++)); do
        for side in A B; do
            if [[ $side == A ]]; then flags=$a run_bin=$a_bin run_file=$a_file
            else flags=$b run_bin=$b_bin run_file=$b_file; fi
            # shellcheck disable=SC2086
            tools/ooc.sh --cold --json --report "$out/cg-$set-$side-$i.json" "$limit" -- sh -c \
                '"$0" "$@" >"'"$out/cold-$set-$side-$i"'.json" && "$0" "$@" >"'"$out/warm-$set-$side-$i"'.json"' \
                "$run_bin" "$run_file" $args $flags --mem-budget "$budget" --json
        done
    done
done
python3 - "$out" "$reps" "$a" "$b" <<'PY'
import json, statistics, sys
out, reps, a, b = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
bad = False
for s, run in [(s, run) for s in ["primary", "random"] for run in ["warm", "cold"]]:
    first = None
    med = {}
    for side, flags in (("A", a), ("B", b)):
        speeds, disk, reads = [], [], []
        for i in range(reps):
            r = json.load(open(f"{out}/{run}-{s}-{side}-{i}.json"))
            rays = sum(x["rays"] for x in r["sets"])
            secs = sum(x["seconds"] for x in r["sets"])
            speeds.append(rays / secs / 1e6)
            disk.append(r["disk_read_bytes_trace"] / rays)
            reads.append(sum(x["page"]["misses"] for x in r["sets"]))
            d = [x["answers_xxh3"] for x in r["sets"]]
            first = first or d
            bad |= d != first
        med[side] = statistics.median(speeds)
        print(f"{s:8} {side} {flags:24} {run} Mrays/s {' '.join(f'{x:.3f}' for x in speeds)}  "
              f"median {med[side]:.3f}  disk B/ray {statistics.median(disk):,.0f}  blocks read {statistics.median(reads):,.0f}")
    print(f"{s:8} {run} B/A {med['B'] / med['A']:.3f}")
print("answers", "DIFFERENT" if bad else "identical")
sys.exit(1 if bad else 0)
PY
