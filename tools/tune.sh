#!/usr/bin/env bash
# Sweeps the build options K (--leaf-size) and D (--max-depth) and prints, for each, OAVM's
# single-thread throughput relative to obvhs on the bunny and the dragon, every ray set of the
# benchmark (the ratio, measured in the same run, is what is stable on a noisy machine). Used to
# choose the defaults.
#
#   tools/tune.sh [K values] [D values]      e.g. tools/tune.sh "8 16 32" "12 16"
set -euo pipefail
cd "$(dirname "$0")/.."
ks=${1:-"8 12 16 24 32 48"}
ds=${2:-"16"}
cargo bench --bench trace --no-run >/dev/null 2>&1
for d in $ds; do
  for k in $ks; do
    printf 'K=%-3s D=%-3s ' "$k" "$d"
    cargo bench --bench trace -- --leaf-size "$k" --max-depth "$d" --reps 3 --random 300000 \
      --only bunny,dragon --peers obvhs 2>/dev/null \
      | grep ' 1T ' | sed -E 's/ +/ /g' \
      | awk '{for (i = 1; i <= NF; i++) if ($i == "oavm/obvhs") r = $(i + 1); printf "%s-%s %s  ", $1, $2, r}'
    echo
  done
done
