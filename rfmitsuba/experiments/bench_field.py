"""Benchmark of the coherent Gaussian field (the default field for unknown rooms and measured
data) and of the Bartlett read-out, against references of the same math, in one run.

Measured (times are medians over ``repeats`` calls after warm-up, with the process CPU time
beside them: CPU time counts every thread of this process and is not inflated by other load on
shared cores; every timing ends with ``dr.sync_thread()``):

- ``field``: render of B = 8 normalised 90 x 360 PAS (forward) and forward + backward of
  ``sum(c * PAS)`` to every parameter, Dr.Jit against the PyTorch-CPU twin
  (:mod:`rfmitsuba.models.coherent_gaussians_torch`, autograd), with the parity of their PAS
  and gradients;
- ``render``: Dr.Jit render time per PAS without gradients, batches of 8 and 40;
- ``bartlett``: the Bartlett op alone (16 channels -> normalised PAS), forward and forward +
  backward, Dr.Jit against NumPy (BLAS complex matrix products for both passes, on one BLAS
  thread: two beside Dr.Jit's pool on 2 cores took 0.7-8 ms for the 8-view forward pass, one
  a steady 1.0 ms);
- ``peak``: the arithmetic limit, one core's measured peak of the read-out's complex product
  (:func:`product_peak`): every timing is also given as the time its read-out products
  (:func:`readout_flops`) would take at that peak, and as a fraction of it;
- ``stage1``: steps per second of a real Stage-1 training (:class:`~rfmitsuba.train.trainer.Trainer`,
  the configuration's batch, full resolution) on a dataset: the given one, or a NeRF2-like folder
  (:func:`rfmitsuba.sim.nerf2like.make_nerf2like`) made once in the cache folder; at 90 x 360
  too where the field trains on block means, and traced every step (``stage1_traced``) beside
  the recorded step the trainer runs (:mod:`rfmitsuba.train.frozen_step`).

The benchmark field: the direct path plus ``images`` reflections across the six walls of a
6 x 5 x 3 m room and ``scatterers`` scattering points, 8 moving transmitters, plane wavefront
and amplitude read-out (the simulated-data configuration).
"""
from __future__ import annotations

import dataclasses
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core import backend as B
from ..models.base import Views, render
from ..models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField, compose_images
from ..rf import bartlett as bartlett_op
from ..rf.bartlett_ref import beamformer
from ..rf.array import NUM_ELEMENTS
from .bench import times_ms

ROOM = np.array([[0.0, 0.0, 0.0], [6.0, 5.0, 3.0]])
FREQUENCY_HZ = 2.4e9


def _load() -> float:
    return os.getloadavg()[0]


def timed(fn, repeats: int, *, warmup: int = 2) -> dict:
    """{"ms": median wall time, "cpu_ms": median process CPU time, "min_ms"} of ``repeats`` calls
    of ``fn`` after ``warmup`` calls (:func:`rfmitsuba.experiments.bench.times_ms`)."""
    cpu: list[float] = []
    wall = times_ms(fn, repeats, warmup=warmup, cpu=cpu)
    return {"ms": statistics.median(wall), "cpu_ms": statistics.median(cpu), "min_ms": min(wall)}


def readout_flops(views: int, pixels: int) -> int:
    """Real floating-point operations of one Bartlett product, ``[views, 16] x [16, pixels]``
    complex (a complex multiply-add is 8): the read-out's forward pass, and its adjoint's."""
    return 8 * int(views) * NUM_ELEMENTS * int(pixels)


