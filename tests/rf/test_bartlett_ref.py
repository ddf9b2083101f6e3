"""Tests of rfmitsuba.rf.bartlett_ref: SPEC layout, Bartlett beamformer, normalisation."""
import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.rf import array as antenna
from rfmitsuba.rf import bartlett_ref as pas
from rfmitsuba.rf import grid

F = 2.4e9


def plane_wave(el, az):
    u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return antenna.array_response(np.ones((1, 1)), u[None, None], frequency_hz=F)


def test_angle_grid_layout():
    el, az = grid.angle_grid()
    assert el.shape == (90, 360)
    assert np.isclose(np.degrees(el[0, 0]), 1) and np.isclose(np.degrees(el[-1, 0]), 90)
    assert np.isclose(np.degrees(az[0, 0]), 0) and np.isclose(np.degrees(az[0, -1]), 359)
    assert grid.angle_grid(resolution_deg=2.0)[0].shape == (45, 180)
    with pytest.raises(ConfigError, match="resolution_deg"):
        grid.angle_grid(resolution_deg=7.0)


@pytest.mark.parametrize("el_deg,az_deg", [(30, 0), (20, 117), (45, 250), (60, 333)])
def test_peak_points_at_plane_wave_source(el_deg, az_deg):
    p = pas.bartlett(plane_wave(np.radians(el_deg), np.radians(az_deg)), frequency_hz=F)
    assert p.shape == (1, 90, 360) and p.dtype == np.float32
    el, az = np.degrees(pas.peak_direction(p[0]))
    assert abs(el - el_deg) <= 2
    assert abs((az - az_deg + 180) % 360 - 180) <= 2
    assert p.max() == pytest.approx(1.0, abs=1e-3)  # unit plane wave, |sum| / 16 at the peak


def test_matches_direct_formula():
    rng = np.random.default_rng(0)
    h = (rng.normal(size=(2, 16)) + 1j * rng.normal(size=(2, 16))).astype(np.complex64)
    p = pas.bartlett(h, frequency_hz=F)
    pos = antenna.element_positions(F)
    k = 2 * np.pi / antenna.wavelength(F)
    for i, j in [(0, 0), (10, 45), (44, 200), (89, 359)]:
        el, az = np.radians(i + 1), np.radians(j)
        d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        v = np.exp(1j * k * pos @ d)
        for n in range(2):
            assert p[n, i, j] == pytest.approx(abs(np.conj(v) @ h[n]) / 16, rel=1e-4)


def test_batching_does_not_change_result():
    rng = np.random.default_rng(2)
    h = rng.normal(size=(7, 16)) + 1j * rng.normal(size=(7, 16))
    a, b = pas.bartlett(h, frequency_hz=F, batch=3), pas.bartlett(h, frequency_hz=F, batch=100)
    assert np.allclose(a, b, rtol=1e-5, atol=1e-7)
    assert np.array_equal(a, pas.bartlett(h, frequency_hz=F, batch=3))  # same input, same bits


def test_images_are_the_padded_product_bit_for_bit_and_the_cached_weights_read_only():
    """bartlett() writes |B h^T| of products a multiple of 8 channels wide (a short one padded
    with zeros) straight into its images through a transposed view and keeps the default array's weights
    between calls: the images are the bits of ``np.abs(B @ h.T).T`` on those padded blocks,
    explicit element positions still give their own weights, and nobody can write into the
    cached ones."""
    rng = np.random.default_rng(5)
    h = (rng.normal(size=(300, 16)) + 1j * rng.normal(size=(300, 16))).astype(np.complex64)
    B = pas.beamformer(frequency_hz=F)
    hp = np.concatenate([h, np.zeros((84, 16), np.complex64)])   # 300 rows padded to 6 x 64
    with threadpool_limits(limits=1, user_api="blas"):   # as bartlett() runs its products
        former = np.concatenate([np.abs(B @ hp[s:s + 64].T).T for s in range(0, 384, 64)])[:300].reshape(-1, 90, 360)
    for _ in range(2):   # the second call uses the cached weights
        assert np.array_equal(pas.bartlett(h, frequency_hz=F), former)
    # the reused work array and a caller's reused ``out``: the same bits
    out = np.full((300, 90, 360), np.nan, np.float32)
    for _ in range(2):
        assert pas.bartlett(h, frequency_hz=F, out=out) is out
        assert np.array_equal(out, former)
    for batch in (32, 100, 128, 256):    # other product sizes: the same bits
        assert np.array_equal(pas.bartlett(h, frequency_hz=F, batch=batch), former), batch
    cached = pas._default_weights(F, 1.0)
    assert np.array_equal(cached, B) and not cached.flags.writeable
    with pytest.raises(ValueError):
        cached[0, 0] = 0
    moved = antenna.element_positions(F) + np.array([0.01, 0.0, 0.0])   # not the default array
    assert not np.array_equal(pas.bartlett(h[:2], frequency_hz=F, positions=moved), former[:2])


