"""Benchmark of the splatting kernels against the same math in PyTorch (CPU).

Measured per Gaussian count N (each in a fresh worker process, one after the
other, so that peak memory is per run and the frameworks do not share cores):

- forward: :func:`rfmitsuba.splat.render` of one PAS, evaluated;
- backward: (forward + a weighted-sum loss + ``dr.backward``) minus forward;
- iteration: forward + the training loss (0.8 L1 + 0.2 (1 - SSIM)) + backward
  + an SGD update of every parameter;
- peak memory: growth of the worker's peak resident set during the timed
  runs, after a warm-up (the peak is reset through /proc/self/clear_refs, so
  LLVM's compilation memory does not count); for Dr.Jit also the JIT
  allocator's watermark;
- compile time of the first iteration in a fresh process, with an empty and
  with a warm kernel cache (``DRJIT_CACHE_DIR`` pointed at a temporary folder).

Times are medians over ``repeats`` runs after one warm-up; the LLVM backend is
asynchronous, so every timing ends with ``dr.sync_thread()``. The scene: N
Gaussians uniformly in a 6 x 5 x 3 m room, standard deviations 2-10 cm,
receiver near the middle.
"""
from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from ..core import backend as B
from ..core.upload import upload, upload_columns
from ..splat.render import render
from ..splat.tiles import lanes_per_tile
from ..train import loss as ssim

#: Gaussian counts of the full benchmark and of ``--quick``.
SIZES = (2_000, 10_000, 50_000)
QUICK_SIZES = (300,)
ROOM = ((0.0, 0.0, 0.0), (6.0, 5.0, 3.0))


def make_scene(n: int, *, seed: int = 0, views: int = 1):
    """Benchmark scene: numpy float32 means [n,3] m, log_scales [n,3], rotations [n,4],
    opacities [n], signals [n], rx [views,3] m (the first near the room's middle)."""
    rng = np.random.default_rng(seed)
    means = rng.uniform(*ROOM, (n, 3))
    log_scales = np.log(rng.uniform(0.02, 0.10, (n, 3)))
    rotations = rng.normal(size=(n, 4))
    opacities = rng.uniform(0.05, 0.9, n)
    signals = rng.uniform(0.0, 1.0, n)
    rx = np.array([[3.1, 2.4, 1.2]] + [list(rng.uniform((1, 1, 0.5), (5, 4, 2.5))) for _ in range(views - 1)])
    return tuple(np.asarray(a, np.float32) for a in (means, log_scales, rotations, opacities, signals)), rx


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _peak_bytes() -> int:
    """Peak resident set (VmHWM) of this process, bytes."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _reset_peak() -> None:
    """Reset the peak resident set to the current one (Linux >= 4.0), so that the
    compiler's memory during warm-up does not count."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


#: Each timed figure calls its function for at least this long (s), so that a fast kernel's
#: median spans as much of the machine's weather as a slow reference's: at 10 000 Gaussians five
#: Dr.Jit iterations last 45 ms and five PyTorch ones 1.3 s.
MIN_TIME_S = 1.0
#: At most this many calls per figure, whatever ``min_time_s`` asks.
MAX_CALLS = 2000


def times_ms(fn, repeats: int, *, warmup: int = 2, cpu: list | None = None, min_time_s: float = 0.0) -> list[float]:
    """Wall times (ms) of at least ``repeats`` calls, more until the calls have taken
    ``min_time_s`` seconds in all (at most :data:`MAX_CALLS`); with ``cpu``, also appends the
    process CPU time (all threads, ms) of each call -- a figure that other load on the cores
    does not inflate."""
    for _ in range(warmup):  # compilation, allocator
        fn()
    times = []
    spent = 0.0
    while len(times) < repeats or (spent < min_time_s and len(times) < MAX_CALLS):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        spent += dt
        times.append(dt * 1e3)
        if cpu is not None:
            cpu.append((time.process_time() - c0) * 1e3)
    return times


def _median_ms(fn, repeats: int, *, warmup: int = 2) -> float:
    return statistics.median(times_ms(fn, repeats, warmup=warmup))


