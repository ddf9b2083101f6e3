"""Tests of rfmitsuba.sim.simulate against closed forms (free space, one metal plate), reciprocity
with an explicit reverse solve, and reproducibility."""
import numpy as np
import pytest
from conftest import write_quads_scene

from rfmitsuba.core.errors import ConfigError, PlacementError, SceneError
from rfmitsuba.rf import array as antenna
from rfmitsuba.rf import bartlett_ref as pas
from rfmitsuba.rf import grid

F = 2.4e9


@pytest.fixture(scope="module")
def empty_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("free") / "empty.xml"
    path.write_text('<scene version="2.1.0"></scene>\n')
    return path


@pytest.fixture(scope="module")
def plate_scene(tmp_path_factory):
    # one 10 x 10 m metal plate in the plane x = 2
    quads = {"plate": [(2, -5, -5), (2, 5, -5), (2, 5, 5), (2, -5, 5)]}
    return write_quads_scene(tmp_path_factory.mktemp("plate"), quads, material="metal")


def sim(xml, fixed, positions, **solver):
    from rfmitsuba.sim.simulate import Simulator, SolverConfig

    s = Simulator(xml, fixed_pos=fixed, frequency_hz=F, solver=SolverConfig(**solver))
    s.set_positions(np.asarray(positions, float))
    return s


def az_el(v):
    return (np.degrees(np.arctan2(v[1], v[0])) % 360, np.degrees(np.arcsin(abs(v[2]) / np.linalg.norm(v))))


def ang_diff(a, b):
    return abs((a - b + 180) % 360 - 180)


def test_free_space_gain_and_peak_both_tasks(variant, empty_scene):
    fixed = np.array([0.0, 0.0, 2.0])
    pos = np.array([[3.0, 4.0, 1.0], [-2.0, 1.0, 0.5], [1.0, -2.5, 1.7]])
    ps = sim(empty_scene, fixed, pos, samples_per_src=1000).solve()
    assert np.all(ps.num_paths == 1)
    d = np.linalg.norm(pos - fixed, axis=1)
    fspl_db = 20 * np.log10(4 * np.pi * d * F / antenna.SPEED_OF_LIGHT)
    assert np.allclose(ps.path_gain_db(), -fspl_db, atol=0.1)
    for task in ("rx", "tx"):
        p = pas.bartlett(ps.channels(task, frequency_hz=F), frequency_hz=F)
        for k in range(len(pos)):
            v = fixed - pos[k] if task == "rx" else pos[k] - fixed  # towards the other device
            az, el = az_el(v)
            pel, paz = np.degrees(pas.peak_direction(p[k]))
            assert ang_diff(paz, az) <= 2 and abs(pel - el) <= 2, (task, k, paz, az, pel, el)


def test_metal_plate_second_peak_at_mirror_image(variant, plate_scene):
    # LoS at 63 deg elevation, the image at 26 deg: both clear of the horizon where a
    # half-wavelength horizontal array has grating lobes
    fixed = np.array([0.0, 0.0, 2.5])
    pos = np.array([[0.0, -1.0, 0.5]])
    ps = sim(plate_scene, fixed, pos, samples_per_src=20000).solve()
    assert ps.num_paths[0] == 2  # LoS + one reflection
    p = pas.bartlett(ps.channels("rx", frequency_hz=F), frequency_hz=F)[0]
    el, az = grid.angle_grid()
    az_los, el_los = az_el(fixed - pos[0])
    az_img, el_img = az_el(np.array([4.0, 0.0, 2.5]) - pos[0])  # the image of the TX in the plate
    pel, paz = np.degrees(pas.peak_direction(p))
    assert ang_diff(paz, az_los) <= 3 and abs(pel - el_los) <= 3
    # second peak: the brightest pixel 40 deg or more (great circle) away from the first
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    u1 = d[np.unravel_index(np.argmax(p), p.shape)]
    far = np.degrees(np.arccos(np.clip(d @ u1, -1, 1))) > 40
    q = np.where(far, p, -1)
    i, j = np.unravel_index(np.argmax(q), q.shape)
    # a 4x4 array's LoS sidelobes pull the second peak by a few degrees
    assert ang_diff(j, az_img) <= 6 and abs(i + 1 - el_img) <= 6, (j, az_img, i + 1, el_img)
    # the reflected path itself arrives exactly from the image and has the image's free-space gain
    img = np.array([4.0, 0.0, 2.5])
    u = ps.u_moving[0, 1]
    assert np.degrees(np.arccos(u @ (img - pos[0]) / np.linalg.norm(img - pos[0]))) < 0.1
    d2 = np.linalg.norm(img - pos[0])
    assert 20 * np.log10(abs(ps.a[0, 1])) == pytest.approx(-20 * np.log10(4 * np.pi * d2 * F / antenna.SPEED_OF_LIGHT),
                                                          abs=0.5)  # |Gamma| of ITU metal ~ 1


