"""rfmitsuba.models.coherent_gaussians_person: Stage 2 of the coherent Gaussian family (body
scatterers + blockage of the background's paths).

Finite-difference gradient checks of every parameter (global and per-source blockage, both
wavefronts, through the channels and through the read-out), exact zero at a = 0 without
scatterers, the blockage's closed-form case (a person on the direct path with a = 1 removes it,
far away leaves it), the state round trip and bad inputs named."""
from __future__ import annotations

import numpy as np
import pytest
from fd_helpers import fd_check

F = 2.4e9
PARAMS = ["sc_offset", "sc_amp", "block_logit", "block_log_radius"]
OCT = 1                       # person-feature octaves in these tests (only the position is read)

pytestmark = pytest.mark.usefixtures("one_thread")


def _bg(*, wavefront="plane", direct_only=False, scatterers=True, perturb=True, seed=0):
    """Background: direct path + one wall reflection (x = 0 plane) + 2 scatterers (or the direct
    path alone, or no scatterers), perturbed away from the initial values."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    A = np.eye(3)[None] if direct_only else np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])])
    order = np.array([0]) if direct_only else np.array([0, 1])
    sc = np.zeros((0, 3)) if direct_only or not scatterers else np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5]])
    f = CoherentGaussianField(A, order, sc, cfg=CoherentGaussianConfig(init_extent=1.5), readout="amplitude",
                              wavefront=wavefront, vis_center=np.array([2.0, 1.5, 1.0]), frequency_hz=F, seed=seed)
    if perturb:
        rng = np.random.default_rng(seed)
        for k, v in f.params.items():
            a = np.asarray(v.numpy(), np.float64)
            f.params[k] = B.Float((a + 0.05 * rng.normal(size=a.shape)).astype(np.float32))
    f.freeze()
    return f


def _person(bg, *, perturb=True, **cfg):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians_person import (
        CoherentGaussianPersonConfig,
        CoherentGaussianPersonField,
    )

    kw = {"num_points": 3, "person_octaves": OCT, "init_gain": 0.3, "init_strength": 0.4, **cfg}
    p = CoherentGaussianPersonField.for_background(bg, cfg=CoherentGaussianPersonConfig(**kw), seed=1)
    if perturb:
        rng = np.random.default_rng(3)
        for k, v in p.params.items():
            a = np.asarray(v.numpy(), np.float64)
            p.params[k] = B.Float((a + 0.1 * rng.normal(size=a.shape)).astype(np.float32))
    return p


def _views(task="tx", n=3, person=None):
    """Moving TX around (2, 1.5, 1.25), array at (3.5, 2.5, 2.0); the person stands near the middle
    of each view's direct path (10-20 cm off it), feet on the floor."""
    from rfmitsuba.data.samples import num_person_features
    from rfmitsuba.models.base import Views

    rng = np.random.default_rng(1)
    q = np.array([1.5, 1.0, 1.0]) + rng.random((n, 3)) * [1.0, 1.0, 0.5]
    fixed = np.tile([3.5, 2.5, 2.0], (n, 1))
    x, y = (fixed, q) if task == "tx" else (q, fixed)
    if person is None:
        person = 0.5 * (x + y) + np.c_[0.1 + 0.1 * rng.random(n), np.zeros(n), np.zeros(n)]
        person[:, 2] = 0.0
    extra = np.concatenate([np.zeros((n, num_person_features(OCT)), np.float32), person], axis=1)
    return Views(antenna_pos=q, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=F, task=task,
                 inputs=lambda field: extra)


def _w(rng, n):
    from rfmitsuba.core import backend as B

    return B.Float(rng.normal(size=n).astype(np.float32))


def _h(field, views):
    hr, hi = field.channels(views)
    return np.asarray(hr.numpy(), np.float64) + 1j * np.asarray(hi.numpy(), np.float64)


#: relative finite-difference steps: a scatterer's offset moves its path by up to 0.9 m per unit; the
#: blockage is curved in log r, so one-sided differences at 1e-2 disagree by more than fd_check's kink test
STEP = {"sc_offset": 1e-3, "block_log_radius": 2e-3}


