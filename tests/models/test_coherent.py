"""The coherent image-source field (rfmitsuba.models.coherent): closed-form free-space and shadow cases,
gradients against finite differences, state round trips, bad input, and training on Sionna data."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError, RunError
from rfmitsuba.rf import array as antenna
from rfmitsuba.rf import images

F = 2.4e9
K = 2 * np.pi / antenna.wavelength(F)
BOX = np.array([[0.0, 0.0, 0.0], [4.0, 3.0, 2.6]])


def _zero(mlp):
    mlp.set_weights(np.zeros(mlp.buffer_size, np.float32))


def direct_field(amp=(1.0, 0.0), **kw):
    """A field of the direct path alone whose gain network outputs 0 (gain = amp exactly)."""
    from rfmitsuba.models.coherent import CoherentField

    maps = images.image_maps(images.box_planes(*BOX), room_order=0, furniture_order=0)
    f = CoherentField(maps, box=BOX, frequency_hz=F, params={"amp": np.asarray(amp, np.float32),
                                                              "embed": np.zeros(16, np.float32)}, **kw)
    _zero(f.gain)
    return f


def _h(pair):
    return np.asarray(pair[0].numpy(), np.float64) + 1j * np.asarray(pair[1].numpy(), np.float64)


@pytest.mark.parametrize("task", ["rx", "tx"])
def test_free_space_is_a_spherical_wave_with_the_synthetic_array_rule(variant, task):
    """h_m = a exp(-jkL)/L exp(+jk r_m.u): the same rule the datasets' channels follow (Sionna's
    synthetic array, rfmitsuba.rf.array.array_response)."""
    f = direct_field(amp=(0.6, -0.3))
    rng = np.random.default_rng(0)
    moving = rng.uniform([0.5, 0.5, 0.5], [3.5, 2.5, 2.0], (5, 3))
    fixed = np.array([3.7, 2.7, 2.0])
    x, y = (moving, np.tile(fixed, (5, 1))) if task == "rx" else (np.tile(fixed, (5, 1)), moving)
    h = _h(f.channels(x, y, moving)).reshape(5, 16)
    d = y - x
    L = np.linalg.norm(d, axis=1)
    a = (0.6 - 0.3j) * np.exp(-1j * K * L) / L
    ref = antenna.array_response(a[:, None], (d / L[:, None])[:, None, :], frequency_hz=F)
    np.testing.assert_allclose(h, ref, rtol=0, atol=2e-5 * np.abs(ref).max())


def test_pas_peak_points_at_the_transmitter(variant):
    from rfmitsuba.rf import bartlett_ref as P

    f = direct_field()
    x, y = np.array([[1.0, 0.8, 1.1]]), np.array([[3.2, 2.4, 2.0]])
    img = f.render(x, y, x).numpy()[0]
    el, az = P.peak_direction(img)
    d = (y - x)[0]
    assert np.degrees(el) == pytest.approx(np.degrees(np.arcsin(d[2] / np.linalg.norm(d))), abs=2.0)
    assert np.degrees(az) == pytest.approx(np.degrees(np.arctan2(d[1], d[0])) % 360, abs=2.0)


def test_gradients_match_finite_differences(variant):
    """d/d(parameters) of a fixed linear read-out of the channels, Dr.Jit AD vs central differences."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent import CoherentField

    maps = images.image_maps(images.box_planes(*BOX), room_order=1, furniture_order=0)
    f = CoherentField(maps, box=BOX, frequency_hz=F, seed=3)
    x = np.array([[1.0, 0.8, 1.1], [2.5, 1.5, 0.7]])
    y = np.tile([3.6, 2.6, 2.0], (2, 1))
    c = np.random.default_rng(1).normal(size=(2, 2 * 16))

    def loss(params):
        f.assign(params)
        hr, hi = f.channels(x, y, x)
        return dr.sum(hr * B.Float(c[:, :16].ravel()) + hi * B.Float(c[:, 16:].ravel()))

    base = {k: B.Float(np.array(v.numpy(), np.float32, copy=True)) for k, v in f.parameters().items()}
    # the embedding and the gain network feed float16 products on CUDA (nn.MLP): finite
    # differences there measure rounding, so only the amplitudes are checked on that backend
    names = ("amp", "embed", "net.gain") if f.gain.precision == "single" else ("amp",)
    for name in names:
        p = dict(base)
        dr.enable_grad(p[name])
        dr.backward(loss(p))
        g = np.asarray(dr.grad(p[name]), np.float64)
        arr = np.asarray(base[name].numpy(), np.float64)
        for i in np.argsort(-np.abs(g))[:3]:
            eps = 1e-2 * max(abs(arr[i]), 0.1)
            plus, minus = arr.copy(), arr.copy()
            plus[i] += eps
            minus[i] -= eps
            fd = (float(loss({**base, name: B.Float(plus.astype(np.float32))}).numpy()[0])
                  - float(loss({**base, name: B.Float(minus.astype(np.float32))}).numpy()[0])) / (2 * eps)
            assert g[i] == pytest.approx(fd, rel=2e-2, abs=1e-3 * np.abs(g).max()), name


