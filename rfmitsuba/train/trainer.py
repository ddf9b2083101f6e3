"""Training of a Gaussian radio field (Stage 1: the empty-room background).

* :class:`TrainConfig` (with :class:`~rfmitsuba.models.splat.SplatConfig`,
  :class:`~rfmitsuba.train.density.DensityConfig`, :class:`OptimConfig`) - typed, TOML round trip.
* :class:`TrainData` - the PAS, positions and split a run trains on, read from a dataset
  folder or a NeRF2 spectrum folder (:func:`rfmitsuba.data.store.open_dataset`).
* :class:`Trainer` - Adam (``drjit.opt.Adam``) with per-parameter learning-rate schedules,
  loss ``0.8*L1 + 0.2*(1-SSIM)`` on per-image min-max normalised PAS, adaptive density
  control, validation SSIM on held-out *training* positions, checkpoints that resume to the
  same result, a progress bar, and the run folder. A run whose last validation check collapsed
  (``TrainConfig.revert_drop`` below the best check of its last 30%) keeps that check's field.

Run folder layout::

    config.toml      the TrainConfig (a run folder of another config is refused)
    run.json         dataset path, task, split sizes, package versions
    split.json       train / validation / test antenna indices
    log.jsonl        one row per logged step: loss, validation SSIM, Gaussians, wall time
    resolved.toml    every "auto" of the configuration as the run decided it, with the reason
                     (rfmitsuba.train.resolve)
    starts.json      with several training starts (TrainConfig.starts): each start's validation
                     SSIM and loss after start_steps(iterations) steps, and the one kept
    checkpoint/      latest resumable state (written atomically)
    final/field.npz  the trained field (rfmitsuba.models.base.load_field)
    final/summary.json
    final/*.ply      what the field exports (Field.export_ply): gaussians.ply and network.npz
                     (splat), sources.ply (coherent)

Tasks: moving RX (view = antenna position, network input = antenna position) and moving TX
(view = the fixed array, network input = transmitter position).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np

from ..core import backend as B
from ..core import config as C
from ..core.atomic import finite_or_null, write_json_with_numpy
from ..core.errors import ConfigError, DatasetError, RunError
from ..core.folder_lock import LOCK_NAME
from ..core.progress import bar
from ..core.ssim import ssim_images
from ..core.upload import upload
from ..data.split import block_split, make_split
from ..data.store import resolve_scene
from ..data.views import TrainData
from ..models.base import Field, FieldSet, Views, field_class, load_field, read_field_state, render
from ..rf.bartlett_ref import (
    normalize as minmax,  # the per-image min-max normalisation, [..., H, W] -> [0, 1]
)
from ..rf.grid import PAS_SHAPE
from . import resolve
from .config import TrainConfig, config_diff, differences, training_downsample
from .density import make_strategy
from .frozen_step import FrozenLoss
from .jitter import jittered
from .pursuit import pursuit_for
from .select import SELECT_DIR, select_model
from .loss import loss


def _lr(v0: float, v1: float | None, t: float) -> float:
    if v1 is None or v0 <= 0 or v1 <= 0:
        return v0
    return float(v0 * (v1 / v0) ** min(max(t, 0.0), 1.0))


def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for p in ("rfmitsuba", "drjit", "numpy"):
        try:
            out[p] = version(p)
        except PackageNotFoundError:
            out[p] = None
    return out


def load_loss():
    """The training loss ``loss(pred, gt) -> Float`` (0.8*L1 + 0.2*(1-SSIM), rfmitsuba.train.loss)."""

    return loss


class Trainer:
    """Train a field (:class:`~rfmitsuba.models.base.Field`) on a :class:`TrainData` into a run folder.

    Args:
        cfg: the configuration.
        data: the data.
        run_dir: the run folder (created; an existing one must hold the same config and dataset,
            and is then resumed from its checkpoint).
        frozen: already trained fields rendered together with the trained one (their
            parameters are not optimised), e.g. a frozen background in Stage 2.
        extra: callable (antenna indices int64 [K]) -> float [K, E] of extra network inputs
            of the trained field (Stage 2: the person position, scaled to about [0, 1]), or None.
        extra_inputs: E, the number of those inputs (the trained field's network takes them).
        quiet: no progress bar.
        name: the trained field's name (its optimizer keys are ``name + "." + key``).
        field_factory: callable (trainer, rng) -> the field to train (default
            :meth:`init_field`: Stage-1 initialisation from the scene), e.g. Stage 2's person field.

    Keys of a field's parameters that contain a dot (``net.<module>``, ``deform.<module>``) are
    network weights and get the network learning rate.

    Use :meth:`run`; afterwards :attr:`field` is the trained field.
    """

    def __init__(self, cfg: TrainConfig, data: TrainData, run_dir: str | Path, *, frozen: list | None = None,
                 extra=None, extra_inputs: int = 0, quiet: bool = False, name: str = "bg",
                 field_factory=None, freeze: bool = True):
        self.cfg = cfg
        #: record a step's render, loss and backward pass once and replay them
        #: (:mod:`rfmitsuba.train.frozen_step`; bit-identical, faster) where the fields allow it
        self.freeze = bool(freeze)
        self._frozen_loss = None
        self.jitter = 0.0          # set from the configuration or the field's advice in _run
        self.extra = extra
        self.extra_inputs = int(extra_inputs)
        self.data = data
        self.run_dir = Path(run_dir)
        self.frozen = list(frozen or [])
        self.field_factory = field_factory
        self.quiet = quiet
        self.name = name
        self.prefix = name + "."
        if cfg.model == "auto":
            raise ConfigError("TrainConfig.model = 'auto' is decided by rfmitsuba.train.trainer.train (the trials of "
                              "rfmitsuba.train.select); a Trainer trains one field kind: set model, e.g. "
                              "model='coherent_gaussians'")
        #: the training images' block size (TrainConfig.downsample, or the field's advice)
        self.d = training_downsample(cfg)
        self.h, self.w = PAS_SHAPE[0] // self.d, PAS_SHAPE[1] // self.d
        #: steps this run trains (rfmitsuba.train.resolve.iterations, set once the field exists)
        self.iterations = cfg.iterations
        self._tail_best = None   # {"step", "val_ssim", "state"}: the best validation check of the tail
        self._check_run_dir()

    # ---- run folder ---------------------------------------------------------------------
    def _check_run_dir(self) -> None:
        rd = self.run_dir
        want = C.to_dict(self.cfg)
        cfg_file = rd / "config.toml"
        if refuse_foreign_folder(rd):
            try:
                have = C.to_dict(C.load(TrainConfig, cfg_file, saved=True))
            except ConfigError as e:
                raise RunError(f"{cfg_file}: unreadable run config ({e}); nothing was changed") from None
            diff = config_diff(have, want)
            if diff:
                raise RunError(f"run folder {rd} belongs to another configuration: {'; '.join(diff)}. "
                               "Use another --out; nothing was changed")
            rj = rd / "run.json"
            if rj.is_file():
                old = json.loads(rj.read_text()).get("dataset")
                if old and Path(old).resolve() != self.data.path.resolve():
                    raise RunError(f"run folder {rd} was trained on dataset {old}, not {self.data.path}; "
                                   "nothing was changed")

    def _init_run_dir(self, split: dict) -> None:
        rd = self.run_dir
        rd.mkdir(parents=True, exist_ok=True)
        if not (rd / "config.toml").exists():
            C.save(self.cfg, rd / "config.toml")
        if not (rd / "run.json").exists():
            write_json_with_numpy(rd / "run.json", {
                "format": "rfmitsuba-run/1", "dataset": str(self.data.path.resolve()), "task": self.data.task,
                "state": self.data.state, "scene_xml": str(self.data.scene_xml) if self.data.scene_xml else None,
                "image": [self.h, self.w], "versions": _versions(),
                "dataset_fingerprint": dataset_fingerprint(self.data.path),
                "sizes": {k: len(v) for k, v in split.items()}})
        if not (rd / "split.json").exists():
            write_json_with_numpy(rd / "split.json", {k: [int(i) for i in v] for k, v in split.items()})

    # ---- setup ----------------------------------------------------------------------------
    def base_split(self) -> tuple[np.ndarray, np.ndarray]:
        """(train, test) antenna indices of ``cfg.split``: the dataset's own, a held-out slab of
        the largest x ("block") or a seeded 80/20 split ("random") of all its positions."""
        if self.cfg.split == "dataset":
            return np.array(self.data.train), np.array(self.data.test)
        every = np.union1d(self.data.train, self.data.test)
        if self.cfg.split == "block":

            tr, te = block_split(self.data.antenna_pos[every])
        else:

            sp = make_split(len(every), 0, seed=self.cfg.seed)
            tr, te = sp.antenna_train, sp.antenna_test
        return every[tr], every[te]

    def _make_split(self, rng: np.random.Generator) -> dict:
        cfg = self.cfg
        train, test = self.base_split()
        if cfg.max_train_positions and cfg.max_train_positions < len(train):
            train = np.sort(rng.choice(train, cfg.max_train_positions, replace=False))
        n_val = int(round(cfg.val_fraction * len(train)))
        n_val = min(n_val, cfg.val_max, len(train) - 1)
        if n_val <= 0:
            val = np.zeros(0, np.int64)
        else:
            val = np.sort(rng.choice(train, n_val, replace=False))
        fit = np.setdiff1d(train, val)
        return {"train": train, "fit": fit, "val": val, "test": test}

    def _init_field(self, rng: np.random.Generator) -> Field:
        if self.field_factory is not None:
            return self.field_factory(self, rng)
        return self.init_field(rng)

    def init_field(self, rng: np.random.Generator) -> Field:
        """The Stage-1 initial field of ``cfg.model`` (a registered field kind, see
        :func:`rfmitsuba.models.base.field_class`), taking ``extra_inputs`` extra per-view
        network inputs: e.g. Gaussians on the scene's meshes ("splat") or the scene's image
        sources ("coherent")."""
        return field_class(self.cfg.model).for_training(self.cfg, self.data, scene_xml=self.scene_xml(), rng=rng,
                                                        extra_inputs=self.extra_inputs, name=self.name)

    def scene_xml(self) -> Path | None:
        """The room's XML: ``cfg.scene`` when set, else the dataset's scene (None when neither)."""
        if self.cfg.scene:

            return resolve_scene(self.cfg.scene)
        return self.data.scene_xml

    def _progress(self, step: int, train_time: float = 0.0) -> float:
        """The share of the run done at step ``step``, in [0, 1]: the larger of the share of
        iterations done and, with a time limit, the share of training time used."""
        t = step / max(self.iterations - 1, 1)
        if self.cfg.time_limit_s:
            t = max(t, train_time / self.cfg.time_limit_s)
        return float(min(1.0, t))

    def _lrs(self, step: int, train_time: float = 0.0) -> dict:
        """Learning rates of step ``step`` at the schedule's progress :meth:`_progress` (so a run
        stopped by its time limit ends with its final learning rates, not half-way down the
        schedule)."""
        o = self.cfg.optim
        t = self._progress(step, train_time)
        net = _lr(o.lr_net, o.lr_net_final, t)
        means = _lr(o.lr_means, o.lr_means_final, t)
        return {"means": means, "log_scales": o.lr_log_scales, "rotations": o.lr_rotations,
                "opacity_logits": o.lr_opacity, "net": net,
                "amp": _lr(o.lr_amp, o.lr_amp_final, t), "embed": net, "offsets": means}

    # ---- rendering -------------------------------------------------------------------------
    def views(self, idx: np.ndarray) -> Views:
        """The views of antenna indices ``idx``; fields with extra inputs get ``extra(idx)``."""
        return Views.of(self.data, idx, inputs=(lambda f: self.extra(idx)) if self.extra is not None else None)

    def render(self, field: Field, idx: np.ndarray, *, h: int | None = None, w: int | None = None):
        """Render the trained field (and the frozen ones) at antenna indices ``idx``:
        TensorXf [K, h, w] (default the training resolution) on the loss's scale
        (:func:`rfmitsuba.models.base.render` with ``normalize``)."""
        return self.render_views(field, self.views(idx), h=h, w=w)

    def render_views(self, field: Field, views: Views, *, h: int | None = None, w: int | None = None):
        """As :meth:`render`, for any :class:`Views` (a training batch with its jittered copies)."""
        h, w = h or self.h, w or self.w
        return render(self.frozen + [field], views, height=h, width=w, normalize=True)

    def predict(self, field: Field, idx: np.ndarray, *, h: int = 90, w: int = 360,
                batch: int = 8) -> np.ndarray:
        """Predicted PAS at antenna indices, as :meth:`render` gives them (on the loss's scale):
        float32 [K, h, w]."""
        import drjit as dr

        out = []
        for i in range(0, len(idx), batch):
            with dr.suspend_grad():
                img = self.render(field, np.asarray(idx[i:i + batch]), h=h, w=w)
            out.append(np.array(img.numpy(), dtype=np.float32).reshape(-1, h, w))
        return np.concatenate(out) if out else np.zeros((0, h, w), np.float32)

    def validate(self, field: Field, val: np.ndarray, gt: np.ndarray) -> float:
        """Mean SSIM (metric protocol (docs/conventions.md), at 90 x 360 whatever the training
        resolution, so runs and fields trained at different ones compare) over the validation
        positions; ``gt``: their normalised PAS, float [K, 90, 360]."""
        if len(val) == 0:
            return float("nan")
        pred = minmax(self.predict(field, val, batch=self.cfg.batch_views * 2))
        return float(np.mean(ssim_images(pred, gt)))

    # ---- checkpoints ------------------------------------------------------------------------
    def _save_checkpoint(self, step, field, opt, strategy, rng, train_time, val_hist) -> None:
        rd = self.run_dir
        tmp = rd / "checkpoint.tmp"
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir()
        arrays = {f"field/{k}": v for k, v in field.state_dict().items()}
        for key, (value, promoted, lr, extra) in opt.state.items():
            t, m, v, _ = extra
            arrays[f"opt/{key}/value"] = np.array(value.numpy(), dtype=np.float32, copy=True)
            arrays[f"opt/{key}/m"] = np.array(m.numpy(), dtype=np.float32, copy=True)
            arrays[f"opt/{key}/v"] = np.array(v.numpy(), dtype=np.float32, copy=True)
            arrays[f"opt/{key}/t"] = np.array(np.asarray(t.numpy()).ravel()[0] if hasattr(t, "numpy") else t)
        arrays.update({f"density/{k}": v for k, v in strategy.state_dict().items()})
        tb = self._tail_best
        if tb is not None:
            arrays.update({f"tail_best/{k}": v for k, v in tb["state"].items()})
        np.savez(tmp / "state.npz", **arrays)
        write_json_with_numpy(tmp / "meta.json", {"step": step, "rng": rng.bit_generator.state, "train_time_s": train_time,
                                        "val_history": val_hist, "density_history": strategy.history,
                                        "tail_best": None if tb is None else
                                        {"step": tb["step"], "val_ssim": tb["val_ssim"]}})
        final = rd / "checkpoint"
        old = rd / "checkpoint.old"
        if old.exists():
            shutil.rmtree(old)
        if final.exists():
            final.rename(old)
        tmp.rename(final)
        if old.exists():
            shutil.rmtree(old)

    def _load_checkpoint(self, field, opt, strategy, rng):
        import drjit as dr

        ck = self.run_dir / "checkpoint"
        if not (ck / "meta.json").is_file():
            old = self.run_dir / "checkpoint.old"
            if (old / "meta.json").is_file():  # killed between the two renames
                old.rename(ck)
            else:
                return None
        meta = json.loads((ck / "meta.json").read_text())
        try:
            with np.load(ck / "state.npz", allow_pickle=False) as z:
                st = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:
            raise RunError(f"{ck / 'state.npz'}: the checkpoint is damaged ({type(e).__name__}: {e}); delete {ck} "
                           "to train this run from the start, or train into another --out") from None
        fs = {k[len("field/"):]: v for k, v in st.items() if k.startswith("field/")}
        field.load_state_dict(fs)
        for key in list(opt.state.keys()):
            value = B.Float(st[f"opt/{key}/value"])
            dr.enable_grad(value)
            _, promoted, lr, _ = opt.state[key]
            t = B.UInt32(int(st[f"opt/{key}/t"]))
            opt.state[key] = (value, promoted, lr, (t, B.Float(st[f"opt/{key}/m"]), B.Float(st[f"opt/{key}/v"]), None))
        strategy.load_state_dict({k[len("density/"):]: v for k, v in st.items() if k.startswith("density/")})
        strategy.history = list(meta.get("density_history", []))
        tb = meta.get("tail_best")
        if tb is not None:
            state = {k[len("tail_best/"):]: v for k, v in st.items() if k.startswith("tail_best/")}
            self._tail_best = {"step": int(tb["step"]), "val_ssim": float(tb["val_ssim"]), "state": state}
        rng.bit_generator.state = meta["rng"]
        return meta

    # ---- main loop --------------------------------------------------------------------------
    def run(self, *, stop_at: int | None = None) -> dict:
        """Train (or resume) to the decided steps (:func:`rfmitsuba.train.resolve.iterations`:
        ``cfg.iterations``, or more where ``cfg.epochs`` asks for more passes); returns the summary dict.

        A run folder this call created is removed again when the run fails before its first
        checkpoint (a configuration the field refuses, bad data, a diverging first step), so a
        corrected retry starts clean; a folder with a checkpoint is kept and resumes.

        Args:
            stop_at: stop after this many steps as if interrupted (no final files; the latest
                checkpoint stays), for tests of resuming.
        """
        import drjit as dr

        created = not self.run_dir.exists()
        B.ensure()
        threads = dr.thread_count()
        if self.cfg.threads:
            dr.set_thread_count(self.cfg.threads)
        try:
            return self._run(stop_at=stop_at)
        except BaseException:
            if created and self.run_dir.is_dir() and not self._has_checkpoint():
                shutil.rmtree(self.run_dir, ignore_errors=True)
            raise
        finally:
            dr.set_thread_count(threads)

    def _has_checkpoint(self) -> bool:
        """Whether the run folder holds trained state: its checkpoint."""
        return (self.run_dir / "checkpoint").is_dir()

    def _run(self, *, stop_at: int | None = None) -> dict:
        B.ensure()
        cfg = self.cfg
        summary_file = self.run_dir / "final" / "summary.json"
        if summary_file.is_file():   # finished: its field must still be readable, or the run is not
            read_field_state(self.run_dir / "final" / "field.npz")
            return json.loads(summary_file.read_text())
        rng = np.random.default_rng(cfg.seed)
        split = self._make_split(rng)
        self._init_run_dir(split)
        field = self._init_field(rng)
        self.field = field
        #: every "auto" of the configuration as this run decided it (rfmitsuba.train.resolve)
        self.decisions = resolve.resolve(cfg, field, num_fit=len(split["fit"]), run_dir=self.run_dir)
        resolve.write(self.run_dir / resolve.RESOLVED_NAME, self.decisions)
        if getattr(field, "closed_form", False):
            return self._condition(field, split)
        self.iterations = resolve.value(self.decisions, "iterations")
        loss_fn = load_loss()
        gt_fit = self.data.pas(split["fit"], d=self.d)
        gt_val = self.data.pas(split["val"])      # validation at the metric's 90 x 360, whatever d
        fit = split["fit"]
        probe = fit[np.linspace(0, len(fit) - 1, min(8, len(fit))).astype(int)]

        opt, strategy = self._optimizer(field, fit, loss_fn)
        meta = self._load_checkpoint(field, opt, strategy, rng)
        start = meta["step"] if meta else 0
        train_time = meta["train_time_s"] if meta else 0.0
        val_hist = meta["val_history"] if meta else []
        self._trim_log(start)
        self._pull(field, opt)

        probe_views = self.views(probe)
        #: spread of the jittered copies of each batch [wavelengths] (0: none; rfmitsuba.train.jitter)
        self.jitter = resolve.value(self.decisions, "jitter")
        n_starts = resolve.value(self.decisions, "starts")
        if meta is None and n_starts > 1:
            field, opt, strategy, rng, start, train_time, val_hist = self._choose_start(
                field, opt, strategy, rng, n_starts, split=split, gt_fit=gt_fit, gt_val=gt_val, loss_fn=loss_fn,
                probe_views=probe_views)
            self.field = field

        rd = self.run_dir
        name = rd.name
        pbar = bar(total=self.iterations, desc=f"train {name}", unit="step", quiet=self.quiet,
                   initial=start)
        log_loss, log_n = 0.0, 0
        last_val = val_hist[-1]["val_ssim"] if val_hist else float("nan")
        stopped = "iterations"
        step = start
        t_last = time.perf_counter()
        try:
            while step < self.iterations:
                if stop_at is not None and step >= stop_at:
                    stopped = "stop_at"
                    break
                if cfg.time_limit_s and train_time >= cfg.time_limit_s:
                    stopped = "time_limit"
                    break
                lv = self._step(field, opt, strategy, rng, step, train_time, fit=fit, gt_fit=gt_fit,
                                loss_fn=loss_fn, probe_views=probe_views, kept=start)
                step += 1
                log_loss += lv
                log_n += 1
                now = time.perf_counter()
                train_time += now - t_last
                t_last = now
                row = None
                if step % cfg.val_every == 0 or step == self.iterations:
                    last_val = self.validate(field, split["val"], gt_val)
                    strategy.on_validation(step, last_val)
                    val_hist.append({"step": step, "val_ssim": last_val, "n_gaussians": field.num_primitives,
                                     "time_s": train_time})
                    row = {"val_ssim": last_val}
                    self._keep_tail_best(field, step, train_time, last_val)
                    t_last = time.perf_counter()  # validation is not training time
                if step % cfg.log_every == 0 or row is not None:
                    self._log({"step": step, "loss": log_loss / max(log_n, 1), "n_gaussians": field.num_primitives,
                               "time_s": round(train_time, 3), **(row or {})})
                    log_loss, log_n = 0.0, 0
                pbar.update(1)
                pbar.set_postfix(loss=f"{lv:.4f}", val_ssim=f"{last_val:.3f}", n=field.num_primitives)
                if step % cfg.checkpoint_every == 0:
                    self._save_checkpoint(step, field, opt, strategy, rng, train_time, val_hist)
                    t_last = time.perf_counter()
        finally:
            pbar.close()
        if stopped == "stop_at":
            return {"stopped": "stop_at", "step": step}
        if step % cfg.checkpoint_every != 0:
            self._save_checkpoint(step, field, opt, strategy, rng, train_time, val_hist)
        return self._finish(field, split, step, train_time, val_hist, stopped, strategy)

    def _run_facts(self) -> dict:
        """What every ``final/summary.json`` records besides the training: the task, the dataset and
        the machine (its cores and the load at the end)."""
        return {"task": self.data.task, "dataset": str(self.data.path.resolve()),
                "cpu_count": os.cpu_count(), "load_average_1min_at_end": os.getloadavg()[0]}

    def _condition(self, field: Field, split: dict) -> dict:
        """Train a closed-form field (``Field.closed_form``, e.g. the Gaussian-process field): condition
        it on the fitting positions' spectra at 90 x 360 and validate it there, then condition it
        again on every training spectrum, the validation ones included (nothing is chosen by the
        validation SSIM, so nothing is lost by using them: it stays the estimate of the fitting-only
        field), write ``final/`` and one ``log.jsonl`` row. No gradient steps and no checkpoint; the
        run's config names the field and ``summary.json``'s ``conditioned_on`` the positions."""
        t0 = time.perf_counter()
        fit, val = split["fit"], split["val"]
        hyper = field.condition(self.data.positions(fit)[2], self.data.pas(fit))
        val_ssim = self.validate(field, val, self.data.pas(val)) if len(val) else None
        conditioned_on = np.asarray(fit)
        if len(val):
            conditioned_on = np.union1d(fit, val)
            hyper = field.condition(self.data.positions(conditioned_on)[2], self.data.pas(conditioned_on))
        train_time = time.perf_counter() - t0
        self._log({"step": 0, "n_gaussians": field.num_primitives, "time_s": round(train_time, 3),
                   **({"val_ssim": val_ssim} if val_ssim is not None else {})})
        fd = self.run_dir / "final"
        fd.mkdir(exist_ok=True)
        field.save(fd / "field.npz")
        summary = {"steps": 0, "iterations": 0, "stopped_by": "closed_form", "train_time_s": train_time,
                   "model": self.cfg.model, "num_gaussians": field.num_primitives,
                   "num_parameters": field.num_parameters, "network_parameters": field.network_parameters,
                   "val_ssim": val_ssim, "best_val_ssim": val_ssim, "revert": None, "init": {"hyperparameters": hyper},
                   "conditioned_on": [int(i) for i in conditioned_on],
                   "image": [PAS_SHAPE[0], PAS_SHAPE[1]], **self._run_facts()}
        summary = finite_or_null(summary)   # standard JSON: a score that could not be computed is null
        write_json_with_numpy(fd / "summary.json", summary)
        return summary

    def _optimizer(self, field: Field, fit: np.ndarray, loss_fn) -> tuple:
        """A fresh Adam over ``field``'s trainable parameters and its density (or pursuit) strategy."""
        from drjit.opt import Adam

        cfg = self.cfg
        opt = Adam(lr=1e-3)
        for k, v in field.trainable().items():
            opt[self.prefix + k] = v
        strategy = pursuit_for(field, data=self.data, fit=fit, frozen=self.frozen, downsample=self.d,
                               prefix=self.prefix, iterations=self.iterations, loss_fn=loss_fn) \
            or make_strategy(cfg.density, field, prefix=self.prefix, iterations=self.iterations)
        return opt, strategy

    def _step(self, field, opt, strategy, rng, step: int, train_time: float, *, fit, gt_fit, loss_fn, probe_views,
              kept: int) -> float:
        """One optimizer step (step ``step`` -> ``step + 1``) on a batch drawn by ``rng``; returns
        the batch's loss. ``kept``: the step of the checkpoint a diverging loss names."""
        import drjit as dr

        lrs = self._lrs(step, train_time)
        for k in list(opt.keys()):
            opt.set_learning_rate({k: lrs[field.lr_group(k[len(self.prefix):])]})
        pick = rng.choice(len(fit), size=min(self.cfg.batch_views, len(fit)), replace=False)
        views, gt_np = self.views(fit[pick]), gt_fit[pick]
        if self.jitter > 0:
            views, gt_np = jittered(views, gt_np, spread=self.jitter, copies=1, rng=rng)   # one copy, as measured
        gt = upload(B.TensorXf, gt_np)   # aligned: the loss's kernels compile once
        if self._records(field):
            loss = self._frozen_loss(self.frozen + [field], views, gt, loss_fn)
        else:
            loss = loss_fn(self.render_views(field, views), gt)
            penalty = field.penalty()
            if penalty is not None:
                loss = loss + penalty
            dr.backward(loss)
        strategy.after_backward(field)
        opt.step()
        self._pull(field, opt)
        lv = float(np.asarray(loss.numpy()).ravel()[0])
        if not math.isfinite(lv):
            raise RunError(f"loss became {lv} at step {step + 1}; lower the learning rates "
                           + (f"(checkpoint of step {kept} kept)" if kept else "(no checkpoint was written yet)"))
        if strategy.step_end(step + 1, field, opt, rng=rng, probe_views=probe_views):
            self._pull(field, opt)
        return lv

    def _records(self, field) -> bool:
        """Whether this step of ``field`` (with the frozen fields) goes through
        :class:`~rfmitsuba.train.frozen_step.FrozenLoss`."""
        if not (self.freeze and FrozenLoss.supports(self.frozen + [field])):
            return False
        if self._frozen_loss is None:
            self._frozen_loss = FrozenLoss(height=self.h, width=self.w)
        return True

    def _choose_start(self, field, opt, strategy, rng, n_starts: int, *, split, gt_fit, gt_val, loss_fn,
                      probe_views) -> tuple:
        """Train ``n_starts`` copies of the initial ``field`` for :func:`start_steps` steps each,
        start ``k`` drawing its batches from its own generator (start 0 from ``rng``, the others
        from ``default_rng([seed, k])``), and keep the one with the best validation SSIM (the
        lowest training loss over the last quarter of its steps without validation positions).
        Writes ``starts.json``. Returns (field, opt, strategy, rng, step, train_time, val_history)
        of the start kept; every start's steps count as training time."""
        cfg = self.cfg
        n = start_steps(self.iterations)
        init_state = field.state_dict()
        report = getattr(field, "init_report", None)
        pbar = bar(total=n * n_starts, desc=f"starts {self.run_dir.name}", unit="step", quiet=self.quiet)
        t0, runs = time.perf_counter(), []
        for k in range(n_starts):
            if k:
                field = type(field).from_state_dict(init_state)
                if report is not None:
                    field.init_report = report
                opt, strategy = self._optimizer(field, split["fit"], loss_fn)
                self._pull(field, opt)
                rng = np.random.default_rng([cfg.seed, k])
            losses = []
            for i in range(n):
                losses.append(self._step(field, opt, strategy, rng, i, time.perf_counter() - t0, fit=split["fit"],
                                         gt_fit=gt_fit, loss_fn=loss_fn, probe_views=probe_views, kept=0))
                pbar.update(1)
            t1 = time.perf_counter()
            val = self.validate(field, split["val"], gt_val)
            t0 += time.perf_counter() - t1            # validation is not training time
            runs.append({"start": k, "val_ssim": val, "loss": float(np.mean(losses[-max(1, n // 4):])),
                         "state": (field, opt, strategy, rng)})
        train_time = time.perf_counter() - t0
        pbar.close()
        score = [(r["val_ssim"] if math.isfinite(r["val_ssim"]) else -r["loss"]) for r in runs]
        best = runs[int(np.argmax(score))]
        write_json_with_numpy(self.run_dir / "starts.json", {
            "steps": n, "chosen": best["start"], "train_time_s": train_time,
            "starts": [{k: v for k, v in r.items() if k != "state"} for r in runs],
            "rule": "best validation SSIM after the steps (lowest training loss without validation positions)"})
        val_hist = [{"step": n, "val_ssim": best["val_ssim"], "n_gaussians": best["state"][0].num_primitives,
                     "time_s": train_time}]
        self._log({"step": n, "loss": best["loss"], "n_gaussians": best["state"][0].num_primitives,
                   "time_s": round(train_time, 3), "val_ssim": best["val_ssim"], "start": best["start"]})
        return (*best["state"], n, train_time, val_hist)

    def _pull(self, field: Field, opt) -> None:
        vals = {k[len(self.prefix):]: opt[k] for k in opt.keys() if k.startswith(self.prefix)}
        if vals:
            field.assign(vals)

    def _log(self, row: dict) -> None:
        with open(self.run_dir / "log.jsonl", "a") as fh:
            fh.write(json.dumps(row) + "\n")

    def _trim_log(self, step: int) -> None:
        """Drop log rows after ``step`` (written by an interrupted run after its last checkpoint)."""
        p = self.run_dir / "log.jsonl"
        if not p.is_file():
            return
        rows = [ln for ln in p.read_text().splitlines() if ln.strip() and json.loads(ln)["step"] <= step]
        tmp = p.with_name(p.name + ".tmp")
        tmp.write_text("".join(r + "\n" for r in rows))
        tmp.replace(p)

    def _keep_tail_best(self, field: Field, step: int, train_time: float, val: float) -> None:
        """Keep the field's state when this validation check is the best of the run's tail
        (progress >= :data:`TAIL`), for :meth:`_revert_collapse`."""
        if self.cfg.revert_drop <= 0 or not math.isfinite(val) or self._progress(step, train_time) < TAIL:
            return
        if self._tail_best is None or val > self._tail_best["val_ssim"]:
            self._tail_best = {"step": step, "val_ssim": val, "state": field.state_dict()}

    def _revert_collapse(self, field: Field, val_hist: list) -> dict | None:
        """If the last validation SSIM lies more than ``cfg.revert_drop`` below the best check of
        the run's tail, load that check's state into ``field``; returns what was done (None: the
        last state stays)."""
        tb = self._tail_best
        if self.cfg.revert_drop <= 0 or tb is None or not val_hist:
            return None
        last = val_hist[-1]["val_ssim"]
        if not (math.isfinite(last) and last < tb["val_ssim"] - self.cfg.revert_drop):
            return None
        now = field.state_dict()
        same = set(now) == set(tb["state"]) and all(np.shape(now[k]) == np.shape(tb["state"][k]) for k in now)
        out = {"from_step": val_hist[-1]["step"], "from_val_ssim": last, "to_step": tb["step"],
               "to_val_ssim": tb["val_ssim"]}
        if not same:   # density control changed the field after that check: keep the last state
            return {**out, "reverted": False, "why": "the field's primitives changed after the check"}
        field.load_state_dict(tb["state"])
        return {**out, "reverted": True}

    def _finish(self, field, split, step, train_time, val_hist, stopped, strategy) -> dict:
        fd = self.run_dir / "final"
        fd.mkdir(exist_ok=True)
        revert = self._revert_collapse(field, val_hist)
        val_ssim = val_hist[-1]["val_ssim"] if val_hist else None
        if revert and revert["reverted"]:
            val_ssim = revert["to_val_ssim"]
        field.save(fd / "field.npz")
        fit = split["fit"]
        field.export_ply(fd, views=self.views(fit[np.linspace(0, len(fit) - 1, min(32, len(fit))).astype(int)]))
        summary = {"steps": step, "iterations": self.iterations, "stopped_by": stopped, "train_time_s": train_time,
                   "model": self.cfg.model,
                   "num_gaussians": field.num_primitives, "num_parameters": field.num_parameters,
                   "network_parameters": field.network_parameters,
                   "val_ssim": val_ssim, "revert": revert,
                   "best_val_ssim": max((v["val_ssim"] for v in val_hist if math.isfinite(v["val_ssim"])),
                                        default=None),
                   "growth_stopped": strategy.growth_stopped, "density_events": strategy.history[-50:],
                   "image": [self.h, self.w], **self._run_facts()}
        if getattr(field, "init_report", None):   # what the field decided at its start (e.g. a frame fit)
            summary["init"] = field.init_report
        summary = finite_or_null(summary)   # standard JSON: a score that could not be computed is null
        write_json_with_numpy(fd / "summary.json", summary)
        return summary


#: the share of a run after which validation checks count as its tail (TrainConfig.revert_drop)
TAIL = 0.7


def dry_run(dataset: str | Path, *, cfg: TrainConfig | None = None) -> str:
    """What ``train(dataset, cfg=cfg)`` would decide, without training: the resolved
    configuration (:mod:`rfmitsuba.train.resolve`) as commented TOML text. For ``model = "auto"``
    it names the trials and gives the decisions of each candidate, should it be chosen.

    The initial field is built (the data scan and the line-of-sight fits run, seconds to a
    minute) in a temporary folder that is removed: nothing is written where the run would go."""
    import tempfile

    from .select import TRIAL_MAX, candidate_config, candidates, trial_config

    cfg = cfg or TrainConfig()
    data = TrainData.open(dataset, state=cfg.state)
    names = candidates(cfg, data) if cfg.model == "auto" else [cfg.model]
    lines = [f"# rfmitsuba train {dataset} --dry-run: what the run would decide (nothing was trained or written)"]
    if cfg.model == "auto":
        steps = trial_config(candidate_config(cfg, names[0]), names[0]).iterations
        lines.append(f"# model = \"auto\": trials of {', '.join(names)} at {steps} steps each (at most {TRIAL_MAX});"
                     " the best by validation SSIM trains with the full budget")
    with tempfile.TemporaryDirectory(prefix="rfmitsuba-dry-run-") as tmp:
        for name in names:
            c = candidate_config(cfg, name) if cfg.model == "auto" else cfg
            t = Trainer(c, data, Path(tmp) / name, quiet=True)
            rng = np.random.default_rng(c.seed)
            split = t._make_split(rng)
            field = t._init_field(rng)
            decided = resolve.resolve(c, field, num_fit=len(split["fit"]))
            changed = [f"{k} = {json.dumps(v)}" for k, _, v in
                       differences(C.to_dict(dataclasses.replace(cfg, model=c.model)), C.to_dict(c))]
            lines += ["", f"# {'if the trials choose ' if cfg.model == 'auto' else ''}{name}"
                          + (f" ({', '.join(changed)})" if changed else "")
                          + f": {len(split['fit'])} fitting, {len(split['val'])} validation, {len(split['test'])} "
                          "test positions"]
            lines.append(resolve.to_toml(decided).rstrip("\n"))
    return "\n".join(lines) + "\n"


def start_steps(iterations: int) -> int:
    """Steps each start trains before one is kept (``TrainConfig.starts``): a tenth of the run,
    within 50..1000 and at most ``iterations - 1``."""
    return int(max(1, min(iterations - 1, max(50, min(1000, round(0.1 * iterations))))))


def refuse_foreign_folder(rd: Path) -> bool:
    """RunError where ``rd`` is a file, or a folder that holds files but no ``config.toml`` (a
    dataset, someone's notes: not a run folder); whether it holds anything besides the "auto"
    trials and the lock (a run to check against the configuration)."""
    if rd.exists() and not rd.is_dir():
        raise RunError(f"run folder {rd} exists and is not a folder")
    if not (rd.is_dir() and any(p.name not in (SELECT_DIR, LOCK_NAME) for p in rd.iterdir())):
        return False
    if not (rd / "config.toml").is_file():
        raise RunError(f"{rd} is not empty and holds no config.toml: not a run folder; nothing was changed")
    return True


def train(dataset: str | Path, out: str | Path, *, cfg: TrainConfig | None = None, quiet: bool = False,
          freeze: bool = True) -> dict:
    """Train a Stage-1 background field: open ``dataset``, run :class:`Trainer` into ``out``
    (``cfg.model == "auto"`` first chooses the field, :func:`rfmitsuba.train.select.select_model`).

    ``freeze``: as :class:`Trainer`. Returns the summary dict (also in ``out/final/summary.json``).

    One writer per run folder: the call holds ``out``'s lock (:func:`rfmitsuba.core.folder_lock.folder_lock`)
    from before the data are opened to the end, so a second ``train`` into ``out`` is refused at once,
    naming the first one's pid, instead of interleaving its steps with the first's. A folder this call
    created is removed again when the call fails before any checkpoint (as :meth:`Trainer.run`)."""
    from ..core.folder_lock import writer

    def trained(folder: Path) -> bool:
        return any((d / "checkpoint").is_dir() for d in (folder, *folder.glob("select/*")))

    refuse_foreign_folder(Path(out))   # before the lock or any "auto" trial writes into it
    with writer(out, what="train", keep=trained):
        cfg = cfg or TrainConfig()
        data = TrainData.open(dataset, state=cfg.state)
        if cfg.model == "auto":
            cfg = select_model(cfg, data, out, trainer=Trainer, quiet=quiet)
        return Trainer(cfg, data, out, quiet=quiet, freeze=freeze).run()


def load_run(run_dir: str | Path) -> tuple[TrainConfig, TrainData, FieldSet]:
    """Open a finished run: (config, data, a renderer of its trained field).

    The renderer's ``fields[0]`` is the trained field; ``render(data, idx)`` gives raw PAS."""
    rd = Path(run_dir)
    if not (rd / "config.toml").is_file() or not (rd / "run.json").is_file():
        raise RunError(f"{rd} is not a run folder (no config.toml / run.json)")
    cfg = C.load(TrainConfig, rd / "config.toml", saved=True)
    info = json.loads((rd / "run.json").read_text())
    data = TrainData.open(info["dataset"], state=cfg.state)
    trained_on = info.get("dataset_fingerprint")
    if trained_on and dataset_fingerprint(data.path) != trained_on:
        warnings.warn(f"{data.path} has changed since {rd} was trained on it (its content fingerprint differs from "
                      "run.json's): scores and predictions compare the field with other data than it was fitted to",
                      stacklevel=2)
    return cfg, data, _trained_renderer(rd)


def dataset_fingerprint(path: str | Path) -> str | None:
    """The content fingerprint of a dataset folder (:meth:`rfmitsuba.data.store.Dataset.fingerprint`,
    or a NeRF2 folder's), or None where it cannot be made (a chunk without ``chunk.json``)."""
    from ..data.store import open_dataset

    try:
        return open_dataset(path, check=False).fingerprint()
    except (DatasetError, OSError):
        return None


def _trained_renderer(rd: Path) -> FieldSet:
    """The renderer of a finished run folder's trained field, read from ``final/`` alone."""
    if (rd / "final" / "members.json").is_file():   # an ensemble run: a removed option
        raise RunError(f"{rd} is an ensemble of independently trained fields (the removed option members); each "
                       f"member is a run of its own: open {rd / 'members' / '0'}")
    fpath = rd / "final" / "field.npz"
    if not fpath.is_file():
        raise RunError(f"{rd}: training has not finished (no final/field.npz); run `rfmitsuba train` again to resume")
    field = load_field(fpath)
    field.freeze()
    return FieldSet([field])
