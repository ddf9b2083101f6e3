"""Every "auto" of a training run, decided in one place, with the reason for each.

A :class:`~rfmitsuba.train.config.TrainConfig` option set to ``"auto"`` is decided here from the
configuration, the data and the initial field:

* ``model``: by the trials of :mod:`rfmitsuba.train.select` (their ``choice.json``);
* ``downsample``: the block size the field kind advises (``Field.downsample_advised``);
* ``epochs`` and so the steps: the passes over the data the initial field advises
  (``Field.epochs_advised``);
* ``starts``: the training starts it advises (``Field.starts_advised``);
* ``jitter``: the spread of jittered training views it advises (``Field.jitter_advised``);
* the field's own choices (for the coherent Gaussian field: read-out, wavefront, coupling, the
  initialisation, the visibility grid, the scanned planes, the pursuit and the line-of-sight
  fits), which the field lists in ``Field.decisions``.

The trainer uses the decided values and writes them to ``RUN/resolved.toml``, one table per
option with its ``value`` and ``reason``; ``rfmitsuba train --dry-run`` prints the same without
training (:func:`rfmitsuba.train.trainer.dry_run`).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from ..core.atomic import write_text
from ..models.base import field_class

#: the file a run folder keeps the decisions in
RESOLVED_NAME = "resolved.toml"


@dataclass(frozen=True)
class Decision:
    """One decided option: ``option`` (dotted ``TrainConfig`` key), the ``value`` the run uses, and
    the ``reason`` (one sentence)."""

    option: str
    value: Any
    reason: str


def downsample(cfg) -> Decision:
    """The training images' block size ``d`` ((90/d) x (360/d) images) of a run of ``cfg``."""
    if cfg.downsample != "auto":
        return Decision("downsample", int(cfg.downsample), "set in the configuration")
    kind = field_class(cfg.model)
    d = int(kind.downsample_advised)
    if getattr(kind, "closed_form", False):
        return Decision("downsample", d, f"{cfg.model} is conditioned in closed form on the full 90 x 360 spectra "
                        "(no training steps)")
    why = (f"{cfg.model} trains on {90 // d} x {360 // d} block means: its read-out is the array's beam, which "
           "2-degree pixels pin as well as 1-degree ones" if d > 1 else
           f"{cfg.model} trains at the full 90 x 360")
    return Decision("downsample", d, why)


def epochs(cfg, field) -> Decision:
    """The least passes over the fitting positions."""
    if cfg.epochs != "auto":
        return Decision("epochs", float(cfg.epochs), "set in the configuration")
    e = float(field.epochs_advised)
    why = (f"the field's visibility grid ({getattr(field, 'grid_cells', '?')} cells per source) learns cell by "
           "cell, from the views near each cell" if e > 0 else "the field asks for no passes beyond the steps")
    return Decision("epochs", e, why)


def iterations(cfg, num_fit: int, passes: float) -> Decision:
    """The steps a run trains: ``cfg.iterations``, or more where ``passes`` over ``num_fit`` fitting
    positions at ``cfg.batch_views`` views a step take more."""
    if passes <= 0 or num_fit <= 0:
        return Decision("iterations", int(cfg.iterations), "as configured (no passes asked for)")
    need = math.ceil(passes * num_fit / cfg.batch_views)
    if need <= cfg.iterations:
        return Decision("iterations", int(cfg.iterations), f"as configured: {passes:g} passes over {num_fit} "
                        f"fitting positions take {need} steps, fewer")
    return Decision("iterations", int(need), f"{passes:g} passes over {num_fit} fitting positions at "
                    f"{cfg.batch_views} views a step (more than the configured {cfg.iterations})")


def starts(cfg, field) -> Decision:
    """The training starts."""
    if cfg.starts != "auto":
        return Decision("starts", int(cfg.starts), "set in the configuration")
    n = int(field.starts_advised)
    why = ("fitting sources and the elements' phases or coupling together is not convex: two starts, the better "
           "by validation SSIM after a tenth of the run" if n > 1 else "one start: the field's fit is stable")
    return Decision("starts", n, why)


def jitter(cfg, field) -> Decision:
    """The spread of jittered training views [carrier wavelengths]."""
    if cfg.jitter != "auto":
        return Decision("jitter", float(cfg.jitter), "set in the configuration")
    j = float(field.jitter_advised)
    why = ("phase-only spectra: jittered copies of each batch keep the field from changing faster than the data"
           if j > 0 else "none: the field was not measured to gain from them")
    return Decision("jitter", j, why)


def model(cfg, run_dir: Path | None) -> Decision | None:
    """How the run's field kind was chosen: by the trials of ``model = "auto"`` (``choice.json``
    in ``run_dir``), else None (it was set)."""
    from .select import SELECT_DIR

    choice = None if run_dir is None else Path(run_dir) / SELECT_DIR / "choice.json"
    if choice is None or not choice.is_file():
        return None
    c = json.loads(choice.read_text())
    scores = ", ".join(f"{k} {v['best_val_ssim']:.3f}" for k, v in c["trials"].items()
                       if v.get("best_val_ssim") is not None)
    return Decision("model", c["chosen"], f"auto: {c.get('rule', 'best validation SSIM')} ({scores})")


def resolve(cfg, field, *, num_fit: int, run_dir: Path | None = None) -> list[Decision]:
    """Every decision of a run of ``cfg`` whose initial field is ``field`` and which fits
    ``num_fit`` positions, in the order above (the field's own last)."""
    out = [d for d in (model(cfg, run_dir),) if d is not None]
    out.append(downsample(cfg))
    if not getattr(field, "closed_form", False):
        e = epochs(cfg, field)
        out += [e, iterations(cfg, num_fit, e.value), starts(cfg, field), jitter(cfg, field)]
    return out + [Decision(*d) for d in field.decisions()]


def value(decisions: list[Decision], option: str):
    """The decided value of ``option``."""
    for d in decisions:
        if d.option == option:
            return d.value
    raise KeyError(option)


def to_toml(decisions: list[Decision]) -> str:
    """The decisions as TOML: one table per option, with its ``value`` and ``reason``."""
    return tomli_w.dumps({d.option: {"value": _plain(d.value), "reason": d.reason} for d in decisions})


def write(path: str | Path, decisions: list[Decision]) -> None:
    """Write :func:`to_toml` to ``path`` atomically."""
    write_text(Path(path), to_toml(decisions))


def _plain(v):
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    if v is None:
        return "none"
    return v