def person_point_on_the_direct_path(x, y):
    """A person field with one scattering point at the middle of the direct segment x -> y, only its
    first path family (direct in, direct out) switched on, and networks that output 0."""
    from rfmitsuba.data.samples import num_person_features
    from rfmitsuba.models.coherent_person import (
        CoherentPersonConfig,
        CoherentPersonField,
        scatter_paths,
    )

    maps = images.image_maps(images.box_planes(*BOX), room_order=1, furniture_order=0)
    cfg = CoherentPersonConfig(num_points=1)
    paths = scatter_paths(maps, 1)
    C = len(paths["pre_b"])
    amp = np.zeros(2 * C, np.float32)
    amp[:2] = (0.2, 0.1)
    h = CoherentPersonField(paths, box=BOX, cfg=cfg, frequency_hz=F, params={
        "offsets": np.array([0.0, 0.0, 0.0], np.float32), "amp": amp, "embed": np.zeros(cfg.embed, np.float32)})
    for m in (h.gain, h.deform):
        _zero(m)
    feet = (x + y) / 2
    extra = np.concatenate([np.zeros((1, num_person_features(cfg.person_octaves))), feet[None]], 1)
    return h, extra


def test_a_scatterer_on_the_direct_path_has_its_length_and_direction(variant):
    """Bistatic scattering from a point on the segment: path length |x - y| (so it can cancel the
    direct path: the person's shadow) and arrival from the transmitter's direction."""
    x, y = np.array([1.0, 0.8, 1.1]), np.array([3.2, 2.4, 2.0])
    h, extra = person_point_on_the_direct_path(x, y)
    hh = _h(h.channels(x[None], y[None], x[None], extra=extra))
    hd = _h(direct_field().channels(x[None], y[None], x[None]))  # exp(-jkL)/L along the same direction
    L = np.linalg.norm(y - x)
    ratio = hh / hd
    np.testing.assert_allclose(ratio, ratio[0], atol=1e-4 * abs(ratio[0]))  # same direction on every element
    assert ratio[0] == pytest.approx((0.2 + 0.1j) * L / ((L / 2) * (L / 2)), rel=1e-4)  # same phase: same length


def test_state_round_trips_and_load_field(variant, tmp_path):
    from rfmitsuba.models.base import load_field
    from rfmitsuba.models.coherent import CoherentField
    from rfmitsuba.models.coherent_person import CoherentPersonField

    maps = images.image_maps(images.box_planes(*BOX), room_order=2, furniture_order=0)
    f = CoherentField(maps, box=BOX, frequency_hz=F, seed=4)
    x = np.array([[1.0, 0.8, 1.1]])
    y = np.array([[3.6, 2.6, 2.0]])
    f.save(tmp_path / "f.npz")
    g = load_field(tmp_path / "f.npz")
    assert isinstance(g, CoherentField) and g.num_sources == 25
    np.testing.assert_allclose(_h(g.channels(x, y, x)), _h(f.channels(x, y, x)), rtol=1e-6)
    hum = CoherentPersonField.for_background(f, seed=2)
    _, extra = person_point_on_the_direct_path(x[0], y[0])
    extra = np.concatenate([np.zeros((1, extra.shape[1] - 3)), [[2.0, 1.5, 0.0]]], 1)
    hum.save(tmp_path / "h.npz")
    h2 = load_field(tmp_path / "h.npz")
    assert isinstance(h2, CoherentPersonField)
    np.testing.assert_allclose(_h(h2.channels(x, y, x, extra=extra)), _h(hum.channels(x, y, x, extra=extra)),
                               rtol=1e-5, atol=1e-9)
    # a damaged state names what is wrong
    state = f.state_dict()
    state["amp"] = state["amp"][:-2]
    with pytest.raises(RunError, match="amp"):
        CoherentField.from_state_dict(state)
    meta = json.loads(str(state["meta"]))
    meta["format"] = "something-else"
    state["meta"] = np.asarray(json.dumps(meta))
    np.savez(tmp_path / "bad.npz", **state)
    with pytest.raises(RunError, match="unknown field format"):
        load_field(tmp_path / "bad.npz")


