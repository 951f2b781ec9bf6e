"""pi3det.eval against the reference evaluator of scripts/crosscheck_eval (mmdet3d's copy of the
numba KITTI evaluator OpenPCDet ships) on its randomized cases, every AP to 1e-4, and the return
values in OpenPCDet's form."""
import glob
import json
import math
import os
import pickle
import sys

import numpy as np
import pytest

import pi3det
from pi3det import _native
from conftest import CROSSCHECK

sys.path.insert(0, CROSSCHECK)
import reference  # noqa: E402  (only its to_anno, which needs numpy alone)

METRICS = ("bbox", "bev", "3d", "aos")
DIFFS = ("easy", "moderate", "hard")
TOL = 1e-4


def same(a, b, tol=TOL):
    if a is None or b is None or math.isnan(a) or math.isnan(b):
        return (a is None or math.isnan(a)) and (b is None or math.isnan(b))
    return abs(a - b) <= tol


def compare(label, ref, ours):
    """Every AP of the reference's {class: [set]{metric: {r11, r40}}} against our detail dict."""
    bad, n = [], 0
    for c, sets in ref.items():
        for s, metrics in enumerate(sets):
            for m in METRICS:
                for kind in ("r11", "r40"):
                    for d in range(3):
                        x, y = metrics[m][kind][d], ours[c]["sets"][s][m][kind][d]
                        n += 1
                        if not same(x, y):
                            bad.append(f"{label}: {c} set {s} {m} {kind} {DIFFS[d]}: reference {x} ours {y}")
    assert not bad, f"{len(bad)} of {n} APs differ:\n" + "\n".join(bad[:30])
    return n


def openpcdet_text(ref, classes, overlaps):
    """The block OpenPCDet's get_official_eval_result prints, made from the reference's numbers."""
    fmt = lambda v, k: "nan" if v is None or math.isnan(v) else f"{v:.{k}f}"  # noqa: E731
    out = []
    for c in classes:
        for s, mo in enumerate(overlaps[c]):
            for tag, kind in (("AP", "r11"), ("AP_R40", "r40")):
                out.append(f"{c} {tag}@{mo[0]:.2f}, {mo[1]:.2f}, {mo[2]:.2f}:")
                for m, label, k in (("bbox", "bbox AP", 4), ("bev", "bev  AP", 4), ("3d", "3d   AP", 4),
                                    ("aos", "aos  AP", 2)):
                    out.append(f"{label}:" + ", ".join(fmt(v, k) for v in ref[c][s][m][kind]))
    return "\n".join(out) + "\n"


def numbers(line):
    return [float(x) for x in line.split(":", 1)[1].split(",")]


def check_text(text, expected):
    """Same lines; numbers within the last printed digit (the reference differs by < 1e-4)."""
    got, want = text.splitlines(), expected.splitlines()
    assert len(got) == len(want), f"{len(got)} lines, expected {len(want)}:\n{text}"
    for g, w in zip(got, want):
        if "@" in w:
            assert g == w
        else:
            assert g.split(":")[0] == w.split(":")[0]
            k = 2 if w.startswith("aos") else 4
            for a, b in zip(numbers(g), numbers(w)):
                assert same(a, b, 1.01 * 10 ** -k) or (math.isnan(a) and math.isnan(b)), f"{g!r} vs {w!r}"


def load_core(core):
    cases = []
    for d in sorted(glob.glob(os.path.join(core, "case_*"))):
        with open(os.path.join(d, "gt.json")) as f:
            gt = json.load(f)
        with open(os.path.join(d, "dt.json")) as f:
            dt = json.load(f)
        with open(os.path.join(d, "reference.json")) as f:
            ref = json.load(f)
        cases.append((d, [reference.to_anno(x) for x in gt], [reference.to_anno(x) for x in dt], ref))
    assert cases, f"no cases in {core}"
    return cases


OVERLAPS = {"Car": ([0.7, 0.7, 0.7], [0.7, 0.5, 0.5]), "Pedestrian": ([0.5, 0.5, 0.5], [0.5, 0.25, 0.25]),
            "Cyclist": ([0.5, 0.5, 0.5], [0.5, 0.25, 0.25])}


def test_kitti_eval_equals_the_reference(reference_cases):
    core, _ = reference_cases
    compared = 0
    for d, gt, dt, ref in load_core(core):
        classes = ref["classes"]
        detail = pi3det.eval.kitti_eval_detail(gt, dt, classes)
        compared += compare(os.path.basename(d), ref["reference"], detail)
        text, ret = pi3det.eval.kitti_eval(gt, dt, classes)
        check_text(text, openpcdet_text(ref["reference"], classes, OVERLAPS))
        # OpenPCDet's ret_dict: R40 at the strict overlaps, aos / 3d / bev / image per class.
        keys = [f"{c}_{m}/{d}_R40" for c in classes for m in ("aos", "3d", "bev", "image") for d in DIFFS]
        assert list(ret) == keys
        src = {"aos": "aos", "3d": "3d", "bev": "bev", "image": "bbox"}
        for k, v in ret.items():
            c, rest = k.split("_", 1) if not k.startswith("Person_sitting") else ("Person_sitting", k[15:])
            m, diff = rest.split("/")
            want = ref["reference"][c][0][src[m]]["r40"][DIFFS.index(diff[:-4])]
            assert isinstance(v, float) and same(v, want), (k, v, want)
        # OpenPCDet's class indices give the same.
        text2, ret2 = pi3det.eval.get_official_eval_result(gt, dt, [0, 1, 2])
        assert text2 == text and ret2.keys() == ret.keys()
    assert compared >= 2 * 3 * 2 * 4 * 2 * 3


