"""The compared methods (a registry), how each trains, and the two evaluations.

Methods (:data:`METHODS`; budgets in optimizer steps, ``n1`` = Stage-1 steps, ``n2`` =
Stage-2 steps of :class:`MethodConfig`):

==================  ================================================================  ===========
name                what it trains                                                    steps
==================  ================================================================  ===========
baseline            one field on the empty-room data                                  n1
continued           Baseline's field trained n2 steps more on the same empty-room     n1 + n2
                    data, at Stage 1's final learning rates (the paper's "continue
                    training the baseline")
duplicated          one field on the empty-room data repeated (1 + H_train) times      n1 + n2
baseline_person     one field on empty + person-present data, no person position      n1 + n2
end_to_end          one field on empty + person-present data, person position as input n1 + n2
                    (coherent Gaussian family: background + person field trained together,
                    :mod:`rfmitsuba.models.coherent_gaussians_joint`)
ours                Stage 1 = baseline (n1), then Stage 2: frozen background + person  n1 + n2
                    Gaussians (:mod:`rfmitsuba.models.splat_person`) on the person-present data
ours_untracked      Ours without the walk's positions: R rounds of a search for the   n1 + R n2
                    walk from frame order alone (grid, walk within a walking speed,
                    descent; :mod:`rfmitsuba.experiments.walk_search`) and Stage 2 on
                    it (coherent Gaussian family only)
ours_people         Ours with one person field for every person of the walk (each     n1 + n2
                    person's feet an input; same body, own scatterers, blockages
                    multiplied; coherent Gaussian family only): on a walk of several
                    people, against Ours whose field sees person 1 alone
refined             Ours, then Stage 3: background and person field trained together    n1 + 2 n2
                    on empty + person-present data at Stage 1's final learning rates
                    (coherent Gaussian family only; does the walk improve the background?)
==================  ================================================================  ===========

So every method of the ablations has the same step budget as Ours; Baseline is Ours' first
stage and Continued's start (before 2026-11-27 Continued trained n1 + n2 steps from scratch on one
schedule). The end-to-end and person-data baselines see the same samples as Ours (empty room +
person-present data at training antenna and training person positions).

Evaluations (:func:`evaluate`), both by the metric protocol (docs/conventions.md) with both floors:

* **dynamic** - unseen antenna positions x unseen person positions, against the person-present
  ground truth; nearest neighbour over (antenna, person) position among the person-present
  training samples. Methods without a person input render the same image for every person.
* **static** - the background alone (person Gaussians off; end-to-end with "no person" input)
  at unseen antenna positions, against the empty-room ground truth; nearest neighbour over
  the antenna position among empty-room training samples.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import time
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path

import numpy as np

from ..core import config as C
from ..core.atomic import write_json_with_numpy
from ..core.errors import ConfigError, RunError
from ..core.legacy_names import current_keys, current_name
from ..data.samples import SampleData, num_person_features
from ..data.store import open_dataset
from ..eval.dynamic_static import evaluate
from ..models.base import FieldSet, field_class, load_field
from ..models.coherent_gaussians_person import CoherentGaussianPersonConfig
from ..models.coherent_person import CoherentPersonConfig
from ..models.splat_person import SplatPersonConfig
from ..train.config import OptimConfig, TrainConfig
from ..train.trainer import Trainer
from .walk_search import WalkSearchConfig


@dataclass(frozen=True)
class Method:
    """One compared method (see the module table)."""

    name: str
    label: str
    description: str
    states: str
    person_input: bool = False
    two_stage: bool = False
    duplicate: bool = False
    long_budget: bool = True
    #: the method whose finished job this one starts from (None: it trains from scratch)
    builds_on: str | None = None


METHODS: dict[str, Method] = {m.name: m for m in [
    Method("baseline", "Baseline", "trained on empty-room data", "empty", long_budget=False),
    Method("continued", "Continued baseline", "baseline trained longer on empty-room data", "empty",
           builds_on="baseline"),
    Method("duplicated", "Baseline (duplicated)", "trained on duplicated empty-room data", "empty", duplicate=True),
    Method("baseline_person", "Baseline (person)", "trained on person-present data, no person position", "all"),
    Method("end_to_end", "End-to-End", "one model on person-present data with the person position as input", "all",
           person_input=True),
    Method("ours", "Ours (two-stage)", "frozen background + person Gaussians", "person", person_input=True,
           two_stage=True, builds_on="baseline"),
    Method("ours_untracked", "Ours (no tracker)", "Ours with the walk's positions estimated from frame order alone",
           "person", person_input=True, two_stage=True, builds_on="baseline"),
    Method("ours_people", "Ours (every person)", "Ours with one person field drawing every person of the walk",
           "person", person_input=True, two_stage=True, builds_on="baseline"),
    Method("refined", "Ours + Stage 3", "Ours, then background and person trained together on empty + walk data",
           "all", person_input=True, builds_on="ours"),
]}


def get_method(name: str) -> Method:
    """The registered method ``name`` (ConfigError listing the known ones)."""
    if name not in METHODS:
        if current_name(name) in METHODS:
            raise ConfigError(f"method {name!r} is called {current_name(name)!r} now (see the changelog)")
        raise ConfigError(f"unknown method {name!r}; known: {', '.join(METHODS)}")
    return METHODS[name]


@dataclass
class MethodConfig:
    """Training sizes shared by all methods.

    stage1: the background training configuration (its ``iterations`` is n1; its ``model``,
    "splat" or "coherent", is the model family of every method); stage2_iterations: n2;
    person: the Stage-2 person Gaussians (model "splat"); coherent_person: the Stage-2 person
    scatterers (model "coherent"); coherent_gaussians_person: the Stage-2 person field of the coherent
    Gaussian family (body scatterers + blockage, model "coherent_gaussians"); stage2_optim:
    Stage-2 learning rates; walk_search: how Ours (no tracker) estimates the walk
    (:class:`~rfmitsuba.experiments.walk_search.WalkSearchConfig`). ``person.person_octaves`` are
    the encoding octaves of the person position for the end-to-end model.
    """

    stage1: TrainConfig = dc_field(default_factory=TrainConfig)
    stage2_iterations: int = 1000
    person: SplatPersonConfig = dc_field(default_factory=SplatPersonConfig)
    coherent_person: CoherentPersonConfig = dc_field(default_factory=CoherentPersonConfig)
    coherent_gaussians_person: CoherentGaussianPersonConfig = dc_field(default_factory=CoherentGaussianPersonConfig)
    stage2_optim: OptimConfig = dc_field(default_factory=lambda: OptimConfig(
        lr_means=1e-2, lr_means_final=5e-4, lr_log_scales=1e-2, lr_rotations=2e-3, lr_opacity=2e-2,
        lr_net=1e-2, lr_net_final=1e-3))
    walk_search: WalkSearchConfig = dc_field(default_factory=WalkSearchConfig)

    def __post_init__(self) -> None:
        if self.stage2_iterations < 1:
            raise ConfigError(f"MethodConfig.stage2_iterations must be >= 1, got {self.stage2_iterations}")


def stage1_config(mcfg: MethodConfig, method: Method, *, seed: int) -> TrainConfig:
    """The single-field training configuration of ``method`` (budget and seed applied)."""
    it = mcfg.stage1.iterations + (mcfg.stage2_iterations if method.long_budget else 0)
    return dataclasses.replace(mcfg.stage1, iterations=it, seed=seed, state=0, max_train_positions=0)


def stage2_config(mcfg: MethodConfig, *, seed: int) -> TrainConfig:
    """Stage-2 training configuration: n2 steps, no density control, Stage-2 learning rates."""
    s1 = mcfg.stage1
    dens = dataclasses.replace(s1.density, enabled=False)
    return dataclasses.replace(s1, iterations=mcfg.stage2_iterations, seed=seed, state=0, max_train_positions=0,
                               density=dens, optim=mcfg.stage2_optim)


def open_data(dataset: str | Path, method: Method, *, noise_snr_db: float | None = None, train_antennas: int = 0,
              seed: int = 0, layout: str = "random", walk_frames: int | None = None) -> SampleData:
    """The samples ``method`` trains on (noise seed = ``seed``; antenna subset seed fixed to 0 so
    that every method sees the same positions; ``layout`` and ``walk_frames`` as
    :meth:`rfmitsuba.data.samples.SampleData.open_samples`)."""
    dup = 1
    if method.duplicate:

        dup = 1 + len(open_dataset(dataset).split.person_train)
    return SampleData.open_samples(dataset, states=method.states, duplicate=dup, noise_snr_db=noise_snr_db,
                                   noise_seed=seed, train_antennas=train_antennas, subset_seed=0, layout=layout,
                                   walk_frames=walk_frames)


def joint_field(mcfg: MethodConfig):
    """End-to-End in the coherent Gaussian family: (field factory for the Trainer, extra-input
    width, features(data, idx)) of :class:`~rfmitsuba.models.coherent_gaussians_joint.CoherentGaussianJointField`,
    the background and Ours' Stage-2 person field (``mcfg.coherent_gaussians_person``) trained together."""
    from ..models.coherent_gaussians_joint import CoherentGaussianJointField

    pcfg = mcfg.coherent_gaussians_person
    width = num_person_features(pcfg.person_octaves) + 3

    def factory(tr, rng):
        return CoherentGaussianJointField.for_training(tr.cfg, tr.data, scene_xml=tr.scene_xml(), rng=rng,
                                                       extra_inputs=width, name=tr.name, person=pcfg)

    return factory, width, lambda data, idx: data.features(idx, octaves=pcfg.person_octaves, raw=True)


