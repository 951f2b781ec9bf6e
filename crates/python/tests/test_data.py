"""pi3det.data.open on every dataset in ../shared/data, against the Rust side: the same frames
written by `pi3det convert --to pi3det-layout` (the Rust readers' frames through the Rust
writer: float32 .bin points, float32 boxes in a pickle) read back with numpy and pickle, and the
raw point files read with numpy.fromfile."""
import os
import pickle

import numpy as np
import pytest

import pi3det
from conftest import run

# Every dataset of ../shared/data (README there); kitti_label_stats holds a CSV of boxes without
# point clouds, which no reader takes.
DATASETS = {
    "kitti/training": 6,
    "kitti_extra/training": 3,
    "argoverse1/training": 3,
    "pi3det_sample": 6,
    "nuscenes_demo": 1,
}


@pytest.fixture(scope="module")
def converted(shared_data, pi3det_cli, tmp_path_factory):
    """{dataset: {frame_id: info dict}} and the output roots of `pi3det convert`."""
    out = {}
    for rel in DATASETS:
        dst = tmp_path_factory.mktemp(rel.replace("/", "_"))
        run([pi3det_cli, "convert", os.path.join(shared_data, rel), "--to", "pi3det-layout", "--out", str(dst),
             "--threads", "2"])
        with open(dst / "pi3det_infos_train.pkl", "rb") as f:
            infos = pickle.load(f)
        out[rel] = (dst, {i["frame_id"]: i for i in infos})
    return out


@pytest.mark.parametrize("rel", list(DATASETS))
def test_frames_equal_the_rust_side(rel, shared_data, converted):
    ds = pi3det.data.open(os.path.join(shared_data, rel))
    assert len(ds) == DATASETS[rel]
    root, infos = converted[rel]
    assert sorted(infos) == sorted(f.id for f in ds.__iter__())
    for frame in ds:
        info = infos[frame.id]
        pts = frame.points
        assert pts.dtype == np.float32 and pts.ndim == 2 and pts.shape[1] == len(frame.channels) >= 4
        assert pts.flags.c_contiguous and not pts.flags.owndata  # a view of the Rust buffer
        assert frame.channels[:4] == ["x", "y", "z", "intensity"]
        rust_pts = np.fromfile(os.path.join(root, info["point_clout_path"]), dtype=np.float32).reshape(-1, 4)
        np.testing.assert_array_equal(pts[:, :4], rust_pts)
        annos = info["annos"]
        assert list(frame.names) == list(annos["gt_names"])
        assert frame.boxes.dtype == np.float64 and frame.boxes.shape == (len(frame.names), 7)
        # The info file stores boxes as float32.
        np.testing.assert_array_equal(frame.boxes.astype(np.float32), annos["gt_boxes_lidar"].reshape(-1, 7))
        np.testing.assert_array_equal(frame.num_points, annos["num_points_in_gt"])
        if "pose" in info:
            np.testing.assert_allclose(frame.pose, info["pose"], rtol=0, atol=1e-12)
        else:
            assert frame.pose is None
        # The annotations without points are the same.
        meta = ds.info(ds_index(ds, frame.id))
        assert meta.points is None and meta.id == frame.id
        np.testing.assert_array_equal(meta.boxes, frame.boxes)


def ds_index(ds, frame_id):
    return [f.id for f in (ds.info(i) for i in range(len(ds)))].index(frame_id)


@pytest.mark.parametrize("rel", list(DATASETS))
def test_points_equal_the_raw_files(rel, shared_data):
    """x, y, z as numpy reads the point file itself (intensity may be rescaled by the reader)."""
    ds = pi3det.data.open(os.path.join(shared_data, rel))
    for i in range(len(ds)):
        frame = ds[i]
        raw = np.fromfile(frame.points_path, dtype=np.float32).reshape(-1, len(frame.channels))
        raw = raw[np.isfinite(raw).all(axis=1)]
        np.testing.assert_array_equal(frame.points[:, :3], raw[:, :3])
        if frame.channels[4:]:
            np.testing.assert_array_equal(frame.points[:, 4:], raw[:, 4:])


def test_indexing_and_iteration(shared_data):
    ds = pi3det.data.open(os.path.join(shared_data, "kitti", "training"))
    assert ds.format == "kitti" and len(ds) == 6
    assert ds[-1].id == ds[5].id == "000005"
    with pytest.raises(IndexError):
        ds[6]
    assert [f.id for f in ds] == [f"{i:06d}" for i in range(6)]
    f = ds.info(1)
    # Frame 000001: a Truck, a Car and a Cyclist (plus DontCare regions, which are no boxes).
    assert sorted(f.names) == ["Car", "Cyclist", "Truck"] and f.points is None
    assert "Frame(" in repr(f) and "Dataset(" in repr(ds)
    nus = pi3det.data.open(os.path.join(shared_data, "nuscenes_demo"))[0]
    assert nus.points.shape == (34688, 5) and nus.boxes.shape == (69, 7) and (nus.num_points >= 0).all()