def product_peak(*, views: int = 64, repeats: int = 7) -> dict:
    """One core's peak of the read-out's product: ``np.matmul`` complex64 [views, 16] x
    [16, 90*360] on one BLAS thread, the fastest of ``repeats`` calls. Returns {"gflops",
    "views", "pixels"}."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    h = (rng.normal(size=(views, NUM_ELEMENTS)) + 1j * rng.normal(size=(views, NUM_ELEMENTS))).astype(np.complex64)
    w = np.ascontiguousarray(beamformer(frequency_hz=FREQUENCY_HZ).T)             # [16, P]
    out = np.empty((views, w.shape[1]), np.complex64)
    with threadpool_limits(limits=1, user_api="blas"):
        best = timed(lambda: np.matmul(h, w, out=out), repeats)["min_ms"]
    return {"gflops": readout_flops(views, w.shape[1]) / (best * 1e6), "views": views, "pixels": w.shape[1]}


def make_field(*, scatterers: int = 96, seed: int = 0, readout: str = "amplitude",
               wavefront: str = "plane") -> CoherentGaussianField:
    """The benchmark field: direct path, the six walls' single and double reflections (31 images)
    and ``scatterers`` points in the room, gains and windows perturbed from their initial values."""
    walls_A = np.repeat(np.eye(3)[None], 6, 0)
    walls_b = np.zeros((6, 3))
    for i, (axis, side) in enumerate((a, s) for a in range(3) for s in range(2)):
        walls_A[i, axis, axis] = -1.0
        walls_b[i, axis] = 2.0 * ROOM[side, axis]
    A, b, order = compose_images(walls_A, walls_b, max_order=2)
    rng = np.random.default_rng(seed)
    pts = rng.uniform(ROOM[0] + 0.3, ROOM[1] - 0.3, (scatterers, 3))
    f = CoherentGaussianField(A, order, pts, cfg=CoherentGaussianConfig(init_extent=2.0), readout=readout,
                              wavefront=wavefront, vis_center=ROOM.mean(0), frequency_hz=FREQUENCY_HZ, seed=seed)
    params = {k: np.asarray(v.numpy(), np.float64) for k, v in f.params.items()}
    params["img_offset"] = b.ravel()
    for k in ("img_amp", "sc_amp", "cal", "vis_center"):
        params[k] = params[k] + 0.05 * rng.normal(size=params[k].shape)
    f.load_state_dict({k: v.astype(np.float32) for k, v in params.items()})
    return f


def make_views(n: int = 8, *, seed: int = 1) -> Views:
    """``n`` moving transmitters in the room, the array fixed near one wall."""
    rng = np.random.default_rng(seed)
    y = rng.uniform(ROOM[0] + 0.5, ROOM[1] - 0.5, (n, 3))
    x = np.tile([5.2, 2.5, 1.5], (n, 1))
    return Views(antenna_pos=y, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=FREQUENCY_HZ, task="tx")


# ------------------------------------------------------------------------------ field
def measure_field(*, views: int = 8, scatterers: int = 96, repeats: int = 7) -> dict:
    """Dr.Jit render and forward + backward of the benchmark field (ms), and the same for the
    PyTorch twin when PyTorch is installed (else its entries are None)."""
    import drjit as dr

    B.ensure()
    f, v = make_field(scatterers=scatterers), make_views(views)
    c_np = np.random.default_rng(3).normal(size=(views, 90, 360)).astype(np.float32)
    c = B.Float(c_np.ravel())
    params = f.trainable()

    def forward():
        with dr.suspend_grad():
            img = render([f], v)
            dr.eval(img)
        dr.sync_thread()
        return img

    def forward_backward():
        for p in params.values():
            dr.enable_grad(p)
            dr.clear_grad(p)
        f.assign(params)
        img = render([f], v)
        dr.backward(dr.sum(img.array * c))
        dr.eval([dr.grad(p) for p in params.values()])
        dr.sync_thread()

    out = {"views": views, "sources": f.num_primitives, "parameters": f.num_parameters,
           "drjit_forward": timed(forward, repeats), "drjit_forward_backward": timed(forward_backward, repeats),
           "render_per_pas_ms": {}}
    for n in (8, 40):
        vn = make_views(n, seed=5)

        def rend(vn=vn):
            with dr.suspend_grad():
                dr.eval(render([f], vn))
            dr.sync_thread()

        out["render_per_pas_ms"][n] = timed(rend, repeats)["ms"] / n
    out["torch_forward"] = out["torch_forward_backward"] = out["parity"] = None
    try:
        import torch
    except ImportError:
        return out
    from ..models import coherent_gaussians_torch as twin

    tp = twin.parameters_from(f)
    ct = torch.from_numpy(c_np)

    def t_forward():
        with torch.no_grad():
            return twin.render(tp, f, v)

    def t_forward_backward():
        for p in tp.values():
            p.grad = None
        (twin.render(tp, f, v) * ct).sum().backward()

    out["torch_forward"] = timed(t_forward, repeats)
    out["torch_forward_backward"] = timed(t_forward_backward, repeats)
    out["torch_threads"] = torch.get_num_threads()
    forward_backward()
    t_forward_backward()
    grad_err = max(float(np.abs(np.asarray(dr.grad(p), np.float64) - tp[k].grad.numpy()).max()
                         / max(np.abs(tp[k].grad.numpy()).max(), 1e-30)) for k, p in params.items())
    out["parity"] = {"pas_max_abs": float(np.abs(forward().numpy() - t_forward().numpy()).max()),
                     "grad_max_rel": grad_err}
    return out


# ------------------------------------------------------------------------------ Bartlett
def numpy_bartlett(h: np.ndarray, W: np.ndarray) -> tuple:
    """NumPy Bartlett read-out: channels h complex [B, 16], weights W complex [P, 16]
    (:func:`~rfmitsuba.rf.bartlett_ref.beamformer`) -> (y complex [B, P] beam outputs, raw PAS
    [B, P], normalised PAS [B, P])."""
    y = h @ W.T
    p = np.abs(y)
    lo, hi = p.min(1, keepdims=True), p.max(1, keepdims=True)
    return y, p, (p - lo) / (hi - lo)


def numpy_bartlett_gradient(h: np.ndarray, W: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Gradient of ``sum(c * normalised PAS)`` with respect to the channels, as
    ``dL/d(re h) + j dL/d(im h)``: complex [B, 16]. c: float [B, P]. The same adjoint as
    :mod:`rfmitsuba.rf.bartlett` (through each image's minimum and maximum pixel too)."""
    y, p, pn = numpy_bartlett(h, W)
    span = (p.max(1) - p.min(1))[:, None]
    gp = c / span
    rows = np.arange(len(h))
    gp[rows, p.argmin(1)] += (c * (pn - 1.0)).sum(1) / span[:, 0]
    gp[rows, p.argmax(1)] -= (c * pn).sum(1) / span[:, 0]
    return ((gp / np.maximum(p, 1e-30)) * y) @ np.conj(W)


