"""rfmitsuba.models.coherent_gaussians_torch: the PyTorch twin of the coherent Gaussian field gives
the Dr.Jit field's PAS and gradients (every parameter, both wavefronts and read-outs). The twin is
the reference of ``rfmitsuba bench field``; PyTorch is an optional dependency ([torch] extra)."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

pytestmark = pytest.mark.usefixtures("one_thread")

F = 2.4e9


def _field(readout, wavefront, vis_grid="auto"):
    from rfmitsuba.core import backend as B
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    A = np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0]), np.diag([1.0, 1.0, -1.0])])
    f = CoherentGaussianField(A, np.array([0, 1, 1]), np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5], [0.3, 3.0, 1.1]]),
                              cfg=CoherentGaussianConfig(init_extent=1.5, vis_grid=vis_grid), readout=readout,
                              wavefront=wavefront, vis_center=np.array([2.0, 1.5, 1.0]), frequency_hz=F)
    rng = np.random.default_rng(0)
    for k, v in f.params.items():
        a = np.asarray(v.numpy(), np.float64)
        scale = 0.05 if k != "vis_grid" else 1.0   # a visibility grid far from its zero start
        f.params[k] = B.Float((a + scale * rng.normal(size=a.shape)).astype(np.float32))
    if vis_grid != "auto":   # a box the views' positions partly leave (the factor is clamped to its faces)
        f.params["vis_grid_box"] = B.Float(np.array([1.4, 1.2, 0.9, 2.2, 1.9, 1.3], np.float32))
    f.params["img_offset"] = B.Float(np.array([0, 0, 0, 0.4, 0, 0, 0, 0, 6.0], np.float32))
    return f


def _views(n=3):
    from rfmitsuba.models.base import Views

    rng = np.random.default_rng(1)
    y = np.array([1.5, 1.0, 1.0]) + rng.random((n, 3)) * [1.0, 1.0, 0.5]
    return Views(antenna_pos=y, view_pos=np.tile([3.5, 2.5, 2.0], (n, 1)), transmitter=y, rx_to_world=None,
                 frequency_hz=F, task="tx")


@pytest.mark.parametrize("readout, wavefront, vis_grid", [("amplitude", "plane", None),
                                                          ("amplitude", "spherical", None),
                                                          ("phase_only", "spherical", None),
                                                          ("amplitude", "plane", (3, 2, 2)),
                                                          ("amplitude", "plane", (4, 1, 3))])
def test_twin_matches_drjit(variant, readout, wavefront, vis_grid):
    """Normalised PAS (45 x 180 grid) within 1e-4, and the gradient of sum(c * PAS) with respect to
    every parameter within 5e-3 of its largest entry (float32 Dr.Jit, phases of ~150 rad, against float64 PyTorch)."""
    import drjit as dr

    from rfmitsuba.core import backend as B
    from rfmitsuba.models.base import render
    from rfmitsuba.models.coherent_gaussians_torch import parameters_from
    from rfmitsuba.models.coherent_gaussians_torch import render as torch_render

    f, views = _field(readout, wavefront, vis_grid), _views()
    c = np.random.default_rng(2).normal(size=(3, 45, 180))
    tp = parameters_from(f, dtype=torch.float64)
    ref = torch_render(tp, f, views, height=45, width=180)
    (ref * torch.tensor(c)).sum().backward()

    params = f.trainable()
    for v in params.values():
        dr.enable_grad(v)
    f.assign(params)
    img = render([f], views, height=45, width=180)
    assert np.abs(img.numpy() - ref.detach().numpy()).max() < 1e-4
    dr.backward(dr.sum(img.array * B.Float(c.ravel().astype(np.float32))))
    for name, v in params.items():
        g, g_ref = np.asarray(dr.grad(v), np.float64), tp[name].grad.numpy()
        scale = np.abs(g_ref).max()
        assert scale > 0, name
        assert np.abs(g - g_ref).max() <= 5e-3 * scale, (name, np.abs(g - g_ref).max(), scale)
