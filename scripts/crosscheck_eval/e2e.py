"""End-to-end cross-check through the readers: seeded random cases written as real datasets and
detection files, evaluated by `pi3det eval` (or the eval_files example until the binary has the
subcommand) and by the reference on what those files hold.

* kitti:  a KITTI folder (label_2 with DontCare, calib, empty velodyne files); detections as a
          KITTI result folder, as pi3det JSON lines (LiDAR boxes with bbox/alpha) and as an
          OpenPCDet result.pkl (float32, with camera fields, as OpenPCDet writes it).
* pi3det: a Pi3DET-layout info pkl (LiDAR boxes, Vehicle/Car names, several platforms);
          detections as JSON lines and result.pkl; the reference gets OpenPCDet's
          transform_annotations_to_kitti_format (fake 50 px boxes, easy = moderate = hard).

    .venv-crosscheck/bin/python scripts/crosscheck_eval/e2e.py --seed 1 --cases 1 --frames 15
"""
import argparse
import json
import math
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("NUMBA_ENABLE_CUDASIM", "1")
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the repository

import numpy as np  # noqa: E402

import crosscheck  # noqa: E402
import gen_cases  # noqa: E402
import reference  # noqa: E402

CALIB = """P0: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 0.000000000000e+00 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 -3.797842000000e+02 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 4.575831000000e+01 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 -3.454157000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.981016000000e-03
P3: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 -3.341081000000e+02 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 2.330660000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.201153000000e-03
R0_rect: 9.999128000000e-01 1.009263000000e-02 -8.511932000000e-03 -1.012729000000e-02 9.999406000000e-01 -4.037671000000e-03 8.470675000000e-03 4.123522000000e-03 9.999556000000e-01
Tr_velo_to_cam: 6.927964000000e-03 -9.999722000000e-01 -2.757829000000e-03 -2.457729000000e-02 -1.162982000000e-03 2.749836000000e-03 -9.999955000000e-01 -6.127237000000e-02 9.999753000000e-01 6.931141000000e-03 -1.143899000000e-03 -3.325860000000e-01
Tr_imu_to_velo: 9.999976000000e-01 7.553071000000e-04 -2.035826000000e-03 -8.086759000000e-01 -7.854027000000e-04 9.998898000000e-01 -1.482298000000e-02 3.195559000000e-01 2.024406000000e-03 1.482454000000e-02 9.998881000000e-01 -7.997231000000e-01
"""


def calib_mats():
    vals = {l.split(":")[0]: np.array([float(x) for x in l.split(":")[1].split()]) for l in CALIB.strip().splitlines()}
    r0 = np.eye(4)
    r0[:3, :3] = vals["R0_rect"].reshape(3, 3)
    v2c = np.eye(4)
    v2c[:3, :] = vals["Tr_velo_to_cam"].reshape(3, 4)
    return r0 @ v2c


RECT_FROM_LIDAR = calib_mats()


def camera_to_lidar(o):
    """OpenPCDet's boxes3d_kitti_camera_to_lidar in float64."""
    p = np.linalg.inv(RECT_FROM_LIDAR) @ np.array([*o["location"], 1.0])
    l, h, w = o["dimensions"]
    return [p[0], p[1], p[2] + h / 2, l, w, h, -(o["rotation_y"] + math.pi / 2)]


def fake_camera_to_lidar(o):
    """Inverse of OpenPCDet's fake KITTI camera (camera x = -y, y = -z_bottom, z = x)."""
    x, y, z = o["location"]
    l, h, w = o["dimensions"]
    return [z, -x, -y + h / 2, l, w, h, -o["rotation_y"] - math.pi / 2]


def label_line(o, with_score):
    l, h, w = o["dimensions"]
    f = [o["name"], repr(o["truncated"]), str(int(o["occluded"])), repr(o["alpha"]), *map(repr, o["bbox"]),
         repr(h), repr(w), repr(l), *map(repr, o["location"]), repr(o["rotation_y"])]
    if with_score:
        f.append(repr(o["score"]))
    return " ".join(f)