@pytest.mark.parametrize("wavefront", ["plane", "spherical"])
@pytest.mark.parametrize("name, per_source", [(n, False) for n in PARAMS]
                         + [("block_logit", True), ("block_log_radius", True)])
def test_channel_gradients(name, per_source, wavefront):
    """d/d(parameter) of <c, h> of the person field's channels (3 views, moving TX), AD against
    central differences at 3 random and 3 large-gradient entries (global and per-source
    blockage); rtol 5e-2, atol 3e-2 * max|FD|."""
    p = _person(_bg(wavefront=wavefront), strength_per_source=per_source, radius_per_source=per_source)
    assert set(p.parameters()) == set(PARAMS)
    _check_channel_gradient(p, _views(), name)


def _check_channel_gradient(p, views, name):
    """AD against central differences of <c, h> of ``p``'s channels in parameter ``name``."""
    rng = np.random.default_rng(2)
    c_re, c_im = _w(rng, 48), _w(rng, 48)

    def loss(q):
        p.assign(q)
        hr, hi = p.channels(views)
        return [hr * c_re, hi * c_im]

    r = fd_check(loss, p.parameters(), name, count=3, top=3, rel_eps=STEP.get(name, 1e-2), min_scale=1.0, seed=4)
    assert len(r.index) >= min(3, p.parameters()[name].shape[0]) and r.ok(5e-2, 3e-2), r.report()


@pytest.mark.parametrize("name", PARAMS)
def test_render_gradients(name):
    """The same through the background + person Bartlett read-out (9 x 36 grid, raw PAS, moving RX)."""
    from rfmitsuba.models.base import render

    bg = _bg()
    p = _person(bg)
    views = _views("rx")
    W = _w(np.random.default_rng(3), 3 * 9 * 36)

    def loss(q):
        p.assign(q)
        return [render([bg, p], views, height=9, width=36, normalize=False).array * W]

    r = fd_check(loss, p.parameters(), name, count=3, top=3, rel_eps=STEP.get(name, 1e-2), min_scale=1.0, seed=5)
    assert len(r.index) >= 1 and r.ok(5e-2, 3e-2), r.report()


def test_zero_at_no_blockage_and_no_scatterers_and_small_at_the_start():
    """a = 0 and no scatterers (or zero gains): exactly zero, so background + person renders the
    background; the default start (a = 0.05, gains 0.02) changes them little (here, with the
    person in the middle of a 1.5 m direct path and 8 scatterers summed, by less than 30%)."""
    from rfmitsuba.models.base import render
    from rfmitsuba.models.coherent_gaussians_person import (
        CoherentGaussianPersonConfig,
        CoherentGaussianPersonField,
    )

    bg = _bg()
    views = _views()
    for kw in ({"num_points": 0}, {"num_points": 4, "init_gain": 0.0}):
        p = CoherentGaussianPersonField.for_background(
            bg, cfg=CoherentGaussianPersonConfig(init_strength=0.0, person_octaves=OCT, **kw))
        assert np.all(_h(p, views) == 0)
        np.testing.assert_array_equal(render([bg, p], views).numpy(), render([bg], views).numpy())
    p = CoherentGaussianPersonField.for_background(bg, cfg=CoherentGaussianPersonConfig(person_octaves=OCT))
    rel = np.abs(_h(p, views)).max() / np.abs(_h(bg, views)).max()
    assert 1e-4 < rel < 0.3, rel


