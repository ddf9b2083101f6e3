"""rfmitsuba.models.coherent_gaussians.field: the coherent Gaussian field (virtual sources and
scatterers with complex gains, per-element calibration and pose, amplitude or phase-only Bartlett
read-out).

Finite-difference gradient checks of every parameter (through the channels and through the
read-out), the physics on hand-made cases (the direct path alone points at the transmitter; the
spherical wavefront tends to the plane wave far away), the state round trip, a training step's
kernels compiled once, a known room's ray-cast visibility (blocked paths, the tracer's depth and
shortest segment), the visibility grid and the mutual coupling."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from coherent_gaussians_cases import F, _field
from fd_helpers import fd_check

PARAMS = ["img_offset", "img_amp", "sc_pos", "sc_amp", "vis_center", "vis_log_extent", "cal", "pose"]


#: every test on one Dr.Jit thread (the ``one_thread`` fixture of tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def _views(task="tx", n=3):
    from rfmitsuba.models.base import Views

    rng = np.random.default_rng(1)
    q = np.array([1.5, 1.0, 1.0]) + rng.random((n, 3)) * [1.0, 1.0, 0.5]
    fixed = np.tile([3.5, 2.5, 2.0], (n, 1))
    x, y = (fixed, q) if task == "tx" else (q, fixed)
    return Views(antenna_pos=q, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=F, task=task)


def _w(rng, n):
    from rfmitsuba.core import backend as B

    return B.Float(rng.normal(size=n).astype(np.float32))


#: finite-difference steps (relative): path lengths move the phase by k = 50 rad/m, so positions take small steps
STEP = {"img_offset": 1e-2, "sc_pos": 3e-4, "vis_center": 1e-2, "pose": 1e-2}


@pytest.mark.parametrize("wavefront", ["plane", "spherical"])
@pytest.mark.parametrize("name", PARAMS)
def test_channel_gradients(name, wavefront):
    """d/d(parameter) of <c, h> of the calibrated channels (3 views, moving TX), AD vs central
    differences at 3 random and 3 large-gradient entries; rtol 5e-2, atol 3e-2 * max|FD|."""
    f = _field(wavefront=wavefront)
    assert set(f.parameters()) == set(PARAMS)
    _check_channel_gradient(f, name)


def _check_channel_gradient(f, name):
    """AD against central differences of <c, h> of ``f``'s calibrated channels in ``name``."""
    views = _views()
    rng = np.random.default_rng(2)
    c_re, c_im = _w(rng, 48), _w(rng, 48)

    def loss(p):
        f.assign(p)
        hr, hi = f.channels(views)
        return [hr * c_re, hi * c_im]

    r = fd_check(loss, f.parameters(), name, count=3, top=3, rel_eps=STEP.get(name, 1e-2), min_scale=1.0, seed=4)
    assert len(r.index) >= 3 and r.ok(5e-2, 3e-2), r.report()


@pytest.mark.parametrize("readout", ["amplitude", "phase_only"])
@pytest.mark.parametrize("name", ["img_amp", "sc_pos", "cal", "pose"])
def test_render_gradients(name, readout):
    """The same through the Bartlett read-out (9 x 36 grid, raw PAS, moving RX)."""
    from rfmitsuba.models.base import render

    f = _field(readout=readout)
    views = _views("rx")
    W = _w(np.random.default_rng(3), 3 * 9 * 36)

    def loss(p):
        f.assign(p)
        return [render([f], views, height=9, width=36, normalize=False).array * W]

    r = fd_check(loss, f.parameters(), name, count=3, top=3, rel_eps=STEP.get(name, 5e-3), min_scale=1.0, seed=5)
    assert len(r.index) >= 3 and r.ok(5e-2, 3e-2), r.report()


