"""pi3det from Python: the parts of the Rust toolkit that need no libtorch.

* :mod:`pi3det.eval` -- the KITTI-protocol evaluator, a drop-in for OpenPCDet's
  ``kitti_common_eval.get_official_eval_result`` (the same APs, much faster), and
  ``kitti_eval_lidar`` for LiDAR-frame boxes (data without cameras);
* :mod:`pi3det.data` -- ``open(path)``: Pi3DET, KITTI, nuScenes (mmdet3d infos) and the full
  Pi3DET sequence release as a lazy sequence of :class:`Frame` (numpy arrays);
* :mod:`pi3det.geometry` -- exact rotated BEV / 3-D IoU matrices and rotated NMS;
* :mod:`pi3det.sim` -- the vehicle / drone / quadruped LiDAR simulator, frame by frame.

Errors of the Rust code are raised as :class:`Pi3detError` with the Rust message; ``err.path``
is the file it is about where there is one.
"""
from . import data, eval, geometry, sim
from ._native import Frame, Pi3detError, __version__

__all__ = ["Frame", "Pi3detError", "__version__", "data", "eval", "geometry", "sim"]
