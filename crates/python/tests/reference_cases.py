"""Writes the cross-check's randomized cases with the reference evaluator's numbers for
test_eval.py: camera-frame cases (scripts/crosscheck_eval/crosscheck.py) and a Pi3DET-layout case
(e2e.py), both scripts at once, in .venv-crosscheck (numba, numpy<2).

    python3 crates/python/tests/reference_cases.py OUT   # scripts/test runs it while cargo tests run

then PI3DET_REFERENCE_CASES=OUT lets the tests read them instead of running the reference again.
"""
import os
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", ".."))
CROSSCHECK = os.path.join(ROOT, "scripts", "crosscheck_eval")
PYTHON = os.path.join(ROOT, ".venv-crosscheck", "bin", "python")
DONE = "complete"


def write(out):
    """Runs both scripts into OUT/core and OUT/e2e; OUT/complete marks a finished run."""
    core, e2e = os.path.join(out, "core"), os.path.join(out, "e2e")
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    cmds = [
        [PYTHON, os.path.join(CROSSCHECK, "crosscheck.py"), "--seed", "12", "--cases", "2", "--frames", "25",
         "--reference-only", "--keep", core],
        [PYTHON, os.path.join(CROSSCHECK, "e2e.py"), "--seed", "12", "--cases", "1", "--frames", "10",
         "--layouts", "pi3det", "--reference-only", "--out", e2e],
    ]
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env) for c in cmds]
    for c, p in zip(cmds, procs):
        log, _ = p.communicate()
        if p.returncode != 0:
            raise RuntimeError(f"{' '.join(c)} failed:\n{log}")
    open(os.path.join(out, DONE), "w").close()
    return core, e2e


def ready(out):
    return os.path.isfile(os.path.join(out, DONE))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    if not os.access(PYTHON, os.X_OK):
        sys.exit(f"{PYTHON} not found: run scripts/crosscheck_eval/setup.sh")
    os.makedirs(sys.argv[1], exist_ok=True)
    write(sys.argv[1])
    print(f"reference cases in {sys.argv[1]}")