def test_direct_path_points_at_the_transmitter_and_phase_only_ignores_amplitude():
    """Only the direct path: the PAS peaks in the transmitter's direction (folded to the upper
    hemisphere); per-element amplitude errors change the amplitude PAS but not the phase-only one."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import render
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    views = _views("tx", n=2)
    imgs = {}
    for ro in ("amplitude", "phase_only"):
        f = CoherentGaussianField(np.eye(3)[None], np.array([0]), np.zeros((0, 3)), cfg=CoherentGaussianConfig(),
                                  readout=ro, wavefront="spherical", vis_center=np.zeros(3), frequency_hz=F)
        base = render([f], views).numpy()
        cal = np.tile([1.0, 0.0], 16)
        cal[::2] = np.linspace(0.3, 2.0, 16)
        f.params["cal"] = B.Float(cal.astype(np.float32))
        imgs[ro] = (base, render([f], views).numpy())
    base = imgs["amplitude"][0]
    d = views.transmitter - views.view_pos
    for b in range(2):
        row, col = np.unravel_index(np.argmax(base[b]), base[b].shape)
        el = np.degrees(np.arcsin(abs(d[b, 2]) / np.linalg.norm(d[b])))
        az = np.degrees(np.arctan2(d[b, 1], d[b, 0])) % 360
        assert abs(row + 1 - el) <= 3 and min(abs(col - az), 360 - abs(col - az)) <= 3
    assert np.abs(imgs["amplitude"][1] - imgs["amplitude"][0]).max() > 1e-2
    np.testing.assert_allclose(imgs["phase_only"][1], imgs["phase_only"][0], atol=1e-4)


def test_spherical_tends_to_plane_wave_far_away():
    """A source 300 m away: the exact per-element path lengths give the plane-wave channel."""
    from rfmitsuba.models.base import Views
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    far = Views(antenna_pos=np.array([[300.0, 40.0, 60.0]]), view_pos=np.zeros((1, 3)),
                transmitter=np.array([[300.0, 40.0, 60.0]]), rx_to_world=None, frequency_hz=F, task="tx")
    h = {}
    for wf in ("plane", "spherical"):
        f = CoherentGaussianField(np.eye(3)[None], np.array([0]), np.zeros((0, 3)), cfg=CoherentGaussianConfig(),
                                  readout="amplitude", wavefront=wf, vis_center=np.array([300.0, 40, 60]),
                                  frequency_hz=F)
        hr, hi = f.channels(far)
        h[wf] = np.asarray(hr.numpy()) + 1j * np.asarray(hi.numpy())
    assert np.abs(np.angle(h["plane"] / h["spherical"])).max() < 0.05  # radians
    assert np.allclose(np.abs(h["plane"]), np.abs(h["spherical"]), rtol=1e-3)


def test_state_round_trip_and_frozen(tmp_path):
    from rfmitsuba.models.base import load_field, render

    f = _field(readout="phase_only", wavefront="spherical")
    f.freeze()
    p = f.save(tmp_path / "f.npz")
    g = load_field(p)
    assert type(g) is type(f) and g.frozen and g.trainable() == {}
    assert (g.readout, g.wavefront, g.num_images, g.num_scatterers) == ("phase_only", "spherical", 2, 2)
    v = _views()
    np.testing.assert_allclose(render([g], v).numpy(), render([f], v).numpy(), atol=1e-6)
    assert g.num_parameters == 6 + 4 + 6 + 4 + 12 + 4 + 32 + 6 + 84   # K: "auto" learns it for phase-only spectra (42 neighbour pairs)
    assert [x.name for x in g.export_ply(tmp_path, views=v)] == ["sources.ply"]


def test_bad_input_is_named():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.base import Views
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    cfg = CoherentGaussianConfig()
    with pytest.raises(ConfigError, match="orthogonal"):
        CoherentGaussianField(np.ones((1, 3, 3)), np.array([0]), np.zeros((0, 3)), cfg=cfg, readout="amplitude",
                              wavefront="plane", vis_center=np.zeros(3), frequency_hz=F)
    with pytest.raises(ConfigError, match="readout"):
        CoherentGaussianConfig(readout="power")
    f = _field()
    bad = Views(antenna_pos=np.full((1, 3), np.nan), view_pos=np.zeros((1, 3)), transmitter=np.zeros((1, 3)),
                rx_to_world=None, frequency_hz=F)
    with pytest.raises(ConfigError, match="finite"):
        f.channels(bad)


def test_training_step_kernels_compile_once(variant):
    """Render + loss + backward + Adam step of the field: after two warm-up steps (Adam's first step
    starts from zero moments, a different kernel), further steps with other views and other
    parameter values (same batch size) launch only kernels already compiled
    (``dr.kernel_history``: every JIT kernel a cache hit), so nothing recompiles per step."""
    import drjit as dr
    from drjit.opt import Adam

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import Views, render
    from rfmitsuba.train.loss import loss

    f = _field(wavefront="spherical")
    opt = Adam(lr=1e-3)
    for k, v in f.trainable().items():
        opt[k] = v
    rng = np.random.default_rng(7)

    def step():
        f.assign({k: opt[k] for k in opt.keys()})
        y = np.array([1.5, 1.0, 1.0]) + rng.random((4, 3))
        views = Views(antenna_pos=y, view_pos=np.tile([3.5, 2.5, 2.0], (4, 1)), transmitter=y, rx_to_world=None,
                      frequency_hz=F, task="tx")
        gt = B.TensorXf(rng.random((4, 45, 180)).astype(np.float32))
        dr.backward(loss(render([f], views, height=45, width=180), gt))
        opt.step()
        dr.eval(opt[k] for k in opt.keys())
        dr.sync_thread()

    step()
    step()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        step()
        step()
        jit = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert len(jit) > 5
    assert all(k["cache_hit"] for k in jit), [k.get("operation_count") for k in jit if not k["cache_hit"]]


def _room_field(max_depth=None, min_segment=None, **cfg):
    """A known-room field in the built-in bedroom (room order 1 and furniture faces, ray-cast
    visibility), its parameters perturbed as in :func:`_field`, and 6 moving-RX views."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import Views
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.rf.images import scene_image_maps
    from rfmitsuba.scenes import path as scene_path
    from rfmitsuba.sim.geometry import RoomGeometry

    xml = scene_path("bedroom")
    maps = scene_image_maps(RoomGeometry.from_xml(xml), room_order=1, furniture_order=1, distinct_paths=True,
                            furniture_planes="faces")
    c = CoherentGaussianConfig(init_extent=3.0, init_through=0.3, **cfg)
    f = CoherentGaussianField(maps.A, maps.order, np.zeros((0, 3)), cfg=c, readout="amplitude", wavefront="plane",
                              vis_center=np.array([2.0, 1.7, 1.0]), frequency_hz=F, planes=maps.planes,
                              scene_xml=xml, init="room", max_depth=max_depth, min_segment=min_segment)
    f.params["img_offset"] = B.Float(maps.b.ravel().astype(np.float32))
    rng = np.random.default_rng(0)
    for k in ("img_amp", "img_through", "img_slope", "cal"):
        if k not in f.params:
            continue
        a = np.asarray(f.params[k].numpy(), np.float64)
        f.params[k] = B.Float((a + 0.05 * rng.normal(size=a.shape)).astype(np.float32))
    q = np.array([[1.0, 1.5, 1.2], [2.0, 2.5, 0.4], [3.0, 2.0, 1.0], [1.5, 0.5, 0.3], [3.5, 2.8, 1.5],
                  [0.9, 2.6, 0.3]])
    y = np.tile([0.3, 0.3, 2.0], (len(q), 1))
    return f, Views(antenna_pos=q, view_pos=q, transmitter=y, rx_to_world=None, frequency_hz=F, task="rx")


