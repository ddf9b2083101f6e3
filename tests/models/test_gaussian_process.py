"""rfmitsuba.models.gaussian_process: the PAS as a Gaussian process of position."""
from __future__ import annotations

import json

import numpy as np
import pytest


def _draw(n=60, m=300, *, ls=(0.1, 0.2, 0.15), nugget=0.01, seed=0):
    """n positions in a 0.5 m box and m outputs drawn from the exponential-kernel process."""
    from rfmitsuba.models.gaussian_process import exponential_kernel

    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 0.5, (n, 3))
    c = exponential_kernel(x, x, np.array(ls)) + nugget * np.eye(n)
    y = np.linalg.cholesky(c) @ rng.standard_normal((n, m))
    return x, y


def test_exponential_kernel_is_exp_of_the_scaled_distance():
    from rfmitsuba.models.gaussian_process import exponential_kernel

    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    b = np.array([[0.0, 0.3, 0.4]])
    k = exponential_kernel(a, b, np.array([1.0, 0.5, 2.0]))
    assert k.shape == (2, 1)
    assert k[0, 0] == pytest.approx(np.exp(-np.hypot(0.6, 0.2)))
    assert k[1, 0] == pytest.approx(np.exp(-np.sqrt(1 + 0.36 + 0.04)))
    kk = exponential_kernel(a, a, np.ones(3))
    assert np.allclose(kk, kk.T) and np.allclose(np.diag(kk), 1.0)


def test_maximum_likelihood_recovers_the_length_scales_and_nugget():
    """Outputs drawn from the process with known hyperparameters: the fit finds them (300 outputs
    share the kernel, so the likelihood is sharp)."""
    from rfmitsuba.models.gaussian_process import fit_hyperparameters

    x, y = _draw(ls=(0.1, 0.2, 0.15), nugget=0.01)
    h = fit_hyperparameters(x, y)
    assert np.allclose(h["length_scales_m"], [0.1, 0.2, 0.15], rtol=0.3)
    assert 0.003 < h["nugget"] < 0.03
    assert h["signal_variance"] == pytest.approx(1.0, rel=0.3)


def test_the_likelihood_prefers_the_true_length_scale():
    from rfmitsuba.models.gaussian_process import profile_nll

    x, y = _draw(ls=(0.1, 0.1, 0.1), nugget=0.01, seed=1)
    g = y @ y.T
    nll = {s: profile_nll(np.log([s, s, s, 0.01]), x, g, y.shape[1]) for s in (0.03, 0.1, 0.3)}
    assert nll[0.1] < nll[0.03] and nll[0.1] < nll[0.3]


def test_the_likelihood_gradient_matches_central_differences():
    """The analytic gradient the fit follows, against central differences of the value, at an
    anisotropic point away from the optimum (every component, to 1e-5 relative)."""
    from rfmitsuba.models.gaussian_process import profile_nll

    x, y = _draw(n=30, m=40, ls=(0.1, 0.2, 0.15), nugget=0.01, seed=2)
    g, t = y @ y.T, np.log([0.3, 0.05, 0.2, 0.1])
    value, grad = profile_nll(t, x, g, y.shape[1], True)
    assert value == profile_nll(t, x, g, y.shape[1])
    h = 1e-6
    fd = [(profile_nll(t + e, x, g, y.shape[1]) - profile_nll(t - e, x, g, y.shape[1])) / (2 * h)
          for e in np.eye(4) * h]
    assert np.allclose(grad, fd, rtol=1e-5, atol=1e-6) and np.all(np.abs(grad) > 1e-3)


def _images(n=50, h=16, w=32, *, ls=0.2, seed=0):
    """n positions and min-max normalised h x w images drawn from the process (isotropic ls [m])."""
    x, y = _draw(n=n, m=h * w, ls=(ls, ls, ls), nugget=1e-4, seed=seed)
    return x, ((y - y.min(1, keepdims=True)) / np.ptp(y, 1, keepdims=True)).reshape(n, h, w)


