"""Kernel time of the training loss (0.8 L1 + 0.2 (1 - SSIM)), forward and backward, on one thread.

    python scripts/bench_loss.py [--batch 8] [--height 45] [--width 180] [--repeats 200]

Prints the wall and kernel time (Dr.Jit's kernel history) per forward + backward pass of a batch
of random image pairs, the number of kernel launches, and the loss and a gradient checksum, so
two commits can be compared on one machine (run it with each commit's ``PYTHONPATH``).
"""
from __future__ import annotations

import argparse
import time

import drjit as dr
import numpy as np

from rfmitsuba.core import backend as B


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--height", type=int, default=45)
    ap.add_argument("--width", type=int, default=180)
    ap.add_argument("--repeats", type=int, default=200)
    a = ap.parse_args()
    B.set_variant("llvm")
    dr.set_thread_count(1)
    from rfmitsuba.train import loss as L

    rng = np.random.default_rng(0)
    shape = (a.batch, a.height, a.width)
    gt_np = rng.random(shape, np.float32)
    pred_np = np.clip(gt_np + 0.1 * rng.standard_normal(shape).astype(np.float32), 0, 1)

    def once():
        pred = B.TensorXf(pred_np)
        dr.enable_grad(pred)
        value = L.loss(pred, B.TensorXf(gt_np))
        dr.backward(value)
        grad = dr.grad(pred)
        dr.eval(grad)
        return float(value.numpy()[0]), grad

    for _ in range(5):
        once()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    t0 = time.perf_counter()
    for _ in range(a.repeats):
        value, grad = once()
    wall = (time.perf_counter() - t0) / a.repeats
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    kernels = sum(h.get("execution_time", 0.0) for h in hist) / a.repeats
    g = np.asarray(grad.numpy(), np.float64)
    print(f"loss forward + backward, {a.batch} x {a.height} x {a.width}, one thread: wall {1e3 * wall:.2f} ms, "
          f"kernels {kernels:.2f} ms, {len(hist) / a.repeats:.0f} launches; loss {value:.9f}, "
          f"gradient sum {g.sum():.6e}, |gradient| sum {np.abs(g).sum():.6e}")


if __name__ == "__main__":
    main()
