"""The one sizes configuration of every job runner: ``reproduce``, ``compare`` and ``demo``.

:class:`DataSize` says how big a generated dataset is, :class:`TrainSize` how long and how big
every method trains (and, through ``overrides``, any finer setting). :class:`ExperimentConfig`
holds both plus what ``reproduce`` runs; ``compare`` holds a :class:`TrainSize` and ``demo`` an
:class:`ExperimentConfig`. :data:`SIZES` holds the named sizes ``tiny`` (synthetic data,
tests), ``quick``, ``medium`` (300 positions: the data-scarce table on 2 cores), ``full`` (the
paper's tables) and ``demo`` / ``demo_tiny`` (the README's main
job); :func:`size_config` returns a copy of one. :func:`method_config` is the one place a
:class:`TrainSize` becomes the :class:`~rfmitsuba.experiments.methods.MethodConfig` every
method shares. :class:`DatasetSpec` names one dataset of a table.
"""
from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field

from ..core import config as C
from ..core.errors import ConfigError
from ..models.coherent import CoherentConfig
from ..models.splat import SplatConfig
from ..models.splat_person import SplatPersonConfig
from ..train.config import TrainConfig
from ..train.density import DensityConfig
from .methods import MethodConfig

TABLES = ("main", "two_stage", "perturbation", "material", "large_room", "positions", "noise", "rx_count",
          "third_stage", "data_scarce")
#: the tables a size runs unless told otherwise: every one but ``data_scarce``, whose long-walk
#: datasets are the largest of all (at the full size 900 positions x 281 states each, about 40 GB;
#: run it by naming it: ``reproduce --tables data_scarce``)
DEFAULT_TABLES = tuple(t for t in TABLES if t != "data_scarce")


@dataclass
class DataSize:
    """Dataset sizes: antenna positions, walk (person) positions, ray samples per source.

    samples_per_src: Sionna's ray samples per source; 0 = ``samples_scale`` times the room's
        default (:func:`rfmitsuba.sim.generate.default_solver`: 1e5, 3e5 over 50 m^2 of floor).
    samples_scale: in (0, 1], the fraction of the room's default used where ``samples_per_src``
        is 0. The solve costs samples x receivers shadow rays (Sionna tests every ray's bounce
        against every receiver), so the full size's 0.25 made its datasets' solves 2.8 times faster (16.7 s against 47 s
        per 900-receiver bedroom state).
        Against a 2e5-sample reference (bedroom, 200 positions) the PAS agree at mean SSIM
        0.9986 with 1e5 samples, 0.9973 with 3e4 and 0.9964 with 2e4 (docs/lab-notes/paper-tables.md).
    """

    positions: int = 900
    person_positions: int = 35
    samples_per_src: int = 0
    samples_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.positions < 1 or self.person_positions < 0 or self.samples_per_src < 0:
            raise ConfigError(f"DataSize: positions must be >= 1, person_positions and samples_per_src >= 0, got "
                              f"{self.positions}, {self.person_positions}, {self.samples_per_src}")
        if not 0.0 < self.samples_scale <= 1.0:
            raise ConfigError(f"DataSize.samples_scale must be in (0, 1], got {self.samples_scale}")


