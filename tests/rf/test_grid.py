"""The PAS grid (rfmitsuba.rf.grid): a coarse grid is sampled where its block means lie."""
import numpy as np
import pytest

from rfmitsuba.core.errors import ConfigError
from rfmitsuba.data.views import downsample
from rfmitsuba.rf import grid
from rfmitsuba.rf.bartlett_ref import bartlett, normalize


@pytest.mark.parametrize("d", [1, 2, 3, 5])
def test_a_coarse_pixel_sits_at_the_centre_of_its_block(d):
    fine_el, fine_az = (np.degrees(a) for a in grid.angle_grid())
    el, az = (np.degrees(a) for a in grid.angle_grid(resolution_deg=d))
    assert el.shape == (90 // d, 360 // d)
    # the mean of the 1-degree pixels each coarse pixel averages (views.downsample's blocks)
    np.testing.assert_allclose(el, downsample(fine_el[None], d)[0], atol=1e-4)
    np.testing.assert_allclose(az, downsample(fine_az[None], d)[0], atol=1e-4)


def test_a_grid_finer_than_the_data_is_refused():
    with pytest.raises(ConfigError, match="resolution_deg"):
        grid.angle_grid(resolution_deg=0.5)


def test_a_coarse_pas_matches_the_block_means_of_the_fine_one():
    """20 random 16-element channels at 2.4 GHz: the 2-degree Bartlett PAS against the 2 x 2 block
    means of the 1-degree one, both min-max normalised. Block centres: mean |difference| 0.0037
    (max 0.018); the old rule, (i + 1) * 2 and j * 2 degrees, gave 0.0092 (max 0.052)."""
    rng = np.random.default_rng(0)
    h = (rng.normal(size=(20, 16)) + 1j * rng.normal(size=(20, 16))).astype(np.complex64)
    full = normalize(bartlett(h, frequency_hz=2.4e9))
    coarse = normalize(bartlett(h, frequency_hz=2.4e9, resolution_deg=2))
    diff = np.abs(coarse - normalize(downsample(full, 2)))
    assert diff.mean() < 0.005 and diff.max() < 0.03


def test_the_elevation_of_row_0_can_be_moved():
    """Row 0 at 0 degrees (the published NeRF2 folders' grid): every row one degree lower than this
    project's, at 1 degree and on a coarser grid's block centres alike; azimuth unchanged."""
    from rfmitsuba.rf.grid import angle_grid

    for res in (1.0, 2.0):
        el1, az1 = angle_grid(resolution_deg=res)
        el0, az0 = angle_grid(resolution_deg=res, elevation_start_deg=0.0)
        np.testing.assert_allclose(np.degrees(el1 - el0), 1.0, atol=1e-12)
        np.testing.assert_array_equal(az0, az1)
    assert np.degrees(angle_grid(elevation_start_deg=0.0)[0][0, 0]) == 0.0