def person_field(mcfg: MethodConfig, bg) -> tuple[str, object]:
    """Stage 2's person field on background ``bg``: (registered kind, its configuration).

    On a splat background ("splat_person", ``mcfg.person``); on a coherent Gaussian one
    ("coherent_gaussians_person", ``mcfg.coherent_gaussians_person``); on a coherent one
    ("coherent_perturb" or "coherent_person", by ``mcfg.coherent_person.kind`` "perturb" or
    "scatter", with ``mcfg.coherent_person``)."""
    if bg.family == "splat":
        return "splat_person", mcfg.person
    if bg.family == "coherent_gaussians":
        return "coherent_gaussians_person", mcfg.coherent_gaussians_person
    kind = "coherent_perturb" if mcfg.coherent_person.kind == "perturb" else "coherent_person"
    return kind, mcfg.coherent_person


def stage3_config(mcfg: MethodConfig, *, seed: int) -> TrainConfig:
    """Stage-3 (and Continued's) training configuration: n2 steps, no density control, Stage 1's
    learning rates held at their final values (a refinement of a trained background, not a new fit)."""
    s1 = mcfg.stage1
    o = s1.optim
    optim = dataclasses.replace(o, lr_means=o.lr_means_final, lr_net=o.lr_net_final, lr_amp=o.lr_amp_final)
    return dataclasses.replace(s1, iterations=mcfg.stage2_iterations, seed=seed, state=0, max_train_positions=0,
                               density=dataclasses.replace(s1.density, enabled=False), optim=optim)