def _channel_loss(f, views, *, seed):
    """A loss of ``f``'s channels for :func:`fd_check`: fixed random weights on every channel."""
    rng = np.random.default_rng(seed)
    n = 16 * views.count
    c_re, c_im = _w(rng, n), _w(rng, n)

    def loss(p):
        f.assign(p)
        hr, hi = f.channels(views)
        return [hr * c_re, hi * c_im]

    return loss


def test_known_room_visibility_and_through_gain_gradients():
    """Ray-cast visibility: some views see a blocked path (the wardrobe, the bed), whose term takes
    ``img_through``; its gradient (and ``img_amp``'s) matches finite differences; a path that does not
    exist contributes nothing (zeroing the gains of absent images changes no channel)."""
    from rfmitsuba.core import backend as B

    f, views = _room_field()
    ex, cl, cos_in = f.visibility(views.view_pos, views.transmitter)
    assert (ex & ~cl).any() and cl.any() and (~ex).any()
    assert np.all((cos_in >= 0) & (cos_in <= 1)) and np.all(cos_in[:, f.order == 0] == 1)
    assert "img_through" in f.parameters()
    loss = _channel_loss(f, views, seed=2)

    for name in ("img_through", "img_slope", "img_amp"):
        r = fd_check(loss, f.parameters(), name, count=3, top=3, rel_eps=1e-2, min_scale=1.0, seed=4)
        assert len(r.index) >= 3 and r.ok(5e-2, 3e-2), r.report()
    h0 = [np.asarray(v.numpy()) for v in f.channels(views)]
    never = ~ex.any(0)                                                    # images no view sees
    for k in ("img_amp", "img_through", "img_slope"):
        a = np.asarray(f.params[k].numpy()).reshape(-1, 2)
        a[never] = 0.0
        f.params[k] = B.Float(a.ravel())
    h1 = [np.asarray(v.numpy()) for v in f.channels(views)]
    np.testing.assert_allclose(h1[0], h0[0], atol=1e-6)
    np.testing.assert_allclose(h1[1], h0[1], atol=1e-6)


