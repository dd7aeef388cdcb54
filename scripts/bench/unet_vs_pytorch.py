#!/usr/bin/env python3
"""tolray's U-Net against the same network in PyTorch on the CPU, in one run.

Nothing in tolray runs this (no test, no CI job); it measures. The network is tolray's decoder
U-Net (`src/decoder/unet.rs`): 8 input channels, width 8, 3 levels; per level two 3x3
convolutions with zero padding and ReLU (8, 16, 32 channels), 2x2 average pooling, a bottleneck
of two convolutions (64), then per level nearest 2x upsampling, concatenation [upsampled, skip],
two convolutions; a final 1x1 convolution to 3 channels. One step is the forward and backward
pass of L = sum(out * g) over a batch of 64 crops, with the gradients of every parameter and of
the input (the decoder's training needs dL/dinput to reach the lens).

  * PyTorch: the batch as one tensor (float32, NCHW), `torch.set_num_threads(--threads)`,
    input with requires_grad; the median of --repeat steps after two warm-up steps.
  * tolray: the criterion benchmark `deep/unet_step/64x{side}px/width8` (benches/deep.rs; crops
    run one by one on the rayon pool, RAYON_NUM_THREADS=--threads, parameter gradients summed
    in crop order), run by this script with `cargo bench`; criterion's median.

Usage: python3 scripts/bench/unet_vs_pytorch.py [--threads 2] [--sides 64 256] [--repeat 10]
(from the repository root; needs `pip install torch numpy`).
"""
import argparse
import os
import platform
import re
import statistics
import subprocess
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


class Unet(nn.Module):
    def __init__(self, cin=8, width=8, levels=3):
        super().__init__()
        ch = [width << l for l in range(levels + 1)]
        self.levels = levels
        self.down = nn.ModuleList()
        c = cin
        for l in range(levels + 1):
            self.down.append(nn.ModuleList([nn.Conv2d(c, ch[l], 3, padding=1),
                                            nn.Conv2d(ch[l], ch[l], 3, padding=1)]))
            c = ch[l]
        self.up = nn.ModuleList()
        for l in reversed(range(levels)):
            self.up.append(nn.ModuleList([nn.Conv2d(ch[l + 1] + ch[l], ch[l], 3, padding=1),
                                          nn.Conv2d(ch[l], ch[l], 3, padding=1)]))
        self.out = nn.Conv2d(width, 3, 1)

    def forward(self, x):
        skips = []
        for l, (a, b) in enumerate(self.down):
            x = F.relu(b(F.relu(a(x))))
            if l < self.levels:
                skips.append(x)
                x = F.avg_pool2d(x, 2)
        for (a, b), s in zip(self.up, reversed(skips)):
            x = torch.cat([F.interpolate(x, scale_factor=2, mode="nearest"), s], dim=1)
            x = F.relu(b(F.relu(a(x))))
        return self.out(x)


def torch_step_ms(side, batch, threads, repeat):
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    net = Unet()
    x = torch.rand(batch, 8, side, side, requires_grad=True)
    g = torch.rand(batch, 3, side, side) - 0.5
    times = []
    for i in range(repeat + 2):
        net.zero_grad(set_to_none=True)
        x.grad = None
        t = time.perf_counter()
        (net(x) * g).sum().backward()
        dt = time.perf_counter() - t
        if i >= 2:
            times.append(dt)
    return 1e3 * statistics.median(times)


UNITS = {"ns": 1e-6, "µs": 1e-3, "us": 1e-3, "ms": 1.0, "s": 1e3}


def tolray_step_ms(sides, threads):
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    out = subprocess.run(["cargo", "bench", "--bench", "deep", "--", "unet_step"], env=env,
                         capture_output=True, text=True, check=True).stdout
    res = {}
    for side in sides:
        m = re.search(rf"unet_step/64x{side}px/width8\s+time:\s+\[\S+ \S+ (\S+) (\S+) \S+ \S+\]",
                      out)
        if not m:
            raise SystemExit(f"no criterion figure for side {side} in:\n{out}")
        res[side] = float(m.group(1)) * UNITS[m.group(2)]
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sides", type=int, nargs="+", default=[64, 256])
    ap.add_argument("--repeat", type=int, default=10)
    a = ap.parse_args()
    print(f"{platform.processor() or platform.machine()}, torch {torch.__version__} "
          f"({torch.backends.cpu.get_cpu_capability()}), {a.threads} threads, batch 64")
    tr = tolray_step_ms(a.sides, a.threads)
    print("| crops | tolray (criterion median) | PyTorch (median) | tolray / PyTorch |")
    print("|---|---|---|---|")
    for side in a.sides:
        pt = torch_step_ms(side, 64, a.threads, a.repeat if side <= 128 else max(3, a.repeat // 3))
        print(f"| 64 x {side}² | {tr[side]:.1f} ms | {pt:.1f} ms | {tr[side] / pt:.2f}x |")


if __name__ == "__main__":
    main()
