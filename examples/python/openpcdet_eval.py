"""Replacing OpenPCDet's KITTI evaluation with pi3det's, on the shared KITTI frames.

In OpenPCDet (pcdet/datasets/kitti/kitti_dataset.py, KittiDataset.evaluation) the call is

    from .kitti_object_eval_python import eval as kitti_eval
    ap_result_str, ap_dict = kitti_eval.get_official_eval_result(eval_gt_annos, eval_det_annos, class_names)

and becomes

    import pi3det.eval as kitti_eval
    ap_result_str, ap_dict = kitti_eval.get_official_eval_result(eval_gt_annos, eval_det_annos, class_names)

For datasets without cameras (Pi3DET's own loader calls transform_annotations_to_kitti_format first)
the LiDAR boxes go in directly: pi3det.eval.kitti_eval_lidar(gt_annos, det_annos, class_names).

This script builds OpenPCDet's annotation dicts from KITTI label files (kitti_common.get_label_anno),
makes "detections" by jittering them, and evaluates (six frames with five cars: the protocol's
11 / 40 recall points make such small splits' APs coarse):

    .venv/bin/python examples/python/openpcdet_eval.py [../shared/data/kitti/training]
"""
import glob
import os
import sys

import numpy as np

import pi3det.eval as kitti_eval


def get_label_anno(path):
    """OpenPCDet's kitti_common.get_label_anno, trimmed."""
    rows = [line.split() for line in open(path) if line.strip()]
    f = lambda i, j=None: np.array([[float(v) for v in r[i:j]] if j else float(r[i]) for r in rows])  # noqa: E731
    anno = {"name": np.array([r[0] for r in rows]), "truncated": f(1), "occluded": f(2).astype(np.int64),
            "alpha": f(3), "bbox": f(4, 8).reshape(-1, 4),
            "dimensions": f(8, 11).reshape(-1, 3)[:, [2, 0, 1]],  # h w l -> l h w
            "location": f(11, 14).reshape(-1, 3), "rotation_y": f(14)}
    anno["score"] = np.zeros(len(rows))
    return anno


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared",
                                                                "data", "kitti", "training")
    gt_annos = [get_label_anno(p) for p in sorted(glob.glob(os.path.join(root, "label_2", "*.txt")))]
    rng = np.random.default_rng(0)
    det_annos = []
    for g in gt_annos:
        keep = g["name"] != "DontCare"
        d = {k: v[keep].copy() for k, v in g.items()}
        d["location"] += rng.normal(0, 0.15, d["location"].shape)
        d["score"] = rng.uniform(0.3, 1.0, keep.sum())
        det_annos.append(d)

    ap_result_str, ap_dict = kitti_eval.get_official_eval_result(gt_annos, det_annos, ["Car", "Pedestrian", "Cyclist"])
    print(ap_result_str)
    print({k: round(v, 2) for k, v in ap_dict.items() if k.startswith("Car_")})


if __name__ == "__main__":
    main()
