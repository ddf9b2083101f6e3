"""AD gradients against central finite differences (Mitsuba-3 style) for the parts of the models
that had no such test: :meth:`Splats.concat`, the Stage-2 splat person field (deformation network
and person Gaussians) and the Stage-2 coherent person fields, alone and through the Bartlett
read-out of :func:`rfmitsuba.models.base.render`.

Each check (``fd_helpers.fd_check``) differentiates a fixed random linear read-out of the model's
output with respect to one parameter array and compares the AD gradient with central differences
at a few random entries (plus a few among the 10 % largest AD entries), in float32 on one Dr.Jit
thread. An entry passes when ``|AD - FD| <= rtol |FD| + atol * max|FD|`` (max over the checked
entries); a sign flip, a factor 2 or a zero gradient fails every check (checked by running the
file with ``RFMITSUBA_FD_AD_SCALE`` = -1, 2 and 0).
"""
from __future__ import annotations

import numpy as np
import pytest
from fd_helpers import fd_check

F = 2.4e9
BOX = np.array([[0.0, 0.0, 0.0], [4.0, 3.0, 2.6]])


#: every test on one Dr.Jit thread (the ``one_thread`` fixture of tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def _assert_fd(result, rtol, atol, min_entries=3):
    assert len(result.index) >= min_entries, result.report()
    assert result.ok(rtol, atol), result.report()


def _weights(rng, n):
    from rfmitsuba.core import backend as B

    return B.Float(rng.normal(size=n).astype(np.float32))


# --------------------------------------------------------------------------- Splats.concat

def _concat_inputs(per_view_geometry: bool):
    """Two Gaussian sets of B = 3 views: set a (N = 5) with per-view opacities and signals (B*N;
    with ``per_view_geometry`` also per-view means, scales and rotations, as a person field
    gives them), set b (N = 4) with everything of size N. Flat float32 arrays by name."""
    rng = np.random.default_rng(11)
    b, na, nb = 3, 5, 4
    comps = {"means": 3, "log_scales": 3, "rotations": 4, "opacities": 1, "signals": 1}
    out = {}
    for key, n, per_view in (("a", na, {"opacities", "signals"} | (set(comps) if per_view_geometry else set())),
                             ("b", nb, set())):
        for name, c in comps.items():
            size = (b * n if name in per_view else n) * c
            out[f"{key}.{name}"] = rng.normal(size=size).astype(np.float32)
    return out, b, na, nb