def get_label_anno(path):
    """The reference tool chain's get_label_anno (kitti_common), for label and result files."""
    with open(path) as f:
        content = [line.strip().split(" ") for line in f if line.strip()]
    n = len(content)
    a = {
        "name": np.array([x[0] for x in content]),
        "truncated": np.array([float(x[1]) for x in content]),
        "occluded": np.array([int(x[2]) for x in content]),
        "alpha": np.array([float(x[3]) for x in content]),
        "bbox": np.array([[float(v) for v in x[4:8]] for x in content]).reshape(-1, 4),
        "dimensions": np.array([[float(v) for v in x[8:11]] for x in content]).reshape(-1, 3)[:, [2, 0, 1]],
        "location": np.array([[float(v) for v in x[11:14]] for x in content]).reshape(-1, 3),
        "rotation_y": np.array([float(x[14]) for x in content]).reshape(-1),
    }
    a["score"] = np.array([float(x[15]) for x in content]) if n and len(content[0]) == 16 else np.zeros(n)
    return a


def transform_to_kitti_format(annos, name_map):
    """OpenPCDet's transform_annotations_to_kitti_format (the fake KITTI camera)."""
    for anno in annos:
        if "name" not in anno:
            anno["name"] = anno.pop("gt_names")
        anno["name"] = np.array([name_map.get(n, n) for n in anno["name"]])
        n = len(anno["name"])
        anno["bbox"] = np.zeros((n, 4))
        anno["bbox"][:, 2:4] = 50
        anno["truncated"] = np.zeros(n)
        anno["occluded"] = np.zeros(n)
        boxes = (anno["boxes_lidar"] if "boxes_lidar" in anno else anno["gt_boxes_lidar"]).copy()
        if len(boxes) > 0:
            boxes[:, 2] -= boxes[:, 5] / 2
            anno["location"] = np.zeros((boxes.shape[0], 3))
            anno["location"][:, 0] = -boxes[:, 1]
            anno["location"][:, 1] = -boxes[:, 2]
            anno["location"][:, 2] = boxes[:, 0]
            anno["dimensions"] = boxes[:, 3:6][:, [0, 2, 1]]
            anno["rotation_y"] = -boxes[:, 6] - np.pi / 2.0
            anno["alpha"] = -np.arctan2(-boxes[:, 1], boxes[:, 0]) + anno["rotation_y"]
        else:
            anno["location"] = anno["dimensions"] = np.zeros((0, 3))
            anno["rotation_y"] = anno["alpha"] = np.zeros(0)
        if "score" not in anno:
            anno["score"] = np.zeros(n)
    return annos


def reference_on_annos(gt, dt, classes):
    """The reference's do_eval on annotation dicts → the crosscheck result layout."""
    frames = lambda annos: [  # noqa: E731
        {"objects": [{"name": str(a["name"][i]), "truncated": float(a["truncated"][i]),
                      "occluded": float(a["occluded"][i]), "alpha": float(a["alpha"][i]),
                      "bbox": [float(v) for v in a["bbox"][i]], "dimensions": [float(v) for v in a["dimensions"][i]],
                      "location": [float(v) for v in a["location"][i]], "rotation_y": float(a["rotation_y"][i]),
                      "score": float(a["score"][i])} for i in range(len(a["name"]))]}
        for a in annos]
    return reference.evaluate(frames(gt), frames(dt), classes)


def ours(gt_path, det_path, classes, extra=()):
    exe = os.path.join(ROOT, "target", "release", "examples", "eval_files")
    cmd = [exe, "--gt", gt_path, "--det", det_path, "--json", "--no-breakdown", "--classes", ",".join(classes), *extra]
    t = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.time() - t
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {p.stderr}")
    r = json.loads(p.stdout)["overall"]
    return {c["class"]: [{m: s[m] for m in crosscheck.METRICS if m in s} for s in c["sets"]] for c in r["classes"]}, wall


