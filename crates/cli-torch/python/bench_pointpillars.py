"""PyTorch side of `pi3det bench nn`: the same PointPillars network (pillar VFE, scatter, BEV
backbone, anchor head), loss (sigmoid focal, smooth-L1 with sin difference, direction
cross-entropy) and AdamW step as pi3det-nn, built with the installed torch and timed on the very
inputs pi3det-nn exported (features, cells, targets). Prints one JSON object.

    python bench_pointpillars.py EXCHANGE_DIR [--iters N] [--warmup N] [--threads N] [--device cuda]
"""

import argparse
import json
import math
import os
import time

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F


def load(dir_, name, dtype, shape):
    a = np.fromfile(os.path.join(dir_, name + ".bin"), dtype=dtype)
    return torch.from_numpy(a.reshape(shape).copy())


class PFN(nn.Module):
    def __init__(self, c_in, c_out, last, bn):
        super().__init__()
        self.last = last
        c = c_out if last else c_out // 2
        self.linear = nn.Linear(c_in, c, bias=False)
        self.norm = nn.BatchNorm1d(c, eps=bn["eps"], momentum=bn["momentum"])

    def forward(self, x):  # [P, M, C]
        p, m, _ = x.shape
        y = self.linear(x)
        y = F.relu(self.norm(y.view(p * m, -1)).view(p, m, -1))
        mx = y.amax(dim=1, keepdim=True)
        if self.last:
            return mx.squeeze(1)
        return torch.cat([y, mx.expand(-1, m, -1)], dim=2)


class Backbone(nn.Module):
    def __init__(self, cfg, c_in, bn):
        super().__init__()
        self.blocks = nn.ModuleList()
        self.deblocks = nn.ModuleList()
        for i, (n, s, c, u, uc) in enumerate(zip(cfg["layer_nums"], cfg["layer_strides"], cfg["num_filters"], cfg["upsample_strides"], cfg["num_upsample_filters"])):
            layers = [nn.Conv2d(c_in, c, 3, stride=s, padding=1, bias=False), nn.BatchNorm2d(c, eps=bn["eps"], momentum=bn["momentum"]), nn.ReLU()]
            for _ in range(n):
                layers += [nn.Conv2d(c, c, 3, padding=1, bias=False), nn.BatchNorm2d(c, eps=bn["eps"], momentum=bn["momentum"]), nn.ReLU()]
            self.blocks.append(nn.Sequential(*layers))
            self.deblocks.append(nn.Sequential(nn.ConvTranspose2d(c, uc, u, stride=u, bias=False), nn.BatchNorm2d(uc, eps=bn["eps"], momentum=bn["momentum"]), nn.ReLU()))
            c_in = c

    def forward(self, x):
        ups = []
        for b, d in zip(self.blocks, self.deblocks):
            x = b(x)
            ups.append(d(x))
        return torch.cat(ups, 1) if len(ups) > 1 else ups[0]


class PointPillars(nn.Module):
    def __init__(self, m):
        super().__init__()
        bn = m["batch_norm"]
        filters = m["vfe_filters"]
        c_in = 10
        self.pfn = nn.ModuleList()
        for i, c in enumerate(filters):
            self.pfn.append(PFN(c_in, c, i == len(filters) - 1, bn))
            c_in = c
        self.backbone = Backbone(m["backbone"], filters[-1], bn)
        c = sum(m["backbone"]["num_upsample_filters"])
        a, k = m["anchors_per_location"], m["num_classes"]
        self.k = k
        self.conv_cls = nn.Conv2d(c, a * k, 1)
        self.conv_box = nn.Conv2d(c, a * 7, 1)
        self.conv_dir = nn.Conv2d(c, a * 2, 1)
        self.nx, self.ny = m["nx"], m["ny"]
        # Like pi3det-nn: the BEV canvas is [B, ny, nx, C] seen as NCHW (channels-last layout)
        # unless the config turns that off.
        self.channels_last = m.get("channels_last", False)
        # Like pi3det-nn's `precision` / `train.precision`: the backbone in bfloat16, the heads
        # in f32 (main() sets it for the training step and for inference).
        self.bf16 = False

    def forward(self, features, cells, batch_size):
        x = features
        for l in self.pfn:
            x = l(x)
        c = x.shape[1]
        canvas = torch.zeros(batch_size * self.ny * self.nx, c, dtype=x.dtype, device=x.device)
        bev = canvas.index_copy(0, cells, x).view(batch_size, self.ny, self.nx, c).permute(0, 3, 1, 2)
        if not self.channels_last:
            bev = bev.contiguous()
        with torch.autocast(device_type=bev.device.type, dtype=torch.bfloat16, enabled=self.bf16):
            f = self.backbone(bev)
        f = f.float()
        flat = lambda t, n: t.permute(0, 2, 3, 1).contiguous().view(batch_size, -1, n)
        return flat(self.conv_cls(f), self.k), flat(self.conv_box(f), 7), flat(self.conv_dir(f), 2)


