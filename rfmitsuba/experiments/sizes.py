"""The sizes of the paper's experiments: one configuration for every table.

:class:`ExperimentConfig` (with :class:`DataSize` and :class:`TrainSize`) says which
datasets are generated and how long every method trains; :data:`SIZES` holds the named sizes
``tiny`` (synthetic data, tests), ``quick`` and ``full``; :func:`size_config` returns a copy of
one. :class:`DatasetSpec` names one dataset of a table; :func:`method_config` turns an
experiment's sizes into the :class:`~rfmitsuba.experiments.methods.MethodConfig` every
method shares.
"""
from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field

from ..core import config as C
from ..core.errors import ConfigError

TABLES = ("main", "two_stage", "perturbation", "material", "large_room", "positions", "noise")


@dataclass
class DataSize:
    """Dataset sizes: antenna positions, walk (human) positions, ray samples per source (0 = the
    dataset module's default for the room)."""

    positions: int = 900
    human_positions: int = 35
    samples_per_src: int = 0


@dataclass
class TrainSize:
    """Training sizes shared by every method (steps, image downsampling, Gaussians) and the model
    family: "coherent" (image sources read out by Bartlett, :mod:`rfmitsuba.models.coherent`; trains at
    full resolution whatever ``downsample`` says; needs a scene, so Sionna data only) or "splat"
    (Gaussian splatting, WRF-GS+ style)."""

    model: str = "coherent"
    stage1_iterations: int = 3000
    stage2_iterations: int = 1000
    downsample: int = 2
    batch_views: int = 4
    num_gaussians: int = 3000
    max_gaussians: int = 20000
    human_gaussians: int = 300
    val_every: int = 250
    density: bool = True


@dataclass
class ExperimentConfig:
    """What :func:`reproduce` runs.

    size: label ("tiny", "quick", "full"); source: "sionna" (rfmitsuba.sim.generate.generate) or
    "synthetic" (rfmitsuba.sim.synthetic, no Sionna); seeds: training seeds (>= 3 for the report's
    mean +- std); rooms / tasks: of the main table (the first room and task are used by the
    ablations); materials: perturber materials; large_room: scene of the large-room table ("" =
    skip); snr_db: noise levels of the noise table; position_counts: training antenna positions of
    the positions table; tables: which tables to run.
    """

    size: str = "full"
    source: str = "sionna"
    seeds: list[int] = dc_field(default_factory=lambda: [0, 1, 2])
    data: DataSize = dc_field(default_factory=DataSize)
    train: TrainSize = dc_field(default_factory=TrainSize)
    rooms: list[str] = dc_field(default_factory=lambda: ["bedroom", "living_room", "dining_room"])
    tasks: list[str] = dc_field(default_factory=lambda: ["rx", "tx"])
    materials: list[str] = dc_field(default_factory=lambda: ["tissue", "metal", "concrete"])
    large_room: str = "large_room"
    snr_db: list[float] = dc_field(default_factory=lambda: [20.0, 10.0, 0.0])
    position_counts: list[int] = dc_field(default_factory=lambda: [180, 360])
    tables: list[str] = dc_field(default_factory=lambda: list(TABLES))

    def __post_init__(self) -> None:
        if self.source not in ("sionna", "synthetic"):
            raise ConfigError(f"ExperimentConfig.source must be 'sionna' or 'synthetic', got {self.source!r}")
        bad = [t for t in self.tables if t not in TABLES]
        if bad:
            raise ConfigError(f"ExperimentConfig.tables: unknown {bad}; known: {list(TABLES)}")
        if not self.seeds or not self.rooms or not self.tasks:
            raise ConfigError("ExperimentConfig: seeds, rooms and tasks must not be empty")
        if any(t not in ("rx", "tx") for t in self.tasks):
            raise ConfigError(f"ExperimentConfig.tasks must be 'rx' / 'tx', got {self.tasks}")
        if self.train.model not in ("splat", "coherent"):
            raise ConfigError(f"ExperimentConfig.train.model must be 'splat' or 'coherent', got {self.train.model!r}")
        if self.train.model == "coherent" and self.source == "synthetic":
            raise ConfigError("train.model = 'coherent' needs Sionna data with a scene; synthetic data has none "
                              "(use train.model = 'splat')")


SIZES = {
    "tiny": ExperimentConfig(
        size="tiny", source="synthetic", seeds=[0, 1, 2], data=DataSize(positions=25, human_positions=6),
        train=TrainSize(model="splat", stage1_iterations=30, stage2_iterations=30, downsample=10, batch_views=4,
                        num_gaussians=120, max_gaussians=400, human_gaussians=24, val_every=30, density=False),
        rooms=["bedroom"], tasks=["rx"], materials=["tissue"], large_room="", snr_db=[10.0],
        position_counts=[10], tables=["main", "two_stage", "perturbation", "positions", "noise"]),
    "quick": ExperimentConfig(
        size="quick", seeds=[0, 1, 2], data=DataSize(positions=36, human_positions=6, samples_per_src=20000),
        train=TrainSize(stage1_iterations=100, stage2_iterations=100, downsample=6, batch_views=4,
                        num_gaussians=400, max_gaussians=1000, human_gaussians=48, val_every=50, density=False),
        snr_db=[10.0], position_counts=[12]),
    "full": ExperimentConfig(),
}


def size_config(name: str) -> ExperimentConfig:
    """A copy of the named size's configuration (ConfigError on an unknown name)."""
    if name not in SIZES:
        raise ConfigError(f"unknown size {name!r}; known: {', '.join(SIZES)}")
    return C.from_dict(ExperimentConfig, C.to_dict(SIZES[name]))


@dataclass(frozen=True)
class DatasetSpec:
    """One dataset: scene, task and perturber material."""

    scene: str
    task: str
    material: str = "tissue"

    @property
    def key(self) -> str:
        return f"{self.scene}_{self.task}_{self.material}"


def method_config(cfg: ExperimentConfig):
    """The :class:`rfmitsuba.experiments.methods.MethodConfig` of an experiment's training sizes."""
    from ..models.splat import FieldConfig
    from ..models.splat_person import SplatPersonConfig
    from ..train.config import TrainConfig
    from ..train.density import DensityConfig
    from .methods import MethodConfig

    t = cfg.train
    s1 = TrainConfig(iterations=t.stage1_iterations, batch_views=t.batch_views, model=t.model,
                     downsample=1 if t.model == "coherent" else t.downsample,
                     val_every=t.val_every, checkpoint_every=t.val_every, log_every=max(1, t.val_every // 4),
                     field=FieldConfig(init="random" if cfg.source == "synthetic" else "mesh",
                                       num_gaussians=t.num_gaussians),
                     density=DensityConfig(enabled=t.density, max_gaussians=t.max_gaussians,
                                           start=max(1, t.stage1_iterations // 4),
                                           every=max(1, t.stage1_iterations // 8)))
    return MethodConfig(stage1=s1, stage2_iterations=t.stage2_iterations,
                        human=SplatPersonConfig(num_gaussians=t.human_gaussians))