def measure_bartlett(*, views: int = 8, repeats: int = 7) -> dict:
    """The Bartlett op (channels [views, 16] -> normalised 90 x 360 PAS), forward and forward +
    backward of ``sum(c * PAS)``: Dr.Jit against NumPy (:func:`numpy_bartlett`,
    :func:`numpy_bartlett_gradient`; complex64 BLAS products on one BLAS thread) (ms), with
    their parity."""
    import drjit as dr
    from threadpoolctl import threadpool_limits

    B.ensure()
    rng = np.random.default_rng(0)
    h = (rng.normal(size=(views, 16)) + 1j * rng.normal(size=(views, 16))).astype(np.complex64)
    c = rng.normal(size=(views, 90 * 360)).astype(np.float32)
    hr0, hi0 = B.Float(np.ascontiguousarray(h.real.ravel())), B.Float(np.ascontiguousarray(h.imag.ravel()))
    cd = B.Float(c.ravel())
    W = np.ascontiguousarray(beamformer(frequency_hz=FREQUENCY_HZ).astype(np.complex64))     # [P, 16]

    def d_forward():
        img = bartlett_op.bartlett(hr0, hi0, frequency_hz=FREQUENCY_HZ)
        dr.eval(img)
        dr.sync_thread()
        return img

    def d_forward_backward():
        hr, hi = B.Float(hr0), B.Float(hi0)
        dr.enable_grad(hr, hi)
        img = bartlett_op.bartlett(hr, hi, frequency_hz=FREQUENCY_HZ)
        dr.backward(dr.sum(img.array * cd))
        dr.eval(dr.grad(hr), dr.grad(hi))
        dr.sync_thread()
        return np.asarray(dr.grad(hr)) + 1j * np.asarray(dr.grad(hi))

    g_ref = numpy_bartlett_gradient(h.astype(np.complex128), W.astype(np.complex128), c.astype(np.float64))
    parity = {"pas_max_abs": float(np.abs(d_forward().numpy().reshape(views, -1) - numpy_bartlett(h, W)[2]).max()),
              "grad_max_rel": float(np.abs(d_forward_backward().reshape(views, 16) - g_ref).max()
                                    / np.abs(g_ref).max())}
    out = {"views": views, "pixels": W.shape[0], "drjit_forward": timed(d_forward, repeats),
           "drjit_forward_backward": timed(d_forward_backward, repeats), "parity": parity}
    with threadpool_limits(limits=1, user_api="blas"):
        out["numpy_forward"] = timed(lambda: numpy_bartlett(h, W), repeats)
        out["numpy_forward_backward"] = timed(lambda: numpy_bartlett_gradient(h, W, c), repeats)
    return out


