"""Cross-check: every AP of the reference evaluator (mmdet3d's copy of the KITTI python
evaluator, run under NUMBA_ENABLE_CUDASIM=1) against ours on seeded random cases.

    .venv-crosscheck/bin/python scripts/crosscheck_eval/crosscheck.py --seed 1 --cases 4 --frames 20

Ours is run as `--ours` (default: the kitti_json example, built on demand) on the same gt.json /
dt.json. Exit status 0 only when all numbers agree to --tol (default 1e-4).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("NUMBA_ENABLE_CUDASIM", "1")
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the repository

import gen_cases  # noqa: E402
import reference  # noqa: E402

METRICS = ("bbox", "bev", "3d", "aos")


def ours_binary():
    exe = os.path.join(ROOT, "target", "release", "examples", "kitti_json")
    subprocess.run(["cargo", "build", "--release", "-q", "-p", "pi3det-eval", "--example", "kitti_json"],
                   cwd=ROOT, check=True)
    return exe


def run_ours(cmd, gt_path, dt_path, classes):
    t = time.time()
    p = subprocess.run(cmd + [gt_path, dt_path, ",".join(classes)], capture_output=True, text=True)
    wall = time.time() - t
    if p.returncode != 0:
        raise RuntimeError(f"ours failed: {p.stderr}")
    r = json.loads(p.stdout)
    out = {}
    for c in r["classes"]:
        sets = []
        for s in c["sets"]:
            sets.append({m: s[m] for m in METRICS if m in s})
        out[c["class"]] = sets
    return out, wall, r.get("eval_seconds")


def same(a, b, tol):
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= tol


def compare(ref, ours, tol):
    """Yields a line per disagreement; returns the number of values compared."""
    bad, n = [], 0
    for c, sets in ref.items():
        for s, metrics in enumerate(sets):
            for m in METRICS:
                if m not in ours[c][s]:
                    bad.append(f"{c} set {s} {m}: missing in ours")
                    continue
                for kind in ("r11", "r40"):
                    for d in range(3):
                        x, y = metrics[m][kind][d], ours[c][s][m][kind][d]
                        n += 1
                        if not same(x, y, tol):
                            bad.append(f"{c} set {s} {m} {kind} diff {d}: reference {x:.6f} ours {y:.6f}")
    return bad, n


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", type=int, default=4)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--classes", default="Car,Pedestrian,Cyclist")
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--ours", help="command printing our JSON for GT.json DT.json CLASSES")
    ap.add_argument("--keep", help="write the cases here instead of a temporary folder")
    ap.add_argument("--reference-only", action="store_true",
                    help="only write case_*/{gt,dt,reference}.json under --keep (the Rust test compares)")
    a = ap.parse_args()
    classes = a.classes.split(",")
    if a.reference_only and not a.keep:
        ap.error("--reference-only needs --keep")
    cmd = None if a.reference_only else (a.ours.split() if a.ours else [ours_binary()])
    work = a.keep or tempfile.mkdtemp(prefix="crosscheck_eval_")
    failures, compared, t_ref, t_ours = 0, 0, 0.0, 0.0
    for c in range(a.cases):
        gt, dt = gen_cases.make_case(a.seed * 1000 + c, a.frames)
        d = os.path.join(work, f"case_{c:03d}")
        os.makedirs(d, exist_ok=True)
        gp, dp = os.path.join(d, "gt.json"), os.path.join(d, "dt.json")
        with open(gp, "w") as f:
            json.dump(gt, f)
        with open(dp, "w") as f:
            json.dump(dt, f)
        t = time.time()
        ref = reference.evaluate(gt, dt, classes)
        t_ref += time.time() - t
        if cmd is None:
            with open(os.path.join(d, "reference.json"), "w") as f:
                json.dump({"classes": classes, "reference": ref}, f)
            print(f"case {c:3d}: reference written", flush=True)
            continue
        ours, wall, _ = run_ours(cmd, gp, dp, classes)
        t_ours += wall
        bad, n = compare(ref, ours, a.tol)
        compared += n
        ngt = sum(len(f["objects"]) for f in gt)
        ndt = sum(len(f["objects"]) for f in dt)
        status = "ok" if not bad else f"{len(bad)} MISMATCHES"
        print(f"case {c:3d}: {a.frames} frames, {ngt} gt, {ndt} dt: {status}", flush=True)
        for line in bad[:20]:
            print("   ", line)
        failures += bool(bad)
    if cmd is None:
        print(f"reference results of {a.cases} cases in {work} ({t_ref:.1f} s)")
        return
    print(f"{a.cases - failures}/{a.cases} cases agree ({compared} APs compared, tol {a.tol}); "
          f"reference {t_ref:.1f} s, ours {t_ours:.2f} s (process start included)")
    if a.keep is None:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
