"""rfmitsuba.experiments.walk_search: Stage 2 without a tracker (the walk from frame order alone)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError


def test_best_walk_without_a_step_bound_takes_each_frames_lowest_loss():
    from rfmitsuba.experiments.walk_search import best_walk

    grid = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    losses = np.array([[0.0, 1, 2, 3], [3, 2, 1, 0.0], [0.0, 1, 1, 1]])
    assert best_walk(losses, grid, None).tolist() == [0, 3, 0]


def test_best_walk_keeps_every_step_within_its_bound_and_finds_the_cheapest_such_walk():
    """Frame 1's lowest loss is 3 m away from frame 0's; with 1.2 m steps the walk must go
    through its neighbours, and among the walks within the bound it is the cheapest (checked
    against every walk)."""
    import itertools

    from rfmitsuba.experiments.walk_search import best_walk

    rng = np.random.default_rng(0)
    grid = np.stack([np.arange(5.0), np.zeros(5)], 1)
    losses = rng.random((4, 5))
    losses[0, 0], losses[1, 4] = -5.0, -5.0
    bound = np.array([1.2, 1.2, 1.2])
    path = best_walk(losses, grid, bound)
    assert np.all(np.abs(np.diff(grid[path, 0])) <= 1.2)
    z = (losses - losses.mean(1, keepdims=True)) / losses.std(1, keepdims=True)
    best = min((sum(z[t, p[t]] for t in range(4)), p) for p in itertools.product(range(5), repeat=4)
               if all(abs(p[t + 1] - p[t]) <= 1 for t in range(3)))
    assert tuple(path) == best[1]
    assert best_walk(losses, grid, None)[1] == 4            # free steps jump there


def test_config_errors_name_the_option():
    from rfmitsuba.experiments.walk_search import WalkSearchConfig

    for bad in ({"rounds": 0}, {"views": 0}, {"grid_m": 0.0}, {"max_speed_mps": -1.0}, {"search_strength": 1.0},
                {"descent_steps": -1}):
        with pytest.raises(ConfigError, match="WalkSearchConfig"):
            WalkSearchConfig(**bad)


def test_with_walk_holds_the_estimates_and_no_stated_position(quick_dataset):
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.experiments.walk_search import frame_interval_s, training_frames, with_walk

    data = SampleData.open_samples(quick_dataset.path, states="person")
    frames = training_frames(data)
    assert len(frames) and np.all(np.diff(frames) > 0)
    est = np.tile([1.0, 1.5, 0.0], (len(frames), 1)) + np.arange(len(frames))[:, None] * [0.1, 0.0, 0.0]
    d = with_walk(data, frames, est)
    for h, p in zip(frames, est):
        assert np.all(d.person_pos[d.states == h + 1] == p)
    others = (d.states > 0) & ~np.isin(d.states, frames + 1)
    assert np.isnan(d.person_pos[others]).all()
    assert np.array_equal(data.person_pos, SampleData.open_samples(quick_dataset.path, states="person").person_pos)
    # a generated dataset states its walk's frame interval: 4 positions over 60 * 4 / 35 s
    assert frame_interval_s(data) == pytest.approx(60.0 * 4 / 35 / 3)


def test_the_search_reads_no_stated_person_position(quick_dataset):
    """The walk found with the dataset's person positions moved 100 m away is the same walk: the
    search sees the PAS, the antennas and the frame order only."""
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.eval.locate import TwoStage
    from rfmitsuba.experiments import walk_search as W
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.models.coherent_gaussians_person import CoherentGaussianPersonConfig, CoherentGaussianPersonField

    data = SampleData.open_samples(quick_dataset.path, states="person")
    A = np.stack([np.eye(3)])
    bg = CoherentGaussianField(A, np.array([0]), np.array([[1.0, 2.0, 1.0]]), cfg=CoherentGaussianConfig(),
                               readout="amplitude",
                               wavefront="plane", vis_center=np.array([2.0, 1.5, 1.0]), frequency_hz=data.frequency_hz)
    bg.freeze()
    person = CoherentGaussianPersonField.for_background(bg, cfg=CoherentGaussianPersonConfig(init_strength=0.9,
                                                                                             init_gain=0.0))
    person.freeze()
    frames = W.training_frames(data)
    region = W.search_region(data)
    cfg = W.WalkSearchConfig(grid_m=0.5, views=4, descent_steps=2)
    found = []
    for shift in (0.0, 100.0):
        moved = W.with_walk(data, frames, np.zeros((len(frames), 3)))
        moved.person_pos = data.person_pos + shift           # what a search that read them would see
        model = TwoStage(background=bg, person=person, data=moved, feet_z=region.z, walk=np.zeros((1, 3)),
                         job=quick_dataset.path)
        found.append(W.search_walk(model, frames, cfg, interval_s=W.frame_interval_s(data), region=region))
    np.testing.assert_array_equal(found[0]["positions"], found[1]["positions"])
    assert region.free(found[0]["positions"][:, :2]).all()
    err = W.walk_error(data, frames, found[0]["positions"])
    assert err["frames"] == len(frames) and err["median_cm"] >= 0


def test_ours_untracked_trains_on_its_own_walk_and_reports_its_error(quick_dataset, tmp_path):
    """The method end to end in a comparison: every round writes its walk, the job's metrics carry
    the walk's error, and the trained model is evaluated like Ours."""
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.compare import CompareConfig, compare

    cfg = C.override(CompareConfig(), ["methods=['ours_untracked']", "seeds=[0]", "train.stage1_iterations=8",
                                       "train.val_every=8", "train.stage2_iterations=6",
                                       "train.overrides=['walk_search.grid_m=0.6', 'walk_search.views=3', "
                                       "'walk_search.descent_steps=1', 'walk_search.rounds=2']"])
    compare(quick_dataset.path, tmp_path / "cmp", cfg=cfg, progress=False)
    job = tmp_path / "cmp" / "seed0" / "ours_untracked"
    walk = json.loads((job / "walk.json").read_text())
    assert len(walk["rounds"]) == 2 and all((job / f"stage2_round{r}" / "final" / "field.npz").is_file() for r in (0, 1))
    m = json.loads((job / "metrics.json").read_text())
    assert set(m["train"]["walk"]) == {"median_cm", "p90_cm", "mean_cm", "frames"}
    # the model is the round of the best validation SSIM, copied to stage2
    r = m["train"]["walk_round"]
    vals = [json.loads((job / f"stage2_round{k}" / "final" / "summary.json").read_text())["val_ssim"] for k in (0, 1)]
    assert r == int(np.argmax(vals)) and m["train"]["walk"] == walk["rounds"][r]["error"]
    assert (job / "stage2" / "final" / "field.npz").read_bytes() == \
        (job / f"stage2_round{r}" / "final" / "field.npz").read_bytes()
    assert len(m["train"]["walk_rounds"]) == 2 and m["train"]["walk_search_s"] > 0
    assert np.isfinite(m["eval"]["dynamic"]["model"]["mean"])
    report = (tmp_path / "cmp" / "report.md").read_text()
    assert "Ours (no tracker)" in report


def test_the_walks_error_on_a_walk_of_two_people_also_counts_the_nearer_person(two_people_dataset):
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.experiments.walk_search import training_frames, walk_error

    data = SampleData.open_samples(two_people_dataset.path, states="person")
    frames = training_frames(data)
    second = np.asarray(two_people_dataset.people_pos)[frames + 1, 1]
    err = walk_error(data, frames, second)
    assert err["nearest_person_median_cm"] == 0.0 and err["median_cm"] > 50.0