def prior_kwargs(name: str, prior_job: str | Path | None) -> dict:
    """The :func:`train_method` / :func:`run_job` keyword that hands method ``name`` the finished
    job folder of the method it builds on (``Method.builds_on``): ``stage1_dir`` (its Baseline's
    run) for Ours and Continued, ``ours_dir`` for Stage 3; {} without one."""
    m = get_method(name)
    if prior_job is None or m.builds_on is None:
        return {}
    return {"stage1_dir": Path(prior_job) / "train"} if m.builds_on == "baseline" else {"ours_dir": Path(prior_job)}


def _train_stage3(dataset, out: Path, *, mcfg: MethodConfig, seed: int, noise_snr_db, train_antennas,
                  layout: str, walk_frames: int | None, ours_dir: Path | None, quiet: bool) -> dict:
    """Stage 3 (method "refined"; :func:`train_method` has checked the model family): Ours'
    background and person field, unfrozen as one joint field
    (:class:`~rfmitsuba.models.coherent_gaussians_joint.CoherentGaussianJointField`), trained on
    empty-room and walk samples into ``out/stage3``."""
    from ..models.coherent_gaussians_joint import CoherentGaussianJointField
    from ..models.coherent_gaussians_person import CoherentGaussianPersonField

    if ours_dir is None:
        ours_dir = out / "ours_job"
        train_method("ours", dataset, ours_dir, mcfg=mcfg, seed=seed, noise_snr_db=noise_snr_db,
                     train_antennas=train_antennas, layout=layout, walk_frames=walk_frames, quiet=quiet)
    ours_dir = Path(ours_dir)
    s2_file = ours_dir / "stage2" / "final" / "summary.json"
    if not s2_file.is_file() or not (ours_dir / "stage1.json").is_file():
        raise RunError(f"Ours job {ours_dir} has not finished (no stage2/final/summary.json)")
    s2 = json.loads(s2_file.read_text())
    s1 = json.loads((Path(json.loads((ours_dir / "stage1.json").read_text())["stage1_dir"]) / "final"
                     / "summary.json").read_text())
    person = load_field(ours_dir / "stage2" / "final" / "field.npz")
    if not isinstance(person, CoherentGaussianPersonField):
        raise RunError(f"{ours_dir}: Stage 3 needs a coherent_gaussians_person Stage 2, found {type(person).__name__}")
    _, width, feats = joint_field(mcfg)
    data = open_data(dataset, get_method("refined"), noise_snr_db=noise_snr_db, train_antennas=train_antennas,
                     layout=layout, walk_frames=walk_frames,
                     seed=seed)
    tr = Trainer(stage3_config(mcfg, seed=seed), data, out / "stage3", quiet=quiet, extra=lambda idx: feats(data, idx),
                 extra_inputs=width, field_factory=lambda t, rng: CoherentGaussianJointField.from_person(person))
    write_json_with_numpy(out / "ours.json", {"ours_dir": str(ours_dir.resolve())})
    s3 = tr.run()
    return {"train_time_s": s1["train_time_s"] + s2["train_time_s"] + s3["train_time_s"],
            "steps": s1["steps"] + s2["steps"] + s3["steps"], "stage1_train_time_s": s1["train_time_s"],
            "val_ssim": s3["val_ssim"], "stage1_val_ssim": s1["val_ssim"], "stage2_val_ssim": s2["val_ssim"],
            "runs": [str(ours_dir / "stage2"), str(out / "stage3")]}