# ------------------------------------------------------------------------------ Stage 1
def default_dataset() -> Path:
    """A 200-tag NeRF2-like folder in the cache folder (made once, about 20 s)."""
    from ..sim.nerf2like import make_nerf2like

    root = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rfmitsuba" / "bench"
    root.mkdir(parents=True, exist_ok=True)
    return make_nerf2like(root / "nerf2like_200", num_tags=200)


def measure_stage1(dataset: str | Path | None = None, *, model: str = "coherent_gaussians", steps: int = 60,
                   config: str | Path | None = None, overrides: list[str] | None = None,
                   freeze: bool = True) -> dict:
    """Steps per second of a Stage-1 training (the configuration's batch, full resolution, no
    validation in the timed span): the trainer's own training clock between its log rows at
    step 10 and at ``steps``, so initialisation and the first steps' compilation are not
    counted. ``overrides``: ``key=value`` items applied to the training configuration;
    ``freeze``: the trainer records its step where the field allows it
    (:mod:`rfmitsuba.train.frozen_step`), or (False) traces every step."""
    from ..core.config import load, override
    from ..train.config import TrainConfig, training_downsample
    from ..train.trainer import train

    ds = Path(dataset) if dataset is not None else default_dataset()
    cfg = load(TrainConfig, config) if config else TrainConfig(model=model)
    if overrides:
        cfg = override(cfg, list(overrides))
    cfg.iterations, cfg.log_every, cfg.val_every, cfg.checkpoint_every = steps, 10, 10**9, 10**9
    cfg.epochs = 0.0                     # exactly ``steps``: a rate is measured, not a fit
    cfg.time_limit_s = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        summary = train(ds, Path(tmp) / "run", cfg=cfg, quiet=True, freeze=freeze)
        total = time.perf_counter() - t0
        rows = [json.loads(line) for line in (Path(tmp) / "run" / "log.jsonl").read_text().splitlines()]
    rows = [r for r in rows if "time_s" in r]
    first = next(r for r in rows if r["step"] >= 10)
    last = rows[-1]
    rate = (last["step"] - first["step"]) / max(last["time_s"] - first["time_s"], 1e-9)
    return {"dataset": str(ds), "model": summary.get("model", cfg.model), "sources": summary.get("num_gaussians"),
            "batch": cfg.batch_views,
            "downsample": training_downsample(dataclasses.replace(cfg, model=summary.get("model", cfg.model))),
            "steps": steps, "steps_per_s": rate,
            "step_ms": 1e3 / rate, "wall_s": total, "freeze": bool(freeze)}