@pytest.mark.parametrize("wavefront", ["plane", "spherical"])
def test_person_on_the_direct_path_removes_it(wavefront):
    """Closed form: a person standing on the direct path with a = 1 removes that path's term exactly
    (and only it: the wall image's legs pass 1.3 m away); standing 5 m away it changes nothing."""
    from rfmitsuba.core import backend as B

    n = 2
    x = np.array([[3.0, 0.5, 1.0], [3.1, 0.6, 1.2]])
    y = np.array([[3.0, 3.5, 1.0], [2.9, 3.4, 0.9]])
    on = 0.5 * (x + y)
    on[:, 2] = 0.0
    for direct_only in (True, False):
        bg = _bg(wavefront=wavefront, direct_only=direct_only, scatterers=False, perturb=False)
        p = _person(bg, perturb=False, num_points=0, init_strength=0.5, init_block_radius=0.2)
        p.params["block_logit"] = B.Float(np.array([50.0], np.float32))          # a = 1 in float32
        from rfmitsuba.data.samples import num_person_features
        from rfmitsuba.models.base import Views

        def views(person):
            extra = np.concatenate([np.zeros((n, num_person_features(OCT))), person], axis=1)
            return Views(antenna_pos=x, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=F, task="rx",
                         inputs=lambda field: extra)

        h_bg = _h(bg, views(on))
        total = h_bg + _h(p, views(on))
        if direct_only:
            assert np.abs(total).max() <= 1e-5 * np.abs(h_bg).max()
        else:   # what is left is the wall image alone
            wall = _bg(wavefront=wavefront, scatterers=False, perturb=False)
            a = np.asarray(wall.params["img_amp"].numpy()).copy()
            a[:2] = 0
            wall.params["img_amp"] = B.Float(a.astype(np.float32))
            np.testing.assert_allclose(total, _h(wall, views(on)), atol=2e-4 * np.abs(h_bg).max())
        far = on + [5.0, 0.0, 0.0]
        assert np.abs(_h(p, views(far))).max() <= 1e-6 * np.abs(h_bg).max()


def test_blockage_distance_is_the_axis_to_leg_distance():
    """axis_distance2 on hand-made legs: a horizontal leg passing 0.3 m beside the axis (0.09 m^2),
    one passing above the head (vertical excess), and one ending before the axis (endpoint distance)."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians_person import axis_distance2

    def d2(p0, p1):
        f = [B.Float([float(v)]) for v in p0], [B.Float([float(v)]) for v in p1]
        return float(axis_distance2(*f, B.Float([0.0]), B.Float([0.0]), B.Float([0.0]), B.Float([1.8]))[0])

    assert d2([-2, 0.3, 1.0], [2, 0.3, 1.0]) == pytest.approx(0.09, rel=1e-5)
    assert d2([-2, 0.0, 2.5], [2, 0.0, 2.5]) == pytest.approx(0.49, rel=1e-5)
    assert d2([-2, 0.0, 1.0], [-1, 0.0, 1.0]) == pytest.approx(1.0, rel=1e-5)


def test_state_round_trip(tmp_path):
    from rfmitsuba.models.base import load_field, render

    bg = _bg(wavefront="spherical")
    p = _person(bg, strength_per_source=True)
    views = _views()
    path = p.save(tmp_path / "person.npz")
    with np.load(path, allow_pickle=False) as z:
        assert "bg.img_amp" in z.files
    g = load_field(path)
    assert type(g) is type(p) and g.person and g.family == "coherent_gaussians"
    assert g.cfg == p.cfg and g.num_parameters == p.num_parameters == 9 + 6 + 4 + 1
    assert g.bg.frozen and g.bg.wavefront == "spherical"
    np.testing.assert_allclose(_h(g, views), _h(p, views), atol=1e-7)
    np.testing.assert_allclose(render([bg, g], views).numpy(), render([bg, p], views).numpy(), atol=1e-6)
    g.freeze()
    assert g.trainable() == {} and load_field(g.save(tmp_path / "frozen.npz")).frozen
    assert [f.name for f in g.export_ply(tmp_path, views=views)] == ["sources.ply"]
    assert {p.lr_group(k) for k in PARAMS} == {"means", "amp", "opacity_logits", "log_scales"}


def test_bad_input_is_named():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.base import Views
    from rfmitsuba.models.coherent_gaussians_person import (
        CoherentGaussianPersonConfig,
        CoherentGaussianPersonField,
    )

    p = _person(_bg())
    bad = np.array([[2.0, np.nan, 0.0], [2.0, 2.0, 0.0], [2.0, 2.0, 0.0]])
    with pytest.raises(ConfigError, match="person position must be finite"):
        p.channels(_views(person=bad))
    v = _views()
    short = Views(antenna_pos=v.antenna_pos, view_pos=v.view_pos, transmitter=v.transmitter, rx_to_world=None,
                  frequency_hz=F, inputs=lambda field: np.zeros((3, 4)))
    with pytest.raises(ConfigError, match=r"extra inputs must be \[B, 13\]"):
        p.channels(short)
    none = Views(antenna_pos=v.antenna_pos, view_pos=v.view_pos, transmitter=v.transmitter, rx_to_world=None,
                 frequency_hz=F)
    with pytest.raises(ConfigError, match="needs the person's features"):
        p.channels(none)
    with pytest.raises(ConfigError, match="coherent_gaussians background"):
        CoherentGaussianPersonField.for_background(object())
    with pytest.raises(ConfigError, match="init_strength"):
        CoherentGaussianPersonConfig(init_strength=1.0)
    with pytest.raises(ConfigError, match="init_radius"):
        CoherentGaussianPersonConfig(init_radius=0.5, max_offset=0.3)


def _two_people_views(second):
    """The views of :func:`_views` with a second person's feet at ``second`` float [3, 3] [m]."""
    from rfmitsuba.data.samples import num_person_features
    from rfmitsuba.models.base import Views

    v = _views()
    one = v.inputs(None)
    extra = np.concatenate([one, np.asarray(second, np.float32)], axis=1)
    assert extra.shape[1] == num_person_features(OCT) + 6
    return Views(antenna_pos=v.antenna_pos, view_pos=v.view_pos, transmitter=v.transmitter, rx_to_world=None,
                 frequency_hz=F, task=v.task, inputs=lambda field: extra)