def loss_fn(out, t, batch_size, w):
    cls, box, dirp = out
    b, n, c = cls.shape
    labels = t["labels"]
    pos = (labels > 0).float()
    cared = (labels >= 0).float()
    cls_w = cared / pos.sum(1, keepdim=True).clamp(min=1.0)
    one_hot = torch.zeros(b, n, c + 1, device=cls.device).scatter_(-1, labels.clamp(min=0).unsqueeze(-1), 1.0)[..., 1:]
    p = torch.sigmoid(cls)
    alpha_w = one_hot * 0.25 + (1 - one_hot) * 0.75
    pt = one_hot * (1 - p) + (1 - one_hot) * p
    bce = cls.clamp(min=0) - cls * one_hot + torch.log1p(torch.exp(-cls.abs()))
    l_cls = (alpha_w * pt.pow(2.0) * bce * cls_w.unsqueeze(-1)).sum() * (w["cls"] / batch_size)
    bp = box.reshape(b * n, 7).index_select(0, t["pos_index"])
    tg = t["pos_codes"]
    pe = torch.cat([bp[:, :6], torch.sin(bp[:, 6:7]) * torch.cos(tg[:, 6:7])], 1)
    te = torch.cat([tg[:, :6], torch.cos(bp[:, 6:7]) * torch.sin(tg[:, 6:7])], 1)
    d = (pe - te).abs()
    beta = 1.0 / 9.0
    sl1 = torch.where(d < beta, 0.5 * d * d / beta, d - 0.5 * beta)
    l_loc = (sl1 * t["pos_weight"].unsqueeze(-1)).sum() * (w["loc"] / batch_size)
    dp = dirp.reshape(b * n, 2).index_select(0, t["pos_index"])
    nll = -F.log_softmax(dp, -1).gather(1, t["pos_dir"].unsqueeze(1)).squeeze(1)
    l_dir = (nll * t["pos_weight"]).sum() * (w["dir"] / batch_size)
    return l_cls + l_loc + l_dir


def timed(fn, iters, warmup, device):
    # CUDA work is asynchronous: each timing ends when the device is done, as on the Rust side.
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for _ in range(warmup):
        fn()
    sync()
    ts = []
    for _ in range(iters):
        t = time.perf_counter()
        fn()
        sync()
        ts.append(time.perf_counter() - t)
    ts.sort()
    return {"mean_ms": 1e3 * sum(ts) / len(ts), "median_ms": 1e3 * ts[len(ts) // 2], "min_ms": 1e3 * ts[0]}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--iters", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--layout", choices=["same", "nchw", "channels_last"], default="same", help="BEV memory layout (same: as pi3det-nn)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda (as pi3det-nn's --device)")
    args = ap.parse_args()
    dev = torch.device(args.device)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    m = json.load(open(os.path.join(args.dir, "meta.json")))
    if args.layout != "same":
        m["channels_last"] = args.layout == "channels_last"
    net = PointPillars(m).to(dev)
    res = {"torch": torch.__version__, "threads": torch.get_num_threads(), "channels_last": net.channels_last, "bf16_train": m.get("bf16_train", False), "bf16_infer": m.get("bf16_infer", False), "parameters": sum(p.numel() for p in net.parameters())}

    tr = m["train"]
    b = tr["batch_size"]
    x = load(args.dir, "train_features", np.float32, (tr["pillars"], m["max_points"], 10)).to(dev)
    cells = load(args.dir, "train_cells", np.int64, (tr["pillars"],)).to(dev)
    t = {
        "labels": load(args.dir, "train_labels", np.int64, (b, m["num_anchors"])),
        "pos_index": load(args.dir, "train_pos_index", np.int64, (tr["positives"],)),
        "pos_codes": load(args.dir, "train_pos_codes", np.float32, (tr["positives"], 7)),
        "pos_dir": load(args.dir, "train_pos_dir", np.int64, (tr["positives"],)),
        "pos_weight": load(args.dir, "train_pos_weight", np.float32, (tr["positives"],)),
    }
    t = {k: v.to(dev) for k, v in t.items()}
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, betas=(0.9, 0.99), weight_decay=0.01)
    w = m["loss_weights"]

    def step():
        opt.zero_grad(set_to_none=False)
        loss = loss_fn(net(x, cells, b), t, b, w)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
        opt.step()
        return loss

    net.train()
    net.bf16 = m.get("bf16_train", False)
    res["train_step"] = timed(step, args.iters, args.warmup, dev)
    res["train_loss"] = float(step())

    inf = m["infer"]
    xi = load(args.dir, "infer_features", np.float32, (inf["pillars"], m["max_points"], 10)).to(dev)
    ci = load(args.dir, "infer_cells", np.int64, (inf["pillars"],)).to(dev)
    net.eval()
    net.bf16 = m.get("bf16_infer", False)

    def fwd():
        with torch.inference_mode():
            return net(xi, ci, 1)

    res["forward"] = timed(fwd, args.iters, args.warmup, dev)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