def measure_stage1_step(*, gaussians: int = 10_000, batch: int = 4, steps: int = 110,
                        dataset: str | None = None) -> dict:
    """A Stage-1 step of the splat field as the trainer runs it (``gaussians`` Gaussians from a
    random start, the EM network, ``batch`` views; the target is 60 ms at batch 4 and
    10 000), at full resolution (90x360) with the networks' products on the host's BLAS (the LLVM
    default) and as cooperative vectors, and at 45x180 (``downsample = 2``, the training images
    of ``reproduce``'s sizes) on the host's BLAS, in one run.

    Returns:
        {"gaussians", "batch", "steps", "host": {...}, "coop_vec": {...}, "host_45x180": {...}}
        with each side's ``step_ms`` (:func:`rfmitsuba.experiments.bench_field.measure_stage1`).
    """
    common = ["splat.init='random'", f"splat.num_gaussians={int(gaussians)}", f"batch_views={int(batch)}"]
    out = {"gaussians": int(gaussians), "batch": int(batch), "steps": int(steps)}
    for key, host, downsample in (("host", True, 1), ("coop_vec", False, 1), ("host_45x180", True, 2)):
        out[key] = measure_stage1(dataset, model="splat", steps=steps,
                                  overrides=common + [f"downsample={downsample}",
                                                      f"splat.net.host_products={'true' if host else 'false'}"])
    return out


def format_stage1_step(r: dict) -> str:
    """One line per side of :func:`measure_stage1_step`, and their ratio."""
    h, c = r["host"], r["coop_vec"]
    line = (f"Stage-1 splat step, {r['gaussians']} Gaussians, batch {r['batch']}, 90x360, EM network "
            f"(steps 10-{r['steps']}): products on the host's BLAS {h['step_ms']:.1f} ms, as cooperative "
            f"vectors {c['step_ms']:.1f} ms, ratio {c['step_ms'] / max(h['step_ms'], 1e-9):.2f}x "
            f"(target 60 ms at batch 4, 10 000 Gaussians)")
    if "host_45x180" in r:
        line += (f"\nthe same at 45x180 (downsample 2, reproduce's training images), products on the host's "
                 f"BLAS: {r['host_45x180']['step_ms']:.1f} ms")
    return line


# ------------------------------------------------------------------------------ report
def run(*, quick: bool = False, dataset: str | Path | None = None, stage1_model: str = "coherent_gaussians",
        stage1_config: str | Path | None = None, stage1: bool = True) -> dict:
    """Every measurement of this module, with the machine load before and after."""
    import drjit as dr

    repeats = 3 if quick else 7
    out = {"load_before": _load(), "threads": None}
    out["field"] = measure_field(repeats=repeats, scatterers=16 if quick else 96)
    out["bartlett"] = measure_bartlett(repeats=repeats)
    out["peak"] = product_peak(repeats=repeats)
    if stage1:
        steps = 30 if quick else 110
        out["stage1"] = measure_stage1(dataset, model=stage1_model, config=stage1_config, steps=steps)
        if out["stage1"]["downsample"] != 1:   # the same training at 90 x 360, the reference of its ratio
            out["stage1_full_res"] = measure_stage1(dataset, model=stage1_model, config=stage1_config, steps=steps,
                                                    overrides=["downsample=1"])
        # the same training traced every step: what recording the step saves
        out["stage1_traced"] = measure_stage1(dataset, model=stage1_model, config=stage1_config, steps=steps,
                                              freeze=False)
    out["threads"] = dr.thread_count()
    out["load_after"] = _load()
    out["cpu_count"] = os.cpu_count()
    return out


def _ratio(ref: dict | None, ours: dict, key: str = "ms") -> str:
    return "-" if ref is None else f"{ref[key] / max(ours[key], 1e-9):.1f}x"


def _t(d: dict | None) -> str:
    return "-" if d is None else f"{d['ms']:.2f} ({d['cpu_ms']:.2f} CPU)"


def _limit_ms(r: dict, views: int, pixels: int, products: int) -> float | None:
    """The time [ms] ``products`` read-out products of ``views`` images of ``pixels`` take at the
    measured peak (:func:`product_peak`), or None without one."""
    peak = r.get("peak")
    if not peak:
        return None
    return products * readout_flops(views, pixels) / (peak["gflops"] * 1e6)


def _of_limit(limit: float | None, ms: float) -> str:
    return "-" if limit is None else f"{limit:.3f} ms, {100 * limit / max(ms, 1e-9):.0f}%"