def test_reciprocity_matches_explicit_reverse_solve(variant, box_room):
    """Moving-TX channels from one forward solve (departure directions) equal an explicit
    solve with the isotropic TX at each position and the flat 4x4 array at the corner."""
    import mitsuba as mi
    from sionna.rt import PathSolver, PlanarArray, Receiver, Transmitter, load_scene

    fixed = np.array([0.4, 0.4, 2.0])
    pos = np.array([[2.5, 1.8, 1.0], [3.2, 0.9, 0.6], [1.2, 2.4, 1.5]])
    h_fwd = sim(box_room, fixed, pos, samples_per_src=20000, max_depth=2).solve().channels("tx", frequency_hz=F)

    scene = load_scene(str(box_room), merge_shapes=False)
    scene.frequency = F
    scene.tx_array = PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    arr = PlanarArray(num_rows=4, num_cols=4, vertical_spacing=0.5, horizontal_spacing=0.5,
                      pattern="iso", polarization="V")
    e = antenna.element_positions(F) / antenna.wavelength(F)  # lay the array flat, SPEC element order
    arr.normalized_positions = mi.Point3f(*[mi.Float(e[:, i].astype(np.float32)) for i in range(3)])
    scene.rx_array = arr
    scene.add(Receiver("corner", position=mi.Point3f(*[float(x) for x in fixed])))
    h_rev = []
    for k, p in enumerate(pos):  # one TX per solve
        name = f"tx{k}"
        scene.add(Transmitter(name, position=mi.Point3f(*[float(x) for x in p])))
        paths = PathSolver()(scene, max_depth=2, samples_per_src=20000, synthetic_array=True)
        h, _ = paths.cir(normalize_delays=False, out_type="numpy")
        h_rev.append(h.reshape(16, -1).sum(axis=1))
        scene.remove(name)
    h_rev = np.array(h_rev)
    err = np.linalg.norm(h_fwd - h_rev, axis=1) / np.linalg.norm(h_rev, axis=1)
    assert np.all(err < 1e-3), err


def test_rx_task_matches_sionna_flat_planar_array(variant, box_room):
    """Our synthetic array on the receiver side equals Sionna's own PlanarArray laid flat."""
    import mitsuba as mi
    from sionna.rt import PathSolver, PlanarArray, Receiver, Transmitter, load_scene

    fixed = np.array([0.4, 0.4, 2.0])
    pos = np.array([[2.5, 1.8, 1.0], [3.2, 0.9, 0.6]])
    h_ours = sim(box_room, fixed, pos, samples_per_src=20000, max_depth=2).solve().channels("rx", frequency_hz=F)
    scene = load_scene(str(box_room), merge_shapes=False)
    scene.frequency = F
    scene.tx_array = PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    arr = PlanarArray(num_rows=4, num_cols=4, pattern="iso", polarization="V")
    e = antenna.element_positions(F) / antenna.wavelength(F)
    arr.normalized_positions = mi.Point3f(*[mi.Float(e[:, i].astype(np.float32)) for i in range(3)])
    scene.rx_array = arr
    scene.add(Transmitter("tx", position=mi.Point3f(*[float(x) for x in fixed])))
    for k, p in enumerate(pos):
        scene.add(Receiver(f"rx{k}", position=mi.Point3f(*[float(x) for x in p])))
    h, _ = PathSolver()(scene, max_depth=2, samples_per_src=20000).cir(normalize_delays=False, out_type="numpy")
    h = h.reshape(len(pos), 16, -1).sum(axis=-1)
    err = np.linalg.norm(h_ours - h, axis=1) / np.linalg.norm(h, axis=1)
    assert np.all(err < 1e-3), err


def test_same_seed_same_channels_and_batching(variant, box_room):
    fixed = np.array([0.4, 0.4, 2.0])
    pos = np.random.default_rng(3).uniform([0.5, 0.5, 0.5], [3.5, 2.5, 2.0], (12, 3))
    a = sim(box_room, fixed, pos, samples_per_src=5000).solve()
    batched = sim(box_room, fixed, pos, samples_per_src=5000, batch_size=5)
    b = batched.solve()
    assert np.array_equal(a.channels("rx", frequency_hz=F), b.channels("rx", frequency_hz=F))
    # every position is back in the scene after a batched solve, and a second one gives the same
    assert set(batched.scene.receivers) == set(batched._receivers)
    assert np.array_equal(batched.solve().channels("rx", frequency_hz=F), b.channels("rx", frequency_hz=F))