def _figures(forward, forward_backward, iteration, repeats: int, *, min_time_s: float = 0.0) -> dict:
    """Median and best (minimum) times, ms, each over at least ``repeats`` calls and
    ``min_time_s`` seconds. Backward = (forward + backward) - forward. The best-of figures are
    the ones least disturbed by other load on shared cores."""
    f = times_ms(forward, repeats, min_time_s=min_time_s)
    fb = times_ms(forward_backward, repeats, min_time_s=min_time_s)
    cpu: list[float] = []
    it = times_ms(iteration, repeats, cpu=cpu, min_time_s=min_time_s)
    med = statistics.median
    return {"forward_ms": med(f), "backward_ms": max(med(fb) - med(f), 0.0), "iteration_ms": med(it),
            "forward_min_ms": min(f), "backward_min_ms": max(min(fb) - min(f), 0.0),
            "iteration_min_ms": min(it), "iteration_cpu_ms": med(cpu), "iteration_calls": len(it)}


# --------------------------------------------------------------------------- Dr.Jit
def _drjit_step_functions(n: int, height: int, width: int, views: int = 1):
    import drjit as dr


    B.ensure()
    (means, ls, rot, op, sig), rx = make_scene(n, views=views)
    # aligned uploads (rfmitsuba.core.upload): the kernels do not depend on where NumPy's memory fell
    vec = lambda tp, a: tp(*upload_columns(B.Float, a))  # noqa: E731
    params = [vec(B.Array3f, means), vec(B.Array3f, ls), vec(B.Array4f, rot), upload(B.Float, op), upload(B.Float, sig)]
    rng = np.random.default_rng(1)
    weights = upload(B.Float, rng.normal(size=views * height * width))
    target = upload(B.TensorXf, rng.uniform(0, 1, (views, height, width)))

    def attach():
        for p in params:
            dr.enable_grad(p)
            dr.clear_grad(p)

    def forward():
        attach()
        img = render(*params, rx, height=height, width=width, check=False)
        dr.eval(img)
        dr.sync_thread()
        return img

    def forward_backward():
        img = forward()
        dr.backward(dr.sum(img.array * weights))
        dr.eval([dr.grad(p) for p in params])
        dr.sync_thread()

    def iteration():
        attach()
        img = render(*params, rx, height=height, width=width, check=False)
        dr.backward(ssim.loss(img, target))
        for i, p in enumerate(params):
            params[i] = type(p)(dr.detach(p) - 1e-4 * dr.grad(p))
        dr.eval(params)
        dr.sync_thread()

    return forward, forward_backward, iteration


def measure_drjit(n: int, *, height: int = 90, width: int = 360, repeats: int = 5, views: int = 1,
                  min_time_s: float = 0.0) -> dict:
    """Dr.Jit timings (ms) and memory (MiB) at N Gaussians and B views, in this process."""
    import drjit as dr

    forward, forward_backward, iteration = _drjit_step_functions(n, height, width, views)
    for fn in (forward, forward_backward, iteration, iteration):
        fn()  # compile everything before memory is watched
    _reset_peak()
    rss0 = _rss_bytes()
    dr.detail.malloc_clear_statistics()
    return {**_figures(forward, forward_backward, iteration, repeats, min_time_s=min_time_s),
            "peak_mib": max(_peak_bytes() - rss0, 0) / 2**20,
            "jit_watermark_mib": dr.detail.malloc_watermark(dr.JitBackend.CUDA if B.is_cuda()
                                                            else dr.JitBackend.LLVM) / 2**20,
            "threads": dr.thread_count()}


def first_call(n: int = 2000) -> dict:
    """Time (ms) of the first and of a later training iteration in this process."""
    forward, forward_backward, iteration = _drjit_step_functions(n, 90, 360)
    t0 = time.perf_counter()
    iteration()
    first = (time.perf_counter() - t0) * 1e3
    later = _median_ms(iteration, 3)
    return {"first_ms": first, "later_ms": later, "compile_ms": max(first - later, 0.0)}


