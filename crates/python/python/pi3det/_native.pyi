"""Type stubs of the Rust extension module (crates/python/src)."""
from os import PathLike
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

class Pi3detError(Exception):
    """An error of pi3det's Rust code, with its message; ``path``: the file it is about."""

    path: Optional[str]

class Frame:
    id: str
    platform: str
    sequence: Optional[str]
    timestamp: Optional[float]
    points: Optional[npt.NDArray[np.float32]]
    channels: List[str]
    boxes: npt.NDArray[np.float64]
    names: npt.NDArray[np.str_]
    scores: Optional[npt.NDArray[np.float64]]
    num_points: npt.NDArray[np.int64]
    pose: Optional[npt.NDArray[np.float64]]
    points_path: Optional[str]

class Dataset:
    format: str
    root: str
    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Frame: ...
    def __iter__(self) -> Iterator[Frame]: ...
    def info(self, index: int) -> Frame: ...

class Simulation:
    def __len__(self) -> int: ...
    def __iter__(self) -> Iterator[Frame]: ...
    def __next__(self) -> Frame: ...

_Classes = Union[str, int, Sequence[Union[str, int]]]
_Detail = Dict[str, Dict[str, Any]]

def kitti_eval(
    gt_annos: Sequence[Mapping[str, Any]],
    dt_annos: Sequence[Mapping[str, Any]],
    current_classes: _Classes,
    compute_aos: Optional[bool] = None,
) -> Tuple[str, Dict[str, float], _Detail]: ...
def kitti_eval_detail(
    gt_annos: Sequence[Mapping[str, Any]],
    dt_annos: Sequence[Mapping[str, Any]],
    current_classes: _Classes,
    compute_aos: Optional[bool] = None,
) -> _Detail: ...
def kitti_eval_lidar(
    gt_annos: Sequence[Mapping[str, Any]],
    dt_annos: Sequence[Mapping[str, Any]],
    current_classes: _Classes,
    name_map: Optional[Dict[str, str]] = None,
    score_threshold: Optional[float] = None,
    bev_range: Optional[List[float]] = None,
    overlaps: Optional[Dict[str, Tuple[List[float], List[float]]]] = None,
) -> Tuple[str, Dict[str, float], _Detail]: ...
def open(path: Union[str, PathLike[str]]) -> Dataset: ...
def rotated_iou_bev(boxes_a: npt.ArrayLike, boxes_b: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
def iou_3d(boxes_a: npt.ArrayLike, boxes_b: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
def nms(
    boxes: npt.ArrayLike,
    scores: npt.ArrayLike,
    iou_threshold: float,
    score_threshold: Optional[float] = None,
    pre_max_size: Optional[int] = None,
    post_max_size: Optional[int] = None,
) -> npt.NDArray[np.int64]: ...
def simulate(
    platform: str,
    sequences: int = 1,
    frames: int = 200,
    seed: int = 0,
    layout: Optional[str] = None,
    config: Optional[Union[str, PathLike[str]]] = None,
    first_sequence: int = 0,
) -> Simulation: ...
