"""Seeded generator of randomized KITTI-protocol cases for the cross-check.

Each case is a folder with gt.json and dt.json: lists of frames {"id", "objects": [...]} in the
reference's camera-frame annotation form (our `KittiFrame`). Cases cover perturbed ground truth,
flipped headings, wrong classes, false positives near and far, misses, empty frames, frames
without ground truth, near-touching boxes, barely overlapping heights, tiny image boxes (ignored
detections), neighbour classes (Van, Person_sitting), truncation/occlusion levels and DontCare
regions, with tied scores (two decimals) that exercise the first-index tie rules.

The reference's float32 rotated IoU is wrong for identical boxes and imprecise near thresholds,
so every detection whose BEV / 3D / 2D overlap with any ground truth of its frame (or whose
DontCare overlap) lies within MARGIN of a threshold is re-drawn; no two boxes are identical or
share a collinear edge.
"""
import argparse
import json
import math
import os
import random

THRESHOLDS = (0.25, 0.5, 0.7)
MARGIN = 0.01
SIZES = {  # l, h, w
    "Car": (3.9, 1.55, 1.65),
    "Pedestrian": (0.8, 1.75, 0.65),
    "Cyclist": (1.75, 1.72, 0.6),
    "Van": (5.0, 2.1, 1.9),
    "Person_sitting": (0.8, 1.3, 0.6),
    "Truck": (10.0, 3.3, 2.6),
    "Misc": (2.0, 1.5, 1.0),
}
GT_CLASSES = ["Car"] * 6 + ["Pedestrian"] * 4 + ["Cyclist"] * 2 + ["Van", "Person_sitting", "Truck", "Misc"]
DET_CLASSES = ["Car", "Pedestrian", "Cyclist"]
FOCAL = 720.0


# ---- f64 geometry in the reference's conventions ------------------------------------------

def corners(o):
    """BEV corners of a camera box in the (x, z) plane as rotate_iou builds them."""
    x, _, z = o["location"]
    l, _, w = o["dimensions"]
    c, s = math.cos(o["rotation_y"]), math.sin(o["rotation_y"])
    pts = [(-l / 2, -w / 2), (-l / 2, w / 2), (l / 2, w / 2), (l / 2, -w / 2)]
    return [(c * u + s * v + x, -s * u + c * v + z) for u, v in pts]


def area(poly):
    a = 0.0
    for i in range(len(poly)):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % len(poly)]
        a += x1 * y2 - x2 * y1
    return a / 2.0


def clip(subject, clipper):
    """Sutherland–Hodgman for convex polygons (both counter-clockwise)."""
    out = subject
    for i in range(len(clipper)):
        a, b = clipper[i], clipper[(i + 1) % len(clipper)]
        inp, out = out, []
        if not inp:
            break

        def inside(p):
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0

        def cross(p, q):
            dx1, dy1 = q[0] - p[0], q[1] - p[1]
            dx2, dy2 = b[0] - a[0], b[1] - a[1]
            den = dx1 * dy2 - dy1 * dx2
            t = ((a[0] - p[0]) * dy2 - (a[1] - p[1]) * dx2) / den
            return (p[0] + t * dx1, p[1] + t * dy1)

        for k in range(len(inp)):
            p, q = inp[k], inp[(k + 1) % len(inp)]
            if inside(q):
                if not inside(p):
                    out.append(cross(p, q))
                out.append(q)
            elif inside(p):
                out.append(cross(p, q))
    return out


def ccw(poly):
    return poly if area(poly) > 0 else poly[::-1]


def bev_inter(a, b):
    p = clip(ccw(corners(a)), ccw(corners(b)))
    return abs(area(p)) if len(p) >= 3 else 0.0


def ious(d, g):
    """(bbox IoU, BEV IoU, 3D IoU) as the reference defines them, in f64."""
    b, q = d["bbox"], g["bbox"]
    iw = min(b[2], q[2]) - max(b[0], q[0])
    ih = min(b[3], q[3]) - max(b[1], q[1])
    i2 = 0.0
    if iw > 0 and ih > 0:
        i2 = iw * ih / ((b[2] - b[0]) * (b[3] - b[1]) + (q[2] - q[0]) * (q[3] - q[1]) - iw * ih)
    inter = bev_inter(d, g)
    la, ha, wa = d["dimensions"]
    lb, hb, wb = g["dimensions"]
    bev = inter / (la * wa + lb * wb - inter) if inter > 0 else 0.0
    yh = min(d["location"][1], g["location"][1]) - max(d["location"][1] - ha, g["location"][1] - hb)
    d3 = 0.0
    if inter > 0 and yh > 0:
        inc = inter * yh
        d3 = inc / (la * ha * wa + lb * hb * wb - inc)
    return i2, bev, d3