# --------------------------------------------------------------------------- PyTorch
def torch_available() -> bool:
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def measure_torch(n: int, *, height: int = 90, width: int = 360, repeats: int = 5, views: int = 1,
                  min_time_s: float = 0.0) -> dict:
    """PyTorch-CPU timings (ms) and memory (MiB) of :mod:`.torch_baseline` at N Gaussians
    (several views: one vectorised render per view)."""
    import torch

    from ..splat.torch_baseline import render as trender

    torch.set_num_threads(os.cpu_count() or 1)
    (means, ls, rot, op, sig), rx = make_scene(n, views=views)
    params = [torch.tensor(a) for a in (means, ls, rot, op, sig)]
    rx_t = [torch.tensor(r, dtype=torch.float32) for r in rx]
    rng = np.random.default_rng(1)
    weights = torch.tensor(rng.normal(size=(views, height, width)).astype(np.float32))
    target = torch.tensor(rng.uniform(0, 1, (views, height, width)).astype(np.float32))
    box = torch.nn.AvgPool2d(7, stride=1)

    def ssim_t(x, y):  # skimage defaults on valid windows (= the cropped mean)
        x, y = x[:, None], y[:, None]
        mx, my = box(x), box(y)
        c = 49.0 / 48.0
        vx = c * (box(x * x) - mx * mx)
        vy = c * (box(y * y) - my * my)
        vxy = c * (box(x * y) - mx * my)
        s = ((2 * mx * my + 1e-4) * (2 * vxy + 9e-4)) / ((mx * mx + my * my + 1e-4) * (vx + vy + 9e-4))
        return s.mean()

    def attach():
        for p in params:
            p.requires_grad_(True)
            p.grad = None

    def forward():
        attach()
        return torch.stack([trender(torch, *params, r, height=height, width=width) for r in rx_t])

    def forward_backward():
        (forward() * weights).sum().backward()

    def iteration():
        img = forward()
        loss = 0.8 * (img - target).abs().mean() + 0.2 * (1 - ssim_t(img, target))
        loss.backward()
        with torch.no_grad():
            for i, p in enumerate(params):
                params[i] = p - 1e-4 * p.grad

    for fn in (forward, forward_backward, iteration, iteration):
        fn()
    _reset_peak()
    rss0 = _rss_bytes()
    return {**_figures(forward, forward_backward, iteration, repeats, min_time_s=min_time_s),
            "peak_mib": max(_peak_bytes() - rss0, 0) / 2**20, "threads": torch.get_num_threads()}


# --------------------------------------------------------------------------- driver
def _worker(args: list[str], env: dict | None = None) -> dict:
    cmd = [sys.executable, "-m", "rfmitsuba.experiments.bench", *args]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"benchmark worker {' '.join(args)} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def compile_times(n: int = 2000) -> dict:
    """First-iteration compile time (ms) with an empty and with a warm Dr.Jit kernel cache."""
    with tempfile.TemporaryDirectory(prefix="rfm-drjit-cache-") as cache:
        env = dict(os.environ, DRJIT_CACHE_DIR=cache)
        cold = _worker(["first-call", "--n", str(n)], env)
        warm = _worker(["first-call", "--n", str(n)], env)
    return {"cold_ms": cold["compile_ms"], "warm_ms": warm["compile_ms"], "n": n,
            "cold_first_ms": cold["first_ms"], "warm_first_ms": warm["first_ms"], "later_ms": warm["later_ms"]}


def run(*, sizes=SIZES, repeats: int = 5, height: int = 90, width: int = 360, torch: bool = True,
        progress=None, compile_n: int = 2000, views: int = 1, min_time_s: float = MIN_TIME_S) -> dict:
    """Run the whole benchmark; returns a JSON-able dict (see :func:`format_report`). Each timed
    figure takes at least ``repeats`` calls and ``min_time_s`` seconds, on both sides."""
    have_torch = torch and torch_available()
    rows = []
    for n in sizes:
        common = ["--n", str(n), "--repeats", str(repeats), "--height", str(height), "--width", str(width),
                  "--views", str(views), "--min-time", str(min_time_s)]
        row = {"n": n, "drjit": _worker(["drjit", *common])}
        if have_torch:
            row["torch"] = _worker(["torch", *common])
        rows.append(row)
        if progress:
            progress(n)
    return {"rows": rows, "compile": compile_times(compile_n), "torch": have_torch,
            "torch_note": "" if have_torch else ("skipped" if not torch else "missing"), "height": height,
            "width": width, "views": views, "repeats": repeats, "min_time_s": min_time_s,
            "load": os.getloadavg(), "cores": os.cpu_count(),
            "tile_lanes": lanes_per_tile()}


