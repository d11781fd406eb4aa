#!/usr/bin/env python3
"""Relative pose errors between consecutive keyframes of a run against the ground truth: the
rotation error of each keyframe-to-keyframe motion (degrees) and its baseline over the true
one (after the keyframe-centre Sim3's scale). These are what the semi-dense search sees of
the poses: a 0.1 deg error of a neighbour's rotation moves its epipolar lines by about
0.0017 f pixels (0.9 px at f = 520).

usage: tools/keyframe_pose_errors.py KEYFRAMES.txt GROUNDTRUTH.txt [--each]
"""
import sys
import numpy as np

from robustness import umeyama  # tools/robustness.py: the suite's Sim3 alignment


def read_tum(p):
    rows = [[float(x) for x in l.split()[:8]] for l in open(p) if l.strip() and not l.startswith('#')]
    return np.array(rows)


def rot(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def angle_deg(r):
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    kf, gt = read_tum(sys.argv[1]), read_tum(sys.argv[2])
    pairs = [(i, int(np.argmin(np.abs(gt[:, 0] - t)))) for i, t in enumerate(kf[:, 0])]
    pairs = [(i, k) for i, k in pairs if abs(gt[k, 0] - kf[i, 0]) <= 0.02]
    if len(pairs) < 3:
        sys.exit("fewer than 3 keyframes matched the ground truth by timestamp")
    src = np.array([kf[i, 1:4] for i, _ in pairs]); dst = np.array([gt[k, 1:4] for _, k in pairs])
    scale, _, _ = umeyama(src, dst)
    rel, base = [], []
    for (i0, k0), (i1, k1) in zip(pairs, pairs[1:]):
        r_est = rot(kf[i0, 4:8]).T @ rot(kf[i1, 4:8])
        r_gt = rot(gt[k0, 4:8]).T @ rot(gt[k1, 4:8])
        rel.append(angle_deg(r_est.T @ r_gt))
        b_gt = np.linalg.norm(gt[k1, 1:4] - gt[k0, 1:4])
        b_est = scale * np.linalg.norm(kf[i1, 1:4] - kf[i0, 1:4])
        base.append(b_est / b_gt if b_gt > 0 else float('nan'))
        if '--each' in sys.argv:
            print(f"{kf[i1, 0]:.3f} relative rotation error {rel[-1]:.3f} deg, baseline x{base[-1]:.3f} ({b_gt:.3f} m)")
    rel, base = np.array(rel), np.array(base)
    print(f"{len(rel)} keyframe pairs: relative rotation error median {np.median(rel):.3f} deg, "
          f"90th percentile {np.percentile(rel, 90):.3f}, max {rel.max():.3f}; "
          f"baseline over truth median {np.nanmedian(base):.3f}")


if __name__ == "__main__":
    main()
