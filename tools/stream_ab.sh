#!/usr/bin/env bash
# What a stream costs against the direct walk, before and after a change: two oavm-trace
# binaries (A, B) on one file, 10^6 rays from a ray file and the 1024x768 frame with its
# shadow rays, in memory and under each budget given, in orders none (in memory), morton and stream,
# all interleaved (every repetition runs every case once) so that the machine's drift falls on
# all of them. Prints each run, then per case the runs' Mrays/s; fails if any run's closest
# hits differ from the first's. The page cache is not dropped: this measures CPU, not the disk
# (tools/ooc_ab.sh does that).
#
#   tools/stream_ab.sh A/oavm-trace B/oavm-trace FILE.oavm RAYS [REPS] [BUDGET...]
# e.g. tools/stream_ab.sh /work/base-target/release/oavm-trace target/release/oavm-trace \
#        /work/big/d7.oavm /work/big/dr.random.rays 3 30M 20M
set -euo pipefail
[ $# -ge 4 ] || { sed -n '2,12p' "$0"; exit 2; }
a=$1 b=$2 file=$3 rays=$4 reps=${5:-3}
shift 4; [ $# -gt 0 ] && shift
budgets=(- "$@")
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
speed() {
    python3 -c 'import json,sys; d=json.load(sys.stdin); print("%.3f" % d["mrays_per_s"], d["order"], (d.get("stream") or {}).get("walks_unparked", "-"))'
}
for ((i = 0; i < reps; i++)); do
    for set in random frame; do
        for budget in "${budgets[@]}"; do
            # (Under a budget the order as given reads blocks again and again: not run.)
            orders=(morton stream)
            [[ $budget == - ]] && orders=(none morton stream)
            for order in "${orders[@]}"; do
                for side in A B; do
                    if [[ $side == A ]]; then bin=$a; else bin=$b; fi
                    args=(--order "$order" --threads 2 --json)
                    [[ $budget != - ]] && args+=(--mem-budget "$budget")
                    if [[ $set == random ]]; then
                        out=$tmp/$set-$budget-$order-$side-$i.hits
                        line=$("$bin" "$file" --rays "$rays" --hits "$out" "${args[@]}" | speed)
                        first=$tmp/first.hits
                        [[ -f $first ]] || cp "$out" "$first"
                        cmp -s "$out" "$first" || { echo "answers differ: $set $budget $order $side" >&2; exit 1; }
                        rm -f "$out"
                    else
                        line=$("$bin" "$file" --primary 1024x768 --shadow "${args[@]}" | speed)
                    fi
                    echo "$set $budget $order $side $line" | tee -a "$tmp/all"
                done
            done
        done
    done
done
echo "# Mrays/s per case (set budget order side: runs)"
awk '{k=$1" "$2" "$3" "$4; a[k]=a[k]" "$5} END {for (k in a) print k ":" a[k]}' "$tmp/all" | sort
echo "answers identical"