def test_path_visibility_cache_is_bounded(monkeypatch):
    """Ray-cast visibility is remembered for at most VIS_CACHE_VIEWS views; past that, new views
    (jittered training views are each seen once) are cast every time, with the same result."""
    from rfmitsuba.models.coherent_gaussians import field as cg

    f, views = _room_field()
    want = f.path_trace(views.view_pos, views.transmitter)
    g, _ = _room_field()
    monkeypatch.setattr(cg, "VIS_CACHE_VIEWS", 1)
    for _ in range(2):
        got = g.path_trace(views.view_pos, views.transmitter)
        assert len(g._vis_cache) == 1 and len(views.view_pos) > 1
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)


def test_paths_deeper_than_the_tracer_are_absent(tmp_path):
    """With the data's tracer depth D, a path exists only if its reflections plus crossings are at
    most D: at D = 1 the blocked direct path (2 wood crossings) and every blocked reflection are
    gone, clear first-order reflections stay; at D = 3 the blocked direct path is back; no depth
    (measured data) or ``depth_limit = false`` keeps every path; the depth travels with the state."""
    from rfmitsuba.models.base import load_field

    free, views = _room_field()
    raw = free.path_trace(views.view_pos, views.transmitter)
    blocked = raw.exists & ~raw.clear
    assert blocked[:, 0].any() and blocked[:, free.order == 1].any()
    d1 = _room_field(max_depth=1)[0].path_trace(views.view_pos, views.transmitter)
    assert not (d1.exists & ~d1.clear).any() and np.array_equal(d1.clear, raw.clear)
    d3 = _room_field(max_depth=3)[0]
    t3 = d3.path_trace(views.view_pos, views.transmitter)
    assert np.array_equal(t3.exists[:, 0], raw.exists[:, 0])
    deep = free.order[None, :] + raw.crossings.sum(-1) > 3
    np.testing.assert_array_equal(t3.exists, raw.exists & ~deep)
    assert _room_field(max_depth=1, depth_limit=False)[0].max_depth is None
    assert load_field(d3.save(tmp_path / "f.npz")).max_depth == 3


