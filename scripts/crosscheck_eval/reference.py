"""The reference evaluator (mmdet3d's copy of the KITTI python evaluator shared with OpenPCDet),
loaded straight from its two files so that mmdet3d's package __init__ (torch, mmcv, ...) is
never imported, plus converters from the cross-check JSON to its annotation dicts.

Run with NUMBA_ENABLE_CUDASIM=1 on machines without a GPU (rotate_iou uses numba.cuda).
"""
import importlib.util
import os
import sys
import types

import numpy as np

CLASS_IDS = {"Car": 0, "Pedestrian": 1, "Cyclist": 2}


def kitti_utils_dir():
    spec = importlib.util.find_spec("mmdet3d")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("mmdet3d is not installed in this interpreter (run scripts/crosscheck_eval/setup.sh)")
    root = list(spec.submodule_search_locations)[0]
    d = os.path.join(root, "evaluation", "functional", "kitti_utils")
    for f in ("eval.py", "rotate_iou.py"):
        if not os.path.isfile(os.path.join(d, f)):
            raise SystemExit(f"{d}/{f} not found: unexpected mmdet3d layout")
    return d


_MODULES = {}


def load():
    """Returns the reference's eval module (rotate_iou loaded beside it as its sibling)."""
    if "eval" in _MODULES:
        return _MODULES["eval"]
    d = kitti_utils_dir()
    pkg = types.ModuleType("kitti_ref")
    pkg.__path__ = [d]  # lets eval.py's `from .rotate_iou import ...` resolve without __init__
    sys.modules["kitti_ref"] = pkg
    for name in ("rotate_iou", "eval"):
        spec = importlib.util.spec_from_file_location(f"kitti_ref.{name}", os.path.join(d, f"{name}.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules[f"kitti_ref.{name}"] = mod
        spec.loader.exec_module(mod)
        _MODULES[name] = mod
    return _MODULES["eval"]


def to_anno(frame):
    """Cross-check JSON frame (our `KittiFrame`) → the reference's annotation dict."""
    objs = frame["objects"]
    n = len(objs)

    def arr(key, shape):
        if n == 0:
            return np.zeros(shape, dtype=np.float64)
        return np.array([o[key] for o in objs], dtype=np.float64).reshape(shape)

    return {
        "name": np.array([o["name"] for o in objs]),
        "truncated": arr("truncated", (n,)),
        "occluded": arr("occluded", (n,)),
        "alpha": arr("alpha", (n,)),
        "bbox": arr("bbox", (n, 4)),
        "dimensions": arr("dimensions", (n, 3)),
        "location": arr("location", (n, 3)),
        "rotation_y": arr("rotation_y", (n,)),
        "score": arr("score", (n,)),
    }


def evaluate(gt_frames, dt_frames, classes):
    """Runs the reference's do_eval with AOS; returns {class: [set][metric][R11|R40][difficulty]}
    with metrics bbox, bev, 3d, aos."""
    ev = load()
    gt = [to_anno(f) for f in gt_frames]
    dt = [to_anno(f) for f in dt_frames]
    ids = [CLASS_IDS[c] for c in classes]
    overlap_0_7 = np.array([[0.7, 0.5, 0.5, 0.7, 0.5], [0.7, 0.5, 0.5, 0.7, 0.5], [0.7, 0.5, 0.5, 0.7, 0.5]])
    overlap_0_5 = np.array([[0.7, 0.5, 0.5, 0.7, 0.5], [0.5, 0.25, 0.25, 0.5, 0.25], [0.5, 0.25, 0.25, 0.5, 0.25]])
    min_overlaps = np.stack([overlap_0_7, overlap_0_5], axis=0)[:, :, ids]
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # 0/0 precision, as upstream
        r = ev.do_eval(gt, dt, ids, min_overlaps, ["bbox", "bev", "3d", "aos"])
    r11 = {"bbox": r[0], "bev": r[1], "3d": r[2], "aos": r[3]}
    r40 = {"bbox": r[4], "bev": r[5], "3d": r[6], "aos": r[7]}
    out = {}
    for j, c in enumerate(classes):
        out[c] = [
            {m: {"r11": [float(r11[m][j, d, s]) for d in range(3)], "r40": [float(r40[m][j, d, s]) for d in range(3)]}
             for m in ("bbox", "bev", "3d", "aos")}
            for s in range(2)
        ]
    return out


if __name__ == "__main__":
    if "--locate" in sys.argv:
        print(kitti_utils_dir())
