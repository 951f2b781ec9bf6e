"""Shared fixtures of the pi3det Python package's tests (run by scripts/test in .venv after
scripts/setup-python-wheel; by hand: `.venv/bin/python -m pytest crates/python/tests`)."""
import os
import subprocess
import sys

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", ".."))
SHARED = os.path.abspath(os.path.join(ROOT, "..", "shared", "data"))
CROSSCHECK = os.path.join(ROOT, "scripts", "crosscheck_eval")
sys.path.insert(0, os.path.dirname(__file__))
sys.dont_write_bytecode = True  # no __pycache__ beside the sources

try:
    import pi3det  # noqa: F401
except ImportError as e:  # the wheel could not be built or installed
    pytest.skip(f"the pi3det wheel is not installed ({e}); run scripts/setup-python-wheel", allow_module_level=True)


@pytest.fixture(scope="session")
def shared_data():
    if not os.path.isdir(SHARED):
        pytest.skip(f"{SHARED} not found: the shared real frames are not on this machine")
    return SHARED


def pi3det_binary():
    """The `pi3det` binary the workspace build made (the newest of debug and release)."""
    found = [os.path.join(ROOT, "target", p, "pi3det") for p in ("debug", "release")]
    found = [p for p in found if os.access(p, os.X_OK)]
    return max(found, key=os.path.getmtime) if found else None


@pytest.fixture(scope="session")
def pi3det_cli():
    exe = pi3det_binary()
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("target/debug/pi3det not found in CI: `cargo test --workspace --no-run` builds it")
        pytest.skip("no target/{debug,release}/pi3det: build it with `cargo build -p pi3det-cli`")
    return exe


def run(cmd, **kw):
    p = subprocess.run(cmd, capture_output=True, text=True, **kw)
    assert p.returncode == 0, f"{' '.join(cmd)} failed:\n{p.stdout}\n{p.stderr}"
    return p


@pytest.fixture(scope="session")
def crosscheck_python():
    py = os.path.join(ROOT, ".venv-crosscheck", "bin", "python")
    if not os.access(py, os.X_OK):
        if os.environ.get("CI"):
            pytest.fail(".venv-crosscheck not found in CI: scripts/crosscheck_eval/setup.sh failed")
        pytest.skip(".venv-crosscheck not found: run scripts/crosscheck_eval/setup.sh for the reference evaluator")
    return py


@pytest.fixture(scope="session")
def reference_cases(crosscheck_python, tmp_path_factory):
    """The cross-check's randomized cases with the reference evaluator's numbers (mmdet3d's
    numba evaluator under the CUDA simulator, in .venv-crosscheck): those PI3DET_REFERENCE_CASES
    names when reference_cases.py finished writing them there (scripts/test), else written now."""
    import reference_cases as rc

    pre = os.environ.get("PI3DET_REFERENCE_CASES")
    if pre and rc.ready(pre):
        return os.path.join(pre, "core"), os.path.join(pre, "e2e")
    return rc.write(str(tmp_path_factory.mktemp("reference")))