def _baseline_run(dataset, out: Path, *, mcfg: MethodConfig, seed: int, noise_snr_db, train_antennas,
                  layout: str, walk_frames: int | None, stage1_dir: str | Path | None,
                  quiet: bool) -> tuple[Path, dict]:
    """The finished Baseline run a method builds on (``stage1_dir``, or one trained into
    ``out/stage1_job``) and its summary. RunError when ``stage1_dir`` has not finished."""
    if stage1_dir is None:
        train_method("baseline", dataset, out / "stage1_job", mcfg=mcfg, seed=seed, noise_snr_db=noise_snr_db,
                     train_antennas=train_antennas, layout=layout, walk_frames=walk_frames, quiet=quiet)
        stage1_dir = out / "stage1_job" / "train"
    stage1_dir = Path(stage1_dir)
    if not (stage1_dir / "final" / "summary.json").is_file():
        raise RunError(f"Stage 1 run {stage1_dir} has not finished (no final/summary.json)")
    return stage1_dir, json.loads((stage1_dir / "final" / "summary.json").read_text())


def _train_continued(dataset, out: Path, *, mcfg: MethodConfig, seed: int, noise_snr_db, train_antennas,
                     layout: str, walk_frames: int | None, stage1_dir: str | Path | None, quiet: bool) -> dict:
    """Continued: the Baseline's trained field (``stage1_dir``) trained n2 steps more on the same
    empty-room data at Stage 1's final learning rates (:func:`stage3_config`), into ``out/train``."""
    stage1_dir, s1 = _baseline_run(dataset, out, mcfg=mcfg, seed=seed, noise_snr_db=noise_snr_db,
                                   train_antennas=train_antennas,
                                   layout=layout, walk_frames=walk_frames, stage1_dir=stage1_dir, quiet=quiet)
    start = load_field(stage1_dir / "final" / "field.npz")
    data = open_data(dataset, get_method("continued"), noise_snr_db=noise_snr_db, train_antennas=train_antennas,
                     layout=layout, walk_frames=walk_frames,
                     seed=seed)
    write_json_with_numpy(out / "stage1.json", {"stage1_dir": str(stage1_dir.resolve())})
    s = Trainer(stage3_config(mcfg, seed=seed), data, out / "train", quiet=quiet,
                field_factory=lambda tr, rng: start).run()
    return {"train_time_s": s1["train_time_s"] + s["train_time_s"], "steps": s1["steps"] + s["steps"],
            "stage1_train_time_s": s1["train_time_s"], "val_ssim": s["val_ssim"], "stage1_val_ssim": s1["val_ssim"],
            "runs": [str(stage1_dir), str(out / "train")]}


