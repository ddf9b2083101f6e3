"""rfmitsuba.experiments.curves: seeds on a common time grid, time to within 0.005 of the final
SSIM, cumulative time over stages, the figure and table of the reports."""
from __future__ import annotations

import json

import numpy as np
import pytest


def test_time_to_within_on_hand_made_curves():
    from rfmitsuba.experiments.curves import time_to_within

    t = [1.0, 2.0, 3.0, 4.0, 5.0]
    # final 0.9: from t=3 on every sample is >= 0.895
    assert time_to_within(t, [0.5, 0.8, 0.896, 0.897, 0.9]) == 3.0
    # it enters the band at t=3 but drops out again at t=4: it stays only from t=5
    assert time_to_within(t, [0.5, 0.8, 0.896, 0.893, 0.9]) == 5.0
    # above the final value counts as within (a curve that falls is done at once)
    assert time_to_within(t[:2], [0.9, 0.8]) == 1.0
    assert time_to_within(t, [0.5, 0.6, 0.7, 0.8, 0.9], tol=0.15) == 4.0


def test_on_grid_interpolates_and_holds_a_finished_seed():
    from rfmitsuba.experiments.curves import on_grid

    a = (np.array([0.0, 10.0]), np.array([0.0, 1.0]))
    b = (np.array([0.0, 5.0]), np.array([0.2, 0.4]))  # finished at t=5: held at 0.4 afterwards
    g = on_grid([a, b], n=11)
    np.testing.assert_allclose(g["t"], np.arange(11.0))
    assert g["mean"][5] == pytest.approx(0.45) and g["mean"][10] == pytest.approx(0.7)
    assert g["min"][10] == pytest.approx(0.4) and g["max"][10] == pytest.approx(1.0)
    assert g["mean"][2] == pytest.approx((0.2 + 0.28) / 2)
    # the grid starts where every seed has a sample
    g = on_grid([(np.array([2.0, 10.0]), np.array([0.0, 1.0])), b], n=9)
    assert g["t"][0] == 2.0 and g["t"][-1] == 10.0 and g["values"].shape == (2, 9)


def _run(folder, rows, train_time_s):
    (folder / "final").mkdir(parents=True)
    (folder / "final" / "summary.json").write_text(json.dumps({"train_time_s": train_time_s}))
    lines = [{"step": 10 * (i + 1), "loss": 0.1, "time_s": t, "val_ssim": s} for i, (t, s) in enumerate(rows)]
    lines.insert(1, {"step": 15, "loss": 0.1, "time_s": 0.1})  # a loss-only row
    (folder / "log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    return str(folder)


def _result(runs, test=0.8):
    floors = {"model": {"mean": test}, "nearest_neighbour": {"mean": 0.7}, "mean_image": {"mean": 0.5}}
    return {"train": {"runs": runs}, "eval": {"dynamic": floors}}


def test_two_stage_curve_is_on_cumulative_time(tmp_path):
    from rfmitsuba.experiments.curves import job_curve

    s1 = _run(tmp_path / "s1", [(5.0, 0.80), (10.0, 0.90)], 10.0)
    s2 = _run(tmp_path / "s2", [(2.0, 0.70), (4.0, 0.75)], 4.5)
    c = job_curve("ours", 0, _result([s1, s2]))
    np.testing.assert_allclose(c.t, [5, 10, 12, 14])
    np.testing.assert_allclose(c.ssim, [0.8, 0.9, 0.7, 0.75])
    assert c.stage_ends == [10.0, 14.5] and c.nn == 0.7 and c.mean_image == 0.5
    t, _ = c.last_stage()
    np.testing.assert_allclose(t, [12, 14])
    assert job_curve("ours", 0, _result([s1, str(tmp_path / "gone")])) is None


def test_speed_accuracy_figure_and_table(tmp_path):
    from rfmitsuba.experiments.curves import speed_accuracy

    b0 = _run(tmp_path / "b0", [(5.0, 0.80), (10.0, 0.90)], 10.0)
    b1 = _run(tmp_path / "b1", [(4.0, 0.897), (8.0, 0.90)], 8.0)
    o0 = _run(tmp_path / "o0", [(2.0, 0.70), (4.0, 0.75)], 4.5)
    jobs = [("baseline", 0, _result([b0])), ("baseline", 1, _result([b1])), ("ours", 0, _result([b0, o0])),
            ("ours", 1, _result([b1, str(tmp_path / "gone")]))]
    lines = speed_accuracy(tmp_path / "sa.png", {"bedroom": jobs})
    assert (tmp_path / "sa.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = "\n".join(lines)
    assert "![validation SSIM against cumulative training time](sa.png)" in text
    assert "validation SSIM on held-out views of the training split" in text and "1 job(s) left out" in text
    # Baseline: within 0.005 at t=10 (seed 0) and t=4 (seed 1); Ours: Stage 2 within at 14 s cumulative
    assert "| bedroom | Baseline | 2 | 0.900 ± 0.000 | 7.0 ± 4.2 | 9.0 ± 1.4 | 0.800 ± 0.000 |" in text
    assert "| bedroom | Ours (two-stage) | 1 | 0.750 ± 0.000 | 14.0 ± 0.0 | 14.5 ± 0.0 | 0.800 ± 0.000 |" in text


def test_speed_accuracy_with_nothing_to_draw_says_so_and_writes_no_figure(tmp_path):
    """No jobs (a selection of data-scarce cells alone), or none with a training log: no blank
    figure, no empty table; a figure of an earlier report at the path is removed."""
    from rfmitsuba.experiments.curves import speed_accuracy

    png = tmp_path / "sa.png"
    png.write_bytes(b"stale")
    assert speed_accuracy(png, {}) == ["None in this selection: no curve to draw.", ""]
    assert not png.exists()
    lines = speed_accuracy(png, {"bedroom": [("baseline", 0, _result([str(tmp_path / "gone")]))]})
    assert "all 1 job(s) were not found" in lines[0] and not png.exists()
    assert not any(line.startswith("| runs |") for line in lines)
