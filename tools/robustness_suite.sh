#!/usr/bin/env bash
# The robustness suite of docs/PERFORMANCE.md in one command: the 11 built-in stress scenes
# and orbit, desk, posters and both KITTI clips, each run once, then one line per source with
# tools/robustness.py's figures and the semi-dense accuracy from report.json.
#
# usage: tools/robustness_suite.sh OUT_DIR [sdslam run options...]
#   e.g. tools/robustness_suite.sh /tmp/suite                      (threaded, unpaced)
#        tools/robustness_suite.sh /tmp/det --deterministic --no-semidense
#        tools/robustness_suite.sh /tmp/rt --realtime --config my.toml
# SDSLAM (default target/release/sdslam) picks the binary; DATA (default ../shared/data) the
# sequences. CAMERA=fisheye runs the 11 built-in scenes through the 170-degree Kannala-Brandt
# lens instead (`synthetic:NAME,fisheye`; the recorded sequences are pinhole and left out).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:?usage: tools/robustness_suite.sh OUT_DIR [sdslam run options...]}"
shift
bin="${SDSLAM:-$here/../target/release/sdslam}"
data="${DATA:-$here/../../shared/data}"
[ -x "$bin" ] || { echo "no sdslam binary at $bin (cargo build --release, or set SDSLAM)" >&2; exit 1; }
[ -d "$data/synthetic/desk" ] || { echo "no sequences under $data (set DATA)" >&2; exit 1; }
python3 -c "import numpy" 2>/dev/null || { echo "tools/robustness.py needs numpy (pip install numpy)" >&2; exit 1; }
mkdir -p "$out"
scenes=(rotation outward-loop forward fast-blur exposure-step blackout repetitive
    moving-objects low-light auto-exposure)
case "${CAMERA:-pinhole}" in
pinhole)
    sources=(
        "desk $data/synthetic/desk $data/synthetic/desk/groundtruth.txt"
        "posters $data/synthetic/posters $data/synthetic/posters/groundtruth.txt"
        "kitti06_51 $data/real/kitti06_51 $data/real/kitti06_51/groundtruth.txt"
        "kitti01_51 $data/real/kitti01_51 $data/real/kitti01_51/groundtruth.txt"
        "orbit synthetic -"
    )
    for s in "${scenes[@]}"; do
        sources+=("$s synthetic:$s -")
    done
    ;;
fisheye)
    sources=("orbit synthetic:fisheye -")
    for s in "${scenes[@]}"; do
        sources+=("$s synthetic:$s,fisheye -")
    done
    ;;
*)
    echo "CAMERA must be pinhole or fisheye" >&2
    exit 1
    ;;
esac
for entry in "${sources[@]}"; do
    read -r name src gt <<<"$entry"
    o="$out/$name"
    rm -rf "$o"
    if ! "$bin" -q run "$src" --no-plots "$@" --out "$o" >"$o.log" 2>&1; then
        echo "$name: sdslam exited with an error (see $o.log)"
    fi
    args=("$o")
    [ "$gt" != "-" ] && args+=("$gt")
    python3 - "$name" "$o" "$(python3 "$here/robustness.py" "${args[@]}" 2>&1)" <<'PY'
import json, sys
name, out, text = sys.argv[1], sys.argv[2], sys.argv[3]
try:
    r = json.loads(text)
except ValueError:
    print(f"{name:15s} {text.strip()[-200:]}")
    sys.exit(0)
def g(k):
    v = r.get(k)
    return "-" if v is None else v
line = (f"{name:15s} first pose {g('first_pose_frame')} | tracked after it {g('tracked_after_first')}"
        f" | kf ATE {g('kf_ate_pct_path')}% of path | worst Ok {g('worst_ok_frame_pct_path')}%"
        f" | Ok > 5% off (all maps) {g('ok_frames_off_all_maps')} | maps {g('maps_made')}"
        f" | posed in any map {g('frames_with_pose_any_map')}")
try:
    a = json.load(open(f"{out}/report.json")).get("semidense_accuracy") or {}
    if a:
        line += (f" | cloud {100 * a['median_relative_error']:.3f}% / "
                 f"{100 * a['outliers_10pct']:.2f}% / {a['points_per_keyframe']:.0f} per kf")
except (OSError, KeyError, ValueError):
    pass
print(line)
PY
done
