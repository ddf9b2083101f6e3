"""Tests of rfmitsuba.core.plots: report figures are written without touching pyplot's state."""
import matplotlib

from rfmitsuba.core import plots


def test_save_writes_png_and_leaves_backend_and_pyplot_alone(tmp_path):
    import matplotlib.pyplot as plt

    backend = matplotlib.get_backend()
    open_before = plt.get_fignums()
    fig, ax = plots.subplots(figsize=(3, 2))
    ax.plot([0, 1], [0, 1], label="line")
    plots.label(ax, xlabel="x", ylabel="y")
    path = plots.save(fig, tmp_path / "f.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert ax.get_xlabel() == "x" and ax.get_legend() is not None
    assert matplotlib.get_backend() == backend
    assert plt.get_fignums() == open_before          # nothing registered, nothing left open


def test_subplots_passes_options():
    fig, axes = plots.subplots(2, 3, figsize=(6, 4), squeeze=False)
    assert axes.shape == (2, 3)
