#!/usr/bin/env bash
# Runs the fuzz targets of fuzz/ (see fuzz/README.md), one at a time, under `nice -n 19` so that
# everyone else's builds win the CPU.
#
#   tools/fuzz.sh build                 build every target (nightly, cargo-fuzz, installed if
#                                       missing; no sanitizer, debug assertions and overflow
#                                       checks on)
#   tools/fuzz.sh seeds                 write the seed inputs (tools/fuzz_seeds.sh)
#   tools/fuzz.sh run TARGET|all [--plateau MIN] [--max MIN] [--stop-on-crash]
#                                       fuzz each target until its coverage (`cov:` in libFuzzer's
#                                       status lines) has not grown for --plateau minutes (default
#                                       30) or it has run --max minutes (default 240)
#   tools/fuzz.sh status                progress of every target from its log
#   tools/fuzz.sh cmin TARGET|all       minimise what fuzzing found, with the committed corpus,
#                                       into fuzz/corpus/TARGET/ (the corpus tests replay): the
#                                       smallest inputs that cover every edge covered
#                                       (-use_counters=0)
#
# Where things go (none of it committed but fuzz/corpus/):
#   fuzz/logs/TARGET.log       libFuzzer's output of the latest run of TARGET
#   fuzz/logs/summary.txt      one line per finished run: hours, executions, cov, ft, crashes
#   fuzz/work/corpus/TARGET/   the inputs fuzzing kept (grows; read again by the next run)
#   fuzz/artifacts/TARGET/     crash-*, oom-*, timeout-* inputs found
#
# `run` uses libFuzzer's fork mode with one job (-fork=1) and -ignore_crashes/-ignore_timeouts/
# -ignore_ooms, so a crash is saved and the run goes on; with --stop-on-crash it runs in-process
# and stops at the first one (what a short run wants, to look at it at once).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
fuzz=$root/fuzz
bin=$fuzz/target/x86_64-unknown-linux-gnu/release
TARGETS=(oavm_fixed oavm pack ply aff obj stl off gltf rays)

max_len() {
    case $1 in
    oavm | oavm_fixed) echo 32768 ;;
    rays) echo 8192 ;;
    *) echo 16384 ;;
    esac
}

die() {
    echo "fuzz.sh: $*" >&2
    exit 2
}

targets_of() {
    if [ "$1" = all ]; then
        echo "${TARGETS[@]}"
    else
        [[ " ${TARGETS[*]} " == *" $1 "* ]] || die "unknown target $1 (one of: ${TARGETS[*]}, all)"
        echo "$1"
    fi
}

# The last libFuzzer status line of a log, and fields of it.
last_status() { grep -a -E '^#[0-9]+.*cov: [0-9]+' "$1" 2>/dev/null | tail -n 1 || true; }
cov_of() { sed -n -E 's/.* cov: ([0-9]+).*/\1/p' <<<"$1"; }
ft_of() { sed -n -E 's/.* ft: ([0-9]+).*/\1/p' <<<"$1"; }
execs_of() { sed -n -E 's/^#([0-9]+).*/\1/p' <<<"$1"; }

build() {
    # cargo-fuzz is not on the machine image: installed here on first use.
    command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
    (cd "$fuzz" && nice -n 19 cargo +nightly fuzz build --release --debug-assertions \
        --sanitizer none)
}

run_one() { # TARGET PLATEAU_MIN MAX_MIN STOP_ON_CRASH
    local t=$1 plateau=$(($2 * 60)) max=$(($3 * 60)) stop=$4
    [ -x "$bin/$t" ] || die "$bin/$t is not built: run tools/fuzz.sh build"
    local corpus=$fuzz/work/corpus/$t artifacts=$fuzz/artifacts/$t log=$fuzz/logs/$t.log
    mkdir -p "$corpus" "$artifacts" "$fuzz/logs"
    [ -d "$fuzz/corpus/$t" ] || die "fuzz/corpus/$t is missing"
    local inputs=("$corpus" "$fuzz/corpus/$t")
    [ -d "$fuzz/work/seeds/$t" ] && inputs+=("$fuzz/work/seeds/$t")
    local mode=(-fork=1 -ignore_crashes=1 -ignore_timeouts=1 -ignore_ooms=1)
    [ "$stop" = 1 ] && mode=()
    local marker
    marker=$(mktemp)
    local start
    start=$(date +%s)
    {
        echo "# fuzz.sh run $t: started $(date -u +%FT%TZ) ($start), plateau ${2} min, max ${3} min"
        echo "# inputs: ${inputs[*]}"
    } >"$log"
    # Job control: the fuzzer gets a process group of its own, so that it and its fork-mode
    # children can be stopped together.
    set -m
    nice -n 19 "$bin/$t" "${mode[@]}" -rss_limit_mb=2048 -timeout=10 -max_len="$(max_len "$t")" \
        -max_total_time=$((max + 300)) -print_final_stats=1 -artifact_prefix="$artifacts/" \
        "${inputs[@]}" >>"$log" 2>&1 &
    local pid=$!
    set +m
    local best=-1 grown=$start why=""
    while kill -0 "$pid" 2>/dev/null; do
        sleep 30
        local now cov
        now=$(date +%s)
        cov=$(cov_of "$(last_status "$log")")
        if [ -n "$cov" ] && [ "$cov" -gt "$best" ]; then
            best=$cov
            grown=$now
        fi
        if [ $((now - grown)) -ge "$plateau" ]; then
            why="coverage flat for ${2} min"
        elif [ $((now - start)) -ge "$max" ]; then
            why="maximum time of ${3} min"
        else
            continue
        fi
        kill -INT -- "-$pid" 2>/dev/null || true
        for _ in $(seq 60); do
            kill -0 "$pid" 2>/dev/null || break
            sleep 1
        done
        kill -KILL -- "-$pid" 2>/dev/null || true
        break
    done
    local rc=0
    wait "$pid" || rc=$?
    [ -n "$why" ] || why="fuzzer exited ($rc)"
    local end status crashes
    end=$(date +%s)
    status=$(last_status "$log")
    local found
    found=$(find "$artifacts" -type f -newer "$marker" | sort)
    crashes=$(grep -c . <<<"$found" || true)
    rm -f "$marker"
    local line
    line=$(printf '%-10s %s  %6.2f h  %12s execs  cov %6s  ft %7s  new artifacts %3d  (%s)' \
        "$t" "$(date -u +%FT%TZ)" "$(echo "($end - $start) / 3600" | bc -l)" \
        "$(execs_of "$status")" "$(cov_of "$status")" "$(ft_of "$status")" "$crashes" "$why")
    echo "$line" | tee -a "$fuzz/logs/summary.txt"
    echo "# fuzz.sh: $line" >>"$log"
    [ "$crashes" -eq 0 ] || sed 's/^/  /' <<<"$found"
}

