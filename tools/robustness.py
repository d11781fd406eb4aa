#!/usr/bin/env python3
"""Robustness figures of one `sdslam run` output folder against its ground truth, as the
evaluation protocol asks: frame of the first pose, share of frames tracked after it, keyframe
ATE (absolute and as % of the ground-truth path length), and the worst per-frame error of a
pose reported Ok (all frames Sim3-aligned to the ground truth, as % of path length).

usage: tools/robustness.py OUT [GROUNDTRUTH]   (GROUNDTRUTH defaults to OUT/groundtruth.txt)
"""
import json
import os, sys
import numpy as np

def read_tum(p):
    rows = []
    for line in open(p):
        if line.startswith('#') or not line.strip():
            continue
        v = [float(x) for x in line.split()[:8]]
        rows.append(v)
    return np.array(rows) if rows else np.zeros((0, 8))

def associate(a, b, dt=0.02):
    pairs, j = [], 0
    for i, t in enumerate(a[:, 0]):
        k = np.argmin(np.abs(b[:, 0] - t))
        if abs(b[k, 0] - t) <= dt:
            pairs.append((i, k))
    return pairs

def umeyama(src, dst):
    mu_s, mu_d = src.mean(0), dst.mean(0)
    s, d = src - mu_s, dst - mu_d
    cov = d.T @ s / len(src)
    u, sig, vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        S[2, 2] = -1
    r = u @ S @ vt
    var = (s ** 2).sum() / len(src)
    c = np.trace(np.diag(sig) @ S) / var if var > 0 else 1.0
    t = mu_d - c * r @ mu_s
    return c, r, t

def input_timestamps(source):
    """Timestamps of a TUM folder's rgb.txt (None for other sources)."""
    if not source or not os.path.isfile(os.path.join(source, "rgb.txt")):
        return None
    out = []
    for line in open(os.path.join(source, "rgb.txt")):
        if line.startswith('#') or not line.strip():
            continue
        out.append(float(line.split()[0]))
    return out

def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    gt_path = sys.argv[2] if len(sys.argv) > 2 else f"{out}/groundtruth.txt"
    for p in (gt_path, f"{out}/report.json", f"{out}/trajectory.txt", f"{out}/keyframes.txt"):
        if not os.path.isfile(p):
            # A source without ground truth (e.g. a EuRoC folder), or a run still going.
            sys.exit(f"robustness.py: {p} not found")
    gt = read_tum(gt_path)
    rep = json.load(open(f"{out}/report.json"))
    res = evaluate(gt, read_tum(f"{out}/trajectory.txt"), read_tum(f"{out}/keyframes.txt"), rep)
    # The atlas: every map in its own frame (trajectory.txt is the primary map's).
    res["maps_made"] = rep.get("maps_made")
    res["maps_merged"] = rep.get("maps_merged")
    res["frames_with_pose_any_map"] = rep.get("tracked_frames_all_maps", rep.get("tracked_frames"))
    others = {}
    for m in rep.get("maps", []):
        if m["id"] == rep.get("primary_map"):
            continue
        t = f"{out}/trajectory_map{m['id']}.txt"
        k = f"{out}/keyframes_map{m['id']}.txt"
        if os.path.exists(t) and os.path.exists(k):
            o = evaluate(gt, read_tum(t), read_tum(k), {"frames": rep["frames"], "source": rep.get("source")})
            others[m["id"]] = {x: o.get(x) for x in ["first_pose_frame", "kf_ate_pct_path", "worst_ok_frame_pct_path", "ok_frames_off_by_5pct"]}
            others[m["id"]]["frames"] = m["tracked_frames"]
    if others:
        res["other_maps"] = others
    # The bar is on every pose reported Ok, whichever map it is in.
    res["ok_frames_off_all_maps"] = (res.get("ok_frames_off_by_5pct") or 0) + sum(
        o.get("ok_frames_off_by_5pct") or 0 for o in others.values())
    print(json.dumps(res))


def evaluate(gt, traj, kfs, rep):
    path = np.linalg.norm(np.diff(gt[:, 1:4], axis=0), axis=1).sum()
    frames = rep["frames"]
    res = {"frames": frames, "path_m": round(path, 3)}
    if len(traj) == 0:
        res["first_pose_frame"] = None
        return res
    first = int(np.argmin(np.abs(gt[:, 0] - traj[0, 0])))
    res["first_pose_frame"] = first
    # The frames after the first pose: by the input list's timestamps when the source folder
    # has one (a list cut or thinned out has fewer frames than the ground truth has rows).
    stamps = input_timestamps(rep.get("source"))
    after = (frames - first) if stamps is None else sum(t >= traj[0, 0] - 1e-6 for t in stamps)
    res["tracked_after_first"] = round(len(traj) / max(1, after), 4)
    p = associate(kfs, gt)
    if len(p) >= 3:
        src = np.array([kfs[i, 1:4] for i, _ in p]); dst = np.array([gt[k, 1:4] for _, k in p])
        c, r, t = umeyama(src, dst)
        e = np.linalg.norm((c * (r @ src.T)).T + t - dst, axis=1)
        res["kf_ate_m"] = round(float(np.sqrt((e ** 2).mean())), 4)
        res["kf_ate_pct_path"] = round(100 * res["kf_ate_m"] / path, 3)
    p = associate(traj, gt)
    if len(p) >= 3:
        src = np.array([traj[i, 1:4] for i, _ in p]); dst = np.array([gt[k, 1:4] for _, k in p])
        c, r, t = umeyama(src, dst)
        e = np.linalg.norm((c * (r @ src.T)).T + t - dst, axis=1)
        res["frame_ate_pct_path"] = round(100 * float(np.sqrt((e ** 2).mean())) / path, 3)
        res["worst_ok_frame_pct_path"] = round(100 * float(e.max()) / path, 3)
        res["ok_frames_off_by_5pct"] = int((e > 0.05 * path).sum())
        off = [int(k) for (_, k), ek in zip(p, e) if ek > 0.05 * path]
        if off:
            # Which frames (ground-truth indices; the first 40), to look them up in a -vv log.
            res["ok_frames_off"] = off[:40]
    for k in ["map_resets", "lost_episodes", "relocalisations", "loops_closed", "keyframes"]:
        if k in rep:
            res[k] = rep[k]
    return res

if __name__ == "__main__":
    main()