def kitti_case(work, seed, frames, classes):
    gt, dt = gen_cases.make_case(seed, frames)
    root = os.path.join(work, "kitti", "training")
    for sub in ("velodyne", "calib", "label_2"):
        os.makedirs(os.path.join(root, sub), exist_ok=True)
    txt = os.path.join(work, "kitti_det")
    os.makedirs(txt, exist_ok=True)
    jsonl, pkl = [], []
    for g, d in zip(gt, dt):
        fid = g["id"]
        open(os.path.join(root, "velodyne", f"{fid}.bin"), "wb").close()
        with open(os.path.join(root, "calib", f"{fid}.txt"), "w") as f:
            f.write(CALIB)
        with open(os.path.join(root, "label_2", f"{fid}.txt"), "w") as f:
            f.write("".join(label_line(o, False) + "\n" for o in g["objects"]))
        with open(os.path.join(txt, f"{fid}.txt"), "w") as f:
            f.write("".join(label_line(o, True) + "\n" for o in d["objects"]))
        objs = d["objects"]
        jsonl.append({"frame_id": fid, "names": [o["name"] for o in objs], "scores": [o["score"] for o in objs],
                      "boxes_lidar": [camera_to_lidar(o) for o in objs], "bbox": [o["bbox"] for o in objs],
                      "alpha": [o["alpha"] for o in objs]})
        n = len(objs)
        pkl.append({
            "frame_id": fid,
            "name": np.array([o["name"] for o in objs]),
            "truncated": np.zeros(n), "occluded": np.zeros(n),
            "alpha": np.array([o["alpha"] for o in objs], dtype=np.float32).reshape(n),
            "bbox": np.array([o["bbox"] for o in objs], dtype=np.float32).reshape(n, 4),
            "dimensions": np.array([o["dimensions"] for o in objs], dtype=np.float32).reshape(n, 3),
            "location": np.array([o["location"] for o in objs], dtype=np.float32).reshape(n, 3),
            "rotation_y": np.array([o["rotation_y"] for o in objs], dtype=np.float32).reshape(n),
            "score": np.array([o["score"] for o in objs], dtype=np.float32).reshape(n),
            "boxes_lidar": np.array([camera_to_lidar(o) for o in objs], dtype=np.float32).reshape(n, 7),
        })
    jp = os.path.join(work, "kitti_det.jsonl")
    with open(jp, "w") as f:
        f.write("".join(json.dumps(x) + "\n" for x in jsonl))
    pp = os.path.join(work, "kitti_result.pkl")
    with open(pp, "wb") as f:
        pickle.dump(pkl, f)

    ids = [g["id"] for g in gt]
    gt_annos = [get_label_anno(os.path.join(root, "label_2", f"{i}.txt")) for i in ids]
    txt_annos = [get_label_anno(os.path.join(txt, f"{i}.txt")) for i in ids]
    pkl_annos = [{k: v for k, v in x.items() if k not in ("frame_id", "boxes_lidar")} for x in pkl]
    t = time.time()
    ref_txt = reference_on_annos(gt_annos, txt_annos, classes)
    ref_pkl = reference_on_annos(gt_annos, pkl_annos, classes)
    t_ref = time.time() - t
    runs = [(f"kitti/{label}", root, path, ref)
            for label, path, ref in (("txt", txt, ref_txt), ("jsonl", jp, ref_txt), ("result.pkl", pp, ref_pkl))]
    return runs, t_ref, sum(len(f["objects"]) for f in gt), sum(len(f["objects"]) for f in dt)


NAME_MAP = {"Vehicle": "Car"}