@dataclass
class TrainSize:
    """Training sizes shared by every method.

    model: the Stage-1 field kind of every method, "coherent_gaussians" (the default, below),
    "coherent" (image sources read out by Bartlett,
    :mod:`rfmitsuba.models.coherent`; trains at full resolution whatever ``downsample`` says; needs
    a scene, so Sionna data only), "coherent_gaussians" (the coherent Gaussian field,
    :mod:`rfmitsuba.models.coherent_gaussians`, known or unknown room; at the resolution it advises
    whatever ``downsample`` says, 45 x 180 (``TrainConfig.downsample = "auto"``); its
    Stage 2 is :mod:`rfmitsuba.models.coherent_gaussians_person`, its End-to-End
    :mod:`rfmitsuba.models.coherent_gaussians_joint`) or "splat"
    (Gaussian splatting, WRF-GS+ style).
    stage1_iterations / stage2_iterations: n1 / n2 optimizer steps; batch_views: PAS per step;
    downsample: training image reduction (splat); num_gaussians / max_gaussians: splat Gaussians
    at the start / at most (density control ``density``); person_gaussians: Stage-2 person Gaussians
    (splat); val_every: validation and checkpoint cadence [steps]; room_order / furniture_order:
    image-source orders of the coherent model (model "coherent"; "coherent_gaussians" keeps its own,
    set them with ``overrides``: ``"stage1.coherent_gaussians.room_order=3"``).
    overrides: ``KEY=VALUE`` settings of the resulting
    :class:`~rfmitsuba.experiments.methods.MethodConfig` applied last (e.g.
    ``"stage1.optim.lr_amp=0.02"``, ``"coherent_person.num_points=8"``): every finer setting
    without a size of its own.
    """

    model: str = "coherent_gaussians"
    stage1_iterations: int = 3000
    stage2_iterations: int = 1500
    downsample: int = 2
    batch_views: int = 8
    num_gaussians: int = 3000
    max_gaussians: int = 20000
    person_gaussians: int = 300
    val_every: int = 500
    density: bool = True
    room_order: int = 3
    furniture_order: int = 2
    overrides: list[str] = dc_field(default_factory=list)

    def __post_init__(self) -> None:
        if self.model not in ("splat", "coherent", "coherent_gaussians"):
            raise ConfigError(f"TrainSize.model must be 'splat', 'coherent' or 'coherent_gaussians', got {self.model!r}")
        for k in ("stage1_iterations", "stage2_iterations", "batch_views", "num_gaussians", "person_gaussians",
                  "val_every"):
            if getattr(self, k) < 1:
                raise ConfigError(f"TrainSize.{k} must be >= 1, got {getattr(self, k)}")


