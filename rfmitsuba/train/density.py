"""Adaptive density control of a Gaussian field (3DGS / gsplat style), as a strategy object.

The trainer calls the named hooks of :class:`Strategy`; :class:`DensityStrategy` implements them:

* :meth:`~DensityStrategy.after_backward` every step: accumulates the norm of each
  Gaussian's position gradient (our renderer takes world-space means, so this is the
  gradient of the loss with respect to the 3-D mean, summed over the views of the step)
  and how often the Gaussian received any gradient;
* :meth:`~DensityStrategy.step_end` after the optimizer step: every ``every`` steps from
  ``start`` on clones small Gaussians and splits large ones whose mean gradient exceeds
  ``grad_threshold`` (largest first, at most ``max_growth`` * N new ones, never more than
  ``max_gaussians`` in all), prunes Gaussians whose attenuation delta stays below
  ``prune_opacity`` in every probe view or whose largest scale exceeds ``prune_scale`` metres,
  and every ``reset_every`` steps lowers every attenuation delta to ``reset_opacity``; given the
  run's length, no reset comes after its first half and no densification in its last
  ``every`` steps (as 3DGS stops both half-way), so the saved field is never a freshly reset one;
* :meth:`~DensityStrategy.on_validation` after each validation: growth stops for good once
  validation SSIM has not improved by ``min_improvement`` for ``patience`` validations
  (a model no larger than the scene needs).

Optimizer moments of kept Gaussians are kept; new Gaussians start with zero moments.
All randomness comes from the numpy generator the trainer passes in.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..core import backend as B
from ..core.errors import ConfigError
from ..models.splat import GAUSSIAN_KEYS, SplatField


@dataclass
class DensityConfig:
    """Adaptive density control settings (steps are optimizer iterations; lengths in metres)."""

    #: options this class no longer has (:mod:`rfmitsuba.core.config`); None: they only steered training
    removed_options: ClassVar[dict] = {"stop": None}

    enabled: bool = True
    start: int = 200
    every: int = 100
    grad_threshold: float = 2e-4
    max_growth: float = 0.3
    max_gaussians: int = 20000
    split_scale: float = 0.05
    prune_opacity: float = 0.005
    prune_scale: float = 1.5
    reset_every: int = 1500
    reset_opacity: float = 0.02
    patience: int = 3
    min_improvement: float = 0.002

    def __post_init__(self) -> None:
        if self.every < 1:
            raise ConfigError(f"DensityConfig.every must be >= 1, got {self.every}")
        if not 0 <= self.max_growth <= 4:
            raise ConfigError(f"DensityConfig.max_growth must be in [0, 4], got {self.max_growth}")
        if self.max_gaussians < 1:
            raise ConfigError(f"DensityConfig.max_gaussians must be >= 1, got {self.max_gaussians}")
        if not 0 < self.reset_opacity < 1 or not 0 <= self.prune_opacity < 1:
            raise ConfigError("DensityConfig: reset_opacity must be in (0, 1), prune_opacity in [0, 1)")


def _logit(p: float) -> float:
    return float(np.log(p / (1 - p)))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions q float [N, 4] (w, x, y, z; any norm) -> [N, 3, 3]."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True).clip(1e-12)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def move_adam_state(opt, key: str, new_value, *, src: np.ndarray, dst: np.ndarray) -> None:
    """Install ``new_value`` (``Float`` [n]) as the parameter ``key`` of the Adam optimizer ``opt``
    after its parameter changed size: the moments of old entries ``src`` move to new entries
    ``dst`` (int arrays of one length); every other entry starts with zero moments. The step
    count is kept."""
    import drjit as dr

    value, promoted, lr, (t, m, v, vmax) = opt.state[key]
    n = dr.width(new_value)

    def remap(x):
        out = np.zeros(n, np.float32)
        out[dst] = np.asarray(x.numpy(), np.float32)[src]
        return B.Float(out)

    dr.enable_grad(new_value)
    opt.state[key] = (new_value, promoted, lr, (t, remap(m), remap(v), None if vmax is None else remap(vmax)))


class Strategy:
    """Base of the density strategies: the trainer calls these named hooks, in this order
    within a step, and each is a no-op here.

    * :meth:`after_backward` (field) - after the loss's backward pass, before the optimizer step;
    * :meth:`step_end` (step, field, opt, rng=, probe_views=) - after the optimizer step; True
      when the field's primitives changed outside the optimizer step;
    * :meth:`on_validation` (step, val_ssim) - after each validation;
    * :meth:`state_dict` / :meth:`load_state_dict` - in checkpoints, so a resumed run continues
      the same schedule.

    ``history`` lists the strategy's events, ``growth_stopped`` says whether growth ended.
    """

    growth_stopped = False

    def __init__(self) -> None:
        self.history: list[dict] = []

    def after_backward(self, field) -> None:
        return None

    def step_end(self, step: int, field, opt, *, rng=None, probe_views=None) -> bool:
        return False

    def on_validation(self, step: int, val_ssim: float) -> None:
        return None

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict) -> None:
        return None


class DensityStrategy(Strategy):
    """Clone / split / prune / reset for one :class:`SplatField` (see module docstring).

    Args:
        cfg: settings.
        prefix: the field's key prefix in the optimizer (``"<field.name>."``).
    """

    def __init__(self, cfg: DensityConfig, *, prefix: str = "bg.", iterations: int | None = None):
        self.cfg = cfg
        self.prefix = prefix
        #: the run's length: no opacity reset after its first half and no densification in its
        #: last ``every`` steps, so the final field has had time to recover from both
        self.iterations = iterations
        self.grad_sum = None  # Float [N], accumulated position-gradient norm
        self.count = None  # Float [N], steps with a non-zero gradient
        self.growth_stopped = False
        self.best_val = -np.inf
        self.since_best = 0
        self.history: list[dict] = []

    # ---- hooks ------------------------------------------------------------------------
    def after_backward(self, field: SplatField) -> None:
        """Accumulate statistics from the gradients of the current step."""
        import drjit as dr

        if not self.cfg.enabled:
            return
        g = dr.grad(field.params["means"])
        n = field.num_gaussians
        if dr.width(g) != 3 * n:
            g = dr.zeros(B.Float, 3 * n)
        g3 = dr.unravel(B.Array3f, g)
        norm = dr.norm(g3)
        if self.grad_sum is None or dr.width(self.grad_sum) != n:
            self.grad_sum = dr.zeros(B.Float, n)
            self.count = dr.zeros(B.Float, n)
        self.grad_sum = dr.detach(self.grad_sum + norm)
        self.count = dr.detach(self.count + dr.select(norm > 0, 1.0, 0.0))
        dr.schedule(self.grad_sum, self.count)

    def on_validation(self, step: int, val_ssim: float) -> None:
        """Record a validation SSIM; stops growth after ``patience`` non-improving ones."""
        if val_ssim > self.best_val + self.cfg.min_improvement:
            self.best_val = float(val_ssim)
            self.since_best = 0
        else:
            self.since_best += 1
            if step >= self.cfg.start and self.since_best >= self.cfg.patience and not self.growth_stopped:
                self.growth_stopped = True
                self.history.append({"step": step, "event": "growth stopped", "val_ssim": float(val_ssim)})

    def step_end(self, step: int, field: SplatField, opt, *, rng: np.random.Generator, probe_views=None) -> bool:
        """Densify / prune / reset after optimizer step ``step`` (1-based count of steps done).

        Args:
            step: number of optimizer steps taken so far.
            field: the field (its parameters are the optimizer's values).
            opt: the ``drjit.opt.Adam`` holding ``prefix + key`` entries.
            rng: numpy generator for split sampling.
            probe_views: :class:`~rfmitsuba.models.base.Views` over which each Gaussian's largest
                attenuation delta decides pruning; None = the view-independent part.

        Returns:
            True when the Gaussian set changed (size or values outside the optimizer step).
        """
        c = self.cfg
        if not c.enabled:
            return False
        changed = False
        grow_until = float("inf") if self.iterations is None else self.iterations - c.every
        reset_until = float("inf") if self.iterations is None else self.iterations // 2 + 1
        if c.start <= step < grow_until and step % c.every == 0 and self.grad_sum is not None:
            changed |= self._densify_and_prune(step, field, opt, rng=rng, probe_views=probe_views)
        if c.reset_every > 0 and step % c.reset_every == 0 and step < reset_until:
            self._reset_opacity(field, opt)
            changed = True
        return changed

    # ---- operations -------------------------------------------------------------------
    @staticmethod
    def _probe_opacity(field: SplatField, views) -> np.ndarray:
        """Largest attenuation delta of every Gaussian over ``views``: float32 [N]."""
        import drjit as dr

        with dr.suspend_grad():
            sp = field.splats(views.antenna_pos, view_pos=views.view_pos, extra=views.extra(field))
            op = np.asarray(sp.opacities.numpy(), dtype=np.float32).reshape(views.count, -1)
        return op.max(axis=0)

    def _densify_and_prune(self, step, field, opt, *, rng, probe_views) -> bool:
        c = self.cfg
        g = field.gaussians_numpy()
        n = len(g["opacity_logits"])
        gsum = np.asarray(self.grad_sum.numpy(), dtype=np.float64)
        cnt = np.asarray(self.count.numpy(), dtype=np.float64)
        avg = np.where(cnt > 0, gsum / np.maximum(cnt, 1), 0.0)
        scale_max = np.exp(g["log_scales"].max(axis=1))

        # -- prune
        if probe_views is not None:
            op = np.asarray(self._probe_opacity(field, probe_views), dtype=np.float64)
        else:
            op = 1 / (1 + np.exp(-g["opacity_logits"].astype(np.float64)))
        prune = (op < c.prune_opacity) | (scale_max > c.prune_scale) | ~np.isfinite(g["means"]).all(1)
        if prune.all():  # never delete everything
            prune[np.argmax(op)] = False

        # -- grow
        new_rows = {k: [] for k in GAUSSIAN_KEYS}
        split_src = np.zeros(n, bool)
        n_clone = n_split = 0
        if not self.growth_stopped:
            room = c.max_gaussians - int((~prune).sum())
            budget = int(min(c.max_growth * n, max(room, 0)))
            cand = np.flatnonzero((avg > c.grad_threshold) & ~prune)
            cand = cand[np.argsort(-avg[cand], kind="stable")]
            picked = []
            used = 0
            for i in cand:  # a split adds one Gaussian net (two new, one removed), a clone one
                if used + 1 > budget:
                    break
                picked.append(i)
                used += 1
            picked = np.asarray(picked, dtype=np.int64)
            big = scale_max[picked] > c.split_scale
            clone_idx, split_idx = picked[~big], picked[big]
            n_clone, n_split = len(clone_idx), len(split_idx)
            for k in GAUSSIAN_KEYS:
                new_rows[k].append(g[k][clone_idx])
            if n_split:
                R = quat_to_matrix(g["rotations"][split_idx].astype(np.float64))
                s = np.exp(g["log_scales"][split_idx].astype(np.float64))
                for _ in range(2):
                    z = rng.standard_normal((n_split, 3)) * s
                    pos = g["means"][split_idx] + np.einsum("nij,nj->ni", R, z)
                    new_rows["means"].append(pos.astype(np.float32))
                    new_rows["log_scales"].append((g["log_scales"][split_idx] - np.log(1.6)).astype(np.float32))
                    new_rows["rotations"].append(g["rotations"][split_idx])
                    new_rows["opacity_logits"].append(g["opacity_logits"][split_idx])
                split_src[split_idx] = True

        keep = np.flatnonzero(~prune & ~split_src)
        n_new = sum(len(a) for a in new_rows["opacity_logits"])
        if len(keep) == n and n_new == 0:
            self._clear_stats(n)
            return False
        arrays = {k: np.concatenate([g[k][keep]] + new_rows[k]) for k in GAUSSIAN_KEYS}
        self._apply(field, opt, arrays, keep, n_new)
        self.history.append({"step": step, "event": "densify", "before": n, "after": len(keep) + n_new,
                             "cloned": n_clone, "split": n_split, "pruned": int(prune.sum())})
        return True

    def _reset_opacity(self, field, opt) -> None:
        import drjit as dr

        key = self.prefix + "opacity_logits"
        cur = opt[key] if key in opt else field.params["opacity_logits"]
        new = dr.minimum(dr.detach(cur), _logit(self.cfg.reset_opacity))
        if key in opt:
            opt[key] = new
            opt.reset(key)
            field.assign({"opacity_logits": opt[key]})
        else:
            field.params["opacity_logits"] = new
        n = field.num_gaussians
        self.history.append({"event": "reset opacity", "n": n})

    def _apply(self, field: SplatField, opt, arrays: dict, keep: np.ndarray, n_new: int) -> None:
        """Install the new Gaussian set in the field and the optimizer, remapping Adam moments:
        kept rows keep their moments, new rows start from zero."""
        field.set_gaussians(arrays)
        for k, d in GAUSSIAN_KEYS.items():
            key = self.prefix + k
            if key not in opt:
                continue
            idx = (keep[:, None] * d + np.arange(d)[None, :]).ravel()
            new_val = B.Float(arrays[k].ravel())
            move_adam_state(opt, key, new_val, src=idx, dst=np.arange(len(idx)))
            field.params[k] = new_val
        self._clear_stats(len(keep) + n_new)

    def _clear_stats(self, n: int) -> None:
        import drjit as dr

        self.grad_sum = dr.zeros(B.Float, n)
        self.count = dr.zeros(B.Float, n)

    # ---- state ------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """numpy state for checkpoints."""
        out = {"growth_stopped": np.array(self.growth_stopped), "best_val": np.array(self.best_val),
               "since_best": np.array(self.since_best)}
        if self.grad_sum is not None:
            out["grad_sum"] = np.array(self.grad_sum.numpy(), dtype=np.float32, copy=True)
            out["count"] = np.array(self.count.numpy(), dtype=np.float32, copy=True)
        return out

    def load_state_dict(self, state: dict) -> None:
        self.growth_stopped = bool(state["growth_stopped"])
        self.best_val = float(state["best_val"])
        self.since_best = int(state["since_best"])
        if "grad_sum" in state:
            self.grad_sum = B.Float(np.asarray(state["grad_sum"], np.float32))
            self.count = B.Float(np.asarray(state["count"], np.float32))
        else:
            self.grad_sum = self.count = None


class NoDensity(Strategy):
    """The density-control hooks for a model without adaptive density (a known room's coherent
    fields: their sources are the room's image points, fixed by the geometry; an unknown room's
    grows by :class:`rfmitsuba.train.pursuit.PlanePursuit` instead). Every hook is a no-op."""


def make_strategy(cfg: DensityConfig, field, *, prefix: str, iterations: int | None = None) -> Strategy:
    """The density strategy of ``field``: :class:`DensityStrategy` for fields whose class
    allows densification (``Field.densify``), :class:`NoDensity` otherwise. ``iterations``: the
    run's length (no reset after its first half, no densification in its last ``every`` steps)."""
    if not getattr(field, "densify", False):
        return NoDensity()
    return DensityStrategy(cfg, prefix=prefix, iterations=iterations)
