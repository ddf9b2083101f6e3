"""rfmitsuba.models.coherent_gaussians_joint: the coherent Gaussian End-to-End model (background and
person field trained together).

Finite-difference gradients of parameters of both parts through the channels, on a batch that
mixes empty-room and person-present views; an empty-room view renders the background alone and a
person-present one exactly background + person field; the state round trip; each parameter in
its own part's optimizer group; bad inputs named."""
from __future__ import annotations

import numpy as np
import pytest
from fd_helpers import fd_check

F = 2.4e9
OCT = 1

pytestmark = pytest.mark.usefixtures("one_thread")


def _joint(seed=0):
    """Direct path + one wall image + 2 scatterers, a person field with 3 scatterers; every
    parameter perturbed away from its initial value."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.models.coherent_gaussians_joint import CoherentGaussianJointField
    from rfmitsuba.models.coherent_gaussians_person import CoherentGaussianPersonConfig, CoherentGaussianPersonField

    bg = CoherentGaussianField(np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])]), np.array([0, 1]),
                               np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5]]),
                               cfg=CoherentGaussianConfig(init_extent=1.5), readout="amplitude", wavefront="plane",
                               vis_center=np.array([2.0, 1.5, 1.0]), frequency_hz=F, seed=seed)
    pf = CoherentGaussianPersonField.for_background(bg, cfg=CoherentGaussianPersonConfig(
        num_points=3, person_octaves=OCT, init_gain=0.3, init_strength=0.4), seed=1)
    rng = np.random.default_rng(seed)
    for part in (bg, pf):
        for k, v in part.params.items():
            a = np.asarray(v.numpy(), np.float64)
            part.params[k] = B.Float((a + 0.05 * rng.normal(size=a.shape)).astype(np.float32))
    return CoherentGaussianJointField(bg, pf)


def _views(present=(True, False, True)):
    """Moving TX near (2, 1.5, 1.25), array at (3.5, 2.5, 2); a person 10-20 cm beside each
    direct path where ``present``, the empty room's all-zero features elsewhere."""
    from rfmitsuba.data.samples import person_features
    from rfmitsuba.models.base import Views

    n = len(present)
    rng = np.random.default_rng(1)
    y = np.array([1.5, 1.0, 1.0]) + rng.random((n, 3)) * [1.0, 1.0, 0.5]
    x = np.tile([3.5, 2.5, 2.0], (n, 1))
    h = 0.5 * (x + y) + np.c_[0.1 + 0.1 * rng.random(n), np.zeros(n), np.zeros(n)]
    h[:, 2] = 0.0
    h[~np.asarray(present)] = np.nan
    box = np.array([[0.0, 0.0, 0.0], [4.0, 3.0, 2.5]])
    extra = np.concatenate([person_features(h, box, octaves=OCT), np.nan_to_num(h)], axis=1).astype(np.float32)
    return Views(antenna_pos=y, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=F, task="tx",
                 inputs=lambda field: extra)


def _h(hr_hi):
    hr, hi = hr_hi
    return np.asarray(hr.numpy(), np.float64) + 1j * np.asarray(hi.numpy(), np.float64)


#: relative finite-difference steps where 1e-2 is too coarse: positions move phases by a good part
#: of a wavelength (12.5 cm), the blockage is curved in log r (as in test_coherent_gaussians_person)
STEP = {"room.img_offset": 1e-3, "room.sc_pos": 1e-3, "person.sc_offset": 1e-3, "person.block_log_radius": 2e-3}


@pytest.mark.parametrize("name", ["room.img_amp", "room.img_offset", "room.sc_pos", "room.cal", "room.pose",
                                  "person.sc_offset", "person.sc_amp", "person.block_logit",
                                  "person.block_log_radius"])
def test_channel_gradients(name):
    """d/d(parameter) of <c, h> over a batch of 2 person-present views and 1 empty-room view, AD
    against central differences (rtol 5e-2, atol 3e-2 * max|FD|)."""
    from rfmitsuba.core import backend as B

    f = _joint()
    views = _views()
    rng = np.random.default_rng(2)
    c_re, c_im = (B.Float(rng.normal(size=48).astype(np.float32)) for _ in range(2))

    def loss(q):
        f.assign(q)
        hr, hi = f.channels(views)
        return [hr * c_re, hi * c_im]

    r = fd_check(loss, f.parameters(), name, count=3, top=3, rel_eps=STEP.get(name, 1e-2), min_scale=1.0, seed=4)
    assert r.ok(5e-2, 3e-2), r.report()


def test_empty_view_is_the_background_and_present_view_is_background_plus_person():
    """Per view: no person -> exactly the background's channels; a person -> exactly the sum of
    the background's and the person field's (the Stage-2 pair rendered together)."""
    f = _joint()
    present = (True, False, True)
    views = _views(present)
    joint = _h(f.channels(views)).reshape(3, 16)
    bg = _h(f.bg.channels(views)).reshape(3, 16)
    both = bg + _h(f.person_field.channels(views)).reshape(3, 16)
    np.testing.assert_array_equal(joint[1], bg[1])
    np.testing.assert_allclose(joint[[0, 2]], both[[0, 2]], rtol=1e-6, atol=1e-6 * np.abs(both).max())
    assert np.abs(joint[0] - bg[0]).max() > 1e-3 * np.abs(bg[0]).max()      # the person changes it
    only_empty = _views((False, False))
    np.testing.assert_array_equal(_h(f.channels(only_empty)), _h(f.bg.channels(only_empty)))


def test_state_round_trip_and_groups(tmp_path):
    """save -> load_field gives the same channels, parameter names and frozen flag; each
    parameter keeps its part's optimizer group."""
    from rfmitsuba.models.base import load_field
    from rfmitsuba.models.coherent_gaussians_joint import CoherentGaussianJointField

    f = _joint()
    views = _views()
    f.save(tmp_path / "j.npz")
    g = load_field(tmp_path / "j.npz")
    assert isinstance(g, CoherentGaussianJointField) and not g.frozen
    assert set(g.parameters()) == set(f.parameters()) == {"room." + k for k in f.bg.params} | \
        {"person." + k for k in f.person_field.params}
    np.testing.assert_array_equal(_h(g.channels(views)), _h(f.channels(views)))
    assert g.num_parameters == f.bg.num_parameters + f.person_field.num_parameters
    assert f.lr_group("room.img_amp") == "amp" and f.lr_group("person.sc_offset") == "means"
    assert f.lr_group("person.block_log_radius") == "log_scales"
    f.freeze()
    assert f.trainable() == {}
    f.save(tmp_path / "k.npz")
    assert load_field(tmp_path / "k.npz").frozen


def test_bad_inputs_are_named():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.base import Views
    from rfmitsuba.models.coherent_gaussians_joint import CoherentGaussianJointField

    f = _joint()
    v = _views()
    with pytest.raises(ConfigError, match=r"extra inputs must be \[B, 13\].*got \(3, 12\)"):
        f.channels(Views(antenna_pos=v.antenna_pos, view_pos=v.view_pos, transmitter=v.transmitter,
                         rx_to_world=None, frequency_hz=F, task="tx",
                         inputs=lambda field: np.zeros((3, 12), np.float32)))
    with pytest.raises(ConfigError, match="no parameter 'img_amp'"):
        f.assign({"img_amp": f.bg.params["img_amp"]})
    with pytest.raises(ConfigError, match="built on its background"):
        CoherentGaussianJointField(_joint(seed=1).bg, f.person_field)