def train_method(name: str, dataset: str | Path, out: str | Path, *, mcfg: MethodConfig, seed: int = 0,
                 noise_snr_db: float | None = None, train_antennas: int = 0, layout: str = "random",
                 walk_frames: int | None = None, stage1_dir: str | Path | None = None,
                 ours_dir: str | Path | None = None, quiet: bool = True) -> dict:
    """Train method ``name`` on ``dataset`` into folder ``out`` (resumable).

    Args:
        name: a key of :data:`METHODS`.
        dataset: dataset folder.
        out: job folder; single-field methods train into ``out/train`` (Continued from the
            field of ``stage1_dir``), Ours into ``out/stage2`` on top of ``stage1_dir`` (default for
            both: trains its own Baseline into ``out/stage1_job``).
        mcfg: sizes; seed: training (and noise) seed; noise_snr_db: noise on the training data;
        train_antennas: number of training antenna positions (0 = all); layout: how they are
        drawn ("random" or "grid"); walk_frames: train on the first this many walk positions only
        (None = the whole walk): :meth:`rfmitsuba.data.samples.SampleData.open_samples`.
        ours_dir: Stage 3 ("refined") starts from this finished Ours job folder (default: trains
            its own ``out/ours_job``).
        quiet: no progress bars.

    Returns:
        {"train_time_s": total training wall time (Stage 1 included for Ours and Continued), "steps": total
        steps, "val_ssim": final validation SSIM of the last stage, "runs": [run folders]}.
    """
    m = get_method(name)
    out = Path(out)
    if m.builds_on == "ours":
        if mcfg.stage1.model != "coherent_gaussians":   # refused before any folder is made
            raise ConfigError(f"method {name!r} (Stage 3) needs model 'coherent_gaussians', not "
                              f"{mcfg.stage1.model!r}: only that family trains its background and person together")
        out.mkdir(parents=True, exist_ok=True)
        return _train_stage3(dataset, out, mcfg=mcfg, seed=seed, noise_snr_db=noise_snr_db,
                             train_antennas=train_antennas,
                             layout=layout, walk_frames=walk_frames, ours_dir=ours_dir, quiet=quiet)
    out.mkdir(parents=True, exist_ok=True)
    if m.builds_on == "baseline" and not m.two_stage:
        return _train_continued(dataset, out, mcfg=mcfg, seed=seed, noise_snr_db=noise_snr_db,
                                train_antennas=train_antennas,
                                layout=layout, walk_frames=walk_frames, stage1_dir=stage1_dir, quiet=quiet)
    if not m.two_stage:
        data = open_data(dataset, m, noise_snr_db=noise_snr_db, train_antennas=train_antennas,
                         layout=layout, walk_frames=walk_frames, seed=seed)
        cfg = stage1_config(mcfg, m, seed=seed)
        kw = {}
        if m.person_input and cfg.model == "coherent_gaussians":
            factory, width, feats = joint_field(mcfg)
            kw = {"extra": lambda idx: feats(data, idx), "extra_inputs": width, "field_factory": factory}
        elif m.person_input:
            nf = num_person_features(mcfg.person.person_octaves)
            kw = {"extra": lambda idx: data.features(idx, octaves=mcfg.person.person_octaves), "extra_inputs": nf}
        s = Trainer(cfg, data, out / "train", quiet=quiet, **kw).run()
        return {"train_time_s": s["train_time_s"], "steps": s["steps"], "val_ssim": s["val_ssim"],
                "runs": [str(out / "train")]}
    stage1_dir, s1 = _baseline_run(dataset, out, mcfg=mcfg, seed=seed, noise_snr_db=noise_snr_db,
                                   train_antennas=train_antennas,
                                   layout=layout, walk_frames=walk_frames, stage1_dir=stage1_dir, quiet=quiet)
    bg = load_field(stage1_dir / "final" / "field.npz")
    bg.freeze()
    data = open_data(dataset, m, noise_snr_db=noise_snr_db, train_antennas=train_antennas,
                     layout=layout, walk_frames=walk_frames, seed=seed)
    cfg2 = stage2_config(mcfg, seed=seed)
    kind, pcfg = person_field(mcfg, bg)
    person_cls = field_class(kind)
    write_json_with_numpy(out / "stage1.json", {"stage1_dir": str(stage1_dir.resolve())})
    if name == "ours_people":
        people = int(np.asarray(data.people_pos).shape[1]) if data.people_pos is not None else 1
        if kind != "coherent_gaussians_person":
            raise ConfigError(f"Ours (every person) needs the coherent Gaussian family (stage1.model = "
                              f"'coherent_gaussians'), got the {kind!r} person field")
        pcfg = dataclasses.replace(pcfg, people=people)
    if name == "ours_untracked":
        s2 = _train_untracked(data, bg, out, mcfg=mcfg, cfg2=cfg2, person_cls=person_cls, pcfg=pcfg, seed=seed,
                              quiet=quiet)
    else:
        s2 = _stage2_trainer(cfg2, data, out / "stage2", bg=bg, person_cls=person_cls, pcfg=pcfg, seed=seed,
                             quiet=quiet).run()
    return {"train_time_s": s1["train_time_s"] + s2["train_time_s"], "steps": s1["steps"] + s2["steps"],
            "stage1_train_time_s": s1["train_time_s"], "val_ssim": s2["val_ssim"],
            "stage1_val_ssim": s1["val_ssim"], "runs": [str(stage1_dir), str(out / "stage2")],
            **{k: s2[k] for k in ("walk", "walk_round", "walk_rounds", "walk_search_s") if k in s2}}