def test_bad_input_is_named(variant):
    f = direct_field()
    with pytest.raises(ConfigError, match="finite"):
        f.channels(np.array([[np.nan, 0, 1.0]]), np.array([[1.0, 1, 1]]), np.array([[1.0, 1, 1]]))
    with pytest.raises(ConfigError, match="shape"):
        f.channels(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros((2, 3)))
    e2e = direct_field(extra_inputs=4)
    with pytest.raises(ConfigError, match="extra inputs"):
        e2e.channels(np.ones((1, 3)), 2 * np.ones((1, 3)), np.ones((1, 3)))
    x, y = np.array([1.0, 0.8, 1.1]), np.array([3.2, 2.4, 2.0])
    h, extra = person_point_on_the_direct_path(x, y)
    with pytest.raises(ConfigError, match="person"):
        h.channels(x[None], y[None], x[None], extra=None)
    with pytest.raises(ConfigError):
        from rfmitsuba.models.coherent import CoherentConfig

        CoherentConfig(furniture_order=3)


def test_leg_features_closed_form():
    """A person standing on the direct path is at distance 0 from both its legs; one 0.5 m to the
    side of a path along x is 0.5 m away; heights are those of the ray above the feet."""
    from rfmitsuba.models.coherent_person import leg_features

    maps = images.image_maps(images.box_planes(*BOX), room_order=1, furniture_order=0)
    x, y = np.array([[1.0, 1.0, 1.0]]), np.array([[3.0, 1.0, 2.0]])
    f = leg_features(maps, x, y, np.array([[2.0, 1.0, 0.0]]))
    assert f.shape == (len(maps), 4)
    np.testing.assert_allclose(f[0], [0.0, 1.5, 0.0, 1.5], atol=1e-6)  # direct path: mid-height 1.5 m
    f = leg_features(maps, x, y, np.array([[2.0, 1.5, 0.0]]))
    np.testing.assert_allclose(f[0, [0, 2]], [0.5, 0.5], atol=1e-6)


def test_perturb_field_starts_at_zero_and_round_trips(variant, tmp_path):
    """The perturbation field adds nothing before training (its network's last layer is zero), is
    saved with its background, and loads back to the same channels."""
    from rfmitsuba.data.samples import num_person_features
    from rfmitsuba.models.base import load_field
    from rfmitsuba.models.coherent import CoherentField
    from rfmitsuba.models.coherent_person import (
        CoherentPersonConfig,
        CoherentPerturbField,
    )

    maps = images.image_maps(images.box_planes(*BOX), room_order=1, furniture_order=0)
    bg = CoherentField(maps, box=BOX, frequency_hz=F, seed=1)
    bg.freeze()
    p = CoherentPerturbField(bg, cfg=CoherentPersonConfig(kind="perturb"), seed=0)
    x, y = np.array([[1.0, 0.8, 1.1]]), np.array([[3.6, 2.6, 2.0]])
    extra = np.concatenate([np.ones((1, num_person_features(3))), [[2.0, 1.5, 0.0]]], 1)
    assert np.abs(_h(p.channels(x, y, x, extra=extra))).max() == 0.0
    w = np.asarray(p.net.weights.numpy()).copy()
    p.net.set_weights(w + 0.01)
    p.save(tmp_path / "p.npz")
    q = load_field(tmp_path / "p.npz")
    assert isinstance(q, CoherentPerturbField) and q.bg.num_sources == bg.num_sources
    np.testing.assert_allclose(_h(q.channels(x, y, x, extra=extra)), _h(p.channels(x, y, x, extra=extra)),
                               rtol=1e-5, atol=1e-9)
    assert np.abs(_h(q.channels(x, y, x, extra=extra))).max() > 0