def format_report(r: dict) -> str:
    """Markdown table of :func:`run`'s result: times in ms (process CPU ms in brackets), the
    reference / Dr.Jit ratios (wall time and CPU time), and the arithmetic limit: the read-out's
    products at one core's measured peak, and what fraction of the measured time that is."""
    f, b = r["field"], r["bartlett"]
    pixels = b.get("pixels", 90 * 360)
    peak = r.get("peak")
    lines = [f"Coherent Gaussian field benchmark: {r['cpu_count']} cores, {r['threads']} Dr.Jit threads, "
             f"1-minute load {r['load_before']:.2f} before, {r['load_after']:.2f} after.", ""]
    if peak:
        lines += [f"Arithmetic limit: the read-out's complex products ({readout_flops(1, pixels) / 1e6:.2f} MFLOP "
                  f"per 90 x 360 image and pass) at one core's measured peak, {peak['gflops']:.1f} GFLOP/s "
                  f"(np.matmul complex64 [{peak['views']}, 16] x [16, {peak['pixels']}], one BLAS thread); "
                  "'of limit' is that time over the measured one.", ""]
    lines += ["| measurement | Dr.Jit ms | reference ms | reference | ratio (wall) | ratio (CPU) | limit, of limit |",
              "|---|---|---|---|---|---|---|"]
    rows = [(f"field render, {f['views']} views ({f['sources']} sources)", f["drjit_forward"], f["torch_forward"],
             "PyTorch", f["views"], 1),
            (f"field forward + backward, {f['views']} views", f["drjit_forward_backward"],
             f["torch_forward_backward"], "PyTorch", f["views"], 2),
            (f"Bartlett forward, {b['views']} views", b["drjit_forward"], b["numpy_forward"], "NumPy (1 thread)",
             b["views"], 1),
            (f"Bartlett forward + backward, {b['views']} views", b["drjit_forward_backward"],
             b["numpy_forward_backward"], "NumPy (1 thread)", b["views"], 2)]
    for name, ours, ref, ref_name, views, products in rows:
        lines.append(f"| {name} | {_t(ours)} | {_t(ref)} | {ref_name} | {_ratio(ref, ours)} | "
                     f"{_ratio(ref, ours, 'cpu_ms')} | {_of_limit(_limit_ms(r, views, pixels, products), ours['ms'])} |")
    lines += ["", "| figure | value | limit, of limit |", "|---|---|---|"]
    for n, ms in f["render_per_pas_ms"].items():
        lines.append(f"| render per PAS, batch {n}, no gradients | {ms:.3f} ms | "
                     f"{_of_limit(_limit_ms(r, 1, pixels, 1), ms)} |")
    for name, par in (("field, PyTorch twin (float32)", f.get("parity")), ("Bartlett, NumPy", b.get("parity"))):
        if par:
            lines.append(f"| parity: {name} | PAS max abs {par['pas_max_abs']:.1e}, gradient max rel "
                         f"{par['grad_max_rel']:.1e} | - |")
    for key in ("stage1", "stage1_full_res", "stage1_traced"):
        s = r.get(key)
        if s:
            d = s.get("downsample", 1)
            d0 = r["stage1"].get("downsample", 1)
            gain = r["stage1"]["steps_per_s"] / max(s["steps_per_s"], 1e-9)
            ratio = {"stage1_full_res": f"; at {90 // d0}x{360 // d0} {gain:.2f}x as many steps/s",
                     "stage1_traced": f"; every step traced, not recorded: recording gives {gain:.2f}x as many "
                                      "steps/s"}.get(key, "")
            limit = _limit_ms(r, s.get("batch", 8), (90 // d) * (360 // d), 2)
            lines.append(f"| Stage-1 training, {s['model']} ({s['sources']} sources), batch {s.get('batch', 8)}, "
                         f"{90 // d}x{360 // d} | {s['steps_per_s']:.1f} steps/s ({s['step_ms']:.1f} ms per step) on "
                         f"`{s['dataset']}`{ratio} | {_of_limit(limit, s['step_ms'])} |")
    return "\n".join(lines)
