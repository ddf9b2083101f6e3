"""Time the splat rasteriser's op alone (forward and backward pass), on the benchmark's scene.

    python scripts/bench_raster.py [--n 10000] [--views 1] [--threads 2] [--repeats 25]

Renders the scene of ``rfmitsuba bench splat`` once to get its projected Gaussians and tile
lists, then times ``splat.raster.Rasterize``'s ``eval`` (forward) and ``backward`` on them with
a fixed random image gradient: the wall time (median), the kernels' own time (Dr.Jit's kernel
history) and a checksum of the image and of each gradient, so that two commits can be compared
on one machine (run it with each commit's ``PYTHONPATH``). The figures of the lab notes'
entry (docs/lab-notes/speed.md, "The splat rasteriser's loops") were taken this way.
"""
from __future__ import annotations

import argparse
import statistics
import time

import drjit as dr
import numpy as np

from rfmitsuba.core import backend as B
from rfmitsuba.experiments import bench
from rfmitsuba.splat import raster


def _captured_inputs(n: int, views: int, height: int, width: int) -> list:
    """The Rasterize op's inputs at the benchmark scene (detached parameters, tile lists, sizes)."""
    seen = {}
    original = raster.Rasterize.eval

    def spy(self, *args):
        seen["args"] = args
        return original(self, *args)

    raster.Rasterize.eval = spy
    try:
        forward, _, _ = bench._drjit_step_functions(n, height, width, views)
        forward()
    finally:
        raster.Rasterize.eval = original
    return [dr.detach(a) if i < 7 else a for i, a in enumerate(seen["args"])]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=10_000, help="Gaussians (default 10000)")
    p.add_argument("--views", type=int, default=1)
    p.add_argument("--height", type=int, default=90)
    p.add_argument("--width", type=int, default=360)
    p.add_argument("--threads", type=int, default=None, help="Dr.Jit threads (default: as configured)")
    p.add_argument("--repeats", type=int, default=25)
    a = p.parse_args()
    B.ensure()
    if a.threads:
        dr.set_thread_count(a.threads)
    args = _captured_inputs(a.n, a.views, a.height, a.width)
    grad = B.Float(np.random.default_rng(0).normal(size=a.views * a.height * a.width).astype(np.float32))

    def once():
        op = raster.Rasterize()
        t0 = time.perf_counter()
        image = op.eval(*args)
        dr.sync_thread()
        t1 = time.perf_counter()
        grads = {}
        op.grad_out = lambda: grad
        op.set_grad_in = grads.__setitem__
        op.backward()
        dr.sync_thread()
        return image, grads, t1 - t0, time.perf_counter() - t1

    for _ in range(3):
        once()
    runs = [once() for _ in range(a.repeats)]
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory):
        dr.kernel_history_clear()
        image, grads, _, _ = once()
        kernel_ms = sum(h["execution_time"] for h in dr.kernel_history())
    ms = lambda k: statistics.median(r[k] for r in runs) * 1e3  # noqa: E731
    print(f"N {a.n}, {a.views} view(s) of {a.height}x{a.width}, {dr.thread_count()} thread(s), "
          f"{args[7].count} pairs: forward {ms(2):.3f} ms, backward {ms(3):.3f} ms (median of {a.repeats}); "
          f"kernels of one forward + backward {kernel_ms:.3f} ms")
    print(f"checksums: image {float(np.abs(image.numpy()).sum()):.6e}, "
          + ", ".join(f"{k} {float(np.abs(v.numpy()).sum()):.6e}" for k, v in grads.items()))


if __name__ == "__main__":
    main()