def test_paths_with_a_segment_shorter_than_the_tracers_are_absent(tmp_path):
    """The bedroom's direct paths from the corner (0.3, 0.3, 2.0) to positions 659 and 870 of a
    900-position moving-TX dataset cut through the corner of the wardrobe (the
    box [0.01, 0.61] x [0.9, 2.1] x [0, 2.1] m; chords by the slab method: 7.4 mm and 5.9 mm), the
    one to position 838 crosses 1.2 m of it: with Sionna RT's 1 cm shortest segment the first two are absent (Sionna
    traced no direct path at 659 and 870), the third stays blocked; without a limit (measured
    data) or with ``segment_limit = false`` all three exist; the limit travels with the state."""
    from rfmitsuba.models.base import Views, load_field

    q = np.array([[1.00091, 1.66908, 1.00383], [1.83874, 3.30400, 1.53262], [0.18255, 2.81388, 1.49865]])
    y = np.tile([0.3, 0.3, 2.0], (len(q), 1))
    lo, hi = np.array([0.01, 0.9, 0.0]), np.array([0.61, 2.1, 2.1])
    d = q - y
    t0, t1 = (lo - y) / d, (hi - y) / d
    chord = (np.maximum(t0, t1).min(1) - np.minimum(t0, t1).max(1)) * np.linalg.norm(d, axis=1)
    views = Views(antenna_pos=q, view_pos=q, transmitter=y, rx_to_world=None, frequency_hz=F, task="rx")
    raw = _room_field()[0].path_trace(views.view_pos, views.transmitter)
    assert raw.exists[:, 0].all() and not raw.clear[:, 0].any()
    np.testing.assert_allclose(raw.shortest_segment[:2, 0], chord[:2], atol=2e-4)
    np.testing.assert_allclose(chord, [0.0074, 0.0059, 1.22], atol=5e-3)
    assert raw.shortest_segment[2, 0] > 0.5             # a leg outside the wardrobe, shorter than the chord
    lim = _room_field(min_segment=0.01)[0]
    tr = lim.path_trace(views.view_pos, views.transmitter)
    np.testing.assert_array_equal(tr.exists[:, 0], [False, False, True])
    np.testing.assert_array_equal(tr.exists[:, 1:], raw.exists[:, 1:] & (raw.shortest_segment[:, 1:] > 0.01))
    assert _room_field(min_segment=0.01, segment_limit=False)[0].min_segment is None
    assert load_field(lim.save(tmp_path / "f.npz")).min_segment == 0.01


def test_known_room_state_round_trip(tmp_path):
    """Planes and the room's XML travel with the state: the loaded field casts the same rays and
    renders the same PAS; a missing XML is named."""
    import json

    from rfmitsuba.core.errors import RunError
    from rfmitsuba.models.base import load_field, render
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianField

    f, views = _room_field()
    g = load_field(f.save(tmp_path / "f.npz"))
    np.testing.assert_array_equal(g.planes, f.planes)
    np.testing.assert_allclose(render([g], views).numpy(), render([f], views).numpy(), atol=1e-6)
    st = f.state_dict()
    meta = json.loads(str(st["meta"]))
    meta["scene_xml"] = str(tmp_path / "gone.xml")
    st["meta"] = np.asarray(json.dumps(meta))
    with pytest.raises(RunError, match="gone.xml"):
        CoherentGaussianField.from_state_dict(st)
    meta["scene_xml"] = str(tmp_path / "elsewhere" / "bedroom.xml")     # a checkout moved: the built-in room
    st["meta"] = np.asarray(json.dumps(meta))
    assert CoherentGaussianField.from_state_dict(st).scene_xml == f.scene_xml
    off = _room_field(ray_visibility=False)[0]                          # the config turns it off
    assert off.scene_xml is None and "img_through" not in off.parameters()
    flat = _room_field(incidence_slope=False)[0]                        # img_slope kept at 0, not trained
    assert "img_slope" in flat.parameters() and "img_slope" not in flat.trainable()


def test_pose_schedule_decays_in_a_known_room_only():
    """The array pose trains on the decaying "means" schedule where the room is known, on the
    constant "rotations" rate from a data scan; every other parameter's group is the table's."""
    from rfmitsuba.models.coherent_gaussians import LR_GROUPS

    known, scanned = _room_field()[0], _field()
    assert known.init == "room" and known.lr_group("pose") == "means"
    assert scanned.init != "room" and scanned.lr_group("pose") == "rotations"
    assert all(scanned.lr_group(k) == LR_GROUPS[k] for k in LR_GROUPS if k != "pose")