@dataclass
class ExperimentConfig:
    """What :func:`reproduce` runs.

    size: label ("tiny", "quick", "full"); source: "sionna" (rfmitsuba.sim.generate.generate) or
    "synthetic" (rfmitsuba.sim.synthetic, no Sionna); seeds: training seeds (>= 3 for the report's
    mean +- std); rooms / tasks: of the main table (the first room and task are used by the
    ablations); materials: perturber materials; large_room: scene of the large-room table ("" =
    skip); snr_db: noise levels of the noise table; position_counts: training antenna positions of
    the positions table; rx_counts: Baseline's training positions in the Rx-count table beyond
    the main dataset's (from an empty-room dataset of ``max(rx_counts) / 0.8`` positions of the
    same room and task, :attr:`DatasetSpec.static_positions`); scarce_positions: the static
    training positions of the data-scarce table, each laid out on a coarse grid over the free
    floor (at most the training split of ``data.positions``); walk_lengths: its walk lengths
    [walk positions], the first N of one walk of ``max(walk_lengths)`` positions at the walk's
    own pace (0 = no walk; the table's datasets, :attr:`DatasetSpec.walk_positions`); tables:
    which tables to run (default :data:`DEFAULT_TABLES`; ``third_stage`` runs only with
    ``train.model = "coherent_gaussians"``, ``data_scarce`` has Stage 3 only then); truth_positions:
    antenna positions of the truth-uncertainty check beside the main table (each room x task of
    Sionna data traced again with every array element as its own antenna,
    :mod:`rfmitsuba.experiments.truth`, at the datasets' ray samples; 0 = skip; at most 200).
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
    rx_counts: list[int] = dc_field(default_factory=lambda: [1800, 3600, 6000])
    scarce_positions: list[int] = dc_field(default_factory=lambda: [20, 45, 90, 180, 360, 720])
    walk_lengths: list[int] = dc_field(default_factory=lambda: [0, 35, 70, 140, 280])
    tables: list[str] = dc_field(default_factory=lambda: list(DEFAULT_TABLES))
    truth_positions: int = 48

    def __post_init__(self) -> None:
        if self.source not in ("sionna", "synthetic"):
            raise ConfigError(f"ExperimentConfig.source must be 'sionna' or 'synthetic', got {self.source!r}")
        bad = [t for t in self.tables if t not in TABLES]
        if bad:
            raise ConfigError(f"ExperimentConfig.tables: unknown {bad}; known: {list(TABLES)}")
        if not self.seeds or not self.rooms or not self.tasks:
            raise ConfigError("ExperimentConfig: seeds, rooms and tasks must not be empty")
        if any(n < 1 for n in self.rx_counts):
            raise ConfigError(f"ExperimentConfig.rx_counts must be >= 1, got {self.rx_counts}")
        train = self.data.positions - int(round(0.2 * self.data.positions))   # data.split.ANTENNA_TEST_FRACTION
        if "data_scarce" in self.tables and any(not 1 <= n <= train for n in self.scarce_positions or [0]):
            raise ConfigError(f"ExperimentConfig.scarce_positions must lie in 1..{train} (the training split of "
                              f"data.positions = {self.data.positions}), got {self.scarce_positions}")
        if any(n < 0 for n in self.walk_lengths) or not any(n > 0 for n in self.walk_lengths):
            raise ConfigError(f"ExperimentConfig.walk_lengths must be >= 0 with one > 0, got {self.walk_lengths}")
        if not 0 <= self.truth_positions <= 200:     # rfmitsuba.sim.generate.EXACT_MAX_POSITIONS
            raise ConfigError(f"ExperimentConfig.truth_positions must be in 0..200, got {self.truth_positions}")
        if any(t not in ("rx", "tx") for t in self.tasks):
            raise ConfigError(f"ExperimentConfig.tasks must be 'rx' / 'tx', got {self.tasks}")
        if self.train.model == "coherent" and self.source == "synthetic":
            raise ConfigError("train.model = 'coherent' needs Sionna data with a scene; synthetic data has none "
                              "(use train.model = 'splat')")


#: the sizes of ``reproduce`` (the paper's tables, 3 seeds); the others are the demo's
PAPER_SIZES = ("tiny", "quick", "medium", "full")

SIZES = {
    "tiny": ExperimentConfig(
        size="tiny", source="synthetic", seeds=[0, 1, 2], data=DataSize(positions=25, person_positions=6),
        train=TrainSize(model="splat", stage1_iterations=30, stage2_iterations=30, downsample=10, batch_views=4,
                        num_gaussians=120, max_gaussians=400, person_gaussians=24, val_every=30, density=False),
        rooms=["bedroom"], tasks=["rx"], materials=["tissue"], large_room="", snr_db=[10.0],
        position_counts=[10], rx_counts=[30], scarce_positions=[4, 8, 20], walk_lengths=[0, 4, 8],
        tables=["main", "two_stage", "perturbation", "positions", "noise", "rx_count"]),
    "quick": ExperimentConfig(
        size="quick", seeds=[0, 1, 2], data=DataSize(positions=36, person_positions=6, samples_per_src=20000),
        train=TrainSize(stage1_iterations=100, stage2_iterations=100, downsample=6, batch_views=4,
                        num_gaussians=400, max_gaussians=1000, person_gaussians=48, val_every=50, density=False),
        snr_db=[10.0], position_counts=[12], rx_counts=[60], scarce_positions=[4, 9, 29], walk_lengths=[0, 6, 12],
        truth_positions=6),
    # between quick and full, for the data-scarce table on 2 cores: the full size's scarce
    # static positions up to its 240 training positions, walks of 35 and 70 positions (the full
    # size's 35-position walk and its double), a fifth of the full size's steps
    "medium": ExperimentConfig(
        size="medium", data=DataSize(positions=300, person_positions=35, samples_per_src=20000),
        train=TrainSize(stage1_iterations=600, stage2_iterations=300, val_every=300, density=False),
        snr_db=[10.0], position_counts=[90], rx_counts=[600], scarce_positions=[20, 45, 90, 180, 240],
        walk_lengths=[0, 35, 70], truth_positions=12),
    # a quarter of each room's default ray samples (DataSize.samples_scale): 2.8x faster solves
    "full": ExperimentConfig(data=DataSize(samples_scale=0.25)),
    # the README's main job (rfmitsuba demo): one bedroom moving-RX dataset, one seed
    "demo": ExperimentConfig(
        size="demo", seeds=[0], data=DataSize(positions=300, person_positions=8, samples_per_src=20000),
        train=TrainSize(stage1_iterations=600, stage2_iterations=300, downsample=3, num_gaussians=1500,
                        max_gaussians=4500, person_gaussians=96, val_every=100, room_order=2, furniture_order=1),
        rooms=["bedroom"], tasks=["rx"], materials=["tissue"], large_room="", tables=[], truth_positions=0),
    "demo_tiny": ExperimentConfig(
        size="demo_tiny", seeds=[0], data=DataSize(positions=30, person_positions=5, samples_per_src=20000),
        train=TrainSize(stage1_iterations=40, stage2_iterations=30, downsample=10, num_gaussians=200,
                        max_gaussians=600, person_gaussians=24, val_every=100, room_order=1, furniture_order=1),
        rooms=["bedroom"], tasks=["rx"], materials=["tissue"], large_room="", tables=[], truth_positions=0),
}


def size_config(name: str) -> ExperimentConfig:
    """A copy of the named size's configuration (ConfigError on an unknown name)."""
    if name not in SIZES:
        raise ConfigError(f"unknown size {name!r}; known: {', '.join(SIZES)}")
    return C.from_dict(ExperimentConfig, C.to_dict(SIZES[name]))


