"""rfmitsuba.models.coherent_gaussians.array: the array model and the read-out.

The mutual coupling's index (reciprocal, one coefficient per pair of neighbouring elements) and the
Bartlett read-out (the op's kernels with gradients, the host products without)."""
from __future__ import annotations

import numpy as np
import pytest
from coherent_gaussians_cases import F


#: every test on one Dr.Jit thread (the ``one_thread`` fixture of tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def test_coupling_index_is_reciprocal_between_neighbours():
    """K = K^T, one coefficient per pair of row, column or diagonal neighbours of the 4 x 4 array
    (12 + 12 + 18 = 42), none on the diagonal or farther apart."""
    from rfmitsuba.models.coherent_gaussians import coupling_index, coupling_size

    idx = coupling_index()
    np.testing.assert_array_equal(idx, idx.T)
    assert coupling_size() == 42 and sorted(set(idx[idx >= 0].tolist())) == list(range(42))
    r, c = np.divmod(np.arange(16), 4)
    far = np.maximum(np.abs(r[:, None] - r[None]), np.abs(c[:, None] - c[None]))
    assert (idx[far != 1] == -1).all() and (idx[far == 1] >= 0).all()
    assert (np.bincount(idx[idx >= 0]) == 2).all()                        # each pair: K[m, n] and K[n, m]


@pytest.mark.parametrize("readout", ["amplitude", "phase_only"])
def test_read_out_runs_the_kernels_with_gradients_and_the_host_products_without(readout):
    """A differentiable read-out (a training step, traced or recorded) is the Bartlett op's
    kernels bit for bit, so a traced step equals its recording; without gradients (rendering,
    prediction) it is the host products (on LLVM; the kernels on CUDA)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians.array import read_out
    from rfmitsuba.rf.bartlett import bartlett

    rng = np.random.default_rng(3)
    h = (rng.normal(size=(3, 16)) + 1j * rng.normal(size=(3, 16))).astype(np.complex64)
    kw = dict(frequency_hz=F, height=9, width=36, normalize=True)

    def channels(grad):
        hr, hi = B.Float(h.real.ravel()), B.Float(h.imag.ravel())
        if grad:
            dr.enable_grad(hr, hi)
        if readout == "phase_only":
            mag = dr.sqrt(hr * hr + hi * hi + 1e-20)
            return (hr, hi), (hr / mag, hi / mag)
        return (hr, hi), (hr, hi)

    for grad, host in ((True, False), (False, not B.is_cuda())):
        (hr, hi), unit = channels(grad)
        got = read_out(hr, hi, readout=readout, **kw).numpy()
        want = bartlett(*(dr.detach(u) for u in unit), host=host, **kw).numpy()
        assert np.array_equal(got, want), (grad, host)
