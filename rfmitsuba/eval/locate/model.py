"""The two-stage model opened for localisation: a frozen Stage-1 background and its Stage-2
person field, with the dataset they trained on (:class:`TwoStage`), and the Ours jobs of a run."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import DatasetError, RunError
from ...data.samples import SampleData, person_features
from ...models.base import Field, load_field


@dataclass
class TwoStage:
    """A trained two-stage model opened for localisation.

    background: the frozen Stage-1 field; person: the frozen Stage-2 person field
    (``Field.person``); data: the dataset the job trained on, as samples of every state
    (:class:`~rfmitsuba.data.samples.SampleData`); feet_z: the feet height [m] of the training
    walk (median); walk: float64 [H, 3] the training walk's feet positions [m]; job: the job folder.
    """

    background: Field
    person: Field
    data: SampleData
    feet_z: float
    walk: np.ndarray
    job: Path

    @property
    def differentiable(self) -> bool:
        """The person field's channels are differentiable in the person's position (AD descent)."""
        return hasattr(self.person, "channels_at") and self.background.family == "coherent_gaussians"

    def features(self, feet: np.ndarray) -> np.ndarray:
        """The person field's extra inputs for feet positions float [N, 3] m: float32 [N, F + 3]
        (features of :func:`~rfmitsuba.data.samples.person_features` on the training box, then the
        position), as :meth:`~rfmitsuba.data.samples.SampleData.features` gives them in training."""
        h = np.asarray(feet, np.float64).reshape(-1, 3)
        f = person_features(h, self.data.box, octaves=self.person.feature_octaves)
        return np.concatenate([f, h.astype(np.float32)], axis=1)


def open_two_stage(job: str | Path) -> TwoStage:
    """Open an Ours job folder (``stage1.json`` naming its Stage-1 run, ``stage2/final/field.npz``).

    Raises:
        RunError: not a two-stage job (a Stage-1 run, another method's job, an unfinished job,
            a Stage-2 field that is not a person field, or a dataset that is gone).
    """
    jd = Path(job)
    if not (jd / "stage1.json").is_file():
        _refuse(jd)
    s2 = jd / "stage2"
    if not (s2 / "final" / "field.npz").is_file() or not (s2 / "run.json").is_file():
        raise RunError(f"{jd}: Stage 2 has not finished (no stage2/final/field.npz); run the comparison again to "
                       "finish it")
    try:
        stage1 = Path(json.loads((jd / "stage1.json").read_text())["stage1_dir"])
        dataset = Path(json.loads((s2 / "run.json").read_text())["dataset"])
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise RunError(f"{jd}: stage1.json or stage2/run.json is malformed ({type(e).__name__}: {e})") from None
    person = load_field(s2 / "final" / "field.npz")
    if not person.person:
        raise RunError(f"{jd}: the Stage-2 field is a {type(person).__name__}, not a person field")
    background = load_field(stage1 / "final" / "field.npz")
    background.freeze()
    person.freeze()
    if not dataset.is_dir():
        raise RunError(f"{jd}: its dataset {dataset} does not exist any more")
    data = SampleData.open_samples(dataset, states="all")
    walk = data.person_pos[np.isin(data.states, np.asarray(data.split.person_train) + 1) & (data.antennas == 0)]
    if len(walk) == 0:
        raise DatasetError(f"{dataset}: no training walk positions")
    return TwoStage(background=background, person=person, data=data, feet_z=float(np.median(walk[:, 2])),
                    walk=walk, job=jd)


def _refuse(jd: Path) -> None:
    """RunError: ``jd`` is not a two-stage job, naming what it is."""
    what = ("a single-field run (config.toml, no stage1.json)" if (jd / "config.toml").is_file()
            else "another method's job (train/, no stage1.json)" if (jd / "train").is_dir() else "not a job folder")
    raise RunError(f"{jd} is not a two-stage job: {what}; localisation needs an Ours job (a Stage-2 person "
                   "field on a frozen Stage-1 background), e.g. COMPARE/seed0/ours of `rfmitsuba compare "
                   "--methods baseline,ours`")


def job_folders(run: str | Path) -> list[tuple[str, Path]]:
    """The Ours jobs of ``run``: (label, folder) of the job itself (label its folder name), of a
    comparison's ``seed<k>/ours`` (label ``seed<k>``), or of a demo folder's ``ours``.

    Raises:
        RunError: none found, naming what was looked for.
    """
    r = Path(run)
    if not r.is_dir():
        raise RunError(f"{r} does not exist")
    if (r / "stage1.json").is_file() or (r / "stage2").is_dir():
        return [(r.name, r)]
    seeds = sorted((p for p in r.glob("seed*/ours") if (p / "stage1.json").is_file()),
                   key=lambda p: int(p.parent.name[4:]) if p.parent.name[4:].isdigit() else 0)
    if seeds:
        return [(p.parent.name, p) for p in seeds]
    if (r / "ours" / "stage1.json").is_file():
        return [("ours", r / "ours")]
    if (r / "config.toml").is_file() or (r / "train").is_dir():
        _refuse(r)
    raise RunError(f"{r} holds no two-stage job (stage1.json; seed<k>/ours/ of a comparison; ours/ of a demo): "
                   "train one with `rfmitsuba compare DATASET --methods baseline,ours`, then locate with it")
