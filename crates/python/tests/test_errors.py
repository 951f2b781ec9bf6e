"""Bad input raises pi3det.Pi3detError with the Rust message, naming the file (`err.path`)."""
import os
import shutil

import numpy as np
import pytest

import pi3det


def test_missing_path(tmp_path):
    p = tmp_path / "nothing-here"
    with pytest.raises(pi3det.Pi3detError) as e:
        pi3det.data.open(p)
    assert str(p) in str(e.value) and e.value.path == str(p)


def test_unknown_folder(tmp_path):
    with pytest.raises(pi3det.Pi3detError, match="not a dataset pi3det recognises") as e:
        pi3det.data.open(tmp_path)
    assert e.value.path == str(tmp_path)


def test_corrupt_info_pickle(tmp_path):
    info = tmp_path / "pi3det_infos_val.pkl"
    info.write_bytes(b"\x80\x04\x95 not a pickle at all")
    with pytest.raises(pi3det.Pi3detError) as e:
        pi3det.data.open(tmp_path)
    assert str(info) in str(e.value) and e.value.path == str(info)


def kitti_copy(shared, tmp_path):
    src = os.path.join(shared, "kitti", "training")
    dst = tmp_path / "kitti"
    for sub in ("velodyne", "label_2", "calib"):
        (dst / sub).mkdir(parents=True)
        name = "000000.bin" if sub == "velodyne" else "000000.txt"
        shutil.copy(os.path.join(src, sub, name), dst / sub / name)
    return dst


def test_bad_label_line_names_file_and_line(shared_data, tmp_path):
    root = kitti_copy(shared_data, tmp_path)
    label = root / "label_2" / "000000.txt"
    label.write_text(label.read_text() + "Car 0.00 0 x 1 2 3 4 1.5 1.6 3.9 1 1.6 10 0.1\n")
    ds = pi3det.data.open(root)
    with pytest.raises(pi3det.Pi3detError) as e:
        ds.info(0)
    assert f"{label}:2" in str(e.value) and e.value.path == str(label)
    with pytest.raises(pi3det.Pi3detError):
        ds[0]


def test_truncated_point_file(shared_data, tmp_path):
    root = kitti_copy(shared_data, tmp_path)
    bin_path = root / "velodyne" / "000000.bin"
    data = bin_path.read_bytes()
    bin_path.write_bytes(data[: len(data) - 6])
    ds = pi3det.data.open(root)
    with pytest.raises(pi3det.Pi3detError) as e:
        ds[0]
    assert str(bin_path) in str(e.value) and e.value.path == str(bin_path)


def test_simulator_config_file(tmp_path):
    cfg = tmp_path / "sim.toml"
    cfg.write_text("[sensor]\nbeams = 'many'\n")
    with pytest.raises(pi3det.Pi3detError) as e:
        pi3det.sim.simulate("drone", config=cfg)
    assert str(cfg) in str(e.value)
    with pytest.raises(ValueError, match="unknown platform"):
        pi3det.sim.simulate("boat")


def test_geometry_input():
    with pytest.raises(ValueError, match=r"boxes_a: expected shape \(N, 7\)"):
        pi3det.geometry.rotated_iou_bev(np.zeros((2, 6)), np.zeros((1, 7)))
    with pytest.raises(ValueError, match="boxes row 1: box has a non-finite value"):
        pi3det.geometry.nms(np.array([[0, 0, 0, 1, 1, 1, 0], [0, 0, 0, np.nan, 1, 1, 0]]), [0.5, 0.4], 0.1)
    with pytest.raises(ValueError, match="2 boxes but 1 scores"):
        pi3det.geometry.nms(np.ones((2, 7)), [0.5], 0.1)
