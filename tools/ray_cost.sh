#!/usr/bin/env bash
# Instructions a ray costs in OAVM, obvhs and Embree on the same rays (callgrind, one thread):
# for each tracer and ray set, ray_cost (tools/ray_cost.rs) runs under callgrind with one pass
# over the rays and with two; the difference of the totals over the number of rays is one
# ray's cost, with loading and building cancelled out.
#
#     tools/ray_cost.sh MESH RAYS_PREFIX [TRACERS]     # TRACERS default: oavm,obvhs,embree
#
# RAYS_PREFIX names the sets `cargo run --release --features tools --example rays -- MESH PREFIX`
# writes (PREFIX.primary.rays, PREFIX.random.rays: closest hit; PREFIX.shadow.rays: any hit).
# Embree comes from tools/embree.sh. Under valgrind, Embree runs its AVX2 kernels (valgrind
# hides AVX-512), as OAVM does everywhere. Takes minutes per set: valgrind runs 50x slower.
set -euo pipefail
[ $# -ge 2 ] || { sed -n '2,12p' "$0"; exit 2; }
mesh=$1 prefix=$2 tracers=${3:-oavm,obvhs,embree}
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
"$root/tools/embree.sh" cargo build --quiet --release --features tools,embree --example ray_cost
bin="${CARGO_TARGET_DIR:-$root/target}/release/examples/ray_cost"
eval "$("$root/tools/embree.sh")"
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
ir() { # total instructions of one run
  valgrind --tool=callgrind --callgrind-out-file="$tmp/cg" "$@" >/dev/null 2>"$tmp/log" ||
    { cat "$tmp/log" >&2; exit 1; }
  sed -n 's/.*I *refs: *//p' "$tmp/log" | tr -d ,
}
for set in primary random shadow; do
  rays=$prefix.$set.rays
  [ -f "$rays" ] || { echo "missing $rays" >&2; exit 1; }
  any=(); [ $set = shadow ] && any=(--any)
  n=$(( ($(stat -c %s "$rays") - 16) / 32 ))
  for t in ${tracers//,/ }; do
    one=$(ir "$bin" "$mesh" "$rays" --tracer "$t" "${any[@]}" --passes 1)
    two=$(ir "$bin" "$mesh" "$rays" --tracer "$t" "${any[@]}" --passes 2)
    awk -v s=$set -v t="$t" -v a="$one" -v b="$two" -v n="$n" \
      'BEGIN { printf "%-8s %-7s %9d rays  %7.0f instructions a ray\n", s, t, n, (b - a) / n }'
  done
done
