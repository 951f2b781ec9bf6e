"""The KITTI-protocol evaluator, with OpenPCDet's signature and return values.

Replace ``from pcdet.datasets.kitti.kitti_object_eval_python import eval as kitti_eval`` and
``kitti_eval.get_official_eval_result(gt, dt, classes)`` with
``pi3det.eval.kitti_eval(gt, dt, classes)``: the same ``(result_str, ret_dict)``.
"""
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

from ._native import kitti_eval as _kitti_eval
from ._native import kitti_eval_detail
from ._native import kitti_eval_lidar as _kitti_eval_lidar

Classes = Union[str, int, Sequence[Union[str, int]]]

__all__ = ["kitti_eval", "kitti_eval_detail", "kitti_eval_lidar", "get_official_eval_result"]


def kitti_eval(
    gt_annos: Sequence[Mapping[str, Any]],
    dt_annos: Sequence[Mapping[str, Any]],
    current_classes: Classes,
    PR_detail_dict: Optional[dict] = None,
    *,
    compute_aos: Optional[bool] = None,
) -> Tuple[str, Dict[str, float]]:
    """OpenPCDet's ``get_official_eval_result``.

    ``gt_annos`` / ``dt_annos``: one dict per frame with numpy arrays ``name``, ``truncated``,
    ``occluded``, ``alpha``, ``bbox`` (N, 4), ``dimensions`` (N, 3, l h w), ``location`` (N, 3,
    camera frame, bottom centre), ``rotation_y`` and, for detections, ``score``; extra keys are
    ignored. ``current_classes``: names or OpenPCDet's indices (0 Car, 1 Pedestrian, 2 Cyclist,
    3 Van, 4 Person_sitting, 5 Truck). AOS is computed when the first detection's alpha is not
    -10, as OpenPCDet decides (``compute_aos`` overrides).

    Returns the text block OpenPCDet prints and its ``ret_dict`` (R40 APs at the strict
    overlaps: ``Car_aos/easy_R40`` ..., ``Car_3d/...``, ``Car_bev/...``, ``Car_image/...``).
    """
    if PR_detail_dict is not None:
        raise NotImplementedError("PR_detail_dict (precision curves) is not filled by pi3det; use kitti_eval_detail")
    result, ret, _ = _kitti_eval(gt_annos, dt_annos, current_classes, compute_aos)
    return result, ret


get_official_eval_result = kitti_eval


def kitti_eval_lidar(
    gt_annos: Sequence[Mapping[str, Any]],
    dt_annos: Sequence[Mapping[str, Any]],
    current_classes: Classes,
    *,
    name_map: Optional[Mapping[str, str]] = None,
    score_threshold: Optional[float] = None,
    bev_range: Optional[Sequence[float]] = None,
    overlaps: Optional[Mapping[str, Tuple[Sequence[float], Sequence[float]]]] = None,
) -> Tuple[str, Dict[str, float]]:
    """The evaluation of LiDAR-frame boxes, for data without cameras (the Pi3DET layout).

    ``gt_annos``: dicts with ``name`` and ``gt_boxes_lidar`` (or ``boxes_lidar``) ``(N, 7)``
    ``[x, y, z_center, dx, dy, dz, heading]``; ``dt_annos``: ``name``, ``boxes_lidar``,
    ``score`` (OpenPCDet's prediction dicts). Frames are matched by position. Both go through
    OpenPCDet's ``transform_annotations_to_kitti_format`` (identity camera, 50 px image boxes,
    every object easy), then the KITTI protocol, as OpenPCDet evaluates Pi3DET.

    ``name_map``: dataset name -> KITTI name (default ``{"Vehicle": "Car"}``);
    ``score_threshold``: drop detections below it; ``bev_range``: keep boxes whose centre lies in
    ``[x_min, y_min, x_max, y_max]``; ``overlaps``: ``{class: (strict, loose)}`` minimum overlaps
    ``[bbox, bev, 3d]`` for classes outside OpenPCDet's table.
    """
    result, ret, _ = _kitti_eval_lidar(
        gt_annos,
        dt_annos,
        current_classes,
        None if name_map is None else dict(name_map),
        score_threshold,
        None if bev_range is None else [float(v) for v in bev_range],
        None if overlaps is None else {k: (list(s), list(l)) for k, (s, l) in overlaps.items()},
    )
    return result, ret
