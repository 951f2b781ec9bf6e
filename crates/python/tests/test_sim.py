"""pi3det.sim: deterministic frames, the same as `pi3det simulate` writes."""
import os
import pickle

import numpy as np

import pi3det
from conftest import run


def test_frames_are_deterministic_and_complete():
    a = list(pi3det.sim.simulate("quadruped", sequences=2, frames=2, seed=5))
    b = list(pi3det.sim.simulate("quadruped", sequences=2, frames=2, seed=5))
    assert len(a) == 4 and [f.id for f in a] == ["0000000", "0000001", "0010000", "0010001"]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.points, y.points)
        np.testing.assert_array_equal(x.boxes, y.boxes)
    f = a[0]
    assert f.platform == "quadruped" and f.sequence.startswith("quadruped_") and f.pose.shape == (4, 4)
    assert f.points.dtype == np.float32 and f.points.shape[1] == 4 and len(f.points) > 1000
    assert f.boxes.shape == (len(f.names), 7) and len(f.num_points) == len(f.names)
    assert len(pi3det.sim.simulate("drone", sequences=3, frames=7)) == 21


def test_frames_equal_pi3det_simulate(pi3det_cli, tmp_path):
    run([pi3det_cli, "simulate", "--platform", "drone", "--sequences", "1", "--frames", "2", "--seed", "3", "--out",
         str(tmp_path)])
    root = tmp_path / "train"
    with open(root / "pi3det_infos_train.pkl", "rb") as f:
        infos = pickle.load(f)
    frames = list(pi3det.sim.simulate("drone", sequences=1, frames=2, seed=3))
    assert [i["frame_id"] for i in infos] == [f.id for f in frames]
    for info, frame in zip(infos, frames):
        pts = np.fromfile(os.path.join(root, info["point_clout_path"]), dtype=np.float32).reshape(-1, 4)
        np.testing.assert_array_equal(frame.points, pts)
        np.testing.assert_array_equal(frame.boxes.astype(np.float32), info["annos"]["gt_boxes_lidar"])
        assert list(frame.names) == list(info["annos"]["gt_names"]) and frame.sequence == info["sequence"]
        np.testing.assert_allclose(frame.pose, info["pose"], atol=1e-12)
