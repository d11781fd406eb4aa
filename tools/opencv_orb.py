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
ap.add_argument("--warp", help="9 comma-separated numbers: homography source -> warped (row-major)")
ap.add_argument("--warp-with", choices=["sdslam", "opencv"], default="sdslam",
                help="sdslam (default): the warped image is made exactly as `sdslam features --warp` "
                     "makes it (float bilinear), so both extractors see the same images; "
                     "opencv: cv2.warpPerspective (5-bit interpolation weights)")
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
out = {"median_ms": mt, "features": mc, "images": len(a.images), "repeat": a.repeat}


def warp_like_sdslam(img, H):
    """sdslam's image::warp::warp_perspective: dst(x) = src(H^-1 x), float bilinear, rounded,
    0 outside the source (inclusive of its last row and column)."""
    import numpy as np
    h, w = img.shape
    inv = np.linalg.inv(H)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    p = inv @ np.stack([xs.ravel(), ys.ravel(), np.ones(w * h)])
    sx, sy, z = p[0] / p[2], p[1] / p[2], p[2]
    ok = (z > 0) & (sx >= 0) & (sy >= 0) & (sx <= w - 1) & (sy <= h - 1)
    sx, sy = np.where(ok, sx, 0), np.where(ok, sy, 0)
    x0, y0 = np.floor(sx).astype(int), np.floor(sy).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = sx - x0, sy - y0
    g = img.astype(np.float64)
    v = (1 - fy) * ((1 - fx) * g[y0, x0] + fx * g[y0, x1]) + fy * ((1 - fx) * g[y1, x0] + fx * g[y1, x1])
    # Rust's f64::round rounds half away from zero; values are >= 0 here.
    out = np.clip(np.floor(v + 0.5), 0, 255).astype(np.uint8)
    out[~ok] = 0
    return out.reshape(h, w)


def warp_quality(path, H, border=16.0, eps=2.5):
    """Same definition as sdslam's features::quality::warp_quality."""
    import numpy as np
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    h, w = img.shape
    if a.warp_with == "sdslam":
        warped = warp_like_sdslam(img, H)
    else:
        warped = cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
    ka, da = orb.detectAndCompute(img, None)
    kb, db = orb.detectAndCompute(warped, None)
    pb = np.array([k.pt for k in kb])
    comparable = repeated = matched = 0
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    nn = {m.queryIdx: m.trainIdx for m in bf.match(da, db)}
    for i, k in enumerate(ka):
        p = H @ np.array([k.pt[0], k.pt[1], 1.0])
        x, y = p[0] / p[2], p[1] / p[2]
        if not (border <= x <= w - 1 - border and border <= y <= h - 1 - border):
            continue
        comparable += 1
        d = np.hypot(pb[:, 0] - x, pb[:, 1] - y)
        repeated += bool((d <= eps).any())
        j = nn.get(i)
        matched += j is not None and d[j] <= eps
    n = max(comparable, 1)
    return repeated / n, matched / n


if a.warp:
    import numpy as np
    H = np.array([float(v) for v in a.warp.split(",")]).reshape(3, 3)
    q = [warp_quality(p, H) for p in a.images]
    out["repeatability"] = sum(r for r, _ in q) / len(q)
    out["matching_score"] = sum(m for _, m in q) / len(q)
if a.json:
    print(json.dumps(out))
else:
    print(f"{len(a.images)} images x {a.repeat} runs: median {mt:.3f} ms per extraction, median {mc} features")
    if a.warp:
        print(f"under the homography: repeatability {out['repeatability']:.3f}, matching score {out['matching_score']:.3f} (mean over images, 2.5 px)")