@dataclass(frozen=True)
class DatasetSpec:
    """One dataset: scene, task and perturber material; ``static_positions`` > 0: instead an
    empty-room dataset of that many antenna positions (another position seed, no walk), the
    Rx-count table's extra training positions; ``walk_positions`` > 0: a walk of that many
    positions at the walk's own pace (35 a minute) instead of the size's, the data-scarce table's."""

    scene: str
    task: str
    material: str = "tissue"
    static_positions: int = 0
    walk_positions: int = 0

    @property
    def key(self) -> str:
        k = f"{self.scene}_{self.task}_{self.material}"
        k += f"_static{self.static_positions}" if self.static_positions else ""
        return k + (f"_walk{self.walk_positions}" if self.walk_positions else "")


def method_config(train: TrainSize, *, scene_known: bool = True):
    """The :class:`rfmitsuba.experiments.methods.MethodConfig` of a :class:`TrainSize`: the one
    place sizes become training configurations (``reproduce``, ``compare`` and ``demo`` all call it).

    Args:
        train: the sizes.
        scene_known: the datasets name their room (Sionna data); without one the splat field
            starts uniform in the bounds instead of on the room's surfaces and the coherent
            Gaussian field from the data scan. The coherent model needs the room.
    Returns:
        the MethodConfig, with ``train.overrides`` applied last.
    """
    import dataclasses


    t = train
    if t.model == "coherent" and not scene_known:
        raise ConfigError("train.model = 'coherent' needs datasets with a scene; use train.model = 'splat'")
    s1 = TrainConfig(iterations=t.stage1_iterations, batch_views=t.batch_views, model=t.model,
                     downsample={"coherent": 1, "coherent_gaussians": "auto"}.get(t.model, t.downsample),
                     val_every=t.val_every, checkpoint_every=t.val_every, log_every=max(1, t.val_every // 10),
                     splat=SplatConfig(init="mesh" if scene_known else "random", num_gaussians=t.num_gaussians),
                     coherent=CoherentConfig(room_order=t.room_order, furniture_order=t.furniture_order),
                     density=DensityConfig(enabled=t.density, max_gaussians=t.max_gaussians,
                                           start=max(1, t.stage1_iterations // 4),
                                           every=max(1, t.stage1_iterations // 8)))
    mcfg = MethodConfig(stage1=s1, stage2_iterations=t.stage2_iterations,
                        person=SplatPersonConfig(num_gaussians=t.person_gaussians))
    if t.model == "coherent":
        # the learning rates of the bedroom figures of docs/lab-notes/paper-tables.md (network 3e-3 -> 3e-4; Stage 2 slower)
        s1.optim.lr_net, s1.optim.lr_net_final = 3e-3, 3e-4
        mcfg.stage2_optim = dataclasses.replace(s1.optim, lr_amp=3e-3, lr_amp_final=3e-4, lr_means=3e-3,
                                                lr_means_final=3e-4)
    return C.override(mcfg, list(t.overrides)) if t.overrides else mcfg
