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


def _job(method, seed, *, snr="none", dyn, stat, floors, noisy=None):
    """A finished job's metrics as the report reads them: floors {part: (NN, IDW-3)}."""
    def part(p):
        d = {"model": {"mean": {"dynamic": dyn, "static": stat}[p]},
             "nearest_neighbour": {"mean": floors[p][0]}, "idw3": {"mean": floors[p][1]}}
        if noisy:
            d["floors_noisy_training"] = {"nearest_neighbour": {"mean": noisy[p][0]}, "idw3": {"mean": noisy[p][1]}}
        return d
    return {"job": {"dataset": "bedroom_rx_tissue", "method": method, "seed": seed, "snr_db": snr, "positions": 0},
            "eval": {"dynamic": part("dynamic"), "static": part("static")}}


def test_where_methods_break_names_each_floor_missed():
    """A result below IDW-3 alone is listed (it was not: the section knew nearest neighbour only), one
    below both names both, one above both is not; with training noise the floors are those of the
    same noisy training data; a result equal to a floor at three digits is printed with more."""
    from rfmitsuba.experiments.report import where_methods_break

    fl = {"dynamic": (0.70, 0.75), "static": (0.72, 0.78)}
    results = {
        "a/0": _job("baseline", 0, dyn=0.73, stat=0.80, floors=fl),             # dynamic below IDW-3 only
        "b/0": _job("ours", 0, dyn=0.80, stat=0.71, floors=fl),                 # static below both
        "c/0": _job("end_to_end", 0, dyn=0.80, stat=0.79, floors=fl),           # above both
        "d/0": _job("baseline", 0, snr=10.0, dyn=0.66, stat=0.70, floors=fl,    # clean floors would list it
                    noisy={"dynamic": (0.60, 0.65), "static": (0.68, 0.70004)}),
    }
    text = "\n".join(where_methods_break(results))
    assert "- Baseline, bedroom_rx_tissue: dynamic 0.730 < IDW-3 0.750\n" in text + "\n"
    assert "- Ours (two-stage), bedroom_rx_tissue: static 0.710 < IDW-3 0.780, NN 0.720" in text
    assert "End-to-End" not in text
    noisy = [line for line in text.splitlines() if "SNR 10 dB" in line]
    assert noisy == ["- Baseline, bedroom_rx_tissue, SNR 10 dB: static 0.70000 < IDW-3 0.70004 "
                     "(floors on the same noisy training data)"]
    assert "checks the pipeline" not in text                                 # 1 of 8 below NN
    assert where_methods_break({"c/0": results["c/0"]})[4].startswith("- none: every method beats")


def test_where_methods_break_says_when_most_results_are_below_nearest_neighbour():
    """More than half of the results below the NN floor: the section says the report checks the
    pipeline, counting each (configuration, part) once."""
    from rfmitsuba.experiments.report import where_methods_break

    fl = {"dynamic": (0.9, 0.95), "static": (0.9, 0.95)}
    results = {f"{m}/0": _job(m, 0, dyn=0.5, stat=0.5, floors=fl) for m in ("baseline", "ours")}
    results["end_to_end/0"] = _job("end_to_end", 0, dyn=0.99, stat=0.99, floors=fl)
    text = "\n".join(where_methods_break(results))
    assert "**4 of 6 results are below the nearest-neighbour floor: at this size the report checks the pipeline" in text
