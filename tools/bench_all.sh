#!/usr/bin/env bash
# The trace benchmark (tools/bench_trace.rs) on all five scenes: the four default ones (bunny,
# dragon, kitchen, sibenik) and `big`, 12 copies of the dragon (10,456,968 triangles), which
# this makes with the make_copies example under target/bench/ if it is not there yet.
#
#     tools/bench_all.sh [ARGS...]                     # ARGS go to the benchmark, e.g. --reps 7
#     tools/embree.sh tools/bench_all.sh [ARGS...]     # with Embree as a peer
#
# Under tools/embree.sh (OAVM_EMBREE_DIR set) the benchmark is built with the `embree` feature.
# ARGS may pick scenes and peers (`--only big`, `--peers obvhs,embree`).
#
# Cost of the big scene (2-core Xeon, commit 37f4c00, all four structures in memory at once):
# builds OAVM 23 s, obvhs 116 s (single-threaded), bvh 13 s, Embree 16 s; 6.6 GiB peak RSS.
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
copies=12
big="${CARGO_TARGET_DIR:-$root/target}/bench/dragons-$copies.ply"

features=()
if [ -n "${OAVM_EMBREE_DIR:-}" ]; then
    features=(--features embree)
fi

if [ ! -e "$big" ]; then
    mkdir -p "$(dirname "$big")"
    echo "bench_all.sh: making $big ($copies dragons)" >&2
    cargo run --release --features tools --example make_copies -- "$big" --copies "$copies"
fi

exec cargo bench --bench trace "${features[@]}" -- --big "$big" "$@"
