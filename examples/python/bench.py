"""Benchmark (not a test): pi3det's Python package against what OpenPCDet users run today, in one
Python process.

1. KITTI-protocol evaluation of a 2,000-frame split (~15 ground truths and ~15 detections per
   frame, Car and Pedestrian, LiDAR boxes made camera-frame annotations by OpenPCDet's
   transform_annotations_to_kitti_format): the reference evaluator (mmdet3d's copy of the numba
   code OpenPCDet ships, its rotated-IoU kernel compiled for the CPU by numba as
   scripts/crosscheck_eval/bench.py does) against pi3det.eval.kitti_eval on the same dicts and
   pi3det.eval.kitti_eval_lidar on the LiDAR boxes.
2. Reading 1,000 simulated frames (written by `pi3det simulate`): pi3det.data.open against
   numpy.fromfile + pickle, points and boxes of every frame.

Needs the reference's venv with the wheel installed in it (release profile for timings):

    scripts/crosscheck_eval/setup.sh
    PI3DET_WHEEL_PROFILE=release PI3DET_WHEEL_VENV=.venv-crosscheck scripts/setup-python-wheel
    cargo build --release -p pi3det-cli
    .venv-crosscheck/bin/python examples/python/bench.py [--frames 2000] [--sim-frames 1000]
"""
import argparse
import os
import pickle
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

import pi3det

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "scripts", "crosscheck_eval"))
sys.dont_write_bytecode = True

SIZES = {"Car": (3.9, 1.65, 1.56), "Pedestrian": (0.8, 0.65, 1.75)}  # dx, dy, dz


def split(frames, per_frame, seed):
    """LiDAR-frame ground truth and detections as OpenPCDet's dicts."""
    rng = np.random.default_rng(seed)
    gts, dts = [], []
    for _ in range(frames):
        n = rng.poisson(per_frame)
        names = rng.choice(["Car", "Car", "Pedestrian"], n)
        size = np.array([SIZES[c] for c in names]).reshape(n, 3) * rng.uniform(0.9, 1.1, (n, 3))
        xy = np.stack([rng.uniform(2, 70, n), rng.uniform(-35, 35, n)], 1)
        z = rng.normal(-0.9, 0.2, n) + size[:, 2] / 2
        boxes = np.concatenate([xy, z[:, None], size, rng.uniform(-np.pi, np.pi, (n, 1))], 1)
        keep = rng.random(n) < 0.85  # misses
        det = boxes[keep] + rng.normal(0, 1, (keep.sum(), 7)) * [0.25, 0.25, 0.1, 0.1, 0.1, 0.1, 0.08]
        det[:, 3:6] = np.abs(det[:, 3:6])
        m = max(0, int(round(per_frame)) - len(det))  # false positives up to ~per_frame detections
        fp_names = rng.choice(["Car", "Pedestrian"], m)
        fp = np.concatenate([rng.uniform(2, 70, (m, 1)), rng.uniform(-35, 35, (m, 1)), np.full((m, 1), -0.1),
                             np.array([SIZES[c] for c in fp_names]).reshape(m, 3), rng.uniform(-3, 3, (m, 1))], 1)
        dnames = np.concatenate([names[keep], fp_names])
        gts.append({"name": names, "gt_boxes_lidar": boxes})
        dts.append({"name": dnames, "boxes_lidar": np.concatenate([det, fp]),
                    "score": np.round(rng.uniform(0.05, 1.0, len(dnames)), 2)})
    return gts, dts


def to_camera(annos, key):
    """OpenPCDet's transform_annotations_to_kitti_format (as e2e.py has it)."""
    import e2e

    return e2e.transform_to_kitti_format(
        [{"gt_names" if key == "gt_boxes_lidar" else "name": a["name"].copy(), key: a[key].copy(),
          **({"score": a["score"]} if "score" in a else {})} for a in annos], e2e.NAME_MAP)


