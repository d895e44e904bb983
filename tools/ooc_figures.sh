#!/usr/bin/env bash
# tools/ooc_figures.sh: the out-of-core figures of a packed file. Traces it without a limit and
# inside a cgroup v1 memory limit (tools/ooc.sh), cold (page cache dropped first) and warm (a
# second run in the same cgroup, so only the page cache it kept, counted against the limit,
# helps; the cgroup's peak covers both runs), for the
# 1024x768 primary rays with their shadow rays and for 10^6 random rays; checks that every run
# gives the same answers, ray for ray (oavm-trace's digest of each set's answers); prints a
# table (speed, its ratio to the unlimited run, bytes the pager read per ray, bytes read from
# the disk per ray, the pager's hit rate, the cgroup's peak, or the unlimited run's peak RSS)
# and keeps the JSON.
#
# Usage (as root):
#   tools/ooc_figures.sh FILE.oavm OUT_DIR [LIMIT [BUDGET [extra oavm-trace flags...]]]
#
#   LIMIT   the cgroup's memory.limit_in_bytes (default 1.5G)
#   BUDGET  oavm-trace --mem-budget inside it (default 1G: what is left of the limit holds the
#           rays, their answers, the top tree and the directory)
#   flags   passed to every run; those after a `--limited` go to the runs in the cgroup only
#           (e.g. `--limited --order stream`: the unlimited run stays the direct walk, the
#           fastest in memory)
#
# With OOC_BASE=DIR (the OUT_DIR of an earlier run, e.g. the raw file's), the ratio column is
# against DIR's unlimited runs instead of this file's: the zstd file's speed against the raw
# file's in memory, the fastest run a user could have with enough memory. The column "reads
# per block" is the blocks read (pager misses) over the blocks the unlimited run read (each
# block it needs, once).
#
# Example: tools/ooc_figures.sh /work/big/c150.oavm target/ooc 1.5G 1G
#          tools/ooc_figures.sh /work/big/c150.oavm target/ooc-lazy 1.5G 1G --no-block-checks
set -euo pipefail
cd "$(dirname "$0")/.."
file=$1
out=$2
limit=${3:-1.5G}
budget=${4:-1G}
shift $(($# < 4 ? $# : 4))
extra=()
limited=()
while (($#)); do
    if [[ $1 == --limited ]]; then
        shift
        limited=("$@")
        break
    fi
    extra+=("$1")
    shift
done
mkdir -p "$out"
cargo build --release --bin oavm-trace >&2
bin=$PWD/target/release/oavm-trace

sets=(primary random)
args_primary=(--primary 1024x768 --shadow)
args_random=(--random 1000000)

for set in "${sets[@]}"; do
    declare -n a="args_$set"
    # Unlimited: twice, the second one warm (the file in the page cache, nothing evicted).
    "$bin" "$file" "${a[@]}" "${extra[@]}" --json >"$out/unlimited-$set-1.json"
    "$bin" "$file" "${a[@]}" "${extra[@]}" --json >"$out/unlimited-$set.json"
    # Cold and warm: the page cache dropped, then two runs in one fresh cgroup, so that the
    # second (warm) one finds only what the first left in the cgroup's own page cache, never
    # pages cached (and charged) outside it.
    tools/ooc.sh --cold --json --report "$out/cgroup-$set.json" "$limit" -- sh -c \
        '"$0" "$@" >"'"$out"'/cold-'"$set"'.json" && "$0" "$@" >"'"$out"'/warm-'"$set"'.json"' \
        "$bin" "$file" "${a[@]}" "${extra[@]}" "${limited[@]}" --mem-budget "$budget" --json
done

python3 - "$out" "${OOC_BASE:-$out}" <<'EOF'
import json, sys
out, based = sys.argv[1], sys.argv[2]
def load(n, d=None): return json.load(open(f"{d or out}/{n}.json"))
print(f"{'set':8} {'run':10} {'Mrays/s':>8} {'x unlim':>8} {'B/ray':>8} {'disk B/ray':>10} {'reads/block':>11} {'hit rate':>8} {'cgroup peak':>12} {'answers':>9}")
bad = False
for s in ["primary", "random"]:
    base = load(f"unlimited-{s}", based)
    own = load(f"unlimited-{s}")
    needed = sum(x["page"]["misses"] for x in own["sets"])
    for run in ["unlimited", "cold", "warm"]:
        r = load(f"{run}-{s}")
        cg = None if run == "unlimited" else load(f"cgroup-{s}")
        rays = sum(x["rays"] for x in r["sets"])
        secs = sum(x["seconds"] for x in r["sets"])
        brd = sum(x["page"]["bytes_read"] for x in r["sets"])
        req = sum(x["page"]["requested"] for x in r["sets"])
        hit = sum(x["page"]["hits"] for x in r["sets"])
        bsecs = sum(x["seconds"] for x in base["sets"])
        misses = sum(x["page"]["misses"] for x in r["sets"])
        same = [x["answers_xxh3"] for x in r["sets"]] == [x["answers_xxh3"] for x in base["sets"]]
        bad |= not same
        print(f"{s:8} {run:10} {rays/secs/1e6:8.3f} {bsecs/secs:8.3f} {brd/rays:8.0f} {r['disk_read_bytes_trace']/rays:10.0f} {misses/max(needed,1):11.2f} {hit/max(req,1):8.4f} "
              f"{(cg['max_usage_bytes']/2**30 if cg else r['peak_rss_bytes']/2**30):10.2f}Gi {'same' if same else 'DIFFERENT':>9}")
sys.exit(1 if bad else 0)
EOF
