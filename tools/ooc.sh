#!/usr/bin/env bash
# tools/ooc.sh: runs one command inside a cgroup v1 memory cgroup limited to LIMIT bytes, to
# measure tracing out of core (a file larger than the memory the process may use, page cache
# included: a v1 memory cgroup charges the file pages its tasks read to it).
#
# Usage:
#   tools/ooc.sh [--cold] [--json] [--report FILE] LIMIT -- COMMAND [ARG...]
#
#   LIMIT        memory.limit_in_bytes of the cgroup: bytes, or with a binary unit (K, M, G, T;
#                e.g. 512M, 1.5G), as `numfmt --from=iec` reads it.
#   --cold       first `sync` and drop the page cache (`echo 3 > /proc/sys/vm/drop_caches`), so
#                the file is read from the disk; the whole machine's cache is dropped.
#   --json       print the summary as one JSON object instead of lines of text.
#   --report F   write the summary to F instead of stderr.
#
# The command's stdout and stderr are its own (so `oavm-trace ... --json` can be piped); the
# summary goes to stderr (or --report): the limit, the cgroup's memory.max_usage_in_bytes (the
# peak of what was charged: the process's memory and the page cache it filled), its
# memory.failcnt (how often the limit was hit, i.e. the kernel had to reclaim), the OOM kills
# if the kernel counts them, the command's exit status and its wall time. The script exits
# with the command's status.
#
# Example (as root; the dragon packed in 64 KiB blocks, about 47 MB, traced within 16 MB):
#   cargo run --release --bin oavm-pack -- ../shared/scenes/dragon/dragon_vrip.ply \
#       /work/big/dragon.oavm --block-size 64K
#   tools/ooc.sh --cold 24M -- target/release/oavm-trace /work/big/dragon.oavm \
#       --random 1000000 --mem-budget 8M --json
#
# Needs root and the cgroup v1 memory controller at /sys/fs/cgroup/memory. The cgroup is made
# as `oavm-ooc-PID` under the memory cgroup this script runs in (so limits above it still hold),
# and removed on exit, also on failure and on Ctrl-C (the command is stopped first).

set -euo pipefail

die() {
    echo "ooc.sh: $*" >&2
    exit 2
}

cold=0
json=0
report=""
while [[ $# -gt 0 ]]; do
    case "$1" in
    --cold) cold=1 ;;
    --json) json=1 ;;
    --report)
        [[ $# -ge 2 ]] || die "--report needs a file"
        report="$2"
        shift
        ;;
    -h | --help)
        sed -n '2,/^$/p' "$0" | sed 's/^# \{0,1\}//'
        exit 0
        ;;
    --) die "LIMIT is missing (usage: ooc.sh [--cold] [--json] [--report FILE] LIMIT -- COMMAND...)" ;;
    -*) die "unknown option $1" ;;
    *) break ;;
    esac
    shift
done
[[ $# -ge 3 && "$2" == "--" ]] || die "usage: ooc.sh [--cold] [--json] [--report FILE] LIMIT -- COMMAND [ARG...]"
limit_arg="$1"
shift 2
limit=$(numfmt --from=iec "${limit_arg%[bB]}" 2>/dev/null) || die "LIMIT $limit_arg is not a size (e.g. 512M, 1.5G)"
[[ "$limit" =~ ^[0-9]+$ && "$limit" -gt 0 ]] || die "LIMIT $limit_arg must be a positive size"

root=/sys/fs/cgroup/memory
[[ -d "$root" ]] || die "$root does not exist: no cgroup v1 memory controller"
[[ "$(stat -fc %T "$root")" == "cgroupfs" && -e "$root/memory.limit_in_bytes" ]] ||
    die "$root is not a cgroup v1 memory hierarchy"
[[ "$(id -u)" == 0 ]] || die "needs root (to make a cgroup)"

# The memory cgroup we are in (a line `N:memory:/path` of /proc/self/cgroup).
parent="$root"
own=$(sed -n 's/^[0-9]*:memory:\(.*\)$/\1/p' /proc/self/cgroup | head -n 1)
if [[ -n "$own" && -d "$root$own" ]]; then
    parent="$root$own"
fi
cg="$parent/oavm-ooc-$$"

child=""
cleanup() {
    local status=$?
    trap - EXIT INT TERM
    if [[ -n "$child" ]] && kill -0 "$child" 2>/dev/null; then
        kill -TERM "$child" 2>/dev/null || true
        wait "$child" 2>/dev/null || true
    fi
    if [[ -d "$cg" ]]; then
        # Tasks leave the cgroup as they exit; rmdir fails while any is left.
        for _ in 1 2 3 4 5 6 7 8 9 10; do
            rmdir "$cg" 2>/dev/null && break
            sleep 0.2
        done
        [[ -d "$cg" ]] && echo "ooc.sh: could not remove $cg" >&2
    fi
    exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

mkdir "$cg"
echo "$limit" >"$cg/memory.limit_in_bytes"
# Without swap accounting this file is absent; with it, swap must not hide the limit.
if [[ -e "$cg/memory.memsw.limit_in_bytes" ]]; then
    echo "$limit" >"$cg/memory.memsw.limit_in_bytes" 2>/dev/null || true
fi
echo 0 >"$cg/memory.swappiness" 2>/dev/null || true

if [[ "$cold" == 1 ]]; then
    sync
    echo 3 >/proc/sys/vm/drop_caches || die "cannot drop the page cache"
fi

start=$(date +%s.%N)
# The child joins the cgroup, then becomes the command: everything it starts is charged there.
sh -c 'echo $$ > "$1/cgroup.procs" && shift && exec "$@"' ooc "$cg" "$@" &
child=$!
set +e
wait "$child"
status=$?
set -e
child=""
end=$(date +%s.%N)

max_usage=$(cat "$cg/memory.max_usage_in_bytes")
failcnt=$(cat "$cg/memory.failcnt")
oom_kills=$(sed -n 's/^oom_kill \([0-9]*\)$/\1/p' "$cg/memory.oom_control" 2>/dev/null || true)
wall=$(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.3f", b - a }')

if [[ "$json" == 1 ]]; then
    summary=$(printf '{"limit_bytes": %s, "max_usage_bytes": %s, "failcnt": %s, "oom_kills": %s, "exit_status": %s, "wall_s": %s, "cold": %s, "cgroup": "%s"}' \
        "$limit" "$max_usage" "$failcnt" "${oom_kills:-null}" "$status" "$wall" \
        "$([[ $cold == 1 ]] && echo true || echo false)" "$cg")
else
    summary=$(printf 'ooc.sh: limit %s bytes (%s)\nooc.sh: max usage %s bytes, failcnt %s, oom kills %s\nooc.sh: exit status %s, wall %s s%s' \
        "$limit" "$limit_arg" "$max_usage" "$failcnt" "${oom_kills:-?}" "$status" "$wall" \
        "$([[ $cold == 1 ]] && echo ', cold (page cache dropped first)' || true)")
fi
if [[ -n "$report" ]]; then
    echo "$summary" >"$report"
else
    echo "$summary" >&2
fi
exit "$status"
