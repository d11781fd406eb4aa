#!/usr/bin/env python3
"""The first frame at which two views of a sequence carry enough parallax to initialise, from its
ground truth: for each frame j with a depth map, pixels on a grid are lifted to the world and
projected into every earlier frame i; where at least half of them are in view of i, the median
angle between the rays from the two camera centres is the parallax of (i, j). The onset is the
first j whose best i reaches the threshold (1 deg, as the evaluation protocol's robustness bar
counts from). Render the sequence with `sdslam synth --depth-every 1` for frame resolution.

usage: tools/parallax_onset.py SEQUENCE_DIR [THRESHOLD_DEG]
"""
import sys
import numpy as np
from PIL import Image

def read_yaml(p):
    v = {}
    for line in open(p):
        if ':' in line and line.startswith('Camera.'):
            k, x = line.split(':', 1)
            try:
                v[k.strip()[7:]] = float(x.split('#')[0])
            except ValueError:
                pass
    return v

def quat_to_r(qx, qy, qz, qw):
    x, y, z, w = qx, qy, qz, qw
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])

def main():
    seq = sys.argv[1]
    thr = float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
    cam = read_yaml(f"{seq}/camera.yaml")
    fx, fy, cx, cy = cam['fx'], cam['fy'], cam['cx'], cam['cy']
    w, h = int(cam['width']), int(cam['height'])
    gt = [l.split() for l in open(f"{seq}/groundtruth.txt") if l.strip() and not l.startswith('#')]
    t = np.array([float(r[0]) for r in gt])
    c = np.array([[float(x) for x in r[1:4]] for r in gt])
    rot = [quat_to_r(*[float(x) for x in r[4:8]]) for r in gt]
    depth = {}
    for l in open(f"{seq}/depth.txt"):
        if l.strip() and not l.startswith('#'):
            ts, f = l.split()
            depth[int(np.argmin(np.abs(t - float(ts))))] = f
    us, vs = np.meshgrid(np.arange(8, w, 16), np.arange(8, h, 16))
    us, vs = us.ravel(), vs.ravel()
    for j in sorted(depth):
        d = np.asarray(Image.open(f"{seq}/{depth[j]}"), dtype=np.float64) / 5000.0
        z = d[vs, us]
        ok = z > 0
        if ok.sum() < 20:
            continue
        pc = np.stack([(us[ok] - cx) / fx * z[ok], (vs[ok] - cy) / fy * z[ok], z[ok]], 1)
        pw = (rot[j] @ pc.T).T + c[j]
        best, best_i = 0.0, None
        for i in range(j):
            q = (rot[i].T @ (pw - c[i]).T).T
            inview = q[:, 2] > 0.05
            uu = fx * q[:, 0] / np.maximum(q[:, 2], 1e-9) + cx
            vv = fy * q[:, 1] / np.maximum(q[:, 2], 1e-9) + cy
            inview &= (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            if inview.sum() < 0.5 * len(pw):
                continue
            a = pw[inview] - c[i]
            b = pw[inview] - c[j]
            cos = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
            par = np.degrees(np.median(np.arccos(np.clip(cos, -1, 1))))
            if par > best:
                best, best_i = par, i
        if best >= thr:
            print(f'{{"onset_frame": {j}, "reference_frame": {best_i}, "median_parallax_deg": {best:.2f}}}')
            return
    print('{"onset_frame": null}')

main()
