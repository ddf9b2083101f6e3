"""Typed training configuration, with a TOML round trip (:mod:`rfmitsuba.core.config`).

:class:`TrainConfig` holds the step counts, batch, resolution, seed, validation and checkpoint
cadence, the model kind (``model``: a registered Stage-1 field kind, e.g. "splat" or
"coherent"), the train/test split (``split``) and the
sub-configurations of each family (``field``, ``coherent``, ``density``) and of the optimizer
(:class:`OptimConfig`). :func:`quick_config` is the ``--quick`` size; :func:`config_diff`
names the keys in which two configurations differ (a run folder of another configuration is
refused with that list).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Literal

from ..core import config as C
from ..core.errors import ConfigError
from ..models.base import field_class
from ..models.coherent import CoherentConfig
from ..models.coherent_gaussians import CoherentGaussianConfig
from ..models.splat import FieldConfig
from .density import DensityConfig


@dataclass
class OptimConfig:
    """Adam learning rates (per step). ``*_final`` values are reached at the last iteration by
    exponential decay; the others are constant, and so is a group whose ``*_final`` is 0."""

    lr_means: float = 2e-3
    lr_means_final: float = 2e-5
    lr_log_scales: float = 5e-3
    lr_rotations: float = 1e-3
    lr_rotations_final: float = 0.0
    lr_opacity: float = 2e-2
    lr_net: float = 2e-3
    lr_net_final: float = 2e-4
    #: complex image amplitudes of the coherent model (model = "coherent")
    lr_amp: float = 1e-2
    lr_amp_final: float = 1e-3

    def __post_init__(self) -> None:
        for k, v in vars(self).items():
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f"OptimConfig.{k} must be a finite number >= 0, got {v!r}")


@dataclass
class TrainConfig:
    """Everything that determines a training run (besides the dataset).

    iterations: optimizer steps (6000 by default, since 2026-11-24: the coherent Gaussian field on a
    NeRF2-like folder, room unknown, 3 seeds, scored 0.948 +- 0.006 at 3000 and 0.956 +- 0.003 at
    6000 on the random split; the bedroom gains 0.001-0.004; experiments set their own budgets);
    epochs: least passes over the fitting positions: a run trains ``max(iterations,
    ceil(epochs * fitting positions / batch_views))`` steps (recorded as ``iterations`` in its
    summary). -1 (the default): as the field advises (``Field.epochs_advised``: a coherent
    Gaussian field with the dense visibility grid of 1000 training positions or more asks for
    40, every other field for none); 0: exactly ``iterations``. Applies to each member and start
    alike; ``model = "auto"`` trials train their fixed budget.
    batch_views: PAS per step; downsample: train on
    (90/d) x (360/d) images (block means of the ground truth, :mod:`rfmitsuba.rf.grid`);
    0 (the default): as the field advises (:func:`training_downsample`: 2 for the coherent
    Gaussian field, 1 for the others). Validation and evaluation are always at 90 x 360;
    seed: all randomness; val_fraction / val_max: training positions held out
    for validation (never test positions); val_positions: which, "random" (seeded at random among
    the training positions, the default) or "slab" (with ``split = "block"``: the training block's
    own outer slab of largest x, so that validation measures extrapolation too, at the price of
    the fit losing the positions nearest the test slab: on the NeRF2-like block split one field
    scored 0.909 +- 0.006 over 10 seeds with "slab" validation and about 0.92 with the slab in
    the fit, docs/lab-notes/measurements.md); val_every / checkpoint_every / log_every: steps;
    time_limit_s: stop early after this much training wall time (0 = no limit; the learning-rate
    schedules then also advance with the share of this time used);
    max_train_positions: use only this many training positions (0 = all; motivation table);
    state: dataset state to train on (0 = empty room).
    threads: Dr.Jit threads while training (0 = leave as is: all cores). With several threads the
    gradients' atomic adds run in no fixed order and Adam amplifies the last-bit differences, so
    two runs of one configuration differ (NeRF2-like, seed 0, 3000 steps: test SSIM 0.955 and
    0.940); 1 makes a run bit-reproducible, at about twice the time on 2 cores.
    starts: training starts (0 = as many as the field advises, ``Field.starts_advised``: 1, or 2
    for a coherent Gaussian field whose elements' offsets were searched or whose mutual coupling
    it learns). With more than one,
    each start trains its own copy of the initial field with its own batches for a tenth of
    the run (:func:`rfmitsuba.train.trainer.start_steps`) and the one with the best validation
    SSIM trains on (the others' steps count as training time; ``starts.json`` in the run folder).
    members: fields trained independently on one split, the run's prediction being the mean of
    their per-image min-max normalised PAS (an ensemble: :mod:`rfmitsuba.models.members`). Member
    ``k`` trains with seed ``seed + k`` in ``RUN/members/k`` (a run folder of its own;
    ``iterations``, ``starts`` and ``time_limit_s`` apply to each member) and the run's training
    time, Gaussians and parameters are the members' sums. Averaging several fits
    tames what one fit guesses where the data do not reach: on the NeRF2-like spatial-block
    split one field scored 0.861 +- 0.028 (30 seeds) with the defaults of 2026-11-26 to 28, the
    mean of 10 0.901 +- 0.003 and its neighbour-anchored prediction 0.917 +- 0.003 against
    nearest neighbour's 0.911 (3 seeds, docs/lab-notes/measurements.md); with today's (``jitter``,
    ``val_positions``, the neighbours' coupling) one field scores 0.921 +- 0.005 (10 seeds) and
    two members gained nothing on one seed (0.908); under the random split, where positions interpolate, 5 members scored
    0.958 +- 0.001 against one field's 0.954 +- 0.003 (seeds 0, 5, 10). K members cost K times
    the training time and Gaussians. Stage 2 and the
    methods train one field (1 = no ensemble).
    revert_drop: a run whose last validation SSIM lies more than this below the best validation
    check of its last 30% (progress, as the learning-rate schedules count it) keeps the field of
    that check instead (``final/summary.json``'s ``revert`` says when and from where); 0: always
    the last state. It catches a collapse that lands on the last check: on NeRF2-like tags with
    −15 dB element coupling, dips of 0.02–0.12 in the last 30% of a run, which recover at the next
    checks, came in 4 of 5 runs, and one run ended in one (validation 0.962 -> 0.942, test 0.945
    against the best floor's 0.952; docs/lab-notes/measurements.md). Not where the field's primitives
    changed after that check (density control).
    jitter: spread of jittered training views [carrier wavelengths] (:mod:`rfmitsuba.train.jitter`):
    each step also trains on ``jitter_views`` copies of its batch with the moving device displaced
    by ``N(0, (jitter * wavelength)^2)`` per axis, each with the spectrum of the view it was copied
    from as its target, so the field changes no faster than the data across that distance. -1
    (the default): as the field advises (``Field.jitter_advised``); 0: none. A copy costs a
    batch's render and backward pass.
    model: "auto" (train each candidate field briefly and keep the best by validation SSIM,
    :mod:`rfmitsuba.train.select`) or a registered Stage-1 field kind
    (:func:`rfmitsuba.models.base.field_class`): "splat"
    (Gaussians splatted into the PAS, WRF-GS+ style; ``field``, ``density``) or "coherent" (image
    sources summed coherently and read out by the Bartlett beamformer,
    :mod:`rfmitsuba.models.coherent`; ``coherent``; needs the scene geometry; train it at downsample 1)
    or "coherent_gaussians" (virtual sources and scatterers with complex gains, for known and unknown
    rooms and measured data, :mod:`rfmitsuba.models.coherent_gaussians`; ``coherent_gaussians``)
    or "gaussian_process" (the spectra as a Gaussian process of position, conditioned in closed form
    on the training spectra, :mod:`rfmitsuba.models.gaussian_process`; for measured folders).
    split: which positions are test positions: "dataset" (the dataset's own split: its
    split.json, or a NeRF2 folder's published index files), "block" (the 20% of all positions
    with the largest x, a held-out slab: :func:`rfmitsuba.data.split.block_split`) or "random"
    (a seeded 80/20 split of all positions, seed ``seed``).
    scene: the room (built-in scene name or XML path) for a dataset that names none, e.g. a
    NeRF2 folder measured in a room you have modelled ("" = the dataset's own scene).
    """

    iterations: int = 6000
    epochs: float = -1.0
    batch_views: int = 4
    downsample: int = 0
    seed: int = 0
    val_fraction: float = 0.05
    val_max: int = 24
    val_positions: Literal["random", "slab"] = "random"
    val_every: int = 250
    checkpoint_every: int = 250
    log_every: int = 25
    time_limit_s: float = 0.0
    max_train_positions: int = 0
    state: int = 0
    threads: int = 0
    starts: int = 0
    members: int = 1
    revert_drop: float = 0.01
    jitter: float = -1.0
    jitter_views: int = 1
    model: str = "splat"
    split: Literal["dataset", "block", "random"] = "dataset"
    scene: str = ""
    field: FieldConfig = dc_field(default_factory=FieldConfig)
    coherent: CoherentConfig = dc_field(default_factory=CoherentConfig)
    coherent_gaussians: CoherentGaussianConfig = dc_field(default_factory=CoherentGaussianConfig)
    density: DensityConfig = dc_field(default_factory=DensityConfig)
    optim: OptimConfig = dc_field(default_factory=OptimConfig)

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.batch_views < 1:
            raise ConfigError("TrainConfig: iterations and batch_views must be >= 1")
        if not (math.isfinite(self.epochs) and (self.epochs >= 0 or self.epochs == -1)):
            raise ConfigError(f"TrainConfig.epochs must be -1 (as the field advises) or a finite number >= 0, "
                              f"got {self.epochs!r}")
        if self.downsample not in (0, 1, 2, 3, 5, 6, 9, 10):
            raise ConfigError("TrainConfig.downsample must be 0 (as the field advises) or divide 90 and 360 "
                              f"(1, 2, 3, 5, 6, 9, 10), got {self.downsample}")
        if not 0 <= self.val_fraction < 0.5:
            raise ConfigError(f"TrainConfig.val_fraction must be in [0, 0.5), got {self.val_fraction}")
        for k in ("val_every", "checkpoint_every", "log_every"):
            if getattr(self, k) < 1:
                raise ConfigError(f"TrainConfig.{k} must be >= 1, got {getattr(self, k)}")

        cls = field_class(self.model) if self.model != "auto" else None  # ConfigError naming the known kinds
        if getattr(cls, "person", False):
            raise ConfigError(f"TrainConfig.model {self.model!r} is a Stage-2 person field; Stage 1 trains a "
                              "background field (e.g. 'splat' or 'coherent')")
        if self.val_positions not in ("random", "slab"):
            raise ConfigError(f"TrainConfig.val_positions must be 'random' or 'slab', got {self.val_positions!r}")
        if self.val_positions == "slab" and self.split != "block":
            raise ConfigError("TrainConfig.val_positions = 'slab' needs split = 'block' (the training block's outer "
                              f"slab), got split = {self.split!r}")
        if self.split not in ("dataset", "block", "random"):
            raise ConfigError(f"TrainConfig.split must be 'dataset', 'block' or 'random', got {self.split!r}")
        if self.time_limit_s < 0 or self.max_train_positions < 0 or self.state < 0:
            raise ConfigError("TrainConfig: time_limit_s, max_train_positions and state must be >= 0")
        if not (math.isfinite(self.revert_drop) and 0 <= self.revert_drop <= 1):
            raise ConfigError(f"TrainConfig.revert_drop must be in [0, 1] (0 = keep the last state), "
                              f"got {self.revert_drop!r}")
        if not 0 <= self.starts <= 16:
            raise ConfigError(f"TrainConfig.starts must be in 0..16 (0 = as the field advises), got {self.starts}")
        if not (isinstance(self.members, int) and not isinstance(self.members, bool) and 1 <= self.members <= 16):
            raise ConfigError(f"TrainConfig.members must be an integer in 1..16 (1 = one field), got {self.members!r}")
        if not (math.isfinite(self.jitter) and (self.jitter >= 0 or self.jitter == -1)):
            raise ConfigError(f"TrainConfig.jitter must be -1 (as the field advises) or a finite number >= 0 "
                              f"[wavelengths], got {self.jitter!r}")
        if not (isinstance(self.jitter_views, int) and not isinstance(self.jitter_views, bool)
                and 1 <= self.jitter_views <= 8):
            raise ConfigError(f"TrainConfig.jitter_views must be an integer in 1..8, got {self.jitter_views!r}")
        if not (isinstance(self.threads, int) and not isinstance(self.threads, bool) and self.threads >= 0):
            raise ConfigError(f"TrainConfig.threads must be an integer >= 0 (0 = all cores), got {self.threads!r}")


def quick_config(cfg: TrainConfig | None = None) -> TrainConfig:
    """A small, fast variant (for --quick and smoke tests): 300 steps, 600 Gaussians, half resolution."""
    cfg = cfg or TrainConfig()
    return C.override(cfg, ["iterations=300", "downsample=2", "val_every=100", "checkpoint_every=100",
                            "field.num_gaussians=600", "density.start=100", "density.every=50",
                            "density.max_gaussians=2000", "density.reset_every=0"])


def config_diff(a: dict, b: dict, prefix: str = "") -> list[str]:
    """Dotted keys where two (nested) config dicts differ, with both values."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k, "<missing>"), b.get(k, "<missing>")
        if isinstance(va, dict) and isinstance(vb, dict):
            out += config_diff(va, vb, f"{prefix}{k}.")
        elif va != vb:
            out.append(f"{prefix}{k} (run has {va!r}, requested {vb!r})")
    return out


def training_downsample(cfg: TrainConfig) -> int:
    """The block size ``d`` a run of ``cfg`` trains at (``(90/d) x (360/d)`` images):
    ``cfg.downsample``, or where it is 0 what the field kind ``cfg.model`` advises
    (``Field.downsample_advised``: 2 for the coherent Gaussian field, 1 for the others)."""
    if cfg.downsample:
        return int(cfg.downsample)
    return int(field_class(cfg.model).downsample_advised)
