#!/usr/bin/env bash
# The Python binding's benchmark (tools/py_bench.py) in one command:
#
#     tools/py_bench.sh [ARGS...]      # ARGS go to tools/py_bench.py, e.g. --reps 5 --json OUT
#
# 1. makes target/bench-venv (python3 -m venv; $OAVM_BENCH_PYTHON picks another interpreter) if
#    it is not there, and installs python/requirements-bench.txt into it (embreex, open3d-cpu,
#    trimesh, numpy). A venv of its own: target/python-venv is the tests', which may hold a
#    debug build of oavm at any moment.
# 2. installs oavm itself into it from ./python in RELEASE mode (maturin's default profile;
#    reinstalled every time, so that it is the working tree's code).
# 3. builds the CLI (cargo build --release --bin oavm-trace) from the same working tree.
# 4. runs tools/py_bench.py with that venv's Python, which makes the ray files with
#    `cargo run --release --features tools --example rays` if they are missing and packs the mesh.
#
# Open3D's wheel links libusb-1.0, which slim Debian images lack: installed with apt-get when
# missing and this runs as root (otherwise said, and Open3D is reported as unavailable).
# Builds run under `nice -n 19` (the machine is shared). OAVM_BENCH_NO_INSTALL=1 skips steps 1-3.
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
venv="${OAVM_BENCH_VENV:-$root/target/bench-venv}"
python="${OAVM_BENCH_PYTHON:-python3}"

if [ -z "${OAVM_BENCH_NO_INSTALL:-}" ]; then
    if [ ! -x "$venv/bin/python" ]; then
        echo "py_bench.sh: making $venv with $("$python" --version 2>&1)" >&2
        "$python" -m venv "$venv"
        "$venv/bin/pip" install --quiet --upgrade pip
    fi
    echo "py_bench.sh: installing python/requirements-bench.txt" >&2
    "$venv/bin/pip" install --quiet -r python/requirements-bench.txt

    if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            echo "py_bench.sh: installing libusb-1.0-0 (Open3D's wheel links it)" >&2
            apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 \
                || { apt-get update -qq && apt-get install -y -qq libusb-1.0-0 >/dev/null; }
        else
            echo "py_bench.sh: warning: libusb-1.0.so.0 is missing; Open3D will not import" >&2
        fi
    fi

    echo "py_bench.sh: installing oavm (release build) from ./python" >&2
    nice -n 19 "$venv/bin/pip" install --quiet --force-reinstall --no-deps ./python

    echo "py_bench.sh: building target/release/oavm-trace" >&2
    nice -n 19 cargo build --release --bin oavm-trace
fi

exec "$venv/bin/python" "$root/tools/py_bench.py" "$@"