@pytest.mark.parametrize("per_view_geometry", [False, True], ids=["shared-geometry", "per-view-geometry"])
def test_splats_concat_gradients(variant, per_view_geometry):
    """d/d(every input array) of sum_k <w_k, concat output k> (w_k fixed random), over all five
    arrays of both sets: AD vs central differences at 6 entries per array, step 1e-2 of the
    array's scale; rtol 1e-2, atol 1e-3 * max|FD| (concat is a gather/select, linear, so the
    differences are exact up to float32 rounding). The output sizes are checked too: everything
    is B*N where set a is per view."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.splat import Splats

    arrays, b, na, nb = _concat_inputs(per_view_geometry)
    types = {"means": B.Array3f, "log_scales": B.Array3f, "rotations": B.Array4f}
    rng = np.random.default_rng(12)
    n = na + nb
    comps = {"means": 3, "log_scales": 3, "rotations": 4, "opacities": 1, "signals": 1}
    per_view_out = {k: per_view_geometry or k in ("opacities", "signals") for k in comps}
    w = {k: _weights(rng, (b * n if per_view_out[k] else n) * c) for k, c in comps.items()}

    def unpack(p, key, name):
        v = p[f"{key}.{name}"]
        if name not in types:
            return v
        # component-wise gathers, not dr.unravel: gathering from an unravelled grad-enabled
        # Array4f aborts Dr.Jit 1.5 (LLVM) in the backward pass ("jit_assemble(): dirty variable")
        c = comps[name]
        i = dr.arange(B.UInt32, dr.width(v) // c) * c
        return types[name](*[dr.gather(B.Float, v, i + j) for j in range(c)])

    def loss(p):
        sets = [Splats(**{k: unpack(p, key, k) for k in comps}, n=cnt, b=b) for key, cnt in (("a", na), ("b", nb))]
        s = Splats.concat(sets)
        assert (s.n, s.b) == (n, b)
        terms = []
        for k, c in comps.items():
            v = getattr(s, k)
            parts = [v] if k not in types else [v[j] for j in range(c)]
            size = dr.width(parts[0])
            assert size * c == dr.width(w[k]), k
            # component j of entry i pairs with w[k][i*c + j] (as a ravel of the output would)
            terms += [x * dr.gather(B.Float, w[k], dr.arange(B.UInt32, size) * c + j) for j, x in enumerate(parts)]
        return terms

    params = {k: B.Float(v) for k, v in arrays.items()}
    for name in params:
        r = fd_check(loss, params, name, count=4, top=2, rel_eps=1e-2, min_scale=1.0, seed=1)
        _assert_fd(r, rtol=1e-2, atol=1e-3, min_entries=4)


# --------------------------------------------------------------------------- Stage-2 splat person field

def _person_field(anchor: str):
    from rfmitsuba.data.samples import person_features
    from rfmitsuba.models.splat import SplatConfig
    from rfmitsuba.models.splat_person import SplatPersonConfig, SplatPersonField

    box = np.array([[0.0, 0.0, 0.0], [4.0, 3.5, 2.8]])
    walk = np.array([[1.0, 1.0, 0.0], [2.0, 1.5, 0.0], [3.0, 2.0, 0.0]])
    hf = SplatPersonField.near_walk(walk, hcfg=SplatPersonConfig(num_gaussians=12, anchor=anchor),
                                    field_cfg=SplatConfig(init="random", num_gaussians=40), box=box,
                                    rng=np.random.default_rng(0), seed=3)
    person = np.array([[1.2, 1.1, 0.0], [2.1, 1.6, 0.0], [2.9, 2.2, 0.0]])
    extra = np.concatenate([person_features(person, box, octaves=hf.feature_octaves), person.astype(np.float32)], 1)
    antenna = np.array([[2.0, 2.0, 1.2], [1.0, 2.5, 1.0], [3.2, 0.8, 1.5]])
    return hf, antenna, extra


#: parameter -> (relative step, rtol, atol); the person means feed 6-octave encodings and
#: LeakyReLU networks, so they take a smaller step than the weights.
PERSON_PARAMS = {
    "deform.mlp": (1e-2, 5e-2, 3e-2),
    "means": (3e-3, 5e-2, 3e-2),
    "opacity_logits": (1e-2, 5e-2, 3e-2),
    "net.gaussian": (1e-2, 5e-2, 3e-2),
    "net.antenna": (1e-2, 5e-2, 3e-2),
    "net.head": (1e-2, 5e-2, 3e-2),
}


@pytest.mark.parametrize("anchor", ["person", "world"])
@pytest.mark.parametrize("name", list(PERSON_PARAMS))
def test_splat_person_field_gradients(variant, name, anchor):
    """d/d(parameter) of <w_m, means> + <w_s, signals> + <w_o, opacities> of
    ``SplatPersonField.splats`` for 3 views with person inputs (features + feet position), all
    B*N per view; w fixed random. AD vs central differences at 3 random entries and 3 among the
    largest AD entries; step (PERSON_PARAMS) times max(|p_i|, rms of the array); rtol 5e-2,
    atol 3e-2 * max|FD| (measured errors: below 1 % of max|FD|)."""
    import drjit as dr

    rel_eps, rtol, atol = PERSON_PARAMS[name]
    hf, antenna, extra = _person_field(anchor)
    nb, n = len(antenna), hf.num_gaussians
    rng = np.random.default_rng(7)
    w = {k: _weights(rng, c * n * nb) for k, c in (("means", 3), ("signals", 1), ("opacities", 1))}

    def loss(p):
        hf.assign(p)
        s = hf.splats(antenna, extra=extra)
        return [dr.ravel(s.means) * w["means"], s.signals * w["signals"], s.opacities * w["opacities"]]

    r = fd_check(loss, hf.parameters(), name, count=3, top=3, rel_eps=rel_eps, min_scale=1.0, seed=1)
    _assert_fd(r, rtol, atol)


# --------------------------------------------------------------------------- Stage-2 coherent person fields

def _coherent_background():
    from rfmitsuba.models.coherent import CoherentField
    from rfmitsuba.rf import images

    maps = images.image_maps(images.box_planes(*BOX), room_order=1, furniture_order=0)
    bg = CoherentField(maps, box=BOX, frequency_hz=F, seed=1)
    bg.freeze()
    return bg


def _coherent_person(kind: str):
    """A frozen box-room background (direct path + 6 first-order images) and a person field of
    ``kind``; the perturbation network's last layer (zero at initialisation) gets random weights
    so that every parameter has a gradient."""
    from rfmitsuba.data.samples import person_features
    from rfmitsuba.models.coherent_person import (
        CoherentPersonConfig,
        CoherentPersonField,
        CoherentPerturbField,
    )

    bg = _coherent_background()
    if kind == "scatter":
        hum = CoherentPersonField.for_background(bg, cfg=CoherentPersonConfig(kind="scatter", num_points=4, embed=8,
                                                                              width=16), seed=2)
    else:
        hum = CoherentPerturbField(bg, cfg=CoherentPersonConfig(kind="perturb", embed=8, width=16), seed=0)
        w = np.array(hum.net.weights.numpy(), np.float32, copy=True)
        hum.net.set_weights(w + 0.05 * np.random.default_rng(3).standard_normal(w.size).astype(np.float32))
    x = np.array([[1.0, 0.8, 1.1], [2.5, 1.5, 0.7], [1.6, 2.2, 1.4]])
    y = np.tile([3.6, 2.6, 2.0], (len(x), 1))
    feet = np.array([[2.0, 1.3, 0.0], [2.9, 2.0, 0.0], [2.4, 2.4, 0.0]])
    extra = np.concatenate([person_features(feet, BOX, octaves=hum.feature_octaves), feet], 1)
    return bg, hum, x, y, extra


COHERENT_PARAMS = {
    "scatter": ["offsets", "amp", "embed", "net.gain", "deform.net"],
    "perturb": ["embed", "net.perturb"],
}
#: relative step: the scatterer offsets (metres) set path lengths, whose phase k L turns by
#: 50 rad per metre at 2.4 GHz, so they take a step 10x smaller than the other arrays
COHERENT_STEP = {"offsets": 1e-3}
#: through the Bartlett read-out the person's part is a small change of an image dominated by the
#: background, so float32 rounding of the image needs larger steps (measured: with 1e-2 the
#: difference quotients of "embed" scatter by ~30 % of the smaller entries, with 5e-2 by < 1 %)
RENDER_STEP = {"offsets": 2e-3}


@pytest.mark.parametrize("kind,name", [(k, n) for k, names in COHERENT_PARAMS.items() for n in names])
def test_coherent_person_channel_gradients(variant, kind, name):
    """d/d(parameter) of <c_re, h_re> + <c_im, h_im> of the person field's ``channels(x, y, q,
    extra=...)`` (moving RX: q = x; 3 views, 16 elements; c fixed random), for every array of
    ``parameters()``: AD vs central differences at 3 random entries and 3 among the largest AD
    entries, step 1e-2 (offsets: 1e-3) * max(|p_i|, rms); rtol 5e-2, atol 3e-2 * max|FD|."""
    bg, hum, x, y, extra = _coherent_person(kind)
    assert set(hum.parameters()) == set(COHERENT_PARAMS[kind])
    rng = np.random.default_rng(5)
    c_re, c_im = _weights(rng, 16 * len(x)), _weights(rng, 16 * len(x))

    def loss(p):
        hum.assign(p)
        hr, hi = hum.channels(x, y, x, extra=extra)
        return [hr * c_re, hi * c_im]

    r = fd_check(loss, hum.parameters(), name, count=3, top=3, rel_eps=COHERENT_STEP.get(name, 1e-2), min_scale=1.0,
                 seed=2)
    _assert_fd(r, rtol=5e-2, atol=3e-2)


@pytest.mark.parametrize("kind,name", [("scatter", "amp"), ("scatter", "net.gain"), ("scatter", "offsets"),
                                       ("perturb", "net.perturb"), ("perturb", "embed")])
def test_coherent_person_render_gradients(variant, kind, name):
    """The same through the full read-out: d/d(parameter) of <W, render([bg, person], views,
    normalize=False)> (background + person channels, Bartlett PAS on a 9 x 36 grid, 3 views,
    W fixed random), AD vs central differences at 6 random and 3 large-gradient entries, step
    5e-2 (offsets: 2e-3) * max(|p_i|, rms) (RENDER_STEP); rtol 5e-2, atol 3e-2 * max|FD|."""
    from rfmitsuba.models.base import Views, render

    bg, hum, x, y, extra = _coherent_person(kind)
    views = Views(antenna_pos=x, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=F, task="rx",
                  inputs=lambda field: extra if field is hum else None)
    h, w = 9, 36
    W = _weights(np.random.default_rng(6), len(x) * h * w)

    def loss(p):
        hum.assign(p)
        img = render([bg, hum], views, height=h, width=w, normalize=False)
        assert img.shape == (len(x), h, w)
        return [img.array * W]

    r = fd_check(loss, hum.parameters(), name, count=6, top=3, rel_eps=RENDER_STEP.get(name, 5e-2), min_scale=1.0,
                 seed=3)
    _assert_fd(r, rtol=5e-2, atol=3e-2)
