#!/usr/bin/env bash
# Reproduces the faults of the review issue against a directory of oavm binaries and prints one
# markdown table row per fault:
#
#     tools/faults.sh BINDIR OUTDIR > table.md
#
# BINDIR holds oavm-pack and oavm-trace (e.g. target/release of an old or a new checkout);
# OUTDIR is a scratch directory for inputs and outputs (created; everything goes under
# OUTDIR/w, which is emptied first). Every command runs under `timeout`; the "what happened"
# column is built from what was observed (exit status, first line of stderr, file types before
# and after, sizes, hit counts, peak RSS from /usr/bin/time -v, elapsed time). The leading word
# of that column (FAULT / OK / ?) is a verdict computed from the same observations.
#
# Needs: bash, python3 (standard library only), coreutils, /usr/bin/time, mknod, mkfifo; root
# for the tmpfs of F23 (falls back to `ulimit -f`); strace for F16 (skipped without it).
# Heavy: about 3 GB of RAM and 2.5 GB of disk at peak (F22 packs 25 million triangles), a few
# minutes of CPU. Environment knobs: FAULTS_SKIP="F22 F07" skips rows; FAULTS_DUP_COPIES sets the
# triangle copies of F22.

set -u
export LC_ALL=C

if [ $# -ne 2 ]; then
    echo "usage: $0 BINDIR OUTDIR" >&2
    exit 2
fi
BIN=$(cd "$1" && pwd) || { echo "$0: no directory $1" >&2; exit 2; }
case "$2" in
    /dev|/dev/*|/proc|/proc/*|/sys|/sys/*|"") echo "$0: refusing OUTDIR $2" >&2; exit 2 ;;
esac
mkdir -p "$2" || exit 2
OUT=$(cd "$2" && pwd)
PACK=$BIN/oavm-pack
TRACE=$BIN/oavm-trace
for b in "$PACK" "$TRACE"; do
    [ -x "$b" ] || { echo "$0: missing $b" >&2; exit 2; }
done
SCENES=${FAULTS_SCENES:-$(cd "$(dirname "$0")/../.." && pwd)/shared/scenes}
BUNNY=$SCENES/bunny/bun_zipper.ply
DRAGON=$SCENES/dragon/dragon_vrip.ply
W=$OUT/w
SMALL=$W/small
if mountpoint -q "$SMALL" 2>/dev/null; then umount "$SMALL"; fi
rm -rf -- "$W"
mkdir -p "$W"
: >"$W/empty"
NULLIN=$W/empty        # stdin of every command: an empty regular file of our own

BG_PIDS=()
cleanup() {
    local p
    for p in "${BG_PIDS[@]}"; do kill -9 "$p" 2>/dev/null; done
    if mountpoint -q "$SMALL" 2>/dev/null; then umount "$SMALL" 2>/dev/null; fi
}
trap cleanup EXIT

skip() { case " ${FAULTS_SKIP:-} " in *" $1 "*) return 0 ;; esac; return 1; }
log() { echo "faults.sh: $*" >&2; }

# ------------------------------------------------------------------------------------------------
# Python helper: inputs and readers (standard library only).
cat >"$W/helper.py" <<'PYEOF'
import math, os, random, struct, sys

def read_ply_ascii(path):
    with open(path, 'rb') as f:
        data = f.read()
    end = data.index(b'end_header') 
    end = data.index(b'\n', end) + 1
    head = data[:end].decode().splitlines()
    nv = nf = 0
    for line in head:
        p = line.split()
        if p[:2] == ['element', 'vertex']:
            nv = int(p[2])
        if p[:2] == ['element', 'face']:
            nf = int(p[2])
    if 'format ascii' not in data[:end].decode():
        raise SystemExit(path + ': not an ascii PLY')
    lines = data[end:].split(b'\n')
    verts = []
    for i in range(nv):
        p = lines[i].split()
        verts.append((float(p[0]), float(p[1]), float(p[2])))
    faces = []
    for i in range(nv, nv + nf):
        p = lines[i].split()
        n = int(p[0])
        faces.append(tuple(int(x) for x in p[1:1 + n]))
    return verts, faces

def write_ply_bin(path, verts, faces, scale=1.0):
    hdr = ('ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\n'
           'property float y\nproperty float z\nelement face %d\n'
           'property list uchar int vertex_indices\nend_header\n' % (len(verts), len(faces)))
    out = bytearray(hdr.encode())
    v3 = struct.Struct('<3f')
    for v in verts:
        out += v3.pack(v[0] * scale, v[1] * scale, v[2] * scale)
    for f in faces:
        out += struct.pack('<B%di' % len(f), len(f), *f)
    with open(path, 'wb') as o:
        o.write(out)

def f32(x):
    return struct.unpack('<f', struct.pack('<f', x))[0]

RAY = struct.Struct('<8f')

def write_rays(path, rays):
    with open(path, 'wb') as o:
        o.write(b'RAYS' + struct.pack('<IQ', 1, len(rays)))
        o.write(b''.join(RAY.pack(*r) for r in rays))

def read_records(path, magic, size):
    with open(path, 'rb') as f:
        b = f.read()
    if b[:4] != magic:
        raise SystemExit('%s: magic %r' % (path, b[:4]))
    n = struct.unpack('<Q', b[8:16])[0]
    return [b[16 + i * size:16 + (i + 1) * size] for i in range(n)]

def oavm_bounds(path):
    with open(path, 'rb') as f:
        h = f.read(96)
    return struct.unpack('<3f', h[72:84]), struct.unpack('<3f', h[84:96])

def unit_dir(rng):
    z = 2.0 * rng.random() - 1.0
    phi = 2.0 * math.pi * rng.random()
    r = math.sqrt(max(0.0, 1.0 - z * z))
    return (r * math.cos(phi), r * math.sin(phi), z)

def cmd_ply2bin(a):        # IN OUT [SCALE]
    verts, faces = read_ply_ascii(a[0])
    write_ply_bin(a[1], verts, faces, float(a[2]) if len(a) > 2 else 1.0)

def cmd_tri(a):            # OUT: one triangle
    write_ply_bin(a[0], [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])

def cmd_grid(a):           # OUT G: G x G squares in z = 0 over [0,1]^2
    g = int(a[1])
    verts = [(i / g, j / g, 0.0) for j in range(g + 1) for i in range(g + 1)]
    faces = []
    for j in range(g):
        for i in range(g):
            v = j * (g + 1) + i
            faces += [(v, v + 1, v + g + 2), (v, v + g + 2, v + g + 1)]
    write_ply_bin(a[0], verts, faces)

def cmd_dup(a):            # OUT N: N copies of one tiny triangle, and one triangle far away
    n = int(a[1])
    hdr = ('ply\nformat binary_little_endian 1.0\nelement vertex 6\nproperty float x\n'
           'property float y\nproperty float z\nelement face %d\n'
           'property list uchar int vertex_indices\nend_header\n' % (n + 1))
    verts = [(0, 0, 0), (1e-3, 0, 0), (0, 1e-3, 0), (1, 1, 1), (0.999, 1, 1), (1, 0.999, 1)]
    with open(a[0], 'wb') as o:
        o.write(hdr.encode())
        o.write(b''.join(struct.pack('<3f', *v) for v in verts))
        one = struct.pack('<B3i', 3, 0, 1, 2)
        left = n
        while left:
            k = min(left, 1 << 22)
            o.write(one * k)
            left -= k
        o.write(struct.pack('<B3i', 3, 3, 4, 5))

def cmd_rays_box(a):       # OAVM OUT N SEED [SCALE]: rays from around the box toward points in it
    lo, hi = oavm_bounds(a[0])
    n, rng = int(a[2]), random.Random(int(a[3]))
    s = float(a[4]) if len(a) > 4 else 1.0
    ext = [hi[k] - lo[k] for k in range(3)]
    rays = []
    for _ in range(n):
        o = [lo[k] - ext[k] + 3.0 * ext[k] * rng.random() for k in range(3)]
        t = [lo[k] + ext[k] * rng.random() for k in range(3)]
        d = [t[k] - o[k] for k in range(3)]
        l = math.sqrt(sum(x * x for x in d)) or 1.0
        rays.append((o[0] * s, o[1] * s, o[2] * s, 0.0, d[0] / l, d[1] / l, d[2] / l, math.inf))
    write_rays(a[1], rays)

def cmd_scale_rays(a):     # IN OUT SCALE: origins scaled (directions kept: t scales by SCALE)
    s = float(a[2])
    recs = [RAY.unpack(r) for r in read_records(a[0], b'RAYS', 32)]
    write_rays(a[1], [(r[0] * s, r[1] * s, r[2] * s) + r[3:] for r in recs])

def cmd_repeat_rays(a):    # IN OUT TIMES
    with open(a[0], 'rb') as f:
        b = f.read()
    n = struct.unpack('<Q', b[8:16])[0] * int(a[2])
    with open(a[1], 'wb') as o:
        o.write(b'RAYS' + struct.pack('<IQ', 1, n) + b[16:] * int(a[2]))

def cmd_subnormal(a):      # OUT: ray 0 subnormal direction, ray 1 a control
    write_rays(a[0], [(0.2, 0.2, 2.0, 0.0, 0.0, 0.0, -1e-40, math.inf),
                      (0.2, 0.2, 2.0, 0.0, 0.0, 0.0, -1.0, math.inf)])

def cmd_ray_header(a):     # OUT COUNT: a RAYS header only
    with open(a[0], 'wb') as o:
        o.write(b'RAYS' + struct.pack('<IQ', 1, int(a[1])))

def cmd_plane(a):          # OUT N SEED G: origins on the grid of cmd_grid, random directions;
    # prints the f64 brute force's hit count and how many of its hits are at t = 0.
    n, rng, g = int(a[1]), random.Random(int(a[2])), int(a[3])
    rays = []
    for _ in range(n):
        o = (f32(0.01 + 0.98 * rng.random()), f32(0.01 + 0.98 * rng.random()), 0.0)
        d = tuple(f32(x) for x in unit_dir(rng))
        rays.append(o + (0.0,) + d + (math.inf,))
    write_rays(a[0], rays)
    tris = []
    for j in range(g):
        for i in range(g):
            p = lambda u, v: (u / g, v / g, 0.0)
            tris.append((p(i, j), p(i + 1, j), p(i + 1, j + 1)))
            tris.append((p(i, j), p(i + 1, j + 1), p(i, j + 1)))
    hits = zero = 0
    for r in rays:
        best = math.inf
        o, d = r[0:3], r[4:7]
        for a0, b0, c0 in tris:
            # (Every hit of these rays is at their origin, in the plane z = 0: a triangle whose
            # xy box does not hold the origin cannot be hit, and is passed.)
            if not (min(a0[0], b0[0], c0[0]) <= o[0] <= max(a0[0], b0[0], c0[0]) and
                    min(a0[1], b0[1], c0[1]) <= o[1] <= max(a0[1], b0[1], c0[1])):
                continue
            t = moller(o, d, a0, b0, c0)
            if t is not None and t < best:
                best = t
        if best < math.inf:
            hits += 1
            zero += best == 0.0
    print(hits, zero)

def moller(o, d, a, b, c):
    e1 = [b[k] - a[k] for k in range(3)]
    e2 = [c[k] - a[k] for k in range(3)]
    p = [d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2], d[0] * e2[1] - d[1] * e2[0]]
    det = sum(e1[k] * p[k] for k in range(3))
    if det == 0.0:
        return None
    inv = 1.0 / det
    tv = [o[k] - a[k] for k in range(3)]
    u = sum(tv[k] * p[k] for k in range(3)) * inv
    if u < 0.0 or u > 1.0:
        return None
    q = [tv[1] * e1[2] - tv[2] * e1[1], tv[2] * e1[0] - tv[0] * e1[2], tv[0] * e1[1] - tv[1] * e1[0]]
    v = sum(d[k] * q[k] for k in range(3)) * inv
    if v < 0.0 or u + v > 1.0:
        return None
    t = sum(e2[k] * q[k] for k in range(3)) * inv
    return t if t >= 0.0 else None

def cmd_hits(a):           # HITS [MAX_T0]: "count hits hits_at_t<MAX_T0 inf_hits" and record 0
    recs = [struct.unpack('<fI', r) for r in read_records(a[0], b'HITS', 8)]
    lim = float(a[1]) if len(a) > 1 else 0.0
    hit = [r for r in recs if r[1] != 0xFFFFFFFF]
    print(len(recs), len(hit), sum(1 for r in hit if 0.0 <= r[0] < lim),
          sum(1 for r in hit if math.isinf(r[0])))

def cmd_hit_records(a):    # HITS: each record as "t=... prim=..."
    for t, p in (struct.unpack('<fI', r) for r in read_records(a[0], b'HITS', 8)):
        print('t=%r prim=%s' % (t, 'miss' if p == 0xFFFFFFFF else p), end='; ')
    print()

def cmd_cmp_scaled(a):     # HITS_1 HITS_S SCALE DIAG: agreement of a scaled run with scale 1
    s, diag = float(a[2]), float(a[3])
    h1 = [struct.unpack('<fI', r) for r in read_records(a[0], b'HITS', 8)]
    hs = [struct.unpack('<fI', r) for r in read_records(a[1], b'HITS', 8)]
    n1 = sum(1 for h in h1 if h[1] != 0xFFFFFFFF)
    ns = sum(1 for h in hs if h[1] != 0xFFFFFFFF)
    lost = gained = wrong_t = 0
    for x, y in zip(h1, hs):
        a1, bs = x[1] != 0xFFFFFFFF, y[1] != 0xFFFFFFFF
        if a1 and not bs:
            lost += 1
        elif bs and not a1:
            gained += 1
        elif a1 and bs and abs(y[0] / s - x[0]) > 1e-4 * diag:
            wrong_t += 1
    print(len(h1), n1, ns, lost, gained, wrong_t)

def cmd_diag(a):           # OAVM: diagonal of the mesh box
    lo, hi = oavm_bounds(a[0])
    print(math.sqrt(sum((hi[k] - lo[k]) ** 2 for k in range(3))))

def cmd_keyed_aff(a):      # OUT N: one `k` block of N keys per motion, N `x` using it, a `tpa`
    n = int(a[1])
    s = ['k a {\n']
    for motion in ('transl', 'scale'):
        s.append('%s %d\n' % (motion, n))
        s += ['%d %d 1 %d 0 0 0\n' % (i, 1 + i % 3, i % 5) for i in range(n)]
    s.append('rot %d\n' % n)
    s += ['%d 0 1 0 %d 0 0 0\n' % (i, (i * 37) % 360) for i in range(n)]
    s.append('visibility %d\n' % n)
    s += ['%d 1\n' % i for i in range(n)]
    s.append('}\n')
    s += ['x a { p 3 0 0 0 1 0 0 0 1 0 }\n'] * n
    s.append('tpa %d\n' % n)
    s += ['%d 0 0 %d 0 0 1 1 0 %d 0 0 1 0 1 %d 0 0 1\n' % (i, i, i, i) for i in range(n)]
    with open(a[0], 'w') as o:
        o.write(''.join(s))

def cmd_set_u64(a):        # FILE OFFSET VALUE
    with open(a[0], 'r+b') as f:
        f.seek(int(a[1]))
        f.write(struct.pack('<Q', int(a[2], 0)))

def cmd_get_u64(a):        # FILE OFFSET
    with open(a[0], 'rb') as f:
        f.seek(int(a[1]))
        print(struct.unpack('<Q', f.read(8))[0])

def cmd_magic(a):          # FILE: its first 8 bytes, printable
    with open(a[0], 'rb') as f:
        print(repr(f.read(8))[2:-1])

globals()['cmd_' + sys.argv[1]](sys.argv[2:])
PYEOF
py() { python3 "$W/helper.py" "$@"; }

# ------------------------------------------------------------------------------------------------
# Running and reporting

# run NAME TIMEOUT CMD...: runs CMD (stdin empty, stdout/stderr to $W/NAME.out/.err) under
# timeout and /usr/bin/time -v; sets RC, EL (seconds), RSS (MB), ERR (first line of stderr, and
# the second for a panic).
run() {
    local name=$1 t=$2
    shift 2
    local t0 t1
    t0=$(date +%s%N)
    /usr/bin/time -v -o "$W/$name.time" timeout -k 5 "$t" "$@" \
        >"$W/$name.out" 2>"$W/$name.err" <"$NULLIN"
    RC=$?
    t1=$(date +%s%N)
    finish "$name" "$t0" "$t1"
}
# start NAME TIMEOUT CMD...: as run, in the background; `wait_for NAME` ends it.
start() {
    local name=$1 t=$2
    shift 2
    date +%s%N >"$W/$name.t0"
    /usr/bin/time -v -o "$W/$name.time" timeout -k 5 "$t" "$@" \
        >"$W/$name.out" 2>"$W/$name.err" <"$NULLIN" &
    BGPID=$!
    BG_PIDS+=("$BGPID")
}
wait_for() {
    wait "$BGPID"
    RC=$?
    finish "$1" "$(cat "$W/$1.t0")" "$(date +%s%N)"
}
finish() {
    local name=$1
    EL=$(awk -v a="$2" -v b="$3" 'BEGIN { printf "%.2f", (b - a) / 1e9 }')
    RSS=$(awk -F': ' '/Maximum resident set size/ { printf "%.0f", $2 / 1024 }' "$W/$name.time" 2>/dev/null)
    RSS=${RSS:-?}
    ERR=$(grep -v '^[[:space:]]*$' "$W/$name.err" | grep -v '^note: run with `RUST_BACKTRACE' | head -1 | cut -c1-170)
    if grep -q 'panicked' "$W/$name.err"; then
        ERR="$ERR / $(grep -A1 'panicked' "$W/$name.err" | sed -n 2p | cut -c1-120)"
    fi
    [ -n "$ERR" ] || ERR="(no stderr)"
}
# status RC: "135 (SIGBUS)", "124 (timeout)", "0"...
status() {
    local rc=$1
    if [ "$rc" = 124 ]; then echo "124 (timeout)"
    elif [ "$rc" -gt 128 ] 2>/dev/null && [ "$rc" -lt 160 ]; then
        echo "$rc (SIG$(kill -l $((rc - 128)) 2>/dev/null))"
    else echo "$rc"; fi
}
esc() { printf '%s' "$*" | sed 's/|/\\|/g; s/`/'"'"'/g' | tr '\n' ' '; }
# row ID FAULT CMD RC WHAT
row() {
    printf '| %s | %s | `%s` | %s | %s |\n' "$1" "$(esc "$2")" "$(esc "$3")" "$(status "$4")" "$(esc "$5")"
}
# The verdicts
clean_error() { [ "$RC" = 1 ] && ! grep -q panicked "$W/$1.err"; }
ftype() { if [ -L "$1" ]; then echo "symbolic link"; elif [ -e "$1" ]; then stat -c %F "$1"; else echo "absent"; fi; }
fsize() { if [ -e "$1" ]; then stat -L -c %s "$1" 2>/dev/null || echo "?"; else echo "-"; fi; }
has_opt() { "$1" --help 2>&1 | grep -q -- "$2"; }
gt() { awk -v a="$1" -v b="$2" 'BEGIN { exit !(a + 0 > b + 0) }'; }
mb() { awk -v b="$1" 'BEGIN { printf "%.1f MB", b / 1e6 }'; }
json_num() { # FILE KEY: a top-level number from the JSON on stdout
    python3 -c 'import json,sys
try:
    d = json.load(open(sys.argv[1]))
    v = d.get(sys.argv[2], "?")
except Exception:
    v = "?"
print("null" if v is None else v)' "$1" "$2"
}

# ------------------------------------------------------------------------------------------------
# Inputs shared by several rows

log "inputs in $W (binaries: $BIN)"
log "version: $("$PACK" --version 2>&1 | head -1)"
INP=$W/in
mkdir -p "$INP"
run pack_bunny 300 "$PACK" "$BUNNY" "$INP/bunny.oavm"
[ "$RC" = 0 ] || log "packing the bunny failed: $ERR"
run pack_bunny_z 300 "$PACK" "$BUNNY" "$INP/bunny_z.oavm" --compress --block-size 16K
[ "$RC" = 0 ] || log "packing the compressed bunny failed: $ERR"
run pack_dragon 600 "$PACK" "$DRAGON" "$INP/dragon.oavm"
DRAGON_PACK_S=$EL
[ "$RC" = 0 ] || log "packing the dragon failed: $ERR"
log "dragon packed in ${DRAGON_PACK_S} s"
py rays_box "$INP/bunny.oavm" "$INP/bunny.rays" 20000 7
py rays_box "$INP/dragon.oavm" "$INP/dragon20k.rays" 20000 11
py repeat_rays "$INP/dragon20k.rays" "$INP/dragon.rays" 100     # 2 million rays
py tri "$INP/tri.ply"

# ================================================================================================
# F01-F03: files changed while they are read

trace_changed() { # ID HOW: HOW = truncate | overwrite
    local id=$1 how=$2 f=$W/$1/traced.oavm
    mkdir -p "$W/$id"
    cp "$INP/dragon.oavm" "$f"
    local before
    before=$(fsize "$f")
    start "$id" 120 "$TRACE" "$f" --random 4000000 --threads 2
    sleep 0.7
    local alive=no
    kill -0 "$BGPID" 2>/dev/null && alive=yes
    if [ "$how" = truncate ]; then truncate -s 4096 "$f"; else cp "$INP/bunny.oavm" "$f"; fi
    wait_for "$id"
    local v
    if [ "$alive" = no ]; then v="?: the trace ended before the change;"
    elif [ "$RC" -gt 128 ]; then v="FAULT: killed by a signal, no message;"
    elif clean_error "$id" && grep -q 'changed while it was being read' "$W/$id.err"; then v="OK: clean error;"
    elif [ "$RC" = 0 ]; then v="FAULT: exit 0 after the file changed;"
    else v="?:"; fi
    row "$id" "$3" "oavm-trace dragon.oavm --random 4000000 --threads 2; at 0.7 s: $4" "$RC" \
        "$v running at the change: $alive; file $before -> $(fsize "$f") bytes; after ${EL} s; stderr: $ERR"
}
skip F01 || trace_changed F01 truncate ".oavm truncated while traced" "truncate -s 4096"
skip F02 || trace_changed F02 overwrite ".oavm overwritten in place while traced" "cp bunny.oavm traced.oavm"

if ! skip F03; then
    mkdir -p "$W/F03"
    ply=$W/F03/dragon.ply
    py ply2bin "$DRAGON" "$ply"
    before=$(fsize "$ply")
    # Truncated as soon as the pack has mapped it (it shows in /proc/PID/maps).
    t0=$(date +%s%N)
    timeout -k 5 300 "$PACK" "$ply" "$W/F03/out.oavm" --mem-budget 64M --threads 1 \
        >"$W/F03.out" 2>"$W/F03.err" <"$NULLIN" &
    tpid=$!
    BG_PIDS+=("$tpid")
    alive=no
    for _ in $(seq 1 20000); do
        # The pack is timeout's child.
        pid=$(awk '{ print $1 }' "/proc/$tpid/task/$tpid/children" 2>/dev/null)
        if [ -n "$pid" ] && grep -q -- "$ply" "/proc/$pid/maps" 2>/dev/null; then
            alive=yes         # mapped in a live process (a dead one has no maps)
            truncate -s 1000 "$ply"
            break
        fi
        kill -0 "$tpid" 2>/dev/null || break
    done
    at=$(awk -v a="$t0" -v b="$(date +%s%N)" 'BEGIN { printf "%.2f", (b - a) / 1e9 }')
    wait "$tpid" 2>>"$W/F03.wait"
    RC=$?
    finish F03 "$t0" "$(date +%s%N)"
    if [ "$alive" = no ]; then v="?: the PLY was never seen mapped (the pack ended first?);"
    elif [ "$RC" -gt 128 ]; then v="FAULT: killed by a signal, no message;"
    elif clean_error F03 && grep -q 'changed while it was being read' "$W/F03.err"; then v="OK: clean error;"
    elif [ "$RC" = 0 ]; then v="FAULT: exit 0;"
    else v="?:"; fi
    row F03 "PLY truncated during a streaming pack (mapped)" \
        "oavm-pack dragon.ply out.oavm --mem-budget 64M --threads 1; once mapped: truncate -s 1000 dragon.ply" "$RC" \
        "$v truncated at ${at} s, once seen mapped: $alive; PLY $before -> $(fsize "$ply") bytes; ended after ${EL} s; output: $(ftype "$W/F03/out.oavm"); stderr: $ERR"
fi

# ================================================================================================
# F04-F06: memory budgets

if ! skip F04; then
    run F04 120 "$TRACE" "$INP/bunny_z.oavm" --random 20000 --json
    b=$(json_num "$W/F04.out" pager_budget)
    asked=$(json_num "$W/F04.out" mem_budget)
    avail=$(awk '/MemAvailable/ { printf "%.0f", $2 * 1024 }' /proc/meminfo)
    if [ "$b" = 18446744073709551615 ]; then v="FAULT: no limit (u64::MAX);"
    elif [ "$b" != "?" ] && awk -v b="$b" -v a="$avail" 'BEGIN { exit !(b <= a) }'; then v="OK: bounded by available memory;"
    else v="?:"; fi
    helpdef=$("$TRACE" --help 2>&1 | awk '/--mem-budget/ { f = 1; next } f && NF { print; exit }' | grep -io 'default[^.;)]*' | head -1)
    row F04 "No memory budget by default" "oavm-trace bunny_z.oavm --random 20000 --json (no --mem-budget)" "$RC" \
        "$v pager_budget $b (JSON mem_budget: $asked; MemAvailable now $avail; --help of --mem-budget: '${helpdef:-no default stated}'); threads $(json_num "$W/F04.out" threads); peak RSS ${RSS} MB; stderr: $ERR"
fi

if ! skip F05; then
    # The dragon in real blocks of about 4 MiB (zstd: the pager's slots), under a budget of
    # 16 MiB: room for three such blocks and little more.
    run F05_pack 600 "$PACK" "$DRAGON" "$W/dragon_z4.oavm" --compress --block-size 4M
    run F05 300 "$TRACE" "$W/dragon_z4.oavm" --random 50000 --mem-budget 16M --json
    b=$(json_num "$W/F05.out" pager_budget)
    m=$(json_num "$W/F05.out" max_block_raw_len)
    th=$(json_num "$W/F05.out" threads)
    if [ "$RC" = 0 ] && [ "$b" != "?" ]; then
        if gt "$b" $((16 << 20)); then v="FAULT: budget raised above 16 MiB;"; else v="OK: budget kept at 16 MiB or less;"; fi
    elif clean_error F05; then v="OK: clean error;"
    else v="?:"; fi
    row F05 "--mem-budget raised to (threads+1) x largest block" \
        "oavm-trace dragon_z4.oavm --random 50000 --mem-budget 16M --json (dragon --compress --block-size 4M)" "$RC" \
        "$v pager_budget $b ($(mb "$b")), threads $th, max_block_raw_len $m, pager peak $(json_num "$W/F05.out" pager_peak_resident_bytes); peak RSS ${RSS} MB; ${EL} s; stderr: $ERR"
fi

if ! skip F06; then
    # The compressed dragon (default blocks) with the header's max_block_raw_len raised to 128 MiB and
    # the header checksum recomputed (format-spec §2: xxh3-64 of header bytes 0..248 and the
    # section table); the checksum is the one the binary itself computes and prints.
    mkdir -p "$W/F06"
    c=$W/F06/crafted.oavm
    run F06_pack 600 "$PACK" "$DRAGON" "$c" --compress
    orig=$(py get_u64 "$c" 144)
    py set_u64 "$c" 144 $((128 << 20))
    timeout 60 "$TRACE" "$c" --random 1 >"$W/F06.probe" 2>&1 <"$NULLIN"
    sum=$(grep -o 'computed 0x[0-9a-f]*' "$W/F06.probe" | head -1 | cut -d' ' -f2)
    if [ -n "$sum" ]; then
        py set_u64 "$c" 248 "$sum"
        run F06 300 "$TRACE" "$c" --random 200000 --mem-budget 64M --json
        b=$(json_num "$W/F06.out" pager_budget)
        if [ "$RC" = 0 ] && [ "$b" != "?" ] && gt "$b" $((64 << 20)); then v="FAULT: 64 MiB asked, $(mb "$b") effective;"
        elif [ "$RC" = 0 ]; then v="OK: budget kept;"
        elif clean_error F06; then v="OK: clean error;"
        else v="?:"; fi
        row F06 "Crafted header (max_block_raw_len 128 MiB) under --mem-budget 64M" \
            "oavm-trace crafted.oavm --random 200000 --mem-budget 64M --json (dragon --compress, header field raised, checksum recomputed)" "$RC" \
            "$v max_block_raw_len $orig -> $(py get_u64 "$c" 144); pager_budget $b, threads $(json_num "$W/F06.out" threads), slots $(json_num "$W/F06.out" pager_slots); peak RSS ${RSS} MB; stderr: $ERR"
        run F06b 300 "$TRACE" "$c" --random 200000 --json
        b=$(json_num "$W/F06b.out" pager_budget)
        if [ "$b" = 18446744073709551615 ]; then v="FAULT: no limit;"; elif [ "$RC" = 0 ]; then v="OK: bounded;"; elif clean_error F06b; then v="OK: clean error;"; else v="?:"; fi
        row F06b "The same crafted file, no --mem-budget" "oavm-trace crafted.oavm --random 200000 --json" "$RC" \
            "$v pager_budget $b, threads $(json_num "$W/F06b.out" threads), pager peak $(json_num "$W/F06b.out" pager_peak_resident_bytes) B; peak RSS ${RSS} MB; stderr: $ERR"
    else
        row F06 "Crafted header (max_block_raw_len 128 MiB)" "oavm-trace crafted.oavm" "-" \
            "?: could not get the header checksum from the binary: $(head -1 "$W/F06.probe")"
    fi
fi

# ================================================================================================
# F07: AFF animation time in the number of keys

if ! skip F07; then
    mkdir -p "$W/F07"
    res=""
    v="?"
    declare -A T07
    for n in 6000 12000; do
        py keyed_aff "$W/F07/keys$n.aff" $n
        run "F07_$n" 300 "$PACK" "$W/F07/keys$n.aff" "$W/F07/keys$n.oavm" --time=$((n / 3))
        T07[$n]=$EL
        res="$res N=$n ($(fsize "$W/F07/keys$n.aff") bytes): exit $RC, ${EL} s, RSS ${RSS} MB;"
    done
    ratio=$(awk -v a="${T07[6000]}" -v b="${T07[12000]}" 'BEGIN { printf "%.1f", b / (a > 0.01 ? a : 0.01) }')
    if awk -v a="${T07[6000]}" -v b="${T07[12000]}" 'BEGIN { exit !(b > 1 && b / a > 3) }'; then v="FAULT: quadratic (2N takes ${ratio}x N);"
    elif [ "$RC" = 0 ]; then v="OK: 2N takes ${ratio}x N;"; fi
    row F07 "AFF animation posed in time quadratic in the keys" \
        "oavm-pack keysN.aff out.oavm --time=N/3 (N keys per motion, N x using them, tpa of N keys)" "$RC" \
        "$v$res"
fi

# ================================================================================================
# F08-F16: outputs

if ! skip F08; then
    mkdir -p "$W/F08"
    f=$W/F08/b.oavm
    cp "$INP/bunny.oavm" "$f"
    cp "$INP/bunny.rays" "$W/F08/r.rays"
    before="$(ftype "$f") $(fsize "$f") B magic $(py magic "$f")"
    run F08 120 "$TRACE" "$f" --rays "$W/F08/r.rays" --hits "$f"
    after="$(ftype "$f") $(fsize "$f") B magic $(py magic "$f")"
    if [ "$before" != "$after" ]; then v="FAULT: the traced file was replaced;"; elif clean_error F08; then v="OK: refused, file intact;"; else v="?:"; fi
    row F08 "--hits naming the traced .oavm" "oavm-trace b.oavm --rays r.rays --hits b.oavm" "$RC" \
        "$v b.oavm before: $before; after: $after; stderr: $ERR"
fi

if ! skip F09; then
    mkdir -p "$W/F09"
    r=$W/F09/r.rays
    cp "$INP/bunny.rays" "$r"
    before="$(fsize "$r") B magic $(py magic "$r")"
    run F09 120 "$TRACE" "$INP/bunny.oavm" --rays "$r" --hits "$r"
    after="$(fsize "$r") B magic $(py magic "$r")"
    if [ "$before" != "$after" ]; then v="FAULT: the ray file was replaced;"; elif clean_error F09; then v="OK: refused, file intact;"; else v="?:"; fi
    row F09 "--hits naming the ray file" "oavm-trace bunny.oavm --rays r.rays --hits r.rays" "$RC" \
        "$v r.rays before: $before; after: $after; stderr: $ERR"
fi

if ! skip F10; then
    mkdir -p "$W/F10"
    m=$W/F10/m.ply
    cp "$BUNNY" "$m"
    chmod u+w "$m"
    before="$(fsize "$m") B magic $(py magic "$m")"
    run F10 120 "$PACK" "$m" "$m"
    after="$(fsize "$m") B magic $(py magic "$m")"
    if [ "$before" != "$after" ]; then v="FAULT: the mesh was replaced;"; elif clean_error F10; then v="OK: refused, mesh intact;"; else v="?:"; fi
    row F10 "oavm-pack m.ply m.ply" "oavm-pack m.ply m.ply" "$RC" "$v m.ply before: $before; after: $after; stderr: $ERR"
fi

if ! skip F11; then
    mkdir -p "$W/F11"
    cp "$INP/tri.ply" "$W/F11/real.oavm"       # the link's target: some existing file
    ln -s real.oavm "$W/F11/link.oavm"
    before="link: $(ftype "$W/F11/link.oavm"), target $(fsize "$W/F11/real.oavm") B"
    run F11 120 "$PACK" "$BUNNY" "$W/F11/link.oavm"
    after="link: $(ftype "$W/F11/link.oavm"), target $(fsize "$W/F11/real.oavm") B magic $(py magic "$W/F11/real.oavm")"
    if [ ! -L "$W/F11/link.oavm" ]; then v="FAULT: the symlink was replaced by a $(ftype "$W/F11/link.oavm");"
    elif [ "$RC" = 0 ] && py magic "$W/F11/real.oavm" | grep -q OAVM; then v="OK: written through the link;"
    elif clean_error F11; then v="OK: clean error, link kept;"
    else v="?:"; fi
    row F11 "A symlink given as output" "oavm-pack bunny.ply link.oavm (link.oavm -> real.oavm)" "$RC" \
        "$v before: $before; after: $after; stderr: $ERR"
fi

if ! skip F12; then
    mkdir -p "$W/F12"
    mkfifo "$W/F12/fifo"
    before=$(ftype "$W/F12/fifo")
    run F12 60 "$TRACE" "$INP/bunny.oavm" --rays "$INP/bunny.rays" --hits "$W/F12/fifo"
    after=$(ftype "$W/F12/fifo")
    if [ "$before" != "$after" ]; then v="FAULT: the FIFO was replaced;"; elif clean_error F12; then v="OK: refused, FIFO kept;"; else v="?:"; fi
    row F12 "A FIFO given as output" "oavm-trace bunny.oavm --rays r.rays --hits fifo" "$RC" \
        "$v fifo: $before -> $after; ${EL} s; stderr: $ERR"
fi

if ! skip F13; then
    mkdir -p "$W/F13"
    dev=$W/F13/dev
    if mknod "$dev" c 1 3 2>"$W/F13.mknod"; then
        before="$(ftype "$dev") $(stat -c '%t,%T' "$dev")"
        run F13 120 "$PACK" "$BUNNY" "$dev"
        after="$(ftype "$dev") $( [ -c "$dev" ] && stat -c '%t,%T' "$dev" || fsize "$dev")"
        if [ ! -c "$dev" ]; then v="FAULT: the device node was replaced;"; elif clean_error F13; then v="OK: refused, node kept;"; else v="?:"; fi
        row F13 "A device given as output (our own node, c 1 3, in OUTDIR)" "oavm-pack bunny.ply OUTDIR/dev" "$RC" \
            "$v dev: $before -> $after; stderr: $ERR"
    else
        row F13 "A device given as output" "mknod OUTDIR/dev c 1 3" "-" "?: mknod failed: $(head -1 "$W/F13.mknod")"
    fi
fi

if ! skip F14; then
    mkdir -p "$W/F14"
    run F14_ok 300 "$TRACE" "$INP/dragon.oavm" --rays "$INP/dragon.rays" --hits "$W/F14/ok.hits"
    ok_el=$EL ok_rc=$RC
    run F14 300 "$TRACE" "$INP/dragon.oavm" --rays "$INP/dragon.rays" --hits "$W/F14/no/such/dir/x.hits"
    if [ "$RC" = 0 ]; then v="?: exit 0;"
    elif ! gt "$ok_el" 0.5; then v="?: the good run is too short to tell;"
    elif gt "$EL" "$(awk -v b="$ok_el" 'BEGIN { print 0.5 * b }')"; then v="FAULT: fails only after the trace;"
    else v="OK: fails before the work;"; fi
    row F14 "Bad output path fails only after the whole trace" \
        "oavm-trace dragon.oavm --rays dragon.rays (2M rays) --hits no/such/dir/x.hits" "$RC" \
        "$v ${EL} s against ${ok_el} s for the same trace to a good path (exit $ok_rc); stderr: $ERR"
    run F14r 300 "$TRACE" "$INP/dragon.oavm" --width 2048 --height 2048 -o "$W/F14/no/such/dir/x.png"
    el_bad=$EL rc_bad=$RC err_bad=$ERR
    run F14r_ok 300 "$TRACE" "$INP/dragon.oavm" --width 2048 --height 2048 -o "$W/F14/x.png"
    if [ "$rc_bad" = 0 ]; then v="?: exit 0;"
    elif ! gt "$EL" 0.5; then v="?: the good run is too short to tell;"
    elif gt "$el_bad" "$(awk -v b="$EL" 'BEGIN { print 0.5 * b }')"; then v="FAULT: fails only after the render;"
    else v="OK: fails before the work;"; fi
    row F14b "Bad output path (render)" "oavm-trace dragon.oavm --width 2048 --height 2048 -o no/such/dir/x.png" "$rc_bad" \
        "$v ${el_bad} s against ${EL} s for the same render to a good path (exit $RC); stderr: $err_bad"
fi

if ! skip F15; then
    d=$W/F15/out
    mkdir -p "$d"
    # Kill -9 the pack as soon as a file it has open in the output directory (named or not:
    # /proc/PID/fd shows O_TMPFILE files as "DIR/#inode (deleted)") holds bytes: it is writing
    # the output. Else at a time limit (4x a normal 2-thread pack). Once that file's descriptor
    # is known, its size is polled with shell builtins only (a write can take a few ms).
    "$PACK" "$DRAGON" "$d/dragon.oavm" --threads 1 >"$W/F15.out" 2>"$W/F15.err" <"$NULLIN" &
    pid=$!
    BG_PIDS+=("$pid")
    t0=$(date +%s%N)
    limit=$(awk -v s="$DRAGON_PACK_S" 'BEGIN { printf "%.0f", (s > 1 ? s : 1) * 4 }')
    how="at the time limit"
    killed=no outfd="" outname=""
    while kill -0 "$pid" 2>/dev/null; do
        if [ -z "$outfd" ]; then
            while read -r n tgt; do
                case "$tgt" in "$d"/*) outfd=$n; outname=${tgt#"$d"/}; break ;; esac
            done < <(ls -l "/proc/$pid/fd" 2>/dev/null | awk '$10 == "->" { print $9, $11, $12 }')
        elif [ -s "/proc/$pid/fd/$outfd" ]; then
            sz=$(stat -L -c %s "/proc/$pid/fd/$outfd" 2>/dev/null)
            kill -9 "$pid" 2>/dev/null && killed=yes
            how="while writing '$outname' (${sz:-?} bytes so far)"
            break
        elif [ ! -e "/proc/$pid/fd/$outfd" ]; then
            outfd=""
        fi
        [ "${EPOCHREALTIME%.*}" -gt $(( ${t0:0:10} + limit )) ] && break
    done
    kill -9 "$pid" 2>/dev/null && killed=yes
    wait "$pid" 2>>"$W/F15.wait"
    RC=$?
    el=$(awk -v a="$t0" -v b="$(date +%s%N)" 'BEGIN { printf "%.2f", (b - a) / 1e9 }')
    left=$(ls -A "$d" | tr '\n' ' ')
    if [ "$killed" = no ]; then v="?: the pack ended (exit $RC) before it could be killed;"
    elif [ -n "$left" ]; then v="FAULT: left behind: $left;"
    else v="OK: nothing left;"; fi
    row F15 "Temporary file left after SIGKILL of oavm-pack during its write" \
        "oavm-pack dragon.ply out/dragon.oavm --threads 1; kill -9 when it has a file open in out/" "$RC" \
        "$v killed $how, after ${el} s; out/ holds: ${left:-nothing}"
fi

if ! skip F16; then
    if command -v strace >/dev/null; then
        d=$W/F16
        mkdir -p "$d"
        # Twice: the first pack creates DIR/b.oavm, the second replaces it.
        what="" ok=yes
        for k in new replace; do
            run "F16_$k" 300 strace -f -y -o "$d/strace_$k.txt" -e trace=fsync,fdatasync,rename,renameat,renameat2,linkat \
                "$PACK" "$BUNNY" "$d/b.oavm"
            sys=$(grep -E '^[0-9]+ +(fsync|fdatasync|rename|renameat|renameat2|linkat)\(' "$d/strace_$k.txt" |
                sed -E 's/^[0-9]+ +//; s/AT_FDCWD<[^>]*>, //g; s/ *<unfinished \.\.\.>//; s/ += .*$//' |
                sed "s|$d|DIR|g" | tr '\n' ';' | sed 's/;/; /g')
            # Synced: an fsync of the directory itself after the last call that names the file.
            dirsync=$(awk -v dir="$d" '/(rename|linkat)[a-z0-9]*\(/ { named = 1; synced = 0 }
                named && /f(data)?sync\(/ && index($0, "<" dir ">") { synced = 1 }
                END { print (named && synced) ? "yes" : "no" }' "$d/strace_$k.txt")
            [ "$dirsync" = yes ] || ok=no
            what="$what $k file (exit $RC, directory synced after naming: $dirsync): $sys"
        done
        if [ "$ok" = yes ]; then v="OK: the directory is synced after the file is named;"; else v="FAULT: no fsync of the directory after the rename;"; fi
        row F16 "No directory fsync after the rename" "strace -f -y -e trace=fsync,fdatasync,rename*,linkat oavm-pack bunny.ply DIR/b.oavm (twice)" "$RC" \
            "$v$what"
    else
        row F16 "No directory fsync after the rename" "strace" "-" "?: strace is not installed"
    fi
fi

# ================================================================================================
# F17-F21: counts and reads without caps

if ! skip F17; then
    run F17 60 "$TRACE" "$INP/bunny.oavm" --random 18446744073709551615
    if [ "$RC" = 101 ] || grep -q panicked "$W/F17.err"; then v="FAULT: panic;"; elif clean_error F17; then v="OK: clean error;"; else v="?:"; fi
    row F17 "--random u64::MAX" "oavm-trace bunny.oavm --random 18446744073709551615" "$RC" "$v ${EL} s, RSS ${RSS} MB; stderr: $ERR"
fi
if ! skip F18; then
    ( ulimit -v $((16 << 20)); run F18 120 "$TRACE" "$INP/bunny.oavm" --random 1000000000000
      echo "$RC|$EL|$RSS|$ERR" >"$W/F18.res" )
    IFS='|' read -r RC EL RSS ERR <"$W/F18.res"
    if [ "$RC" -gt 128 ]; then v="FAULT: aborted;"; elif [ "$RC" = 101 ]; then v="FAULT: panic;"; elif clean_error F18; then v="OK: clean error;"; else v="?:"; fi
    row F18 "--random 1000000000000" "oavm-trace bunny.oavm --random 1000000000000 (ulimit -v 16G)" "$RC" "$v ${EL} s, RSS ${RSS} MB; stderr: $ERR"
fi
if ! skip F19; then
    mkdir -p "$W/F19"
    run F19 60 "$TRACE" "$INP/bunny.oavm" --random 10 --hits "$W/F19/x.hits"
    if [ "$RC" = 0 ] && [ ! -e "$W/F19/x.hits" ]; then v="FAULT: accepted and ignored;"
    elif [ "$RC" = 2 ] || clean_error F19; then v="OK: refused;"
    else v="?:"; fi
    row F19 "--hits with --random accepted and ignored" "oavm-trace bunny.oavm --random 10 --hits x.hits" "$RC" \
        "$v x.hits: $(ftype "$W/F19/x.hits"); stderr: $ERR"
fi
if ! skip F20; then
    mkdir -p "$W/F20"
    r=$W/F20/huge.rays
    count=$(( ((100 << 30) - 16) / 32 ))
    py ray_header "$r" "$count"
    truncate -s $((16 + count * 32)) "$r"
    ( ulimit -v $((16 << 20)); run F20 300 "$TRACE" "$INP/bunny.oavm" --rays "$r" --hits "$W/F20/x.hits"
      echo "$RC|$EL|$RSS|$ERR" >"$W/F20.res" )
    IFS='|' read -r RC EL RSS ERR <"$W/F20.res"
    if [ "$RC" -gt 128 ] || [ "$RC" = 101 ]; then v="FAULT: crash;"
    elif grep -qi 'alloc\|memory' "$W/F20.err" && ! grep -q 'more than the' "$W/F20.err"; then v="FAULT: tried to read it whole (the allocation failed);"
    elif clean_error F20; then v="OK: refused before reading;"
    else v="?:"; fi
    row F20 "Ray file read whole, no cap (sparse 100 GiB, valid header)" \
        "oavm-trace bunny.oavm --rays huge.rays --hits x.hits (ulimit -v 16G)" "$RC" \
        "$v header count $count; ${EL} s, peak RSS ${RSS} MB; stderr: $ERR"
    rm -f "$r"
fi
if ! skip F21; then
    mkdir -p "$W/F21"
    printf 'p 3 0 0 0 1 0 0 0 1 0\ni 0 big.aff\n' >"$W/F21/top.aff"
    truncate -s $((2 << 30)) "$W/F21/big.aff"
    ( ulimit -v $((16 << 20)); run F21 300 "$PACK" "$W/F21/top.aff" "$W/F21/out.oavm"
      echo "$RC|$EL|$RSS|$ERR" >"$W/F21.res" )
    IFS='|' read -r RC EL RSS ERR <"$W/F21.res"
    if [ "$RC" -gt 128 ] || [ "$RC" = 101 ]; then v="FAULT: crash;"
    elif [ "$RSS" != "?" ] && gt "$RSS" 1000; then v="FAULT: read the include whole (${RSS} MB);"
    elif clean_error F21; then v="OK: refused before reading;"
    else v="?:"; fi
    row F21 "AFF include read whole, no cap (sparse 2 GiB include)" "oavm-pack top.aff out.oavm (top.aff: i 0 big.aff)" "$RC" \
        "$v ${EL} s, peak RSS ${RSS} MB; stderr: $ERR"
    rm -f "$W/F21/big.aff"
fi

# ================================================================================================
# F22: a leaf that cannot split, beyond MAX_BLOCK_RAW_LEN (1 GiB = 24.4M triangles of 44 bytes)

if ! skip F22; then
    mkdir -p "$W/F22"
    n=${FAULTS_DUP_COPIES:-25000000}
    py dup "$W/F22/dup.ply" "$n"
    ( ulimit -v $((20 << 20)); run F22 900 "$PACK" "$W/F22/dup.ply" "$W/F22/dup.oavm"
      echo "$RC|$EL|$RSS|$ERR" >"$W/F22.res" )
    IFS='|' read -r RC EL RSS ERR <"$W/F22.res"
    prc=$RC pel=$EL prss=$RSS perr=$ERR
    what="pack: exit $prc, ${pel} s, peak RSS ${prss} MB, output $(fsize "$W/F22/dup.oavm") B"
    if [ -e "$W/F22/dup.oavm" ]; then
        what="$what, header max_block_raw_len $(py get_u64 "$W/F22/dup.oavm" 144)"
        run F22t 300 "$TRACE" "$W/F22/dup.oavm" --random 1000
        what="$what; trace --random 1000: exit $RC, stderr: $ERR"
        if [ "$RC" != 0 ]; then v="FAULT: the writer made a file the tracer refuses;"; else v="OK: the file traces;"; fi
    elif [ "$prc" = 1 ] && grep -qi 'block' "$W/F22.err"; then v="OK: refused at pack time;"; what="$what; stderr: $perr"
    else v="?:"; what="$what; stderr: $perr"; fi
    row F22 "Writer does not enforce MAX_BLOCK_RAW_LEN" "oavm-pack dup.ply dup.oavm ($n copies of one tiny triangle + 1)" "$prc" "$v $what"
    rm -f "$W/F22/dup.ply" "$W/F22/dup.oavm"
fi

# ================================================================================================
# F23: a write error during pack names the output

if ! skip F23; then
    mkdir -p "$SMALL"
    if mount -t tmpfs -o size=1M tmpfs "$SMALL" 2>"$W/F23.mount"; then
        how="tmpfs of 1 MiB"
        run F23 120 "$PACK" "$BUNNY" "$SMALL/b.oavm"
        left=$(ls -A "$SMALL" | tr '\n' ' ')
        umount "$SMALL"
    else
        how="ulimit -f 64 (mount failed: $(head -1 "$W/F23.mount"))"
        run F23 120 bash -c "ulimit -f 64; trap '' XFSZ; exec \"\$0\" \"\$@\"" "$PACK" "$BUNNY" "$SMALL/b.oavm"
        left=$(ls -A "$SMALL" | tr '\n' ' ')
    fi
    if grep -q "small/b.oavm" "$W/F23.err" && clean_error F23; then v="OK: the message names the output;"
    elif [ "$RC" != 0 ]; then v="FAULT: the message does not name the output;"
    else v="?: exit 0;"; fi
    row F23 "Write error during pack loses the output path" "oavm-pack bunny.ply small/b.oavm ($how)" "$RC" \
        "$v stderr: $ERR; left in small/: ${left:-nothing}"
fi

# ================================================================================================
# F24-F27: answers

if ! skip F24; then
    mkdir -p "$W/F24"
    run F24_pack 60 "$PACK" "$INP/tri.ply" "$W/F24/tri.oavm"
    py subnormal "$W/F24/s.rays"
    run F24 60 "$TRACE" "$W/F24/tri.oavm" --rays "$W/F24/s.rays" --hits "$W/F24/s.hits"
    if [ -e "$W/F24/s.hits" ]; then
        recs=$(py hit_records "$W/F24/s.hits")
        r0=${recs%%;*}
        case "$r0" in
            *"t=inf prim=miss"*) v="OK: a miss;" ;;
            *"t=inf prim="*) v="FAULT: a hit record with t = +inf;" ;;
            *) v="?:" ;;
        esac
        row F24 "Subnormal direction gives a hit with t = +inf" \
            "oavm-trace tri.oavm --rays s.rays --hits s.hits (ray 0: o (0.2,0.2,2), d (0,0,-1e-40); ray 1: d (0,0,-1))" "$RC" \
            "$v records: $recs"
    else
        row F24 "Subnormal direction gives a hit with t = +inf" "oavm-trace tri.oavm --rays s.rays --hits s.hits" "$RC" "?: no hits file; stderr: $ERR"
    fi
fi

if ! skip F25; then
    mkdir -p "$W/F25"
    py grid "$W/F25/flat.ply" 16
    run F25_pack 60 "$PACK" "$W/F25/flat.ply" "$W/F25/flat.oavm"
    ref=$(py plane "$W/F25/p.rays" 3000 5 16)
    run F25 60 "$TRACE" "$W/F25/flat.oavm" --rays "$W/F25/p.rays" --hits "$W/F25/p.hits"
    if [ -e "$W/F25/p.hits" ]; then
        read -r n hits at0 infs <<<"$(py hits "$W/F25/p.hits" 1e-6)"
        read -r rhits rzero <<<"$ref"
        if [ "$hits" -lt "$rhits" ]; then v="FAULT: $((rhits - hits)) hits missed;"; else v="OK: every hit found;"; fi
        row F25 "Rays from a point on a flat mesh (t = 0, tmin = 0) missed" \
            "oavm-trace flat.oavm --rays p.rays --hits p.hits (16x16 squares in z = 0; 3000 origins on it, random directions)" "$RC" \
            "$v oavm $hits hits of $n ($at0 at t < 1e-6); f64 brute force $rhits hits ($rzero at t = 0)"
    else
        row F25 "Rays from a point on a flat mesh missed" "oavm-trace flat.oavm --rays p.rays --hits p.hits" "$RC" "?: no hits file; stderr: $ERR"
    fi
fi

scale_row() { # ID SCALE
    local id=$1 s=$2 d=$W/$1
    mkdir -p "$d"
    if [ ! -e "$W/scale1.hits" ]; then
        run scale1 120 "$TRACE" "$INP/bunny.oavm" --rays "$INP/bunny.rays" --hits "$W/scale1.hits"
    fi
    py ply2bin "$BUNNY" "$d/bunny.ply" "$s"
    run "${id}_pack" 120 "$PACK" "$d/bunny.ply" "$d/bunny.oavm"
    local prc=$RC perr=$ERR
    if [ "$prc" = 0 ]; then
        py scale_rays "$INP/bunny.rays" "$d/r.rays" "$s"
        run "$id" 120 "$TRACE" "$d/bunny.oavm" --rays "$d/r.rays" --hits "$d/r.hits"
        if [ -e "$d/r.hits" ]; then
            read -r n n1 ns lost gained wrong <<<"$(py cmp_scaled "$W/scale1.hits" "$d/r.hits" "$s" "$(py diag "$INP/bunny.oavm")")"
            if [ $((lost + gained + wrong)) -gt $((n / 1000 + 2)) ]; then v="FAULT: wrong answers, no error;"; else v="OK: same answers;"; fi
            row "$id" "Bunny scaled by $s: hits lost with no error" \
                "oavm-pack bunny_x$s.ply; oavm-trace --rays (the scale-1 rays, origins x $s) --hits" "$RC" \
                "$v pack exit 0; $ns hits of $n against $n1 at scale 1: $lost lost, $gained gained, $wrong at another t"
        else
            row "$id" "Bunny scaled by $s" "oavm-trace bunny_x$s.oavm --rays --hits" "$RC" "?: no hits file; stderr: $ERR"
        fi
    else
        if [ "$prc" = 1 ] && ! grep -q panicked "$W/${id}_pack.err"; then v="OK: refused at pack time;"; else v="?:"; fi
        row "$id" "Bunny scaled by $s: hits lost with no error" "oavm-pack bunny_x$s.ply bunny.oavm" "$prc" \
            "$v output $(ftype "$d/bunny.oavm"); stderr: $perr"
    fi
}
skip F26 || scale_row F26 1e-20
skip F27 || scale_row F27 1e-30

log "done"
