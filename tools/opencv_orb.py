#!/usr/bin/env python3
"""Measuring tool (not a dependency): OpenCV ORB on the same images as `sdslam features`.

    pip install opencv-python-headless
    python3 tools/opencv_orb.py IMAGE... [--n 1000] [--repeat R] [--json]

Prints the median time of ORB_create(n, 1.2, 8).detectAndCompute on one thread and the
median feature count, like `sdslam features`.
"""
import argparse, json, statistics, time

import cv2

ap = argparse.ArgumentParser()
ap.add_argument("images", nargs="+")
ap.add_argument("--n", type=int, default=1000)
ap.add_argument("--repeat", type=int, default=10)
ap.add_argument("--json", action="store_true")
a = ap.parse_args()
cv2.setNumThreads(1)
orb = cv2.ORB_create(a.n, 1.2, 8)
times, counts = [], []
for p in a.images:
    img = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise SystemExit(f"{p}: cannot read image")
    for _ in range(a.repeat):
        t = time.perf_counter()
        kps, desc = orb.detectAndCompute(img, None)
        times.append((time.perf_counter() - t) * 1e3)
        counts.append(len(kps))
mt, mc = statistics.median(times), statistics.median(counts)
if a.json:
    print(json.dumps({"median_ms": mt, "features": mc, "images": len(a.images), "repeat": a.repeat}))
else:
    print(f"{len(a.images)} images x {a.repeat} runs: median {mt:.3f} ms per extraction, median {mc} features")