def dc_overlap(d, dc):
    b, q = d["bbox"], dc["bbox"]
    iw = min(b[2], q[2]) - max(b[0], q[0])
    ih = min(b[3], q[3]) - max(b[1], q[1])
    if iw > 0 and ih > 0:
        return iw * ih / ((b[2] - b[0]) * (b[3] - b[1]))
    return 0.0


def near_threshold(v):
    return any(abs(v - t) < MARGIN for t in THRESHOLDS) or (0 < v < 1e-3)


def safe(det, gts):
    for g in gts:
        if g["name"] == "DontCare":
            if near_threshold(dc_overlap(det, g)):
                return False
            continue
        for v in ious(det, g):
            if near_threshold(v):
                return False
    return True


# ---- random objects ------------------------------------------------------------------------

def image_box(rng, o, small=False):
    x, y, z = o["location"]
    l, h, w = o["dimensions"]
    hp = FOCAL * h / z
    if small:
        hp = rng.uniform(8.0, 38.0)
    wp = FOCAL * max(l, w) / z * rng.uniform(0.6, 1.0)
    u = 620.0 + FOCAL * x / z
    v = 180.0 + FOCAL * (y - h / 2) / z
    return [round(u - wp / 2, 2), round(v - hp / 2, 2), round(u + wp / 2, 2), round(v + hp / 2, 2)]


def gt_object(rng, name):
    l, h, w = SIZES[name]
    o = {
        "name": name,
        "truncated": rng.choice([0.0] * 6 + [0.1, 0.2, 0.4, 0.6]),
        "occluded": float(rng.choice([0, 0, 0, 0, 1, 1, 2, 3])),
        "dimensions": [round(l * rng.uniform(0.85, 1.15), 3), round(h * rng.uniform(0.9, 1.1), 3),
                       round(w * rng.uniform(0.9, 1.1), 3)],
        "location": [round(rng.uniform(-15, 15), 3), round(1.65 + rng.gauss(0, 0.1), 3), round(rng.uniform(4, 45), 3)],
        "rotation_y": round(rng.uniform(-math.pi, math.pi), 4),
        "score": 0.0,
    }
    o["alpha"] = round(o["rotation_y"] - math.atan2(o["location"][0], o["location"][2]), 4)
    o["bbox"] = image_box(rng, o)
    return o


def dontcare(rng):
    u, v = rng.uniform(0, 1100), rng.uniform(100, 300)
    return {"name": "DontCare", "truncated": -1.0, "occluded": -1.0, "alpha": -10.0,
            "bbox": [round(u, 2), round(v, 2), round(u + rng.uniform(20, 150), 2), round(v + rng.uniform(15, 80), 2)],
            "dimensions": [-1.0, -1.0, -1.0], "location": [-1000.0, -1000.0, -1000.0], "rotation_y": -10.0,
            "score": 0.0}