def _stage2_trainer(cfg2: TrainConfig, data: SampleData, folder: Path, *, bg, person_cls, pcfg, seed: int,
                    quiet: bool) -> Trainer:
    """The Stage-2 trainer of a two-stage method: a fresh ``person_cls`` field of ``pcfg`` (one
    or ``pcfg.people`` people) on the frozen background ``bg``, trained on ``data``'s person
    features and positions into ``folder``; its walk is ``data``'s training person positions."""
    people = getattr(pcfg, "people", 1)
    walk = np.unique(data.person_pos[data.train], axis=0)
    oct_ = pcfg.person_octaves

    def factory(tr, rng):
        return person_cls.for_background(bg, cfg=pcfg, walk=walk, rng=rng, seed=seed, name="person")

    return Trainer(cfg2, data, folder, frozen=[bg], quiet=quiet, name="person",
                   extra=lambda idx: data.features(idx, octaves=oct_, raw=True, people=people),
                   extra_inputs=num_person_features(oct_) + 3 * people, field_factory=factory)


def _train_untracked(data: SampleData, bg, out: Path, *, mcfg: MethodConfig, cfg2: TrainConfig, person_cls,
                     pcfg, seed: int, quiet: bool) -> dict:
    """Stage 2 of Ours (no tracker): rounds of walk search and Stage-2 training into
    ``out/stage2_round<r>`` (:mod:`rfmitsuba.experiments.walk_search`); the round of the best
    validation SSIM is copied to ``out/stage2`` (the model), the walks are ``out/walk.json``. Returns the last Stage-2 summary, its training time the rounds' and the
    searches' sum (``walk_search_s`` the searches'), with
    ``walk``: the chosen round's (``walk_round``) walk error against the dataset's person positions [cm]
    (a report only)."""
    from ..eval.locate import TwoStage
    from . import walk_search as W

    wcfg = mcfg.walk_search
    if bg.family != "coherent_gaussians" or person_cls.kind != "coherent_gaussians_person":
        raise ConfigError(f"Ours (no tracker) needs the coherent Gaussian family (stage1.model = "
                          f"'coherent_gaussians'), got {bg.family!r}")
    frames = W.training_frames(data)
    region = W.search_region(data)
    interval = W.frame_interval_s(data)
    centre = region.feet(0.5 * (region.lo + region.hi)[None])
    walk_data = W.with_walk(data, frames, np.repeat(centre, len(frames), axis=0))
    person = person_cls.for_background(bg, cfg=dataclasses.replace(pcfg, init_strength=wcfg.search_strength,
                                                                    init_gain=0.0), seed=seed, name="person")
    person.freeze()
    rounds, summaries, total_s, search_s = [], [], 0.0, 0.0
    for r in range(wcfg.rounds):
        model = TwoStage(background=bg, person=person, data=walk_data, feet_z=region.z, walk=centre, job=out)
        t0 = time.perf_counter()
        found = W.search_walk(model, frames, wcfg, interval_s=interval, region=region, quiet=quiet)
        search_s += time.perf_counter() - t0
        walk_data = W.with_walk(data, frames, found["positions"])
        rounds.append({**found, "error": W.walk_error(data, frames, found["positions"])})
        W.write_walk(out / "walk.json", rounds, frames)
        folder = out / f"stage2_round{r}"
        summaries.append(_stage2_trainer(cfg2, walk_data, folder, bg=bg, person_cls=person_cls, pcfg=pcfg, seed=seed,
                                         quiet=quiet).run())
        total_s += summaries[-1]["train_time_s"]
        person = load_field(folder / "final" / "field.npz")
        person.freeze()
    # the round whose field draws its own walk's validation PAS best is the model (no position
    # is read: the validation PAS are training frames at their estimated positions)
    best = int(np.argmax([s["val_ssim"] for s in summaries]))
    if not (out / "stage2" / "final" / "field.npz").is_file():
        if (out / "stage2").exists():
            shutil.rmtree(out / "stage2")                     # a copy cut short
        shutil.copytree(out / f"stage2_round{best}", out / "stage2")
    return {**summaries[best], "train_time_s": total_s + search_s, "walk_search_s": search_s,
            "walk": rounds[best]["error"], "walk_round": best, "walk_rounds": [x["error"] for x in rounds]}