def pi3det_case(work, seed, frames, classes):
    gt, dt = gen_cases.make_case(seed, frames)
    rng = np.random.default_rng(seed)
    root = os.path.join(work, "pi3det")
    os.makedirs(root, exist_ok=True)
    infos, jsonl, pkl = [], [], []
    for g, d in zip(gt, dt):
        fid = g["id"]
        objs = [o for o in g["objects"] if o["name"] != "DontCare"]
        names = ["Vehicle" if o["name"] == "Car" and rng.random() < 0.5 else o["name"] for o in objs]
        infos.append({
            "frame_id": fid,
            "platform": ["vehicle", "drone", "quadruped"][int(rng.integers(3))],
            "point_clout_path": f"training/point_cloud/{fid}.bin",
            "annos": {"gt_names": np.array(names, dtype=str), "gt_boxes_lidar": np.array([fake_camera_to_lidar(o) for o in objs],
                                                                               dtype=np.float32).reshape(-1, 7)},
        })
        dets = d["objects"]
        n = len(dets)
        boxes = [fake_camera_to_lidar(o) for o in dets]
        jsonl.append({"frame_id": fid, "names": [o["name"] for o in dets], "scores": [o["score"] for o in dets],
                      "boxes_lidar": boxes})
        pkl.append({"frame_id": fid, "name": np.array([o["name"] for o in dets]),
                    "score": np.array([o["score"] for o in dets], dtype=np.float32).reshape(n),
                    "boxes_lidar": np.array(boxes, dtype=np.float32).reshape(n, 7)})
    info_path = os.path.join(root, "pi3det_infos_val.pkl")
    with open(info_path, "wb") as f:
        pickle.dump(infos, f)
    jp = os.path.join(work, "pi3det_det.jsonl")
    with open(jp, "w") as f:
        f.write("".join(json.dumps(x) + "\n" for x in jsonl))
    pp = os.path.join(work, "pi3det_result.pkl")
    with open(pp, "wb") as f:
        pickle.dump(pkl, f)

    def gt_annos():
        return transform_to_kitti_format(
            [{"gt_names": i["annos"]["gt_names"].copy(), "gt_boxes_lidar": i["annos"]["gt_boxes_lidar"].astype(np.float64)}
             for i in infos], NAME_MAP)

    json_dt = transform_to_kitti_format(
        [{"name": np.array(x["names"]), "score": np.array(x["scores"], dtype=np.float64),
          "boxes_lidar": np.array(x["boxes_lidar"], dtype=np.float64).reshape(-1, 7)} for x in jsonl], NAME_MAP)
    pkl_dt = transform_to_kitti_format(
        [{"name": x["name"].copy(), "score": x["score"].astype(np.float64),
          "boxes_lidar": x["boxes_lidar"].astype(np.float64)} for x in pkl], NAME_MAP)
    t = time.time()
    ref_json = reference_on_annos(gt_annos(), json_dt, classes)
    ref_pkl = reference_on_annos(gt_annos(), pkl_dt, classes)
    t_ref = time.time() - t
    runs = [(f"pi3det/{label}", info_path, path, ref)
            for label, path, ref in (("jsonl", jp, ref_json), ("result.pkl", pp, ref_pkl))]
    return runs, t_ref, sum(len(f["objects"]) for f in gt), sum(len(f["objects"]) for f in dt)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", type=int, default=1)
    ap.add_argument("--frames", type=int, default=15)
    ap.add_argument("--classes", default="Car,Pedestrian,Cyclist")
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--layouts", default="kitti,pi3det")
    ap.add_argument("--out", help="keep the datasets here (default: a temporary folder, removed)")
    ap.add_argument("--reference-only", action="store_true",
                    help="only write the files and OUT/manifest.json with the reference's results")
    a = ap.parse_args()
    if a.reference_only and not a.out:
        ap.error("--reference-only needs --out")
    if not a.reference_only:
        subprocess.run(["cargo", "build", "--release", "-q", "-p", "pi3det-eval", "--features", "cli", "--example",
                        "eval_files"], cwd=ROOT, check=True)
    classes = a.classes.split(",")
    base = a.out or tempfile.mkdtemp(prefix="crosscheck_e2e_")
    failures = total = 0
    manifest = []
    for c in range(a.cases):
        for layout in a.layouts.split(","):
            work = os.path.join(base, f"case_{c}_{layout}")
            os.makedirs(work, exist_ok=True)
            fn = kitti_case if layout == "kitti" else pi3det_case
            runs, t_ref, ngt, ndt = fn(work, 7000 + a.seed * 100 + c, a.frames, classes)
            for label, gt_path, det_path, ref in runs:
                if a.reference_only:
                    manifest.append({"label": f"case {c} {label}", "gt": gt_path, "det": det_path,
                                     "classes": classes, "reference": ref})
                    continue
                mine, _ = ours(gt_path, det_path, classes)
                bad, n = crosscheck.compare(ref, mine, a.tol)
                total += 1
                failures += bool(bad)
                status = "ok" if not bad else f"{len(bad)} MISMATCHES"
                print(f"case {c} {label}: {a.frames} frames, {ngt} gt, {ndt} dt, {n} APs: {status}", flush=True)
                for line in bad[:20]:
                    print("   ", line)
    if a.reference_only:
        with open(os.path.join(base, "manifest.json"), "w") as f:
            json.dump(manifest, f)
        print(f"wrote {len(manifest)} reference results to {base}/manifest.json")
        return
    if a.out is None:
        shutil.rmtree(base, ignore_errors=True)
    print(f"{total - failures}/{total} end-to-end comparisons agree (tol {a.tol})")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
