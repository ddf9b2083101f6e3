"""Tests of rfmitsuba.sim.nerf2like: a NeRF2-like folder (30 tags, few ray samples) reads back with
rfmitsuba.data.nerf2, its tags follow 9 mm trajectories, rfmitsuba.json records the impairments,
the phase-only Bartlett ignores element amplitudes, and bad input raises the named errors."""
import json
import math

import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError, DatasetError, SceneError
from rfmitsuba.data import nerf2
from rfmitsuba.rf import array as antenna
from rfmitsuba.rf import bartlett_ref
from rfmitsuba.sim import nerf2like as nl

N = 30
F = nerf2.NERF2_FREQUENCY_HZ


def fast_solver():
    from rfmitsuba.sim.simulate import SolverConfig

    return SolverConfig(samples_per_src=20_000)


@pytest.fixture(scope="module")
def folder(tmp_path_factory, variant):
    out = tmp_path_factory.mktemp("nl") / "nerf2like"
    return nl.make_nerf2like(out, num_tags=N, seed=3, solver=fast_solver())


@pytest.fixture(scope="module")
def extra(folder):
    return json.loads((folder / nerf2.EXTRA).read_text())


def test_folder_reads_back(folder):
    ds = nerf2.read(folder)
    assert ds.task == "tx" and ds.frequency_hz == F and ds.num_antennas == N
    pas = ds.pas(0)
    assert pas.shape == (N, 90, 360)
    assert np.allclose(pas * 255, np.round(pas * 255), atol=1e-4)         # 8-bit
    assert np.allclose(pas.min(axis=(1, 2)), 0) and np.allclose(pas.max(axis=(1, 2)), 1)
    assert len(ds.split.antenna_train) == N - round(0.2 * N) and len(ds.split.antenna_test) == round(0.2 * N)
    assert np.intersect1d(ds.split.antenna_train, ds.split.antenna_test).size == 0
    assert np.allclose(ds.fixed_pos, nl.LAYOUTS["large_room"]["gateway_pos"])
    assert np.allclose(ds.rx_to_world, np.eye(3))
    from PIL import Image

    im = Image.open(folder / "spectrum" / "00001.png")
    assert im.mode == "L" and im.size == (360, 90)
    assert (folder / "tx_pos.csv").read_text().splitlines()[0] == "x,y,z"
    first = (folder / "train_index.txt").read_text().split()[0]
    assert first == f"{ds.split.antenna_train[0] + 1:05d}"                  # 1-based, zero-padded


def test_tags_follow_9mm_trajectories(folder, extra):
    ds = nerf2.read(folder)
    pos = ds.antenna_pos.astype(np.float64)
    traj = np.asarray(extra["trajectories"]["id"])
    steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    same = np.diff(traj) == 0
    assert same.sum() == N - extra["trajectories"]["count"]
    assert np.allclose(steps[same], nl.STEP_M, atol=2e-6)
    lay = extra["layout"]
    assert np.all(pos >= np.asarray(lay["region_lo"]) - 1e-6) and np.all(pos <= np.asarray(lay["region_hi"]) + 1e-6)
    assert np.allclose(np.subtract(lay["region_hi"], lay["region_lo"]), nl.REGION_SIZE)
    assert 4.5 < lay["gateway_to_region_center_m"] < 5.5


def test_extra_records_impairments(extra):
    assert extra["generator"] == nl.GENERATOR and extra["task"] == "tx" and extra["frequency_hz"] == F
    imp = extra["impairments"]
    off = np.asarray(imp["phase_offset"]["per_element_deg"])
    assert off.shape == (16,) and np.all(np.abs(off) <= 30.0) and np.std(off) > 1.0
    assert imp["phase_offset"]["max_deg"] == 30.0
    assert imp["noise"]["snr_db"] == 20.0
    assert math.isclose(imp["noise"]["noise_power"], imp["noise"]["signal_power"] / 100.0, rel_tol=1e-9)
    assert "phase-only" in imp["readout"]
    assert extra["seeds"]["split"] == 3 and extra["split_seed"] == 3
    assert extra["config"]["num_tags"] == N and extra["config"]["seed"] == 3
    # ITU concrete starts at 1 GHz: it is extrapolated to 920 MHz, wood is not
    assert extra["materials"]["wall_concrete"]["extrapolated"] is True
    assert extra["materials"]["furniture_wood"]["extrapolated"] is False
    assert extra["array"]["pitch_m"] == pytest.approx(antenna.wavelength(F) / 2)


