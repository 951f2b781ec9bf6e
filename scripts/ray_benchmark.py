#!/usr/bin/env python3
"""Run a `pi3det bench suite` suite on a Ray cluster: one Ray task per cell.

    .venv-ray/bin/python scripts/ray_benchmark.py --suite configs/benchmark/mini.toml \
        --out runs/bench_ray [--address auto] [--pi3det target/release/pi3det] [--cpus-per-cell 2]

Every cell is independent (`pi3det bench suite --list` names them), so each Ray task runs
`pi3det bench suite --suite SUITE --only CELL --out TMP` on the node Ray picks and returns its
`cells/` folder as a tar archive; the driver unpacks them under OUT/parts/ and writes the tables
with `pi3det bench suite --merge` (the same merge as for `--shard i/N` runs on separate machines).
Every node needs the pi3det binaries and the suite's files at the same paths (one image, or a
shared filesystem). With --shared-out the tasks write straight into OUT instead (a filesystem all
nodes see): then artifacts several cells share (simulated data, the source model) are made once,
under a file lock, instead of once per task.

Without --address a local Ray instance is started on 127.0.0.1 with --num-cpus CPUs. Install Ray
with scripts/setup-ray (into .venv-ray). Exit status: 0 when every cell finished, 1 when some
failed (the table still lists them), 2 on a usage or cluster error.
"""

import argparse
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile


def parse_args():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--suite", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--pi3det", default="target/release/pi3det", help="pi3det (or pi3det-torch) binary")
    p.add_argument("--address", default=None, help="Ray cluster address (default: start a local instance)")
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local instance")
    p.add_argument("--cpus-per-cell", type=float, default=1.0)
    p.add_argument("--gpus-per-cell", type=float, default=0.0)
    p.add_argument("--torch-threads", type=int, default=None, help="libtorch threads per cell")
    p.add_argument("--only", default=None, help="cell patterns, as pi3det bench suite --only")
    p.add_argument("--shared-out", action="store_true", help="tasks write into --out directly (shared filesystem)")
    return p.parse_args()


def cell_ids(a):
    cmd = [a.pi3det, "bench", "suite", "--suite", a.suite, "--list"]
    if a.only:
        cmd += ["--only", a.only]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.stderr.write(r.stderr)
        sys.exit(2)
    return [line for line in r.stdout.splitlines() if line.strip()]


def run_cell(pi3det, suite, cell, out, torch_threads):
    """One cell; returns (cell, exit status, tar of cells/ or None, stderr tail)."""
    own = out is None
    work = tempfile.mkdtemp(prefix="pi3det_cell_") if own else out
    cmd = [pi3det, "bench", "suite", "--suite", suite, "--only", cell, "--out", work]
    if torch_threads:
        cmd += ["--torch-threads", str(torch_threads)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    blob = None
    if own:
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode="w:gz") as tar:
            cells = os.path.join(work, "cells")
            if os.path.isdir(cells):
                tar.add(cells, arcname="cells")
        blob = buf.getvalue()
        subprocess.run(["rm", "-rf", work])
    return cell, r.returncode, blob, r.stderr[-4000:]


def main():
    a = parse_args()
    try:
        import ray
    except ImportError:
        sys.stderr.write("ray is not installed: run scripts/setup-ray and use .venv-ray/bin/python\n")
        return 2
    a.suite = os.path.abspath(a.suite)
    a.out = os.path.abspath(a.out)
    a.pi3det = os.path.abspath(a.pi3det)
    cells = cell_ids(a)
    if a.address:
        ray.init(address=a.address, log_to_driver=False)
    else:
        ray.init(num_cpus=a.num_cpus, _node_ip_address="127.0.0.1", include_dashboard=False, log_to_driver=False)
    task = ray.remote(num_cpus=a.cpus_per_cell, num_gpus=a.gpus_per_cell)(run_cell)
    out_for_tasks = a.out if a.shared_out else None
    futures = [task.remote(a.pi3det, a.suite, c, out_for_tasks, a.torch_threads) for c in cells]
    parts = []
    failed = 0
    for k, (cell, status, blob, err) in enumerate(ray.get(futures)):
        if blob is not None:
            part = os.path.join(a.out, "parts", f"{k:04d}")
            os.makedirs(part, exist_ok=True)
            with tarfile.open(fileobj=io.BytesIO(blob), mode="r:gz") as tar:
                tar.extractall(part, filter="data")
            parts.append(part)
        result = os.path.join(parts[-1] if blob is not None else a.out, "cells", cell.replace("/", "__"), "result.json")
        try:
            with open(result) as f:
                done = json.load(f).get("status") == "done"
        except (OSError, ValueError):
            done = False
        print(f"[{k + 1}/{len(cells)}] {cell}: {'done' if done else 'FAILED'}", flush=True)
        if status != 0 or not done:
            failed += 1
            sys.stderr.write(err)
    ray.shutdown()
    merge = [a.pi3det, "bench", "suite", "--suite", a.suite, "--out", a.out, "--merge"] + (parts or [a.out])
    r = subprocess.run(merge)
    if r.returncode != 0:
        return 2
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
