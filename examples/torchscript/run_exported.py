"""Runs a model exported by `pi3det export` in Python (PyTorch only), on the example inputs the
export saved beside it, and checks the result against what Rust computed.

    pi3det export --ckpt runs/pp/final.safetensors --out model.pt
    python examples/torchscript/run_exported.py model.pt

The contract (see crates/nn/src/export.rs):
- inputs of `model.pt`: `features` float32 [P, M, 10] (pillars × points per pillar × the
  decorated point: x, y, z, intensity, offsets to the pillar's mean and centre) and `cells` int64
  [P] (the flat BEV cell iy * nx + ix of each pillar), as `pi3det`'s pillarization makes them
  from points in the detector frame (the config's grid, in model.json);
- output: one flat float32 tensor, the outputs of model.json's `dense_shapes` concatenated
  (the BEV map first for two-stage models, then the head: anchor head cls/boxes/dir logits,
  center head heatmap/codes); decode them with the config's box coder and NMS, or run the file
  with `pi3det run --ckpt model.pt`, which does all of it.
- `model.roi.pt` (two-stage): inputs the BEV map and rois [1, N, 7] (zero-padded proposals),
  output the RoI head's outputs flat (`roi_shapes`).
"""
import json
import sys

import numpy as np
import torch

model_path = sys.argv[1]
stem = model_path[: -len(".pt")]
meta = json.load(open(stem + ".json"))
example = np.load(stem + ".example.npz")
model = torch.jit.load(model_path)
with torch.no_grad():
    flat = model(torch.from_numpy(example["features"]), torch.from_numpy(example["cells"]))
sizes = [int(np.prod(s)) for s in meta["dense_shapes"]]
outputs = [t.reshape(s) for t, s in zip(torch.split(flat, sizes), meta["dense_shapes"])]
for s, t in zip(meta["dense_shapes"], outputs):
    print(f"output {s}: mean {t.mean().item():+.4f}")
diff = (flat - torch.from_numpy(example["output"])).abs().max().item()
print(f"max |python - rust| = {diff:.2e}")
sys.exit(0 if diff < 1e-4 else 1)
