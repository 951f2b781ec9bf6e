"""Datasets: ``open(path)`` on every format pi3det reads, frames as numpy arrays.

    ds = pi3det.data.open("data/kitti/training")     # Pi3DET, KITTI, nuScenes infos, sequences
    frame = ds[0]                                     # points float32 (N, C), boxes float64 (M, 7)
    info = ds.info(0)                                 # annotations only, points not read
"""
from ._native import Dataset, Frame, open

__all__ = ["Dataset", "Frame", "open"]
