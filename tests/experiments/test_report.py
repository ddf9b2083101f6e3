"""rfmitsuba.experiments.report: the model line says at which resolution each family trains."""
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
