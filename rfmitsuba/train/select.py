"""``model = "auto"``: choose the Stage-1 field for a dataset by validation SSIM.

Which field family suits a dataset is an empirical question: the coherent Gaussian field draws
the interference of a simulated room's paths that splats cannot, while on measured spectra
whose stated frame may be off, the splat field's freedom can serve better. :func:`select_model`
trains every candidate of :data:`AUTO_KINDS` for a quarter of the budget (at least 50 steps, at most
:data:`TRIAL_MAX` steps) on
the training positions and keeps the one with the best validation SSIM (validation positions
are training positions; test positions are never seen). Where the dataset names its room, the
coherent Gaussian field is tried three times: with ray-cast visibility (its default), with
more paths (:data:`PATHS`: room order 3 and furniture order 2, the double reflections off
furniture, doors and windows) and with its Gaussian visibility windows alone (:data:`WINDOWS`).
How many paths a room needs depends on the data: the bedroom's 720 positions spread through the
room gain from the double reflections (moving RX 0.909 -> 0.947 test SSIM over 3 seeds), while
NeRF2-like tags in a 1.6 m region seen from 5 m lose (0.955 -> 0.937, seed 0). The casts fit a
room's shadows, the windows extrapolate more smoothly beyond the training positions (NeRF2-like,
known room, block split, 3 seeds: 0.801 against 0.916 with the windows alone), and validation
decides (it may not see such a difference: docs/lab-notes/nerf2like.md). The trial runs stay in ``RUN/select/``
with ``choice.json``; the chosen field then trains with the full budget into ``RUN`` itself,
whose ``config.toml`` names it. The same command resumes at any point, and a finished choice
is not made again.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from ..core.atomic import write_json
from ..core.errors import ConfigError, RunError
from ..data.views import TrainData

#: candidate Stage-1 fields of ``model = "auto"``, in order of preference on a tie
AUTO_KINDS = ("coherent_gaussians", "splat")
#: candidates added where the spectra vary by measurement (``TrainData.varies_by_measurement``:
#: measured data, or a simulation with a measurement drift). The Gaussian-process field interpolates
#: the spectra themselves: on the measured NeRF2 RFID folder it scores 0.941 / 0.977 (mean / median
#: test SSIM, published split) against IDW-3's 0.933 / 0.973 and the coherent Gaussian field's
#: 0.851 / 0.888 (docs/results/measured/fields.md); on NeRF2-like folders with a measurement drift it
#: beats the floors where the coherent Gaussian field falls below them (docs/results/measured/simulator.md).
#: Not tried on ray-traced simulations without a drift: there the coherent Gaussian field draws what
#: an interpolator cannot, and a trial of a quarter of its training can score below the interpolator
#: (the living room, fully blind: validation 0.592 after 750 steps against the Gaussian-process
#: field's 0.778, where the trained field scores 0.918 test SSIM).
MEASURED_KINDS = ("gaussian_process",)
#: the candidate name of the coherent Gaussian field without ray-cast visibility (known rooms only)
WINDOWS = "coherent_gaussians_windows"
#: the candidate name of the coherent Gaussian field with more image paths (known rooms only)
PATHS = "coherent_gaussians_paths"
#: room order and furniture order of :data:`PATHS` (at least these; more where the config asks)
PATHS_ORDERS = (3, 2)
#: the longest trial: a quarter of the old 3000-step default (a splat trial of 750 steps takes
#: about 5 min on 2 cores for a NeRF2-like folder; a longer budget trains the choice longer)
TRIAL_MAX = 750
#: the sub-folder of a run that holds the trial runs and ``choice.json``
SELECT_DIR = "select"


def trial_config(cfg, kind: str):
    """The configuration of one trial: ``kind`` at a quarter of the budget (50 to :data:`TRIAL_MAX`
    steps, whatever passes ``epochs`` asks for)."""
    it = max(50, min(TRIAL_MAX, cfg.iterations // 4))
    every = max(1, min(cfg.val_every, it // 2))
    return dataclasses.replace(cfg, model=kind, iterations=it, epochs=0.0, val_every=every, checkpoint_every=every,
                               log_every=max(1, min(cfg.log_every, every)),
                               time_limit_s=cfg.time_limit_s / 4 if cfg.time_limit_s else 0.0)


def candidates(cfg, data: TrainData) -> list[str]:
    """The candidate names for ``data``: :data:`AUTO_KINDS` (and :data:`MEASURED_KINDS` where the
    spectra vary by measurement), with :data:`PATHS` and
    :data:`WINDOWS` after the coherent Gaussian field where the room is known (``cfg.scene``, or
    the dataset names it) and the field would cast visibility (:data:`PATHS` only where it adds
    paths to the configured orders)."""
    names = list(AUTO_KINDS) + (list(MEASURED_KINDS) if getattr(data, "varies_by_measurement", False) else [])
    c = cfg.coherent_gaussians
    known = bool(cfg.scene) or data.scene_xml is not None    # the trainer's room: cfg.scene first
    if "coherent_gaussians" in names and known and c.ray_visibility and c.init != "data":
        at = names.index("coherent_gaussians") + 1
        more = (c.room_order, c.furniture_order) != _paths_orders(c)
        names[at:at] = [PATHS, WINDOWS] if more else [WINDOWS]
    return names


def _paths_orders(c) -> tuple[int, int]:
    return max(c.room_order, PATHS_ORDERS[0]), max(c.furniture_order, PATHS_ORDERS[1])


def candidate_config(cfg, name: str):
    """``cfg`` with the candidate ``name`` (a field kind, or :data:`WINDOWS`)."""
    if name == WINDOWS:
        return dataclasses.replace(cfg, model="coherent_gaussians",
                                   coherent_gaussians=dataclasses.replace(cfg.coherent_gaussians, ray_visibility=False))
    if name == PATHS:
        room, furniture = _paths_orders(cfg.coherent_gaussians)
        return dataclasses.replace(cfg, model="coherent_gaussians",
                                   coherent_gaussians=dataclasses.replace(cfg.coherent_gaussians, room_order=room,
                                                                          furniture_order=furniture))
    return dataclasses.replace(cfg, model=name)


def select_model(cfg, data: TrainData, run_dir: str | Path, *, trainer, quiet: bool = False):
    """Resolve ``cfg.model == "auto"``: the configuration with the chosen kind.

    Args:
        cfg: the :class:`~rfmitsuba.train.config.TrainConfig`; data: the training data;
        run_dir: the run folder (trials go to ``run_dir/select/<kind>``); trainer: the trainer
        class (:class:`rfmitsuba.train.trainer.Trainer`); quiet: no progress bars.
    Returns:
        ``cfg`` with the chosen model (unchanged when its model is not "auto"), and for
        :data:`WINDOWS` without ray-cast visibility, for :data:`PATHS` with its orders.
    Raises:
        ConfigError: no candidate can train on this dataset (each candidate's refusal or
        divergence is named).
    """
    if cfg.model != "auto":
        return cfg
    sel = Path(run_dir) / SELECT_DIR
    choice = sel / "choice.json"
    if choice.is_file():
        return candidate_config(cfg, json.loads(choice.read_text())["chosen"])
    scores, refused = {}, {}
    names = candidates(cfg, data)
    for kind in names:
        try:
            c = candidate_config(cfg, kind)
            s = trainer(trial_config(c, c.model), data, sel / kind, quiet=quiet).run()
        except (ConfigError, RunError) as e:  # refused this dataset, or diverged: the other candidates go on
            refused[kind] = str(e)
            continue
        scores[kind] = {"best_val_ssim": s["best_val_ssim"], "train_time_s": s["train_time_s"], "steps": s["steps"],
                        "num_gaussians": s["num_gaussians"], "num_parameters": s["num_parameters"]}
    if not scores:
        raise ConfigError("model = 'auto': no candidate field can train on this dataset: "
                          + "; ".join(f"{k}: {v}" for k, v in refused.items()))
    scored = [k for k in scores if scores[k]["best_val_ssim"] is not None]
    if scored:
        chosen = max(scored, key=lambda k: (scores[k]["best_val_ssim"], -names.index(k)))
        rule = f"best validation SSIM after a quarter of the budget (at most {TRIAL_MAX} steps)"
    else:   # too few positions to hold any back for validation: nothing to compare the trials by
        chosen = next(k for k in names if k in scores)
        rule = ("no validation positions (too few training positions at this val_fraction): the first candidate "
                "that trained, in the order of preference")
    write_json(choice, {"chosen": chosen, "trials": scores, "refused": refused, "rule": rule})
    return candidate_config(cfg, chosen)
