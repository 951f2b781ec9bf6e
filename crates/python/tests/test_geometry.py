"""pi3det.geometry on hand-checked boxes (areas by hand) and NMS with OpenPCDet's semantics."""
import math

import numpy as np

import pi3det

G = pi3det.geometry


def box(x=0.0, y=0.0, z=0.0, dx=4.0, dy=2.0, dz=1.5, h=0.0):
    return [x, y, z, dx, dy, dz, h]


def test_iou_by_hand():
    a = np.array([box(), box(x=2.0), box(x=10.0), box(h=math.pi / 2)])
    b = np.array([box(), box(dx=2.0, dy=4.0)])
    bev = G.rotated_iou_bev(a, b)
    assert bev.shape == (4, 2) and bev.dtype == np.float64
    # Same box; half-overlapping along x (4 / 12); disjoint; a 4x2 box turned 90 deg is the 2x4 one.
    np.testing.assert_allclose(bev[:, 0], [1.0, 4.0 / 12.0, 0.0, 4.0 / 12.0], atol=1e-12)
    np.testing.assert_allclose(bev[3, 1], 1.0, atol=1e-12)
    # 3-D: half the height overlapping -> intersection 8 * 0.75 over 12 + 12 - 6.
    c = np.array([box(z=0.75)])
    np.testing.assert_allclose(G.iou_3d(np.array([box()]), c), [[6.0 / 18.0]], atol=1e-12)
    np.testing.assert_allclose(G.rotated_iou_bev(np.array([box()]), c), [[1.0]], atol=1e-12)
    assert G.iou_3d(a, np.zeros((0, 7))).shape == (4, 0)
    # float32 and lists are taken too
    np.testing.assert_allclose(G.rotated_iou_bev(a.astype(np.float32).tolist(), b), bev, atol=1e-6)


def test_nms():
    boxes = np.array([box(), box(x=0.5), box(x=10.0), box(x=10.2), box(x=30.0)])
    scores = np.array([0.9, 0.95, 0.3, 0.8, 0.05])
    keep = G.nms(boxes, scores, 0.1)
    assert keep.dtype == np.int64 and list(keep) == [1, 3, 4]
    assert list(G.nms(boxes, scores, 0.1, score_threshold=0.1)) == [1, 3]
    assert list(G.nms(boxes, scores, 0.1, post_max_size=1)) == [1]
    assert list(G.nms(boxes, scores, 0.99)) == [1, 0, 3, 2, 4]
    assert list(G.nms(boxes, scores, 0.1, pre_max_size=2)) == [1]