def test_the_scale_factor_moves_wrong_length_scales_towards_the_true_ones():
    """Images drawn with length scale 0.2 m: given scales a quarter of that, the leave-one-out SSIM
    picks the largest factor and gains over the scales given; given twice the truth, a factor of at
    most 1; the scores recorded are the leave-one-out SSIMs, and the chosen one is their best."""
    from rfmitsuba.models.gaussian_process import SCALE_FACTORS, choose_scale_factor

    x, img = _images()
    short = choose_scale_factor(x, img, {"length_scales_m": [0.05] * 3, "nugget": 1e-4})
    scores = short["loo_ssim_by_factor"]
    assert short["scale_factor"] == max(SCALE_FACTORS) and set(scores) == {str(f) for f in SCALE_FACTORS}
    assert scores[str(short["scale_factor"])] == max(scores.values()) > scores["1.0"] + 0.05
    long = choose_scale_factor(x, img, {"length_scales_m": [0.4] * 3, "nugget": 1e-4})
    assert long["scale_factor"] <= 1.0


def test_the_factor_is_scored_on_an_even_subset_beyond_loo_scored(monkeypatch):
    """Beyond LOO_SCORED spectra a factor scores the leave-one-out SSIM of an evenly spaced
    subset, each still predicted from all the others: the scores equal those computed by hand."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.models import gaussian_process as gp
    from rfmitsuba.rf.bartlett_ref import normalize

    x, img = _images(n=30)
    hyper = {"length_scales_m": [0.1] * 3, "nugget": 1e-4}
    monkeypatch.setattr(gp, "LOO_SCORED", 7)
    got = gp.choose_scale_factor(x, img, hyper)
    idx = np.unique(np.linspace(0, 29, 7).round().astype(int))
    flat = img.reshape(30, -1)
    for f, v in got["loo_ssim_by_factor"].items():
        prec = np.linalg.inv(gp.exponential_kernel(x, x, float(f) * np.full(3, 0.1)) + 1e-4 * np.eye(30))
        loo = gp.leave_one_out(flat, prec @ (flat - flat.mean(0)), prec).reshape(img.shape)[idx]
        assert v == pytest.approx(float(np.mean(ssim_images(normalize(loo), img[idx]))), abs=1e-9)
    assert "7 of 30 spectra" in got["why"]


def test_conditioning_records_the_likelihood_and_the_factor():
    from rfmitsuba.models.gaussian_process import GaussianProcessField

    x, img = _images(n=40)
    f = GaussianProcessField(height=16, width=32)
    h = f.condition(x, img)
    assert np.allclose(h["length_scales_m"], h["scale_factor"] * np.asarray(h["likelihood_length_scales_m"]))
    assert h["scale_factor"] in (1.0, 0.5, 0.7, 1.4, 2.0, 3.0) and "leave-one-out" in h["why"]
    tiny = GaussianProcessField(height=6, width=12)
    t = tiny.condition(x, img[:, :6, :12])
    assert t["scale_factor"] == 1.0 and "window" in t["why"]
    assert t["length_scales_m"] == t["likelihood_length_scales_m"]


def _field(n=40, h=6, w=12, seed=0):
    from rfmitsuba.models.gaussian_process import GaussianProcessField

    x, y = _draw(n=n, m=h * w, ls=(0.2, 0.2, 0.2), nugget=1e-4, seed=seed)
    img = (y - y.min()) / (y.max() - y.min())
    f = GaussianProcessField(height=h, width=w)
    f.condition(x, img.reshape(n, h, w))
    return f, x, img.reshape(n, h, w)


def test_it_interpolates_close_to_the_data_and_falls_back_to_the_mean_far_away():
    f, x, img = _field()
    assert np.abs(f.predict(x) - img).max() < 0.02                 # a small nugget: nearly the data
    far = f.predict(np.array([[50.0, 50.0, 50.0]]))[0]
    assert np.allclose(far, img.mean(0), atol=1e-5)
    sd = f.predictive_sd(np.r_[x[:3], [[50.0, 50.0, 50.0]]])
    s2, nu = f.hyper["signal_variance"], f.hyper["nugget"]
    assert (sd[:3] < 0.05 * np.sqrt(s2)).all() and sd[3] == pytest.approx(np.sqrt(s2 * (1 + nu)), rel=1e-6)


def test_leave_one_out_predictions_match_conditioning_on_the_others():
    """The closed form equals the posterior mean given every other spectrum (same prior mean and
    hyperparameters), computed directly."""
    f, x, img = _field(n=25)
    loo = f.loo_predictions()
    for i in (0, 7, 24):
        keep = np.arange(len(x)) != i
        k = np.exp(-np.sqrt((((x[i] - x[keep]) / np.array(f.hyper["length_scales_m"])) ** 2).sum(-1)))
        m = img.mean(0).ravel()
        c = np.exp(-np.sqrt((((x[keep][:, None] - x[keep][None]) / np.array(f.hyper["length_scales_m"])) ** 2)
                            .sum(-1))) + f.hyper["nugget"] * np.eye(len(x) - 1)
        want = m + k @ np.linalg.solve(c, img[keep].reshape(len(x) - 1, -1) - m)
        assert np.allclose(loo[i].ravel(), want, atol=1e-4)


def test_save_load_round_trip_and_damaged_states(tmp_path):
    from rfmitsuba.core.errors import RunError
    from rfmitsuba.models.base import load_field

    f, x, _ = _field()
    p = f.save(tmp_path / "field.npz")
    g = load_field(p)
    assert type(g).__name__ == "GaussianProcessField" and g.hyper == f.hyper
    assert np.array_equal(g.predict(x[:4]), f.predict(x[:4]))
    with np.load(p) as z:
        state = {k: z[k] for k in z.files}
    bad = dict(state, weights=state["weights"][:-1])
    with pytest.raises(RunError, match="'weights'"):
        type(f).from_state_dict(bad)
    meta = json.loads(str(state["meta"]))
    meta["hyper"] = {}
    with pytest.raises(RunError, match="hyperparameters"):
        type(f).from_state_dict(dict(state, meta=np.array(json.dumps(meta))))


def test_render_normalises_downsamples_and_renders_alone():
    from rfmitsuba.core.errors import ConfigError, RunError
    from rfmitsuba.models.base import Views, render
    from rfmitsuba.models.gaussian_process import GaussianProcessField

    f, x, _ = _field()
    v = Views(antenna_pos=x[:3], view_pos=np.zeros((3, 3)), transmitter=np.zeros((3, 3)), rx_to_world=None,
              frequency_hz=9.2e8, task="tx")
    img = np.asarray(render([f], v, height=6, width=12, normalize=True).numpy()).reshape(3, 6, 12)
    assert np.allclose(img.min((1, 2)), 0) and np.allclose(img.max((1, 2)), 1)
    raw = np.asarray(render([f], v, height=3, width=6, normalize=False).numpy()).reshape(3, 3, 6)
    assert np.allclose(raw, f.predict(x[:3]).reshape(3, 3, 2, 6, 2).mean((2, 4)), atol=1e-6)
    with pytest.raises(ConfigError, match="cannot render 4 x 12"):
        render([f], v, height=4, width=12, normalize=True)
    with pytest.raises(ConfigError, match="renders alone"):
        render([f, f], v, height=6, width=12, normalize=True)
    with pytest.raises(RunError, match="not conditioned"):
        GaussianProcessField().predict(x[:1])


def test_bad_conditioning_data_is_named():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.gaussian_process import GaussianProcessField

    f = GaussianProcessField(height=2, width=2)
    with pytest.raises(ConfigError, match="do not match"):
        f.condition(np.zeros((3, 2)), np.zeros((3, 2, 2)))
    with pytest.raises(ConfigError, match="at least 2"):
        f.condition(np.zeros((1, 3)), np.zeros((1, 2, 2)))
    with pytest.raises(ConfigError, match="same point"):
        f.condition(np.zeros((3, 3)), np.random.default_rng(0).random((3, 2, 2)))
    with pytest.raises(ConfigError, match="NaN"):
        f.condition(np.eye(3), np.full((3, 2, 2), np.nan))
    with pytest.raises(ConfigError, match="Stage-2"):
        GaussianProcessField.for_training(None, None, extra_inputs=2)