def load_model(name: str, job_dir: str | Path, *, octaves: int = 3) -> FieldSet:
    """The trained model of method ``name`` in job folder ``job_dir``: a
    :class:`~rfmitsuba.models.base.FieldSet` (the background, then the person field of a
    two-stage method). ``octaves``: the person-feature octaves of the End-to-End model."""
    m = get_method(name)
    jd = Path(job_dir)
    if not m.two_stage:
        f = load_field(jd / ("stage3" if m.builds_on == "ours" else "train") / "final" / "field.npz")
        f.freeze()
        return FieldSet([f], octaves=octaves)
    info = json.loads((jd / "stage1.json").read_text()) if (jd / "stage1.json").is_file() else None
    if info is None:
        raise RunError(f"{jd}: no stage1.json; the two-stage job has not run")
    bg = load_field(Path(info["stage1_dir"]) / "final" / "field.npz")
    bg.freeze()
    hf = load_field(jd / "stage2" / "final" / "field.npz")
    hf.freeze()
    return FieldSet([bg, hf], octaves=octaves)


#: the folder of an experiment (``compare``, ``reproduce``) where :func:`run_job`'s evaluations keep
#: the floors they share (:mod:`rfmitsuba.eval.floor_cache`)
FLOORS_FOLDER = "floors"


