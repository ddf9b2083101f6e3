"""rfmitsuba.eval.folder_profile: floors on two splits, co-array fit, line of sight, SSIM by distance."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def _folder(tmp_path, *, nuisance: float):
    """A NeRF2 folder of 60 tags 5 m from a horizontal 4 x 4 gateway: each spectrum the amplitude
    Bartlett image of the line-of-sight plane wave plus one fixed reflection, times per-tag random
    complex element gains of spread ``nuisance`` (0: none)."""
    from rfmitsuba.data import nerf2
    from rfmitsuba.data.split import make_split
    from rfmitsuba.rf import array as antenna
    from rfmitsuba.rf.bartlett_ref import bartlett

    f = nerf2.NERF2_FREQUENCY_HZ
    rng = np.random.default_rng(0)
    gateway = np.array([0.0, 0.0, 2.0])
    t = np.linspace(0, 1, 60)[:, None]
    tags = np.array([3.0, 3.5, 0.5]) + t * np.array([0.3, 0.4, 0.1]) + 0.002 * rng.standard_normal((60, 3))
    pos = antenna.element_positions(f)
    k = 2 * np.pi / antenna.wavelength(f)
    u = (tags - gateway) / np.linalg.norm(tags - gateway, axis=1, keepdims=True)
    refl = np.array([0.6, -0.7, 0.4]) / np.linalg.norm([0.6, -0.7, 0.4])
    h = np.exp(1j * k * (u @ pos.T)) + 0.5 * np.exp(1j * k * (refl @ pos.T))[None] \
        * np.exp(1j * k * np.linalg.norm(tags - gateway, axis=1))[:, None]
    h = h * np.exp(nuisance * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)))
    pas = bartlett(h, frequency_hz=f, positions=pos)
    src = SimpleNamespace(pas=lambda state=0: pas, antenna_pos=tags, fixed_pos=gateway, split=make_split(60, 0, seed=0),
                          person_pos=np.full((1, 3), np.nan), task="tx", frequency_hz=f, num_states=1, path="test")
    return nerf2.write(src, tmp_path / f"n{nuisance}")


def test_profile_tells_a_clean_folder_from_one_with_measurement_nuisance(tmp_path):
    from rfmitsuba.eval.folder_profile import DISTANCE_BINS_M, profile

    kw = {"coarray_images": 8, "pairs_per_bin": 40, "frame_candidates": 20, "frame_views": 12}
    clean, noisy = profile(_folder(tmp_path, nuisance=0.0), **kw), profile(_folder(tmp_path, nuisance=0.3), **kw)
    for p in (clean, noisy):
        assert p["positions"] == 60 and not p["measured"]
        for split in ("dataset", "block"):
            assert set(p["floors"][split]) == {"nearest_neighbour", "idw3", "mean_image"}
            assert all(0 < v["mean"] <= 1 for v in p["floors"][split].values())
        assert len(p["ssim_by_distance"]["ssim"]) == len(DISTANCE_BINS_M) - 1
    assert clean["coarray_fit"] > 0.99 and noisy["coarray_fit"] > 0.98     # both are Bartlett images
    assert clean["line_of_sight"]["stated"] > noisy["line_of_sight"]["stated"]
    assert clean["line_of_sight"]["stated"] > 0.5
    near = lambda p: next(s for s in p["ssim_by_distance"]["ssim"] if s is not None)
    assert near(noisy) < near(clean) - 0.05                                # neighbours differ more
    assert noisy["floors"]["dataset"]["nearest_neighbour"]["mean"] < clean["floors"]["dataset"]["nearest_neighbour"]["mean"]