def bench_eval(frames, per_frame):
    import bench as ref_bench
    import reference

    gts, dts = split(frames, per_frame, seed=0)
    gt_cam, dt_cam = to_camera(gts, "gt_boxes_lidar"), to_camera(dts, "boxes_lidar")
    classes = ["Car", "Pedestrian"]
    ngt, ndt = sum(len(g["name"]) for g in gts), sum(len(d["name"]) for d in dts)
    print(f"evaluation: {frames} frames, {ngt} GT, {ndt} detections, classes {', '.join(classes)}")

    ev = reference.load()
    sys.modules["kitti_ref.rotate_iou"].rotate_iou_gpu_eval = ref_bench.cpu_rotate_iou(reference.kitti_utils_dir())
    ids = [reference.CLASS_IDS[c] for c in classes]
    o7 = np.array([[0.7, 0.5, 0.5, 0.7, 0.5]] * 3)
    o5 = np.array([[0.7, 0.5, 0.5, 0.7, 0.5], [0.5, 0.25, 0.25, 0.5, 0.25], [0.5, 0.25, 0.25, 0.5, 0.25]])
    mo = np.stack([o7, o5])[:, :, ids]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ev.do_eval(gt_cam[:2], dt_cam[:2], ids, mo, ["bbox", "bev", "3d", "aos"])  # numba JIT, not counted
        t = time.perf_counter()
        res = ev.do_eval(gt_cam, dt_cam, ids, mo, ["bbox", "bev", "3d", "aos"])
        t_ref = time.perf_counter() - t

    def best(f, n=3):
        walls = []
        for _ in range(n):
            t = time.perf_counter()
            out = f()
            walls.append(time.perf_counter() - t)
        return min(walls), out

    t_cam, (_, _, detail) = best(lambda: pi3det._native.kitti_eval(gt_cam, dt_cam, classes))
    t_lidar, (_, _, detail_l) = best(lambda: pi3det._native.kitti_eval_lidar(gts, dts, classes))
    worst = 0.0
    for j, c in enumerate(classes):
        for s in range(2):
            for k, m in enumerate(("bbox", "bev", "3d", "aos")):
                for d in range(3):
                    for got in (detail, detail_l):
                        ours = got[c]["sets"][s][m]
                        worst = max(worst, abs(res[k][j, d, s] - ours["r11"][d]), abs(res[4 + k][j, d, s] - ours["r40"][d]))
    print(f"  reference do_eval (numba CPU port of the IoU kernel, JIT excluded): {t_ref:.2f} s")
    print(f"  pi3det.eval.kitti_eval (same camera-frame dicts, best of 3):    {t_cam:.3f} s  ({t_ref / t_cam:.0f}x)")
    print(f"  pi3det.eval.kitti_eval_lidar (LiDAR boxes, best of 3):         {t_lidar:.3f} s  ({t_ref / t_lidar:.0f}x)")
    print(f"  largest AP difference to the reference: {worst:.2e} (no threshold margins in this split)")


def bench_read(sim_frames, cli):
    work = tempfile.mkdtemp(prefix="pi3det_read_bench_")
    t = time.perf_counter()
    subprocess.run([cli, "simulate", "--platform", "vehicle", "--sequences", "1", "--frames", str(sim_frames),
                    "--out", work], check=True, capture_output=True)
    print(f"reading: {sim_frames} simulated vehicle frames written by pi3det simulate ({time.perf_counter() - t:.0f} s)")
    root = os.path.join(work, "train")

    def ours():
        n = 0
        for f in pi3det.data.open(root):
            n += len(f.points) + len(f.boxes)
        return n

    def numpy_pickle():
        with open(os.path.join(root, "pi3det_infos_train.pkl"), "rb") as fh:
            infos = pickle.load(fh)
        n = 0
        for i in infos:
            pts = np.fromfile(os.path.join(root, i["point_clout_path"]), dtype=np.float32).reshape(-1, 4)
            boxes = i["annos"]["gt_boxes_lidar"]
            n += len(pts) + len(boxes)
        return n

    for label, f in (("pi3det.data.open", ours), ("numpy.fromfile + pickle", numpy_pickle)) * 2:
        walls = []
        for _ in range(3):
            t = time.perf_counter()
            n = f()
            walls.append(time.perf_counter() - t)
        print(f"  {label:<24} best of 3 {min(walls):.3f} s ({sim_frames / min(walls):.0f} frames/s), {n} points + boxes")
    import shutil

    shutil.rmtree(work, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--per-frame", type=float, default=15.0)
    ap.add_argument("--sim-frames", type=int, default=1000)
    ap.add_argument("--cli", default=os.path.join(ROOT, "target", "release", "pi3det"))
    a = ap.parse_args()
    print(f"pi3det {pi3det.__version__} ({pi3det._native.__file__}), numpy {np.__version__}, {os.cpu_count()} CPUs")
    bench_eval(a.frames, a.per_frame)
    bench_read(a.sim_frames, a.cli)


if __name__ == "__main__":
    main()
