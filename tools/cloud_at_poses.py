#!/usr/bin/env python3
"""Moves each keyframe's points of a semi-dense cloud from the pose they were reconstructed at
to another pose of the same keyframe: e.g. a cloud densified at ground-truth poses, placed
where a run put its keyframes. With `sdslam eval cloud` this splits a cloud's depth error into
the search's (ground-truth poses), the neighbours' relative poses, and each keyframe's
placement (docs/PERFORMANCE.md, 2026-12-07 tenth session).

usage: tools/cloud_at_poses.py CLOUD.ply FROM_POSES.txt TO_POSES.txt OUT.ply
  FROM_POSES: the poses the cloud was made at (TUM, T_wc); TO_POSES: the keyframes' new poses.
  Depths are rescaled from FROM's units to TO's by the Sim3 between the keyframe centres.
"""
import sys
import numpy as np

from robustness import umeyama  # tools/robustness.py: the suite's Sim3 alignment


def read_tum(p):
    return {round(float(l.split()[0]), 6): np.array([float(x) for x in l.split()[1:8]])
            for l in open(p) if l.strip() and not l.startswith('#')}


def matrix(v):
    x, y, z, w = v[3:]
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = v[:3]
    return m


def main():
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    ply, from_p, to_p, out = sys.argv[1:]
    src, dst = read_tum(from_p), read_tum(to_p)
    near = lambda d, t: min(d, key=lambda g: abs(g - t))
    raw = open(ply, 'rb').read()
    end = raw.index(b'end_header\n') + len(b'end_header\n')
    header = raw[:end].decode('ascii', 'replace')
    if 'property double timestamp' not in header or 'property float sigma' not in header:
        sys.exit(f"{ply}: not an sdslam semi-dense cloud (x y z rgb sigma timestamp)")
    dt = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('r', 'u1'), ('g', 'u1'),
                   ('b', 'u1'), ('s', '<f4'), ('t', '<f8')])
    pts = np.frombuffer(raw[end:], dtype=dt).copy()
    ts = sorted(dst)
    a = np.array([src[near(src, t)][:3] for t in ts]); b = np.array([dst[t][:3] for t in ts])
    # Scale of FROM's units in TO's: Umeyama between the keyframe centres.
    scale, _, _ = umeyama(a, b)
    for t in np.unique(pts['t']):
        m = pts['t'] == t
        x = np.stack([pts['x'][m], pts['y'][m], pts['z'][m], np.ones(m.sum())])
        cam = np.linalg.inv(matrix(src[near(src, t)])) @ x
        cam[:3] *= scale
        moved = matrix(dst[near(dst, t)]) @ cam
        pts['x'][m], pts['y'][m], pts['z'][m] = moved[0], moved[1], moved[2]
    with open(out, 'wb') as f:
        f.write(raw[:end] + pts.tobytes())
    print(f"{len(pts)} points of {len(np.unique(pts['t']))} keyframes moved; scale {scale:.4f}")


if __name__ == "__main__":
    main()