def format_report(result: dict) -> str:
    """Plain-text table of :func:`run`'s result."""
    h, w = result["height"], result["width"]
    views = result.get("views", 1)
    what = f"one {h}x{w} PAS" if views == 1 else f"{views} PAS of {h}x{w} (one call)"
    min_time = result.get("min_time_s", 0.0)
    calls = f"median of at least {result['repeats']} calls" + (f" and {min_time:g} s" if min_time else "")
    lines = [f"splat benchmark: {what} per iteration, {calls} per figure "
             f"(cores {result['cores']}, load {' '.join(f'{x:.2f}' for x in result['load'])}"
             + (f", {result['tile_lanes']} rasteriser lanes per tile" if "tile_lanes" in result else "") + ")",
             f"{'N':>7} | {'Dr.Jit fwd':>10} {'bwd':>8} {'iter':>8} {'mem':>8} |"
             + (f" {'torch fwd':>10} {'bwd':>8} {'iter':>8} {'mem':>8} | {'speed-up fwd':>12} {'bwd':>6} {'iter':>6}"
                if result["torch"] else "")]
    for row in result["rows"]:
        d = row["drjit"]
        mem = d.get("jit_watermark_mib", d["peak_mib"])
        line = (f"{row['n']:>7} | {d['forward_ms']:>8.1f}ms {d['backward_ms']:>6.1f}ms {d['iteration_ms']:>6.1f}ms "
                f"{mem:>5.1f}MiB |")
        if result["torch"]:
            t = row["torch"]
            line += (f" {t['forward_ms']:>8.1f}ms {t['backward_ms']:>6.1f}ms {t['iteration_ms']:>6.1f}ms "
                     f"{t['peak_mib']:>5.1f}MiB | {t['forward_ms'] / d['forward_ms']:>11.1f}x "
                     f"{t['backward_ms'] / max(d['backward_ms'], 1e-3):>5.1f}x "
                     f"{t['iteration_ms'] / d['iteration_ms']:>5.1f}x")
        lines.append(line)
    if result["rows"] and "iteration_min_ms" in result["rows"][0]["drjit"]:
        lines.append("best call (least disturbed by other load), ms:")
        for row in result["rows"]:
            d = row["drjit"]
            line = (f"{row['n']:>7} | Dr.Jit fwd {d['forward_min_ms']:.1f}  bwd {d['backward_min_ms']:.1f}  "
                    f"iter {d['iteration_min_ms']:.1f}")
            if result["torch"]:
                t = row["torch"]
                line += (f" | torch fwd {t['forward_min_ms']:.1f}  bwd {t['backward_min_ms']:.1f}  "
                         f"iter {t['iteration_min_ms']:.1f} | speed-up iter "
                         f"{t['iteration_min_ms'] / d['iteration_min_ms']:.1f}x")
            lines.append(line)
        lines.append("CPU time per iteration (all threads, median; not inflated by other load), ms:")
        for row in result["rows"]:
            d = row["drjit"]
            line = f"{row['n']:>7} | Dr.Jit {d['iteration_cpu_ms']:.1f}"
            if result["torch"]:
                t = row["torch"]
                line += (f" | torch {t['iteration_cpu_ms']:.1f} | ratio "
                         f"{t['iteration_cpu_ms'] / max(d['iteration_cpu_ms'], 1e-3):.1f}x")
            lines.append(line)
    lines.append("mem: Dr.Jit = peak of the JIT allocator (arrays alive) during the timed runs; "
                 "torch = growth of the peak resident set")
    c = result["compile"]
    lines.append(f"compile time of a first iteration (N = {c['n']}, 90x360): empty kernel cache {c['cold_ms'] / 1e3:.2f} s, "
                 f"warm cache {c['warm_ms'] / 1e3:.2f} s"
                 + (f" (first iteration {c['cold_first_ms'] / 1e3:.2f} s / {c['warm_first_ms'] / 1e3:.2f} s, "
                    f"later ones {c['later_ms']:.1f} ms)" if "later_ms" in c else ""))
    if result.get("torch_note") == "missing":
        lines.append("PyTorch is missing: no comparison (pip install 'rfmitsuba[torch]', i.e. torch==2.13.0 CPU)")
    elif result.get("torch_note") == "skipped":
        lines.append("PyTorch comparison skipped (--no-torch)")
    return "\n".join(lines)


def _main(argv: list[str]) -> int:
    import argparse

    import rfmitsuba  # noqa: F401  (libLLVM before drjit)

    p = argparse.ArgumentParser(prog="python -m rfmitsuba.experiments.bench")
    p.add_argument("mode", choices=["drjit", "torch", "first-call"])
    p.add_argument("--n", type=int, default=10_000)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--height", type=int, default=90)
    p.add_argument("--width", type=int, default=360)
    p.add_argument("--views", type=int, default=1)
    p.add_argument("--min-time", type=float, default=0.0, help="seconds of calls per timed figure, at least")
    a = p.parse_args(argv)
    if a.mode == "drjit":
        res = measure_drjit(a.n, height=a.height, width=a.width, repeats=a.repeats, views=a.views,
                            min_time_s=a.min_time)
    elif a.mode == "torch":
        res = measure_torch(a.n, height=a.height, width=a.width, repeats=a.repeats, views=a.views,
                            min_time_s=a.min_time)
    else:
        res = first_call(a.n)
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