def test_bad_channels():
    with pytest.raises(ConfigError, match="elements"):
        pas.bartlett(np.ones((2, 8)), frequency_hz=F)
    with pytest.raises(ConfigError, match="NaN"):
        pas.bartlett(np.full((1, 16), np.nan), frequency_hz=F)
    with pytest.raises(ConfigError, match=r"\[K, M\]"):
        pas.bartlett(np.ones(16), frequency_hz=F)
    with pytest.raises(ConfigError, match="batch must be >= 1"):
        pas.bartlett(np.ones((2, 16)), frequency_hz=F, batch=0)


def test_an_image_does_not_depend_on_what_it_was_beamformed_with():
    """Any number of channels in one call, from any offset, gives each image the same bits (BLAS
    took another kernel for fewer than 8 columns: noisy samples asked for in sets of 1-7 differed
    in the last bits from the same samples asked for together, and so did the jobs trained on them)."""
    rng = np.random.default_rng(3)
    h = (rng.normal(size=(150, 16)) + 1j * rng.normal(size=(150, 16))).astype(np.complex64)
    full = pas.bartlett(h, frequency_hz=F)
    for k in (1, 2, 3, 5, 7, 8, 9, 63, 64, 65, 130):
        assert np.array_equal(pas.bartlett(h[:k], frequency_hz=F), full[:k]), k
    for s in (1, 17, 64, 101):
        assert np.array_equal(pas.bartlett(h[s:s + 6], frequency_hz=F), full[s:s + 6]), s


@pytest.mark.parametrize("out", [np.empty((3, 90, 360), np.float32), np.empty((2, 90, 360), np.float64),
                                 np.empty((2, 360, 90), np.float32).transpose(0, 2, 1), [[0.0]]])
def test_out_of_the_wrong_kind_is_named(out):
    with pytest.raises(ConfigError, match=r"out must be a writeable C-contiguous float32 array of shape \(2, 90, 360\)"):
        pas.bartlett(np.ones((2, 16)), frequency_hz=F, out=out)


def test_threads_keep_their_own_work_array():
    """Two threads beamforming at once each use their own work array: each gets its own images
    (to float32 rounding: BLAS's one-thread limit is process-wide, and one thread leaving it while
    the other multiplies lets a product take another kernel path; a shared work array would give
    wrong images)."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(8)
    hs = [(rng.normal(size=(150, 16)) + 1j * rng.normal(size=(150, 16))).astype(np.complex64) for _ in range(4)]
    want = [pas.bartlett(h, frequency_hz=F) for h in hs]
    with ThreadPoolExecutor(2) as ex:
        got = list(ex.map(lambda h: pas.bartlett(h, frequency_hz=F), hs * 3))
    for i, g in enumerate(got):
        np.testing.assert_allclose(g, want[i % 4], rtol=1e-5, atol=1e-6 * float(want[i % 4].max()))


def test_normalize_is_the_min_max_formula_and_leaves_its_input_alone():
    """(p - min) / (max - min) per image in float32, bit for bit; a constant or NaN image gives 0;
    the caller's array is not written to."""
    rng = np.random.default_rng(4)
    x = (rng.random((4, 9, 11), np.float32) * 4 - 1).astype(np.float32)
    x[1] = 7.0
    x[2, 3, 4] = np.nan
    keep = x.copy()
    n = pas.normalize(x)
    np.testing.assert_array_equal(x, keep)
    for i in (0, 3):
        lo, hi = x[i].min(), x[i].max()
        np.testing.assert_array_equal(n[i], (x[i] - lo) / (hi - lo))
    assert np.all(n[1] == 0) and np.all(n[2] == 0) and n.dtype == np.float32


def test_normalize_per_image():
    x = np.stack([np.linspace(2, 5, 90 * 360).reshape(90, 360), np.full((90, 360), 3.0)])
    n = pas.normalize(x)
    assert n[0].min() == 0 and n[0].max() == pytest.approx(1)
    assert np.all(n[1] == 0)  # constant image
    assert n.dtype == np.float32