def test_person_mesh_moves_absolutely(variant, box_room):
    """Moving the perturber to a position gives the same channel as placing it there first."""
    from sionna.rt import ITURadioMaterial

    fixed = np.array([0.4, 0.4, 2.0])
    pos = np.array([[3.5, 2.5, 1.0], [3.0, 0.6, 1.2]])
    box = np.array([[0, 0, 0], [.4, 0, 0], [.4, .3, 0], [0, .3, 0], [0, 0, 1.7], [.4, 0, 1.7], [.4, .3, 1.7],
                    [0, .3, 1.7]], float)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                      [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    at = lambda x, y: box + [x, y, 0]  # noqa: E731
    s1 = sim(box_room, fixed, pos, samples_per_src=5000)
    s1.set_person(at(1.0, 1.0), faces, material=ITURadioMaterial("h-metal", "metal", 0.01))
    h_empty_far = s1.solve().channels("rx", frequency_hz=F)
    s1.set_person(at(2.0, 1.3))
    h1 = s1.solve().channels("rx", frequency_hz=F)
    s2 = sim(box_room, fixed, pos, samples_per_src=5000)
    s2.set_person(at(2.0, 1.3), faces, material=ITURadioMaterial("h-metal", "metal", 0.01))
    h2 = s2.solve().channels("rx", frequency_hz=F)
    assert np.array_equal(h1, h2)
    assert not np.allclose(h1, h_empty_far)  # the perturber matters
    with pytest.raises(PlacementError, match="vertices"):
        s2.set_person(box[:4])


def test_bad_inputs(variant, box_room, tmp_path):
    from rfmitsuba.sim.simulate import Simulator, SolverConfig

    with pytest.raises(SceneError, match="does not exist"):
        Simulator(tmp_path / "nope.xml", fixed_pos=[0, 0, 1])
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='2.1.0'><shape type='ply'><string name='filename' value='gone.ply'/></shape>")
    with pytest.raises(SceneError, match="bad.xml"):
        Simulator(bad, fixed_pos=[0, 0, 1])
    with pytest.raises(PlacementError, match="fixed device"):
        Simulator(box_room, fixed_pos=[0, np.nan, 1])
    with pytest.raises(ConfigError, match="samples_per_src"):
        Simulator(box_room, fixed_pos=[1, 1, 1], solver=SolverConfig(samples_per_src=0))
    s = Simulator(box_room, fixed_pos=[1, 1, 1])
    with pytest.raises(PlacementError, match="position 1 is not finite"):
        s.set_positions(np.array([[1, 1, 1], [np.inf, 1, 1]], float))
    with pytest.raises(PlacementError, match=r"\[N, 3\]"):
        s.set_positions(np.ones((3, 2)))
    with pytest.raises(ConfigError, match="set_positions"):
        s.solve()
    with pytest.raises(ConfigError, match="task"):
        from rfmitsuba.sim.simulate import PathSet
        PathSet(np.zeros((1, 1)), np.zeros((1, 1, 3)), np.zeros((1, 1, 3)), np.zeros(1)).channels("up",
                                                                                                  frequency_hz=F)


def _corr(a, b):
    return np.abs(np.sum(np.conj(a) * b, axis=1)) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)


def test_exact_array_is_the_spherical_wave_and_differs_from_synthetic_near(variant, empty_scene):
    """Tracing each element (array="exact") gives every element its own free-space path: the
    spherical wave, which the synthetic array's plane wave matches far away but not at 0.3 m."""
    from rfmitsuba.core.ssim import ssim_images

    fixed = np.array([0.0, 0.0, 2.0])
    far = np.array([[15.0, 10.0, 1.0], [-12.0, 9.0, 0.5]])
    near = np.array([[0.3, 0.1, 1.9], [0.2, -0.25, 1.8]])
    pos = np.concatenate([far, near])
    r = antenna.element_positions(F)
    k = 2 * np.pi / antenna.wavelength(F)
    for task in ("rx", "tx"):
        s = sim(empty_scene, fixed, pos, samples_per_src=1000)
        hs, he = s.channels(task), s.channels(task, array="exact")
        # exact: |h_m| = lambda / (4 pi d_m), phase -k d_m (one common constant), d_m from element m
        ends = pos[:, None, :] + r if task == "rx" else pos[:, None, :] - r  # rx: element at pos + r_m
        d = np.linalg.norm(ends - fixed, axis=-1)
        ref = np.exp(-1j * k * d) / (2 * k * d)
        assert np.allclose(np.abs(he), np.abs(ref), rtol=1e-3), task
        assert np.all(_corr(he, ref) > 0.99999), (task, _corr(he, ref))
        c = _corr(hs, he)
        img = lambda h: pas.normalize(pas.bartlett(h, frequency_hz=F))  # noqa: E731
        sim_ = ssim_images(img(hs), img(he))
        assert np.all(c[:2] > 0.999) and np.all(sim_[:2] > 0.99), (task, c, sim_)
        assert np.all(c[2:] < 0.97) and np.all(sim_[2:] < 0.9), (task, c, sim_)
        # the receivers are the antenna positions again afterwards
        assert np.array_equal(s.positions, pos) and len(s._receivers) == len(pos)
        assert np.allclose(s.channels(task), hs)


def test_exact_array_bad_options(variant, box_room):
    s = sim(box_room, [0.4, 0.4, 2.0], [[2.0, 1.5, 1.0]], samples_per_src=1000)
    with pytest.raises(ConfigError, match="array must be one of synthetic, exact"):
        s.channels("rx", array="bogus")
    with pytest.raises(ConfigError, match="task"):
        s.channels("up", array="exact")