def test_same_configuration_is_not_simulated_again(folder):
    stamp = (folder / nerf2.EXTRA).stat().st_mtime_ns
    stale = folder.parent / f".{folder.name}.tmp-999999999"
    stale.mkdir()
    assert nl.make_nerf2like(folder, num_tags=N, seed=3, solver=fast_solver()) == folder
    assert (folder / nerf2.EXTRA).stat().st_mtime_ns == stamp
    assert not stale.exists()                                  # a dead run's temporary folder is removed


def test_other_configuration_or_folder_is_refused(folder, tmp_path):
    with pytest.raises(DatasetError, match="config.snr_db"):
        nl.make_nerf2like(folder, num_tags=N, seed=3, snr_db=10.0, solver=fast_solver())
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(DatasetError, match="not empty"):
        nl.make_nerf2like(other, num_tags=N, solver=fast_solver())


def test_diffuse_scattering_changes_the_spectra_and_is_recorded(folder, extra, tmp_path):
    """--diffuse traces diffuse reflections on top of the same tags; a folder without it records
    no scattering coefficient (so folders made before the option still match their configuration)."""
    assert "scattering_coefficient" not in extra["config"] and extra["solver"]["diffuse_reflection"] is False
    rough = nl.make_nerf2like(tmp_path / "rough", num_tags=N, seed=3, solver=fast_solver(), diffuse=0.5)
    rec = json.loads((rough / nerf2.EXTRA).read_text())
    assert rec["config"]["scattering_coefficient"] == 0.5 and rec["solver"]["diffuse_reflection"] is True
    assert rec["impairments"]["diffuse_scattering"] == {"scattering_coefficient": 0.5, "traced": True}
    a, b = nerf2.read(folder), nerf2.read(rough)
    assert np.array_equal(a.antenna_pos, b.antenna_pos)
    diff = np.abs(a.pas(0) - b.pas(0)).mean(axis=(1, 2))
    assert diff.min() > 0.005                           # every tag's spectrum changed (8-bit steps are 0.004)
    with pytest.raises(DatasetError, match="config.(scattering_coefficient|solver.diffuse_reflection)"):
        nl.make_nerf2like(folder, num_tags=N, seed=3, solver=fast_solver(), diffuse=0.5)


def test_coupling_matrix_is_reciprocal_and_local():
    C = nl.coupling_matrix(-20.0, rng=np.random.default_rng(0))
    assert C.shape == (16, 16) and np.allclose(C, C.T) and np.allclose(np.diag(C), 1.0)
    mag = np.abs(C - np.eye(16))
    # element 5 (row 1, col 1): row/column neighbours 1, 4, 6, 9 at -20 dB, diagonal ones 6 dB below
    np.testing.assert_allclose(mag[5, [1, 4, 6, 9]], 0.1)
    np.testing.assert_allclose(mag[5, [0, 2, 8, 10]], 0.05)
    assert np.count_nonzero(mag[5]) == 8 and mag[0, 15] == 0
    assert not np.allclose(C, nl.coupling_matrix(-20.0, rng=np.random.default_rng(1)))   # seeded phases


def test_coupling_changes_the_spectra_and_is_recorded(folder, extra, tmp_path):
    assert "coupling_db" not in extra["config"] and extra["impairments"]["coupling"] is None
    coupled = nl.make_nerf2like(tmp_path / "coupled", num_tags=N, seed=3, solver=fast_solver(), coupling_db=-15.0)
    rec = json.loads((coupled / nerf2.EXTRA).read_text())
    assert rec["config"]["coupling_db"] == -15.0
    C = np.asarray(rec["impairments"]["coupling"]["matrix_re"]) + 1j * np.asarray(rec["impairments"]["coupling"]["matrix_im"])
    np.testing.assert_allclose(C, nl.coupling_matrix(-15.0, rng=np.random.default_rng([3, 4])))
    diff = np.abs(nerf2.read(folder).pas(0) - nerf2.read(coupled).pas(0)).mean(axis=(1, 2))
    assert diff.min() > 0.005