def run_job(name: str, dataset: str | Path, job_dir: str | Path, *, mcfg: MethodConfig, seed: int, record: dict,
            noise_snr_db: float | None = None, train_antennas: int = 0, layout: str = "random",
            walk_frames: int | None = None, stage1_dir: str | Path | None = None,
            ours_dir: str | Path | None = None, reevaluate: bool = False, quiet: bool = True,
            eval_dataset: str | Path | None = None, floors_cache: str | Path | None = None) -> dict:
    """Train method ``name`` into ``job_dir``, evaluate it (on ``eval_dataset``, default
    ``dataset``), and mark the job done; or return the metrics of a job done before.

    The job folder holds the training runs (:func:`train_method`), ``metrics.json`` (written
    atomically) and then the ``DONE`` marker: a job with a marker is not trained again, so a
    killed caller (:mod:`rfmitsuba.experiments.compare`, :mod:`rfmitsuba.experiments.reproduce`) resumes where it stopped.

    Args:
        name, dataset, mcfg, seed, noise_snr_db, train_antennas, layout, walk_frames, stage1_dir, ours_dir:
            as :func:`train_method`; the evaluation's floors look up the same training samples.
        job_dir: the job folder.
        record: what the caller files the job under (merged into the metrics).
        reevaluate: a finished job is evaluated again (its training kept, ``metrics.json``
            rewritten), for when the evaluation changed.
        quiet: no progress bars.
        floors_cache: folder of the evaluation floors shared by the jobs of one experiment
            (:mod:`rfmitsuba.eval.floor_cache`); None computes them for this job.

    Returns:
        ``record`` plus {"train": :func:`train_method`'s summary, "eval": :func:`evaluate`'s
        result, "wall_s": training + evaluation wall time in seconds}.
    """
    jd = Path(job_dir)
    # the floors look up what the model trained on (on another dataset: its whole training split)
    chosen = ({} if eval_dataset is not None else
              {"train_antennas": train_antennas, "layout": layout, "walk_frames": walk_frames})
    if (jd / "DONE").is_file():
        # a job finished before a name changed reads under today's names (rfmitsuba.core.legacy_names)
        metrics = {**current_keys(json.loads((jd / "metrics.json").read_text())), **record}
        if reevaluate:
            metrics["eval"] = evaluate(load_model(name, jd, octaves=mcfg.person.person_octaves), eval_dataset or dataset,
                                       noise_snr_db=noise_snr_db, noise_seed=seed, floors_cache=floors_cache,
                                       **chosen)
            write_json_with_numpy(jd / "metrics.json", metrics)
        return metrics
    t0 = time.perf_counter()
    tr = train_method(name, dataset, jd, mcfg=mcfg, seed=seed, noise_snr_db=noise_snr_db,
                      train_antennas=train_antennas,
                      layout=layout, walk_frames=walk_frames, stage1_dir=stage1_dir, ours_dir=ours_dir, quiet=quiet)
    ev = evaluate(load_model(name, jd, octaves=mcfg.person.person_octaves), eval_dataset or dataset,
                  noise_snr_db=noise_snr_db, noise_seed=seed, floors_cache=floors_cache, **chosen)
    metrics = {**record, "train": tr, "eval": ev, "wall_s": time.perf_counter() - t0}
    write_json_with_numpy(jd / "metrics.json", metrics)
    (jd / "DONE").write_text("done\n")
    return metrics




def config_dict(mcfg: MethodConfig) -> dict:
    """Plain dict of a :class:`MethodConfig`."""
    return C.to_dict(mcfg)
