"""The examples in examples/python run (the PyTorch one without torch, as plain datasets)."""
import os
import subprocess
import sys

import numpy as np

from conftest import ROOT

EXAMPLES = os.path.join(ROOT, "examples", "python")
sys.path.insert(0, EXAMPLES)


def test_openpcdet_eval_example(shared_data):
    p = subprocess.run([sys.executable, os.path.join(EXAMPLES, "openpcdet_eval.py"),
                        os.path.join(shared_data, "kitti", "training")], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("Car AP@0.70, 0.70, 0.70:\nbbox AP:") and "Car_3d/moderate_R40" in p.stdout


def test_torch_dataset_example(shared_data):
    import torch_dataset as td

    ds = td.LidarDataset(os.path.join(shared_data, "kitti", "training"))
    assert len(ds) == 6
    batch = td.collate([ds[0], ds[1]])
    points = np.asarray(batch["points"])
    assert points.shape == (len(ds[0]["points"]) + len(ds[1]["points"]), 5)
    assert set(np.unique(points[:, 0])) == {0.0, 1.0}
    sim = list(td.SimulatedFrames(platform="quadruped", sequences=2, frames=1))
    assert [s["frame_id"] for s in sim] == ["0000000", "0010000"]