def test_position_error_moves_only_the_stated_positions(folder, extra, tmp_path):
    """The spectra are the error-free folder's; tx_pos.csv holds the true positions plus errors of
    the asked standard deviation, which rfmitsuba.json records with the true positions."""
    off = nl.make_nerf2like(tmp_path / "off", num_tags=N, seed=3, solver=fast_solver(), position_error_m=0.01)
    a, b = nerf2.read(folder), nerf2.read(off)
    np.testing.assert_array_equal(b.pas(0), a.pas(0))
    d = b.antenna_pos.astype(np.float64) - a.antenna_pos.astype(np.float64)
    assert 0.006 < d.std() < 0.014 and abs(d.mean()) < 0.005
    rec = json.loads((off / nerf2.EXTRA).read_text())
    assert rec["config"]["position_error_m"] == 0.01 and "position_error_m" not in extra["config"]
    err = rec["impairments"]["position_error"]
    np.testing.assert_allclose(err["true_tx_pos_m"], a.antenna_pos, atol=1e-6)
    assert err["rms_m"] == pytest.approx(np.sqrt((d ** 2).sum(1).mean()), rel=1e-3)
    assert extra["impairments"]["position_error"] is None
    with pytest.raises(ConfigError, match="position_error_m"):
        nl.make_nerf2like(tmp_path / "bad", num_tags=N, position_error_m=float("nan"))


def test_phase_only_bartlett_ignores_element_amplitudes():
    rng = np.random.default_rng(0)
    h = rng.normal(size=(3, 16)) + 1j * rng.normal(size=(3, 16))
    scale = rng.uniform(0.1, 10.0, size=(1, 16))                # per-element gains
    a = bartlett_ref.bartlett(h, frequency_hz=F, phase_only=True)
    b = bartlett_ref.bartlett(h * scale, frequency_hz=F, phase_only=True)
    assert np.allclose(a, b, atol=1e-6)
    assert not np.allclose(bartlett_ref.bartlett(h, frequency_hz=F), bartlett_ref.bartlett(h * scale, frequency_hz=F))
    assert a.max() <= 1.0 + 1e-6
    # a unit-modulus plane wave: the same image either way, peak at the source
    u = np.array([np.cos(0.3) * np.cos(2.0), np.cos(0.3) * np.sin(2.0), np.sin(0.3)])
    hw = antenna.array_response(np.ones((1, 1)), u[None, None], frequency_hz=F)
    assert np.allclose(bartlett_ref.bartlett(hw, frequency_hz=F, phase_only=True),
                       bartlett_ref.bartlett(hw, frequency_hz=F), atol=1e-6)
    el, az = bartlett_ref.peak_direction(bartlett_ref.bartlett(3.0 * hw, frequency_hz=F, phase_only=True)[0])
    assert abs(el - 0.3) < np.deg2rad(2) and abs(az - 2.0) < np.deg2rad(2)
    assert np.all(bartlett_ref.unit_modulus(np.zeros((1, 16))) == 0)


def test_trajectories_are_smooth_and_inside():
    lo, hi = np.zeros(3), np.array([1.6, 1.3, 0.9])
    p, t = nl.tag_trajectories(200, lo=lo, hi=hi, num_trajectories=4, rng=np.random.default_rng(1))
    assert p.shape == (200, 3) and np.bincount(t).tolist() == [50] * 4
    assert np.all(p >= lo) and np.all(p <= hi)
    d = np.diff(p, axis=0)[np.diff(t) == 0]
    assert np.allclose(np.linalg.norm(d, axis=1), nl.STEP_M)
    cos = np.sum(d[1:] * d[:-1], axis=1) / nl.STEP_M ** 2
    assert np.median(cos) > 0.99                               # smooth: consecutive steps nearly parallel
    q, _ = nl.tag_trajectories(200, lo=lo, hi=hi, num_trajectories=4, rng=np.random.default_rng(1))
    assert np.array_equal(p, q)