def test_visibility_grid():
    """vis_grid: each source's window times 2 sigmoid(trilinear cells over the box): 1 at the zero
    start (the channels equal the grid-free field's), gradients match finite differences, the
    config names a bad grid, and the grid travels with the state."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.base import load_field
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    A = np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])])
    sc = np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5]])
    make = lambda grid: CoherentGaussianField(A, np.array([0, 1]), sc, cfg=CoherentGaussianConfig(  # noqa: E731
        init_extent=1.5, vis_grid=grid), readout="amplitude", wavefront="plane", vis_center=np.array([2.0, 1.5, 1.0]),
        frequency_hz=F)
    views = _views()
    f, plain = make((3, 2, 2)), make((0, 0, 0))
    assert f.grid_cells == 12 and len(f.params["vis_grid"].numpy()) == 12 * 4 and plain.grid_cells == 0
    for a, b in zip(f.channels(views), plain.channels(views)):
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=1e-5, atol=1e-7)
    rng = np.random.default_rng(5)
    f.params["vis_grid"] = B.Float(rng.normal(size=48).astype(np.float32))
    f.params["vis_grid_box"] = B.Float(np.array([1.4, 1.2, 0.9, 2.2, 1.9, 1.3], np.float32))  # views partly outside
    r = fd_check(_channel_loss(f, views, seed=2), f.parameters(), "vis_grid", count=4, top=3, rel_eps=1e-2,
                 min_scale=1.0, seed=4)
    assert len(r.index) >= 3 and r.ok(5e-2, 3e-2), r.report()
    tmp = Path(tempfile.mkdtemp())
    g = load_field(f.save(tmp / "f.npz"))
    assert g.cfg.vis_grid == (3, 2, 2)
    for a, b in zip(g.channels(views), f.channels(views)):
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=1e-6, atol=1e-8)
    for bad in ((0, 2, 2), (2, 2), (-1, 1, 1), None):
        with pytest.raises(ConfigError, match="vis_grid"):
            CoherentGaussianConfig(vis_grid=bad)


def _coupled_field(seed=0):
    """_field's sources with the mutual coupling on, every parameter perturbed (K too)."""
    import dataclasses

    from rfmitsuba.models.coherent_gaussians import CoherentGaussianField, coupling_size

    f = _field(seed=seed)
    g = CoherentGaussianField(f.A, f.order, np.asarray(f.params["sc_pos"].numpy()).reshape(-1, 3),
                              cfg=dataclasses.replace(f.cfg, coupling=True), readout=f.readout,
                              wavefront=f.wavefront, vis_center=np.zeros(3), frequency_hz=F, seed=seed)
    assert np.all(g.params["coupling"].numpy() == 0)                    # starts as no coupling
    state = {k: np.asarray(v.numpy()) for k, v in f.params.items()}
    state["coupling"] = 0.1 * np.random.default_rng(seed).normal(size=2 * coupling_size())
    g.load_state_dict(state)
    return f, g


@pytest.mark.parametrize("name", ["coupling", "cal", "sc_amp"])
def test_coupling_gradients(name):
    """d/d(parameter) of <c, h> with the coupling on: AD against central differences."""
    _, g = _coupled_field()
    _check_channel_gradient(g, name)


def test_coupling_mixes_the_elements_as_i_plus_k(tmp_path):
    """h_coupled = cal * ((I + K) h) against NumPy on the uncoupled field's channels; K = 0 gives
    the uncoupled channels; the state round-trips with its coupling; older states load without,
    and a state with a free 16 x 16 K (a removed option) is refused, naming it."""
    from rfmitsuba.core.errors import RunError
    import json

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianField, coupling_index, coupling_size

    f, g = _coupled_field(seed=1)
    views = _views()
    with np.errstate(all="ignore"):
        cal = np.asarray(f.params["cal"].numpy(), np.float64).reshape(-1, 2) @ [1, 1j]
        f.params["cal"] = B.Float(np.tile([1.0, 0.0], 16).astype(np.float32))
        hr, hi = f.channels(views)
        h = (hr.numpy() + 1j * hi.numpy()).reshape(-1, 16)
        coef = np.asarray(g.params["coupling"].numpy(), np.float64).reshape(-1, 2) @ [1, 1j]
        idx = coupling_index()
        K = np.where(idx >= 0, coef[np.maximum(idx, 0)], 0)
        want = cal[None] * (h + h @ K.T)
        gr, gi = g.channels(views)
    np.testing.assert_allclose(gr.numpy() + 1j * gi.numpy(), want.ravel(), rtol=2e-4, atol=2e-4 * np.abs(want).max())
    g.save(tmp_path / "g.npz")
    back = CoherentGaussianField.load(tmp_path / "g.npz")
    np.testing.assert_array_equal(back.params["coupling"].numpy(), g.params["coupling"].numpy())
    assert back.cfg.coupling
    assert back.num_parameters == f.num_parameters + 2 * coupling_size()
    old = f.state_dict()                          # a state saved before the option existed
    meta = json.loads(str(old["meta"]))
    del meta["config"]["coupling"]
    old["meta"] = np.asarray(json.dumps(meta))
    assert not CoherentGaussianField.from_state_dict(old).cfg.coupling
    full = g.state_dict()                         # a free K, the removed coupling_model = "full"
    full["coupling"] = np.zeros(512, np.float32)
    with pytest.raises(RunError, match="256 coefficients .* train the field again"):
        CoherentGaussianField.from_state_dict(full)
    g.params["coupling"] = B.Float(np.zeros(2 * coupling_size(), np.float32))
    g.params["cal"] = f.params["cal"]
    zr, zi = g.channels(views)
    np.testing.assert_allclose(zr.numpy(), hr.numpy(), rtol=1e-6, atol=1e-7)


