"""Fixtures of the device-free localisation tests: a two-stage model of known fields, the PAS it
renders with a person at a known position, and a tiny trained comparison."""
from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def known_model(synthetic_ds, variant):
    """A two-stage model of known fields on the synthetic dataset's geometry: a background of the
    direct path, one wall reflection and two scatterers; a person who blocks strongly and carries
    three scatterers."""
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.eval.locate import TwoStage
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.models.coherent_gaussians_person import CoherentGaussianPersonConfig, CoherentGaussianPersonField

    data = SampleData.open_samples(synthetic_ds, states="all")
    A = np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])])
    bg = CoherentGaussianField(A, np.array([0, 1]), np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5]]),
                               cfg=CoherentGaussianConfig(init_extent=1.5), readout="amplitude", wavefront="spherical",
                               vis_center=np.array([2.0, 1.75, 1.0]), frequency_hz=float(data.frequency_hz), seed=0)
    bg.freeze()
    pcfg = CoherentGaussianPersonConfig(num_points=3, person_octaves=1, init_gain=0.5, init_strength=0.9,
                                        init_block_radius=0.3)
    person = CoherentGaussianPersonField.for_background(bg, cfg=pcfg, seed=1)
    person.freeze()
    train = np.isin(data.states, np.asarray(data.split.person_train) + 1) & (data.antennas == 0)
    return TwoStage(background=bg, person=person, data=data, feet_z=0.0, walk=data.person_pos[train], job=synthetic_ds)


@pytest.fixture(scope="module")
def true_feet():
    """The person's feet position [m] the known model's query PAS are rendered at."""
    return np.array([1.9, 1.7, 0.0])


@pytest.fixture(scope="module")
def pas_at():
    """The known model's raw PAS float32 [K, 90, 360] with the feet at ``feet`` (or no person)."""
    return _pas_at


def _pas_at(model, feet, antenna_pos, *, person=True):
    """The model's raw PAS float32 [K, 90, 360] with the person's feet at ``feet`` (or no person)."""
    import drjit as dr

    from rfmitsuba.eval.predict import views_at
    from rfmitsuba.models.base import render

    views = views_at(model.data, antenna_pos)
    ext = model.features(np.tile(feet, (len(antenna_pos), 1)))
    views.inputs = lambda field: ext
    fields = [model.background, model.person] if person else [model.background]
    with dr.suspend_grad():
        img = render(fields, views, height=90, width=360, normalize=False)
    return np.asarray(img.numpy(), np.float32).reshape(-1, 90, 360)


@pytest.fixture(scope="module")
def tiny_two_stage(synthetic_ds, tmp_path_factory, variant):
    """A tiny comparison folder (Baseline + Ours, one seed) on the synthetic dataset."""
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.compare import CompareConfig, compare

    out = tmp_path_factory.mktemp("locate_cmp") / "cmp"
    cfg = C.override(CompareConfig(), ["methods=['baseline','ours']", "seeds=[0]", "train.stage1_iterations=6",
                                       "train.val_every=6", "train.stage2_iterations=4"])
    compare(synthetic_ds, out, cfg=cfg, progress=False)
    return out