def test_auto_layout_in_a_small_room():
    from rfmitsuba.sim.geometry import RoomGeometry

    g = RoomGeometry.from_scene("living_room")
    c, gw = nl.auto_layout(g)
    size = np.asarray(nl.REGION_SIZE)
    nl.check_layout(g, c - size / 2, c + size / 2, gw)         # raises if it does not fit
    assert np.linalg.norm(c - gw) > 3.0                       # as far apart as the 4.3 x 3.5 m room allows


@pytest.mark.parametrize("kw, match", [
    ({"num_tags": 5}, "num_tags"),
    ({"num_tags": 20.5}, "num_tags"),
    ({"snr_db": float("nan")}, "snr_db"),
    ({"snr_db": -math.inf}, "snr_db"),
    ({"phase_error_deg": 200.0}, "phase_error_deg"),
    ({"diffuse": 1.5}, "diffuse"),
    ({"diffuse": float("nan")}, "diffuse"),
    ({"coupling_db": 3.0}, "coupling_db"),
    ({"coupling_db": float("inf")}, "coupling_db"),
    ({"seed": -1}, "seed"),
    ({"num_trajectories": 0}, "num_trajectories"),
    ({"num_tags": 10, "num_trajectories": 6}, "num_trajectories"),
    ({"step_m": 0.0}, "step_m"),
    ({"frequency_hz": float("inf")}, "frequency_hz"),
    ({"region_size": (1.6, 1.3)}, "region_size"),
    ({"region_center": (10.5, 1.6, 0.95)}, "tag region .* not inside the room"),
    ({"region_center": (5.8, 3.65, 0.95)}, "tag region .* not free"),
    ({"gateway_pos": (12.0, 1.6, 2.0)}, "gateway .* not free: outside the room"),
    ({"gateway_pos": (10.7, 0.7, 1.0)}, "gateway .* not free: inside 'metal_cabinet'"),
    ({"gateway_pos": (3.0, 2.5, 1.0)}, "from the tag region"),
])
def test_bad_input_raises_config_error(tmp_path, kw, match):
    with pytest.raises(ConfigError, match=match):
        nl.make_nerf2like(tmp_path / "x", **kw)
    assert not (tmp_path / "x").exists()


def test_unknown_scene(tmp_path):
    with pytest.raises(SceneError, match="unknown scene"):
        nl.make_nerf2like(tmp_path / "x", scene="castle")


def test_carrier_scene_rewrites_only_uncovered_materials(tmp_path, variant):
    from rfmitsuba import scenes

    xml = scenes.path("large_room")
    same, rec = nl.scene_for_carrier(xml, 2.4e9, tmp_path)
    assert same == xml and not any(r["extrapolated"] for r in rec.values())
    new, rec = nl.scene_for_carrier(xml, F, tmp_path)
    assert new.parent == tmp_path
    text = new.read_text()
    assert 'type="itu-radio-material"' in text                 # wood and glass stay ITU materials
    assert text.count('type="radio-material"') == sum(r["extrapolated"] for r in rec.values()) == 4
    assert str(xml.parent.resolve() / "meshes") in text


def test_measurement_drift_has_the_asked_spread_and_correlation_and_restarts_per_path():
    traj = np.repeat([0, 1], 4000)
    g = nl.measurement_drift(traj, magnitude_db=6.0, phase_deg=30.0, correlation=0.7,
                             rng=np.random.default_rng(0), elements=16)
    assert g.shape == (8000, 16) and g.dtype == np.complex128
    db, ph = 20 * np.log10(np.abs(g)), np.degrees(np.angle(g))
    assert db.std() == pytest.approx(6.0, rel=0.05) and ph.std() == pytest.approx(30.0, rel=0.05)
    lag1 = np.mean([np.corrcoef(db[1:4000, m], db[:3999, m])[0, 1] for m in range(16)])
    assert lag1 == pytest.approx(0.7, abs=0.03)
    across = np.corrcoef(db[3999], db[4000])[0, 1]          # the second path starts afresh
    assert abs(across) < 0.8
    none = nl.measurement_drift(traj[:10], magnitude_db=0.0, phase_deg=0.0, correlation=0.5,
                                rng=np.random.default_rng(0))
    np.testing.assert_allclose(none, 1.0)
    with pytest.raises(ConfigError, match="drift_correlation"):
        nl.measurement_drift(traj, magnitude_db=1.0, phase_deg=0.0, correlation=1.0, rng=np.random.default_rng(0))