def _people_field(bg, people):
    p1 = _person(bg)
    p = _person(bg, people=people)
    p.assign(p1.parameters())
    return p1, p


def test_two_people_far_apart_are_one_and_the_order_of_people_does_not_matter():
    """With the scatterers' gains zero, a second person 100 m away changes nothing (its blockage
    factor is 1); the two people swapped draw the same channels; two people on the paths change
    them more than one."""
    from rfmitsuba.core import backend as B

    bg = _bg()
    one, two = _people_field(bg, 2)
    for f in (one, two):
        f.params["sc_amp"] = B.Float(np.zeros(f.params["sc_amp"].shape[0], np.float32))
    v1 = _views()
    feet = v1.inputs(None)[:, -3:]
    far = feet + [100.0, 100.0, 0.0]
    h1 = np.concatenate([np.asarray(a.numpy()) for a in one.channels(v1)])
    h2 = np.concatenate([np.asarray(a.numpy()) for a in two.channels(_two_people_views(far))])
    np.testing.assert_allclose(h2, h1, rtol=1e-6, atol=1e-9)
    near = feet + [0.05, -0.05, 0.0]
    ab = np.concatenate([np.asarray(a.numpy()) for a in two.channels(_two_people_views(near))])
    from rfmitsuba.data.samples import num_person_features
    from rfmitsuba.models.base import Views

    swapped = np.concatenate([np.zeros((3, num_person_features(OCT)), np.float32), near, feet], axis=1)
    v = _views()
    ba = np.concatenate([np.asarray(a.numpy()) for a in two.channels(
        Views(antenna_pos=v.antenna_pos, view_pos=v.view_pos, transmitter=v.transmitter, rx_to_world=None,
              frequency_hz=F, task=v.task, inputs=lambda field: swapped))])
    np.testing.assert_allclose(ab, ba, rtol=1e-5, atol=1e-7)
    assert np.abs(ab).sum() > 1.05 * np.abs(h1).sum()


@pytest.mark.parametrize("name", PARAMS)
def test_two_people_channel_gradients(name):
    """The shared parameters of a two-person field against central differences (as
    :func:`test_channel_gradients`, both people near the direct paths)."""
    _, p = _people_field(_bg(), 2)
    _check_channel_gradient(p, _two_people_views(_views().inputs(None)[:, -3:] + [-0.15, 0.1, 0.0]), name)


def test_people_is_checked_and_the_inputs_must_hold_every_person():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.coherent_gaussians_person import CoherentGaussianPersonConfig

    with pytest.raises(ConfigError, match="people must be >= 1"):
        CoherentGaussianPersonConfig(people=0)
    _, two = _people_field(_bg(), 2)
    with pytest.raises(ConfigError, match="each of 2 people"):
        two.channels(_views())
