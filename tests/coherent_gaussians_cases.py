"""Cases the coherent Gaussian field's tests share (tests/models/coherent_gaussians/): the frequency,
a perturbed field and a stand-in for the training data."""
from __future__ import annotations

import numpy as np

#: the carrier frequency of every case [Hz]
F = 2.4e9


def _field(*, readout="amplitude", wavefront="plane", seed=0):
    """A field of the direct path, one wall reflection (x = 0) and 2 scatterers, every parameter perturbed."""
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    A = np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])])
    f = CoherentGaussianField(A, np.array([0, 1]), np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5]]),
                              cfg=CoherentGaussianConfig(init_extent=1.5), readout=readout, wavefront=wavefront,
                              vis_center=np.array([2.0, 1.5, 1.0]), frequency_hz=F, seed=seed)
    rng = np.random.default_rng(seed)
    for k, v in f.params.items():
        a = np.asarray(v.numpy(), np.float64)
        f.params[k] = B.Float((a + 0.05 * rng.normal(size=a.shape)).astype(np.float32))
    return f


def _stub_training_data(n: int, *, seed: int):
    """A stand-in for TrainData (n moving-RX positions q, the fixed TX y, random PAS): (data, q, y)."""
    from types import SimpleNamespace

    rng = np.random.default_rng(seed)
    q = np.c_[rng.uniform(1.0, 2.2, n), rng.uniform(2.2, 2.8, n), rng.uniform(1.0, 1.6, n)]
    y = np.tile([0.3, 0.3, 2.0], (n, 1))
    data = SimpleNamespace(path="stub", train=np.arange(n), rx_to_world=None, frequency_hz=F, measured=False,
                           readout="amplitude", task="rx", positions=lambda idx: (q[idx], y[idx], q[idx]),
                           pas=lambda idx, d=1: rng.random((len(idx), 90 // d, 360 // d)).astype(np.float32))
    return data, q, y