def perturbed(rng, g):
    """A detection of ground truth g in one of several regimes."""
    d = json.loads(json.dumps(g))
    regime = rng.random()
    # Better detections tend to score higher, so curves reach high precision at low recall.
    d["score"] = round(min(1.0, max(0.01, 1.0 - 0.6 * regime + rng.gauss(0, 0.15))), 2)
    scale = min(g["dimensions"][0], g["dimensions"][2])
    if regime < 0.45:
        sigma = 0.05 * scale
    elif regime < 0.8:
        sigma = 0.2 * scale
    else:
        sigma = 0.5 * scale
    d["location"] = [round(d["location"][0] + rng.gauss(0, sigma), 3),
                     round(d["location"][1] + rng.gauss(0, 0.05), 3),
                     round(d["location"][2] + rng.gauss(0, sigma), 3)]
    d["dimensions"] = [round(v * rng.uniform(0.9, 1.1), 3) for v in d["dimensions"]]
    d["rotation_y"] = round(d["rotation_y"] + rng.gauss(0, 0.08) + 0.003, 4)
    if rng.random() < 0.1:
        d["rotation_y"] = round(d["rotation_y"] + math.pi, 4)  # flipped heading: same box, AOS 0
    if rng.random() < 0.1:
        # Barely overlapping heights: shift almost a full height up or down.
        h = d["dimensions"][1]
        d["location"][1] = round(d["location"][1] + rng.choice([-1, 1]) * h * rng.uniform(0.85, 0.98), 3)
    if rng.random() < 0.08:
        # Near-touching neighbour along the length axis (gap, slightly turned: not collinear).
        l = d["dimensions"][0]
        gap = l / 2 + g["dimensions"][0] / 2 + rng.uniform(0.01, 0.1)
        ry = g["rotation_y"]
        d["location"][0] = round(g["location"][0] + gap * math.cos(ry), 3)
        d["location"][2] = round(g["location"][2] - gap * math.sin(ry), 3)
        d["rotation_y"] = round(ry + rng.choice([-1, 1]) * rng.uniform(0.02, 0.05), 4)
    d["alpha"] = round(g["alpha"] + (d["rotation_y"] - g["rotation_y"]) + rng.gauss(0, 0.1), 4)
    small = rng.random() < 0.1
    if small:
        d["bbox"] = image_box(rng, d, small=True)
    else:
        px = 1.0 + 6.0 * regime
        jitter = [rng.gauss(0, px) for _ in range(4)]
        b = [g["bbox"][k] + jitter[k] for k in range(4)]
        d["bbox"] = [round(min(b[0], b[2] - 2), 2), round(min(b[1], b[3] - 2), 2), round(max(b[2], b[0] + 2), 2),
                     round(max(b[3], b[1] + 2), 2)]
    if rng.random() < 0.08:
        d["name"] = rng.choice([c for c in DET_CLASSES if c != g["name"]])
    elif g["name"] not in DET_CLASSES:
        d["name"] = rng.choice(DET_CLASSES + [g["name"]])
    for k in ("truncated", "occluded"):
        d[k] = 0.0
    return d


def false_positive(rng, gts):
    name = rng.choice(DET_CLASSES)
    d = gt_object(rng, name)
    real = [g for g in gts if g["name"] != "DontCare"]
    if real and rng.random() < 0.5:
        g = rng.choice(real)
        d["location"][0] = round(g["location"][0] + rng.uniform(-3, 3), 3)
        d["location"][2] = round(g["location"][2] + rng.uniform(-3, 3), 3)
        d["bbox"] = image_box(rng, d, small=rng.random() < 0.1)
    d["score"] = round(rng.uniform(0.01, 0.8), 2)
    d["truncated"] = d["occluded"] = 0.0
    return d


def frame(rng, idx, frame_kind):
    gts, dts = [], []
    if frame_kind != "empty" and frame_kind != "no_gt":
        for _ in range(rng.randint(1, 8)):
            gts.append(gt_object(rng, rng.choice(GT_CLASSES)))
        for _ in range(rng.choice([0, 0, 0, 1, 2, 4])):
            gts.append(dontcare(rng))
    if frame_kind not in ("empty", "no_det"):
        for g in gts:
            if g["name"] == "DontCare" or rng.random() > 0.85:
                continue  # a miss
            for _ in range(20):
                d = perturbed(rng, g)
                if safe(d, gts):
                    dts.append(d)
                    break
            if rng.random() < 0.1:  # a duplicate detection of the same object
                for _ in range(20):
                    d = perturbed(rng, g)
                    if safe(d, gts):
                        dts.append(d)
                        break
        for _ in range(rng.choice([0, 1, 2, 3, 5])):
            for _ in range(20):
                d = false_positive(rng, gts)
                if safe(d, gts):
                    dts.append(d)
                    break
        rng.shuffle(dts)
    fid = f"{idx:06d}"
    return {"id": fid, "objects": gts}, {"id": fid, "objects": dts}


def make_case(seed, num_frames):
    rng = random.Random(seed)
    gt, dt = [], []
    for i in range(num_frames):
        kind = rng.choices(["normal", "empty", "no_gt", "no_det"], weights=[7, 1, 1, 1])[0]
        g, d = frame(rng, i, kind)
        gt.append(g)
        dt.append(d)
    return gt, dt


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", type=int, default=4)
    ap.add_argument("--frames", type=int, default=20)
    a = ap.parse_args()
    for c in range(a.cases):
        gt, dt = make_case(a.seed * 1000 + c, a.frames)
        d = os.path.join(a.out, f"case_{c:03d}")
        os.makedirs(d, exist_ok=True)
        with open(os.path.join(d, "gt.json"), "w") as f:
            json.dump(gt, f)
        with open(os.path.join(d, "dt.json"), "w") as f:
            json.dump(dt, f)
    print(f"wrote {a.cases} cases of {a.frames} frames to {a.out}")


if __name__ == "__main__":
    main()
