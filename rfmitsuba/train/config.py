"""Typed training configuration, with a TOML round trip (:mod:`rfmitsuba.core.config`).

:class:`TrainConfig` holds the step counts, batch, resolution, seed, validation and checkpoint
cadence, the model kind (``model``: a registered Stage-1 field kind, e.g. "splat" or
"coherent"), the train/test split (``split``) and the
sub-configurations of each family (``splat``, ``coherent``, ``coherent_gaussians``, ``density``) and of the optimizer
(:class:`OptimConfig`). :func:`quick_config` is the ``--quick`` size; :func:`config_diff`
names the keys in which two configurations differ (a run folder of another configuration is
refused with that list).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import ClassVar, Literal

from ..core import config as C
from ..core.config import differences
from ..core.errors import ConfigError
from ..models.base import field_class
from ..models.coherent import CoherentConfig
from ..models.coherent_gaussians import CoherentGaussianConfig
from ..models.splat import SplatConfig
from . import resolve
from .density import DensityConfig


@dataclass
class OptimConfig:
    """Adam learning rates (per step). ``*_final`` values are reached at the last iteration by
    exponential decay; the others are constant, and so is a group whose ``*_final`` is 0. The
    rotations (and an array's pose) keep a constant rate: decaying it lost on NeRF2-like folders
    (docs/lab-notes/nerf2like.md)."""

    #: options this class no longer has (:mod:`rfmitsuba.core.config`); None: they only steered training
    removed_options: ClassVar[dict] = {"lr_rotations_final": None}

    lr_means: float = 2e-3
    lr_means_final: float = 2e-5
    lr_log_scales: float = 5e-3
    lr_rotations: float = 1e-3
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

    One line per option: meaning [unit] (default). "auto" is decided in one place
    (:mod:`rfmitsuba.train.resolve`) from the configuration, the data and the initial field, and a
    run records each decision with its reason in ``RUN/resolved.toml`` (``rfmitsuba train
    --dry-run`` prints them without training); the measurements behind each default are in the lab
    notes (docs/lab-notes/defaults.md).

    iterations: optimizer steps (6000).
    epochs: least passes over the fitting positions, ``max(iterations, ceil(epochs * positions /
        batch_views))`` steps; "auto": as the field advises (40 for a dense visibility grid, else 0); 0:
        exactly ``iterations`` ("auto").
    batch_views: PAS per step (4).
    downsample: train on (90/d) x (360/d) block-mean images; "auto": as the field advises (2 for the
        coherent Gaussian field, else 1); validation and evaluation are always at 90 x 360 ("auto").
    seed: all randomness (0).
    val_fraction: share of the training positions held out for validation, chosen at random (0.05).
    val_max: most validation positions (24).
    val_every / checkpoint_every / log_every: cadence [steps] (250 / 250 / 25).
    time_limit_s: stop after this much training wall time; the learning-rate schedules then advance with
        the share used; 0: no limit [s] (0).
    max_train_positions: use only this many training positions; 0: all (0).
    state: dataset state to train on; 0: the empty room (0).
    threads: Dr.Jit threads; 0: all cores; 1 makes a run bit-reproducible at about twice the time (0).
    starts: training starts, each trained for a tenth of the run, the best by validation SSIM kept;
        "auto": as the field advises (1, or 2 for a coherent field with searched offsets or learned
        coupling) ("auto").
    revert_drop: a run ending this much below the best validation check of its last 30% keeps that
        check's field; 0: always the last [SSIM] (0.01).
    jitter: spread of one jittered copy of each batch, the moving device displaced by N(0, (jitter *
        wavelength)^2) per axis; "auto": as the field advises (0.153 for phase-only spectra, else 0)
        [wavelengths] ("auto").
    model: a registered Stage-1 field kind ("splat", "coherent", "coherent_gaussians",
        "gaussian_process") or "auto": train the candidates briefly and keep the best by validation SSIM
        (:mod:`rfmitsuba.train.select`; :func:`rfmitsuba.train.trainer.train` decides it, a
        :class:`~rfmitsuba.train.trainer.Trainer` trains one kind) ("auto", in Python and on the CLI).
    split: test positions: "dataset" (its split.json or published index files), "block" (the 20% with the
        largest x) or "random" (seeded 80/20) ("dataset").
    scene: the room (built-in name or XML path) of a dataset that names none; "": the dataset's own ("").
    splat / coherent / coherent_gaussians / density / optim: the splat field, the image-source field, the
        coherent Gaussian field, the splat density control, the learning rates.
    """

    #: options that were removed because they did not help (core.config: saved files still load)
    removed_options: ClassVar[dict] = {"members": 1, "val_positions": "random", "jitter_views": None}
    #: options that were renamed (core.config: saved files still load)
    renamed_options: ClassVar[dict] = {"field": "splat"}
    #: the sentinels "auto" replaced (core.config: saved files still load)
    removed_values: ClassVar[dict] = {"epochs": {-1: "auto"}, "downsample": {0: "auto"}, "starts": {0: "auto"},
                                      "jitter": {-1: "auto"}}

    iterations: int = 6000
    epochs: float | Literal["auto"] = "auto"
    batch_views: int = 4
    downsample: int | Literal["auto"] = "auto"
    seed: int = 0
    val_fraction: float = 0.05
    val_max: int = 24
    val_every: int = 250
    checkpoint_every: int = 250
    log_every: int = 25
    time_limit_s: float = 0.0
    max_train_positions: int = 0
    state: int = 0
    threads: int = 0
    starts: int | Literal["auto"] = "auto"
    revert_drop: float = 0.01
    jitter: float | Literal["auto"] = "auto"
    model: str = "auto"
    split: Literal["dataset", "block", "random"] = "dataset"
    scene: str = ""
    splat: SplatConfig = dc_field(default_factory=SplatConfig)
    coherent: CoherentConfig = dc_field(default_factory=CoherentConfig)
    coherent_gaussians: CoherentGaussianConfig = dc_field(default_factory=CoherentGaussianConfig)
    density: DensityConfig = dc_field(default_factory=DensityConfig)
    optim: OptimConfig = dc_field(default_factory=OptimConfig)

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.batch_views < 1:
            raise ConfigError("TrainConfig: iterations and batch_views must be >= 1")
        if self.epochs != "auto" and not (_number(self.epochs) and math.isfinite(self.epochs) and self.epochs >= 0):
            raise ConfigError(f"TrainConfig.epochs must be 'auto' (as the field advises) or a finite number >= 0, "
                              f"got {self.epochs!r}")
        if self.downsample != "auto" and (isinstance(self.downsample, bool) or self.downsample not in (1, 2, 3, 5, 6,
                                                                                                      9, 10)):
            raise ConfigError("TrainConfig.downsample must be 'auto' (as the field advises) or divide 90 and 360 "
                              f"(1, 2, 3, 5, 6, 9, 10), got {self.downsample!r}")
        if not 0 <= self.val_fraction < 0.5:
            raise ConfigError(f"TrainConfig.val_fraction must be in [0, 0.5), got {self.val_fraction}")
        for k in ("val_every", "checkpoint_every", "log_every"):
            if getattr(self, k) < 1:
                raise ConfigError(f"TrainConfig.{k} must be >= 1, got {getattr(self, k)}")

        cls = field_class(self.model) if self.model != "auto" else None  # ConfigError naming the known kinds
        if getattr(cls, "person", False):
            raise ConfigError(f"TrainConfig.model {self.model!r} is a Stage-2 person field; Stage 1 trains a "
                              "background field (e.g. 'splat' or 'coherent')")
        if self.split not in ("dataset", "block", "random"):
            raise ConfigError(f"TrainConfig.split must be 'dataset', 'block' or 'random', got {self.split!r}")
        if self.time_limit_s < 0 or self.max_train_positions < 0 or self.state < 0:
            raise ConfigError("TrainConfig: time_limit_s, max_train_positions and state must be >= 0")
        if not (math.isfinite(self.revert_drop) and 0 <= self.revert_drop <= 1):
            raise ConfigError(f"TrainConfig.revert_drop must be in [0, 1] (0 = keep the last state), "
                              f"got {self.revert_drop!r}")
        if self.starts != "auto" and not (_number(self.starts) and self.starts in range(1, 17)):
            raise ConfigError(f"TrainConfig.starts must be 'auto' (as the field advises) or in 1..16, got "
                              f"{self.starts!r}")
        if self.jitter != "auto" and not (_number(self.jitter) and math.isfinite(self.jitter) and self.jitter >= 0):
            raise ConfigError(f"TrainConfig.jitter must be 'auto' (as the field advises) or a finite number >= 0 "
                              f"[wavelengths], got {self.jitter!r}")
        if not (isinstance(self.threads, int) and not isinstance(self.threads, bool) and self.threads >= 0):
            raise ConfigError(f"TrainConfig.threads must be an integer >= 0 (0 = all cores), got {self.threads!r}")


def quick_config(cfg: TrainConfig | None = None) -> TrainConfig:
    """A small, fast variant (for --quick and smoke tests): 300 steps, 600 Gaussians, half resolution."""
    cfg = cfg or TrainConfig()
    return C.override(cfg, ["iterations=300", "downsample=2", "val_every=100", "checkpoint_every=100",
                            "splat.num_gaussians=600", "density.start=100", "density.every=50",
                            "density.max_gaussians=2000", "density.reset_every=0"])


def config_diff(a: dict, b: dict, prefix: str = "") -> list[str]:
    """Dotted keys where two (nested) config dicts differ, with both values."""
    return [f"{k} (run has {va!r}, requested {vb!r})" for k, va, vb in differences(a, b, prefix)]


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def training_downsample(cfg: TrainConfig) -> int:
    """The block size ``d`` a run of ``cfg`` trains at (``(90/d) x (360/d)`` images):
    ``cfg.downsample``, or for "auto" what the field kind ``cfg.model`` advises
    (:func:`rfmitsuba.train.resolve.downsample`)."""
    return int(resolve.downsample(cfg).value)
