"""Benchmark: the reference evaluator against `pi3det eval` on the same large synthetic split,
printing both wall times and their ratio (and how far the APs agree).

The split (default: the issue's 2,000 frames, ~30k GT, 30k detections, Car + Pedestrian, Pi3DET
layout with the fake KITTI fields) is written by our synthetic_bench example; the reference reads
the same pi3det_infos_val.pkl / result.pkl through OpenPCDet's transform_annotations_to_kitti_format.

The reference's rotated IoU is a numba.cuda kernel; without a GPU it runs either under the CUDA
simulator (--iou cudasim: the real code, hours at this size, use --frames to shrink) or, as the
issue measured it, with the same device functions compiled for the CPU by numba (--iou cpu,
default; the kernel's float32 arithmetic is kept).

    .venv-crosscheck/bin/python scripts/crosscheck_eval/bench.py [--frames 2000 --gt 15 --det 15]
"""
import argparse
import json
import os
import pickle
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the repository


def cpu_rotate_iou(ref_dir):
    """rotate_iou.py's device functions compiled for the CPU, same float32 arithmetic."""
    import math

    import numba
    import numpy as np

    src = open(os.path.join(ref_dir, "rotate_iou.py")).read()
    src = src[: src.index("@cuda.jit(\n    '(int64")]
    src = src.replace("@cuda.jit(device=True, inline=True)", "@numba.njit")
    src = re.sub(r"cuda\.local\.array\(\((\d+), \), dtype=numba\.float32\)", r"np.zeros((\1,), dtype=np.float32)", src)
    ns = {"math": math, "numba": numba, "np": np}
    exec(compile(src, "rotate_iou_cpu", "exec"), ns)
    dev = ns["devRotateIoUEval"]

    @numba.njit
    def kernel(boxes, qboxes, iou, criterion):
        for i in range(boxes.shape[0]):
            for j in range(qboxes.shape[0]):
                iou[i, j] = dev(qboxes[j], boxes[i], criterion)

    def rotate_iou_cpu(boxes, query_boxes, criterion=-1, device_id=0):
        b = np.ascontiguousarray(boxes, dtype=np.float32)
        q = np.ascontiguousarray(query_boxes, dtype=np.float32)
        iou = np.zeros((b.shape[0], q.shape[0]), dtype=np.float32)
        if b.shape[0] and q.shape[0]:
            kernel(b, q, iou, criterion)
        return iou.astype(boxes.dtype)

    return rotate_iou_cpu


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--gt", type=int, default=15, help="ground truths per frame (mean)")
    ap.add_argument("--det", type=int, default=15, help="detections per frame")
    ap.add_argument("--iou", choices=["cpu", "cudasim"], default="cpu")
    ap.add_argument("--keep", help="write the split here instead of a temporary folder")
    a = ap.parse_args()
    if a.iou == "cudasim":
        os.environ["NUMBA_ENABLE_CUDASIM"] = "1"
    import numpy as np

    import e2e
    import reference

    subprocess.run(["cargo", "build", "--release", "-q", "-p", "pi3det-eval", "--features", "cli", "--example",
                    "eval_files", "--example", "synthetic_bench"], cwd=ROOT, check=True)
    work = a.keep or tempfile.mkdtemp(prefix="eval_bench_")
    subprocess.run([os.path.join(ROOT, "target/release/examples/synthetic_bench"), str(a.frames), str(a.gt), str(a.det),
                    "--write", work], check=True, capture_output=True)
    classes = ["Car", "Pedestrian"]

    # Ours: the whole command, process start and file reading included; best of 3.
    exe = os.path.join(ROOT, "target/release/examples/eval_files")
    cmd = [exe, "--gt", os.path.join(work, "pi3det_infos_val.pkl"), "--det", os.path.join(work, "result.pkl"),
           "--classes", ",".join(classes), "--json", "--no-breakdown"]
    walls = []
    for _ in range(3):
        t = time.time()
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        walls.append(time.time() - t)
    t_ours = min(walls)
    r = json.loads(out)["overall"]
    ours = {c["class"]: [{m: s[m] for m in ("bbox", "bev", "3d", "aos") if m in s} for s in c["sets"]]
            for c in r["classes"]}

    # The reference on the same files (reading included).
    t0 = time.time()
    ev = reference.load()
    if a.iou == "cpu":
        sys.modules["kitti_ref.rotate_iou"].rotate_iou_gpu_eval = cpu_rotate_iou(reference.kitti_utils_dir())
        # Compile once on a tiny input so that JIT time is not counted.
        sys.modules["kitti_ref.rotate_iou"].rotate_iou_gpu_eval(np.ones((1, 5)), np.ones((1, 5)))
    t_load = time.time() - t0
    t = time.time()
    with open(os.path.join(work, "pi3det_infos_val.pkl"), "rb") as f:
        infos = pickle.load(f)
    with open(os.path.join(work, "result.pkl"), "rb") as f:
        dets = pickle.load(f)
    by_id = {d["frame_id"]: d for d in dets}
    gt = e2e.transform_to_kitti_format(
        [{"gt_names": i["annos"]["gt_names"].copy(), "gt_boxes_lidar": i["annos"]["gt_boxes_lidar"].astype(np.float64)}
         for i in infos], e2e.NAME_MAP)
    dt = e2e.transform_to_kitti_format(
        [{"name": by_id[i["frame_id"]]["name"].copy(), "score": by_id[i["frame_id"]]["score"].astype(np.float64),
          "boxes_lidar": by_id[i["frame_id"]]["boxes_lidar"].astype(np.float64)} for i in infos], e2e.NAME_MAP)
    ids = [reference.CLASS_IDS[c] for c in classes]
    o7 = np.array([[0.7, 0.5, 0.5, 0.7, 0.5], [0.7, 0.5, 0.5, 0.7, 0.5], [0.7, 0.5, 0.5, 0.7, 0.5]])
    o5 = np.array([[0.7, 0.5, 0.5, 0.7, 0.5], [0.5, 0.25, 0.25, 0.5, 0.25], [0.5, 0.25, 0.25, 0.5, 0.25]])
    import warnings

    t_read = time.time() - t
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        # Warm-up on two frames: numba compiles the evaluator's functions on first use.
        t = time.time()
        ev.do_eval(gt[:2], dt[:2], ids, np.stack([o7, o5])[:, :, ids], ["bbox", "bev", "3d", "aos"])
        t_load += time.time() - t
        t = time.time()
        res = ev.do_eval(gt, dt, ids, np.stack([o7, o5])[:, :, ids], ["bbox", "bev", "3d", "aos"])
    t_ref = time.time() - t + t_read
    r11 = dict(zip(("bbox", "bev", "3d", "aos"), res[:4]))
    r40 = dict(zip(("bbox", "bev", "3d", "aos"), res[4:]))
    worst = 0.0
    for j, c in enumerate(classes):
        for s in range(2):
            for m in ("bbox", "bev", "3d", "aos"):
                for d in range(3):
                    worst = max(worst, abs(r11[m][j, d, s] - ours[c][s][m]["r11"][d]),
                                abs(r40[m][j, d, s] - ours[c][s][m]["r40"][d]))
    ngt = sum(len(i["annos"]["gt_names"]) for i in infos)
    ndt = sum(len(d["name"]) for d in dets)
    print(f"{len(infos)} frames, {ngt} GT, {ndt} detections, classes {', '.join(classes)}")
    print(f"reference ({'numba CPU port of the IoU kernel' if a.iou == 'cpu' else 'CUDA simulator'}): "
          f"{t_ref:.2f} s, reading included (+{t_load:.1f} s import and JIT warm-up, not counted)")
    print(f"pi3det eval (process start, reading, evaluation): {t_ours:.3f} s")
    print(f"ratio: {t_ref / t_ours:.0f}x")
    # No margins here: a pair whose float32 IoU lands on the other side of a threshold moves an AP.
    print(f"largest AP difference: {worst:.2e}")
    if a.keep is None:
        import shutil

        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
