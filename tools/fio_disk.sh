#!/usr/bin/env bash
# What the disk gives to random reads of one file: fio --readonly on FILE, direct I/O (no page
# cache), random reads of each size at each queue depth, one job, io_uring. This is the
# yardstick out-of-core traces are held to (a trace's read bandwidth against fio's at the same
# read size and depth on the same file, in the same session), and what picks the size of the
# chunks a trace reads.
#
#     tools/fio_disk.sh FILE [SIZES [DEPTHS [SECONDS]]]
#
# SIZES and DEPTHS are comma-separated (defaults 4k,16k,32k,64k,128k,256k and 1,4,16,32;
# SECONDS per run defaults to 5). Direct I/O bypasses this machine's page cache (fio fails if the
# file system refuses it; it does not fall back), but a virtual disk's host may cache too: run
# it twice and compare. Prints one line per size and depth: MB/s (10^6 bytes), reads a second,
# and mean and 99th-percentile completion latency. Needs fio (Debian: apt-get install fio).
# Reads only: fio --readonly refuses to write.
set -euo pipefail
[ $# -ge 1 ] || { sed -n '2,15p' "$0"; exit 2; }
file=$1 sizes=${2:-4k,16k,32k,64k,128k,256k} depths=${3:-1,4,16,32} secs=${4:-5}
[ -f "$file" ] || { echo "fio_disk.sh: no file $file" >&2; exit 1; }
command -v fio >/dev/null || { echo "fio_disk.sh: fio is not installed (apt-get install fio)" >&2; exit 1; }
command -v python3 >/dev/null || { echo "fio_disk.sh: needs python3 to read fio's JSON" >&2; exit 1; }
echo "file $file ($(stat -c %s "$file") bytes), ${secs} s a run, direct I/O, io_uring, 1 job"
printf '%6s %5s %10s %10s %10s %10s\n' size depth MB/s reads/s mean_us p99_us
for bs in ${sizes//,/ }; do
  for qd in ${depths//,/ }; do
    fio --readonly --name=r --filename="$file" --rw=randread --bs="$bs" --iodepth="$qd" \
        --ioengine=io_uring --direct=1 --numjobs=1 --time_based --runtime="$secs" \
        --group_reporting --output-format=json |
      python3 -c '
import json, sys
j = json.load(sys.stdin)["jobs"][0]["read"]
lat = j["clat_ns"]
p99 = lat.get("percentile", {}).get("99.000000", 0)
print("%6s %5s %10.1f %10.0f %10.1f %10.1f" % (sys.argv[1], sys.argv[2], j["bw_bytes"] / 1e6,
      j["iops"], j["lat_ns"]["mean"] / 1e3, p99 / 1e3))' "$bs" "$qd"
  done
done
