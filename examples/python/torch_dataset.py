"""PyTorch datasets over pi3det: any dataset pi3det reads (map-style) and the simulator (iterable,
sequences split across DataLoader workers). The classes work without torch as plain Python
datasets; with torch installed (`pip install torch`), run

    .venv/bin/python examples/python/torch_dataset.py ../shared/data/kitti/training

to iterate both through a DataLoader with OpenPCDet-style collation (points concatenated with
their sample index in column 0, boxes padded).
"""
import sys

import numpy as np

import pi3det

try:
    import torch
    from torch.utils.data import Dataset, IterableDataset, get_worker_info
except ImportError:  # no torch: the same classes as plain Python datasets
    torch = None
    Dataset = IterableDataset = object

    def get_worker_info():
        return None


def sample(frame):
    """One training sample: what OpenPCDet's data_dict holds before its processors."""
    return {"frame_id": frame.id, "points": frame.points, "gt_boxes": frame.boxes, "gt_names": frame.names}


class LidarDataset(Dataset):
    """A Pi3DET root, KITTI folder, nuScenes info .pkl or Pi3DET sequence release, frame by frame."""

    def __init__(self, path, classes=("Car", "Pedestrian", "Cyclist")):
        self.frames = pi3det.data.open(path)
        self.classes = list(classes)

    def __len__(self):
        return len(self.frames)

    def __getitem__(self, index):
        s = sample(self.frames[index])
        keep = np.isin(s["gt_names"], self.classes)
        s["gt_boxes"], s["gt_names"] = s["gt_boxes"][keep], s["gt_names"][keep]
        return s


class SimulatedFrames(IterableDataset):
    """`sequences` simulated sequences of `frames` frames; each worker renders its own sequences."""

    def __init__(self, platform="drone", sequences=4, frames=20, seed=0):
        self.platform, self.sequences, self.frames, self.seed = platform, sequences, frames, seed

    def __iter__(self):
        info = get_worker_info()
        workers, me = (info.num_workers, info.id) if info else (1, 0)
        for seq in range(me, self.sequences, workers):
            for frame in pi3det.sim.simulate(self.platform, sequences=1, frames=self.frames, seed=self.seed,
                                             first_sequence=seq):
                yield sample(frame)


def collate(batch):
    """OpenPCDet's batching: points (sum N, 1 + C) with the sample index first, boxes (B, max M, 7)."""
    points = np.concatenate([np.pad(s["points"], ((0, 0), (1, 0)), constant_values=i) for i, s in enumerate(batch)])
    m = max(len(s["gt_boxes"]) for s in batch)
    boxes = np.zeros((len(batch), m, 7), dtype=np.float32)
    for i, s in enumerate(batch):
        boxes[i, : len(s["gt_boxes"])] = s["gt_boxes"]
    out = {"frame_id": [s["frame_id"] for s in batch], "points": points, "gt_boxes": boxes}
    if torch is not None:
        out["points"], out["gt_boxes"] = torch.from_numpy(out["points"]), torch.from_numpy(out["gt_boxes"])
    return out


def main():
    if torch is None:
        sys.exit("this example's DataLoader part needs torch (pip install torch)")
    from torch.utils.data import DataLoader

    path = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/kitti/training"
    for batch in DataLoader(LidarDataset(path), batch_size=2, collate_fn=collate, num_workers=2):
        print(batch["frame_id"], tuple(batch["points"].shape), tuple(batch["gt_boxes"].shape))
    for batch in DataLoader(SimulatedFrames(frames=3), batch_size=4, collate_fn=collate, num_workers=2):
        print(batch["frame_id"], tuple(batch["points"].shape), tuple(batch["gt_boxes"].shape))


if __name__ == "__main__":
    main()