def test_coupling_auto_follows_the_readout():
    """``coupling = "auto"`` (the default) learns K for phase-only spectra (a NeRF2 gateway) and
    not for the amplitude read-out of simulated rooms; a phase-only state saved without K loads
    without it; anything but true, false or "auto" is refused."""
    import json

    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    assert CoherentGaussianConfig().coupling == "auto"
    amp, pha = _field(), _field(readout="phase_only", wavefront="spherical")
    assert amp.cfg.coupling is False and "coupling" not in amp.params
    assert pha.cfg.coupling is True and pha.num_parameters == amp.num_parameters + 84
    old = pha.state_dict()
    del old["coupling"]
    meta = json.loads(str(old["meta"]))
    meta["config"]["coupling"] = "auto"
    old["meta"] = np.asarray(json.dumps(meta))
    back = CoherentGaussianField.from_state_dict(old)
    assert back.cfg.coupling is False and "coupling" not in back.params
    with pytest.raises(ConfigError, match="coupling"):
        CoherentGaussianConfig(coupling="on")


def test_candidate_image_gradient_sees_the_coupling():
    """``image_gain_gradients`` of a coupled field: the gradient of ``sum Re(conj(G) h)`` with
    respect to a candidate's gain equals ``<G, h_c>``, ``h_c`` the channel the candidate adds at
    gain 1 when appended to the field (its coupling and calibration included)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.train.pursuit import reflection

    _, g = _coupled_field(seed=2)
    views = _views(n=4)
    A, b = reflection(1, -0.4)
    rng = np.random.default_rng(5)
    G = rng.normal(size=(2, 64))
    got = g.image_gain_gradients(views, G[0], G[1], A[None], b[None])[0]
    with dr.suspend_grad():
        h0r, h0i = g.channels(views)
        g.add_images(A[None], b[None], np.array([1]), vis_center=np.zeros(3))
        amp = np.asarray(g.params["img_amp"].numpy()).copy()
        ext = np.asarray(g.params["vis_log_extent"].numpy()).copy()
        amp[-2:] = [1.0, 0.0]
        ext[g.num_images - 1] = 30.0                  # the new image's window: 1 everywhere
        g.params["img_amp"], g.params["vis_log_extent"] = B.Float(amp), B.Float(ext)
        h1r, h1i = g.channels(views)
    hcr = np.asarray(h1r.numpy(), np.float64) - np.asarray(h0r.numpy(), np.float64)
    hci = np.asarray(h1i.numpy(), np.float64) - np.asarray(h0i.numpy(), np.float64)
    # d/d re of sum(Gr Re h + Gi Im h) with h = gain * h_c: <G, h_c>; d/d im: <G, j h_c>
    want = [G[0] @ hcr + G[1] @ hci, -G[0] @ hci + G[1] @ hcr]
    np.testing.assert_allclose(got, want, rtol=2e-3, atol=2e-3 * np.abs(want).max())
