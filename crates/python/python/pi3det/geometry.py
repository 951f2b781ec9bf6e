"""Box geometry on numpy arrays of ``[x, y, z_center, dx, dy, dz, heading]`` boxes (LiDAR frame):
exact rotated IoU (f64 polygon clipping) and OpenPCDet's class-agnostic rotated NMS."""
from ._native import iou_3d, nms, rotated_iou_bev

__all__ = ["iou_3d", "nms", "rotated_iou_bev"]
