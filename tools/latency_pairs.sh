#!/usr/bin/env bash
# Interleaved A/B runs of `sdslam bench latency` on 2 pinned cores, with the process's CPU
# share and peak RSS from /usr/bin/time: the comparison issue 29's figures are measured with.
# One run of the bench spreads by about +-10% in CPU share and keyframe time on the project
# host (docs/PERFORMANCE.md, sixteenth session), so a change is judged on the medians of
# several interleaved pairs, never on one run.
#
# usage: tools/latency_pairs.sh OUT_DIR RUNS BIN_A BIN_B [bench latency options...]
#   e.g. tools/latency_pairs.sh /tmp/lp 3 /tmp/old/sdslam target/release/sdslam
#        tools/latency_pairs.sh /tmp/lp 3 target/release/sdslam target/release/sdslam --simd 128
# SOURCE (default ../shared/data/synthetic/desk) picks the sequence, CORES (default 0,1) the
# CPUs. Prints one line per run and the medians of each binary.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:?usage: tools/latency_pairs.sh OUT_DIR RUNS BIN_A BIN_B [options...]}"
runs="${2:?number of interleaved pairs}"
bin_a="${3:?first binary}"
bin_b="${4:?second binary}"
shift 4
source="${SOURCE:-$here/../../shared/data/synthetic/desk}"
cores="${CORES:-0,1}"
for b in "$bin_a" "$bin_b"; do
    [ -x "$b" ] || { echo "no sdslam binary at $b" >&2; exit 1; }
done
[ -x /usr/bin/time ] || { echo "needs /usr/bin/time (apt-get install time)" >&2; exit 1; }
mkdir -p "$out"
for i in $(seq 1 "$runs"); do
    for side in a b; do
        bin="$bin_a"
        [ "$side" = b ] && bin="$bin_b"
        o="$out/${side}$i"
        rm -rf "$o"
        /usr/bin/time -f "%U %S %e %M" -o "$o.time" taskset -c "$cores" "$bin" -q bench latency \
            "$source" --cores "$cores" "$@" --out "$o" >"$o.log" 2>&1 ||
            { echo "run $o failed (see $o.log)" >&2; exit 1; }
    done
done
python3 - "$out" "$runs" "$cores" <<'PY'
import json, statistics, sys
out, runs, cores = sys.argv[1], int(sys.argv[2]), sys.argv[3]
n_cores = len(cores.split(','))
rows = {'a': [], 'b': []}
for i in range(1, runs + 1):
    for side in 'ab':
        o = f'{out}/{side}{i}'
        r = json.load(open(o + '/report.json'))
        u, s, e, m = open(o + '.time').read().split()[-4:]
        t = r.get('timing_ms', {})
        acc = r.get('semidense_accuracy') or {}
        row = {
            'cpu %': 100 * (float(u) + float(s)) / float(e) / n_cores,
            'rss MB': int(m) / 1024,
            'track p50': t.get('tracking', {}).get('p50', 0),
            'track p99': t.get('tracking', {}).get('p99', 0),
            'kf p50': t.get('semidense_keyframe', {}).get('p50', 0),
            'depth p50': t.get('semidense_depth', {}).get('p50', 0),
            'misses': r.get('deadline_misses', 0),
            'pts/kf': acc.get('points_per_keyframe', 0),
        }
        rows[side].append(row)
        print(f'{side}{i}: ' + '  '.join(f'{k} {v:.1f}' for k, v in row.items()))
for side in 'ab':
    med = {k: statistics.median(r[k] for r in rows[side]) for k in rows[side][0]}
    print(f'median {side}: ' + '  '.join(f'{k} {v:.1f}' for k, v in med.items()))
PY