status() {
    local now
    now=$(date +%s)
    for t in "${TARGETS[@]}"; do
        local log=$fuzz/logs/$t.log
        [ -f "$log" ] || {
            printf '%-10s not run\n' "$t"
            continue
        }
        local start s state
        start=$(sed -n -E '1s/.*started [^ ]+ \(([0-9]+)\).*/\1/p' "$log")
        s=$(last_status "$log")
        state="running"
        grep -q '^# fuzz.sh: ' "$log" && state="done: $(sed -n 's/^# fuzz.sh: .*(\(.*\))$/\1/p' "$log")"
        printf '%-10s %6.2f h since start  %12s execs  cov %6s  ft %7s  artifacts %3d  %s\n' \
            "$t" "$(echo "($now - ${start:-$now}) / 3600" | bc -l)" "$(execs_of "$s")" \
            "$(cov_of "$s")" "$(ft_of "$s")" \
            "$(find "$fuzz/artifacts/$t" -type f 2>/dev/null | wc -l)" "$state"
    done
    [ -f "$fuzz/logs/summary.txt" ] && { echo "finished runs:"; cat "$fuzz/logs/summary.txt"; }
    return 0
}

cmin() { # TARGET: merge the committed corpus and fuzz/work/corpus into a new minimal corpus
    local t=$1 new=$fuzz/work/cmin/$1
    [ -x "$bin/$t" ] || die "$bin/$t is not built: run tools/fuzz.sh build"
    rm -rf "$new"
    mkdir -p "$new" "$fuzz/corpus/$t" "$fuzz/work/corpus/$t"
    # -use_counters=0: one input per coverage edge, not per hit-count bucket of an edge (ft),
    # which keeps the committed corpus to a few MB; fuzz/work/corpus keeps everything.
    nice -n 19 "$bin/$t" -merge=1 -use_counters=0 -rss_limit_mb=2048 -timeout=10 \
        -max_len="$(max_len "$t")" \
        "$new" "$fuzz/corpus/$t" "$fuzz/work/corpus/$t" >"$fuzz/logs/$t.cmin.log" 2>&1 ||
        die "merge of $t failed, see fuzz/logs/$t.cmin.log"
    rm -rf "$fuzz/corpus/$t"
    mv "$new" "$fuzz/corpus/$t"
    printf '%-10s %4d files %8d bytes\n' "$t" "$(ls "$fuzz/corpus/$t" | wc -l)" \
        "$(cat "$fuzz/corpus/$t"/* 2>/dev/null | wc -c)"
}

cmd=${1:-}
shift || true
case $cmd in
build) build ;;
seeds) tools/fuzz_seeds.sh ;;
status) status ;;
cmin)
    [ $# -eq 1 ] || die "usage: tools/fuzz.sh cmin TARGET|all"
    for t in $(targets_of "$1"); do cmin "$t"; done
    ;;
run)
    [ $# -ge 1 ] || die "usage: tools/fuzz.sh run TARGET|all [--plateau MIN] [--max MIN] [--stop-on-crash]"
    which=$1
    shift
    plateau=30 max=240 stop=0
    while [ $# -gt 0 ]; do
        case $1 in
        --plateau) plateau=$2 && shift 2 ;;
        --max) max=$2 && shift 2 ;;
        --stop-on-crash) stop=1 && shift ;;
        *) die "unknown option $1" ;;
        esac
    done
    for t in $(targets_of "$which"); do run_one "$t" "$plateau" "$max" "$stop"; done
    ;;
*) sed -n '2,25p' "$0" && exit 2 ;;
esac