def test_measured_style_options_change_the_spectra_and_are_recorded(folder, extra, tmp_path):
    """The amplitude read-out and the measurement drift: recorded in rfmitsuba.json, the folder is read
    back with the amplitude read-out, and neighbouring tags' spectra differ more than without drift."""
    from rfmitsuba.core.ssim import ssim_images

    amp = nl.make_nerf2like(tmp_path / "amp", num_tags=N, seed=3, solver=fast_solver(), readout="amplitude")
    drift = nl.make_nerf2like(tmp_path / "drift", num_tags=N, seed=3, solver=fast_solver(), readout="amplitude",
                              drift_db=6.0, drift_deg=40.0, drift_correlation=0.7)
    a, b, c = nerf2.read(folder), nerf2.read(amp), nerf2.read(drift)
    assert a.readout == "phase_only" and b.readout == "amplitude" and c.readout == "amplitude"
    assert not np.array_equal(a.pas(0), b.pas(0))
    rec = json.loads((drift / nerf2.EXTRA).read_text())
    assert rec["config"]["drift"] == {"db": 6.0, "deg": 40.0, "correlation": 0.7}
    assert rec["impairments"]["drift"]["correlation"] == 0.7 and "drift" not in extra["config"]
    assert json.loads((amp / nerf2.EXTRA).read_text())["config"]["readout"] == "amplitude"
    nb = lambda d: float(np.mean(ssim_images(d.pas(0)[:-1], d.pas(0)[1:])))   # consecutive tags, 9 mm apart
    assert nb(c) < nb(b) - 0.02
    from rfmitsuba.data.views import TrainData
    # the drift makes the spectra vary by measurement (auto then tries the Gaussian-process field); the tracer alone does not
    assert TrainData.open(drift).varies_by_measurement and not TrainData.open(amp).varies_by_measurement
    with pytest.raises(ConfigError, match="readout"):
        nl.make_nerf2like(tmp_path / "bad", num_tags=N, readout="power")
    with pytest.raises(ConfigError, match="drift_db"):
        nl.make_nerf2like(tmp_path / "bad", num_tags=N, drift_db=-1.0)


def test_measured_style_folder_is_where_the_gaussian_process_field_beats_idw3(tmp_path):
    """The CI-sized regression for measured-style data: 120 tags in a 0.5 x 1.0 x 0.2 m region, the
    amplitude read-out and a measurement drift (8 dB, 60 degrees, 0.985 from tag to tag; the setting
    whose floors and SSIM-against-distance curve come closest to the measured RFID folder's,
    docs/results/measured/simulator.md). The spectra of neighbouring tags differ as measured ones do,
    they vary by measurement (so auto tries the Gaussian-process field), and the Gaussian-process
    field beats IDW-3 on the folder's own split."""
    from rfmitsuba.core.ssim import ssim_images
    from rfmitsuba.eval.metrics import floors
    from rfmitsuba.models.gaussian_process import GaussianProcessField
    from rfmitsuba.rf.bartlett_ref import normalize

    out = nl.make_nerf2like(tmp_path / "measured_style", num_tags=120, seed=1, solver=fast_solver(),
                            region_size=(0.5, 1.0, 0.2), readout="amplitude", snr_db=30.0,
                            drift_db=8.0, drift_deg=60.0, drift_correlation=0.985)
    from rfmitsuba.data.views import TrainData

    assert TrainData.open(out).varies_by_measurement
    ds = nerf2.read(out)
    pas = ds.pas(0).astype(np.float32)
    pas = normalize(pas)
    tr, te = ds.split.antenna_train, ds.split.antenna_test
    x = ds.antenna_pos.astype(np.float64)
    f = floors(pas[tr], x[tr], pas[te], x[te])
    gp = GaussianProcessField()
    gp.condition(x[tr], pas[tr])
    model = ssim_images(normalize(gp.predict(x[te])), pas[te])
    assert model.mean() > f["idw3"].mean() and model.mean() > f["nearest_neighbour"].mean()
    assert 0.5 < f["nearest_neighbour"].mean() < 0.97            # neighbours alike, but not as a field keeps them