def test_float32_and_int_arrays_are_taken_as_openpcdet_gives_them(reference_cases):
    core, _ = reference_cases
    _, gt, dt, ref = load_core(core)[0]
    # get_label_anno gives int occlusion; detections often come as float32.
    gt32 = [dict(a, occluded=a["occluded"].astype(np.int64)) for a in gt]
    dt32 = [{k: (v.astype(np.float32) if v.dtype.kind == "f" else v) for k, v in a.items()} for a in dt]
    base = pi3det.eval.kitti_eval_detail(gt, dt, ref["classes"])
    other = pi3det.eval.kitti_eval_detail(gt32, dt32, ref["classes"])
    assert base.keys() == other.keys()
    # float32 scores and boxes move APs by at most rounding (none of the cases sits on a threshold)
    compare("float32", {c: v["sets"] for c, v in base.items()}, other)


def test_lidar_variant_equals_the_reference_on_pi3det_files(reference_cases):
    """e2e.py's Pi3DET case: an info .pkl (Vehicle / Car names) and OpenPCDet result.pkl
    detections, evaluated by the reference after transform_annotations_to_kitti_format."""
    _, e2e = reference_cases
    with open(os.path.join(e2e, "manifest.json")) as f:
        manifest = json.load(f)
    runs = [r for r in manifest if r["det"].endswith(".pkl")]
    assert runs, manifest
    for run in runs:
        with open(run["gt"], "rb") as f:
            infos = pickle.load(f)
        with open(run["det"], "rb") as f:
            dets = pickle.load(f)
        gt = [{"name": i["annos"]["gt_names"], "gt_boxes_lidar": i["annos"]["gt_boxes_lidar"]} for i in infos]
        _, ret, detail = _native.kitti_eval_lidar(gt, dets, run["classes"])
        compare(run["label"], run["reference"], detail)
        text, ret2 = pi3det.eval.kitti_eval_lidar(gt, dets, run["classes"])
        assert ret2 == ret and text.startswith("Car AP@0.70, 0.70, 0.70:\nbbox AP:")


def test_empty_and_single_class():
    empty = {k: np.zeros((0,) + s) for k, s in (("truncated", ()), ("occluded", ()), ("alpha", ()), ("bbox", (4,)),
                                                ("dimensions", (3,)), ("location", (3,)), ("rotation_y", ()),
                                                ("score", ()))}
    empty["name"] = np.array([], dtype=str)
    text, ret = pi3det.eval.kitti_eval([empty], [empty], "Car")
    assert text.startswith("Car AP@0.70, 0.70, 0.70:\n")
    # No detection at all: OpenPCDet does not compute AOS, so no aos keys.
    assert list(ret)[:3] == ["Car_3d/easy_R40", "Car_3d/moderate_R40", "Car_3d/hard_R40"]


def test_bad_annotations_raise_with_the_frame_and_key():
    good = {"name": np.array(["Car"]), "truncated": np.zeros(1), "occluded": np.zeros(1), "alpha": np.zeros(1),
            "bbox": np.array([[0, 0, 50, 50.0]]), "dimensions": np.array([[4, 1.5, 1.6]]),
            "location": np.array([[0, 1.6, 10.0]]), "rotation_y": np.zeros(1), "score": np.ones(1)}
    missing = {k: v for k, v in good.items() if k != "bbox"}
    with pytest.raises(KeyError, match=r"dt_annos\[1\].*bbox"):
        pi3det.eval.kitti_eval([good, good], [good, missing], ["Car"])
    with pytest.raises(ValueError, match=r"gt_annos\[0\]\['location'\].*shape"):
        pi3det.eval.kitti_eval([dict(good, location=np.zeros((1, 2)))], [good], ["Car"])
    with pytest.raises(ValueError, match="'alpha' has 2 entries for 1 names"):
        pi3det.eval.kitti_eval([good], [dict(good, alpha=np.zeros(2))], ["Car"])
    with pytest.raises(ValueError, match="2 gt_annos but 1 dt_annos"):
        pi3det.eval.kitti_eval([good, good], [good], ["Car"])
    with pytest.raises(KeyError, match="Sign"):
        pi3det.eval.kitti_eval([good], [good], ["Sign"])
    with pytest.raises(pi3det.Pi3detError, match="non-finite"):
        pi3det.eval.kitti_eval([good], [dict(good, score=np.array([np.nan]))], ["Car"])
