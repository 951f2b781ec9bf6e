"""Reference for the box-fusion cross-check: MS3D++'s kernel-density box fusion of one cluster,
written against scipy.stats.gaussian_kde. Reads JSON clusters on stdin
([{"boxes": [[x,y,z,dx,dy,dz,h],...], "scores": [...], "weights": [...]}, ...]) and prints the
fused [x,y,z,dx,dy,dz,h,score] per cluster (null where scipy cannot fit) as JSON."""
import json
import sys

import numpy as np
from scipy import stats


def densest(samples, weights, bw):
    kde = stats.gaussian_kde(samples.T if samples.ndim > 1 else samples, bw_method=bw, weights=weights)
    d = kde(samples.T if samples.ndim > 1 else samples)
    return int(np.where(d == d.max())[0][0])


def peak(values, weights, bw, n=100):
    kde = stats.gaussian_kde(values, bw_method=bw, weights=weights)
    grid = np.linspace(values.min(), values.max(), n)
    d = kde(grid)
    return float(grid[np.where(d == d.max())[0][0]])


def attempt(f, fallback):
    try:
        return f()
    except Exception:  # scipy raises for singular covariances, as the public code expects
        return fallback()


def fuse(boxes, scores, weights):
    c = boxes[:, :3]
    if np.linalg.det(np.cov(c.T, bias=False)) < 1e-7:
        i = attempt(lambda: densest(c[:, :2], weights, 1.0), lambda: None)
        xy = c[i, :2] if i is not None else np.average(c[:, :2], axis=0, weights=weights)
        j = attempt(lambda: densest(c[:, 2], weights, 1.0), lambda: None)
        z = c[j, 2] if j is not None else np.average(c[:, 2], weights=weights)
        centre = [xy[0], xy[1], z]
    else:
        i = attempt(lambda: densest(c, weights, 1.0), lambda: None)
        centre = c[i] if i is not None else np.average(c, axis=0, weights=weights)
    size = [attempt(lambda k=k: peak(boxes[:, k], None, 2.0), lambda k=k: float(np.mean(boxes[:, k]))) for k in (3, 4, 5)]
    i = attempt(lambda: densest(np.sin(boxes[:, 6]), weights, 0.1), lambda: None)
    heading = float(boxes[i, 6]) if i is not None else None
    score = attempt(lambda: peak(scores, weights, 2.0), lambda: float(np.average(scores, weights=weights)))
    return [float(v) for v in centre] + size + [heading, score]


out = []
for cl in json.load(sys.stdin):
    out.append(fuse(np.array(cl["boxes"], dtype=float), np.array(cl["scores"], dtype=float), np.array(cl["weights"], dtype=float)))
print(json.dumps(out))
