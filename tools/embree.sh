#!/usr/bin/env bash
# Embree 4 for the benchmark peer (cargo feature `embree`, tools/peers/embree.rs).
#
#     tools/embree.sh                      # fetch if needed, print the environment to export
#     tools/embree.sh COMMAND [ARGS...]    # fetch if needed, run COMMAND with it set
#
# e.g. tools/embree.sh cargo bench --bench trace --features embree -- --scene bunny=PATH
#
# Embree's own release binaries are not on a package registry; the `embreex` Python wheel (PyPI)
# ships them: embreex.libs/libembree4-<hash>.so.4 (Embree 4.4.0, the official x86-64 Linux
# release build) and the libtbb it needs (found through the library's own RPATH $ORIGIN). This
# downloads the wheel with pip into target/embree/ (under $CARGO_TARGET_DIR if set, or
# $OAVM_EMBREE_CACHE), unpacks the shared libraries there and adds a
# `libembree4.so` link so that `-lembree4` finds them. build.rs passes OAVM_EMBREE_DIR to the
# linker as search path and rpath, so the binaries run without LD_LIBRARY_PATH (set anyway, for
# binaries linked elsewhere). Nothing here is committed (target/ is ignored).
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
version="${OAVM_EMBREEX_VERSION:-4.4.0.post1}"
dir="${OAVM_EMBREE_CACHE:-${CARGO_TARGET_DIR:-$root/target}/embree}/embreex-$version"

if [ ! -e "$dir/libembree4.so" ]; then
    (
        tmp="$(mktemp -d)"
        trap 'rm -rf "$tmp"' EXIT
        echo "embree.sh: downloading embreex==$version with pip" >&2
        python3 -m pip download --quiet --no-deps --only-binary=:all: -d "$tmp" "embreex==$version"
        mkdir -p "$dir"
        # A wheel is a zip; take only the shared libraries, flattened into $dir.
        python3 - "$tmp" "$dir" <<'PY'
import glob, os, sys, zipfile
tmp, out = sys.argv[1], sys.argv[2]
(wheel,) = glob.glob(os.path.join(tmp, "embreex-*.whl"))
with zipfile.ZipFile(wheel) as z:
    for name in z.namelist():
        if name.startswith("embreex.libs/") and ".so" in name:
            with z.open(name) as src, open(os.path.join(out, os.path.basename(name)), "wb") as dst:
                dst.write(src.read())
PY
        lib="$(cd "$dir" && ls libembree4*.so.4 | head -n 1)"
        [ -n "$lib" ] || { echo "embree.sh: no libembree4*.so.4 in the embreex wheel" >&2; exit 1; }
        ln -sf "$lib" "$dir/libembree4.so"
    )
fi

export OAVM_EMBREE_DIR="$dir"
export LD_LIBRARY_PATH="$dir${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
if [ $# -eq 0 ]; then
    echo "export OAVM_EMBREE_DIR=$OAVM_EMBREE_DIR"
    echo "export LD_LIBRARY_PATH=$LD_LIBRARY_PATH"
else
    exec "$@"
fi
