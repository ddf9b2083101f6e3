"""rfmitsuba.experiments.report: the header says at which resolution each family trains and how many
ray samples the datasets were traced with, and their sizes."""
from __future__ import annotations

from rfmitsuba.experiments.report import _model_line
from rfmitsuba.experiments.sizes import size_config


def test_model_line_names_the_training_resolution_of_each_family():
    full = size_config("full")
    assert full.train.model == "coherent_gaussians"
    line = _model_line(full)
    assert "training images 45x180 (block means), validation at 90x360" in line, line
    full.train.model = "splat"
    assert "training images 45x180" in _model_line(full)       # the size's own downsample, 2
    full.train.model = "coherent"
    assert "training images 90x360" in _model_line(full)


def test_header_states_the_ray_samples_per_source():
    from rfmitsuba.experiments.report import _ray_samples

    full = size_config("full")
    assert _ray_samples(full) == ", 0.25 x each room's default ray samples per source"
    full.data.samples_per_src = 25000
    assert _ray_samples(full) == ", 25000 ray samples per source in every room"
    full.data.samples_per_src, full.data.samples_scale = 0, 1.0
    assert _ray_samples(full) == ", each room's default ray samples per source"
    assert _ray_samples(size_config("tiny")) == ""          # synthetic data: no rays


def test_header_states_the_datasets_each_table_uses():
    from rfmitsuba.experiments.report import _dataset_sizes

    full = size_config("full")
    # the main tables' walk datasets and the Rx-count table's empty-room datasets
    assert _dataset_sizes(full) == "900 antenna positions x (1 + 35) states; 7500 antenna positions x 1 state"
    # the data-scarce table alone: one long walk per room and task
    full.tables, full.walk_lengths = ["data_scarce"], [0, 35, 280]
    assert _dataset_sizes(full) == "900 antenna positions x (1 + 280) states"
