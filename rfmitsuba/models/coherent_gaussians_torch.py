"""PyTorch twin of the coherent Gaussian field's channels and Bartlett read-out.

The same math as :meth:`rfmitsuba.models.coherent_gaussians.CoherentGaussianField.channels` and
:func:`rfmitsuba.rf.bartlett.bartlett`, written as dense batched tensors with autograd, for two
uses: the reference the Dr.Jit kernels are tested against (values and gradients,
tests/models/test_coherent_gaussians_torch.py) and the reference of ``rfmitsuba bench field``.
PyTorch is an optional dependency (``pip install -e ".[torch]"``); this module imports it only
inside its functions.

Shapes: B views, M = 16 elements, S image sources, P scatterers, K = S + P sources.
"""
from __future__ import annotations

import numpy as np

from ..rf import array as antenna
from ..rf.bartlett_ref import beamformer
from .coherent_gaussians import coupling_index


def parameters_from(field, *, dtype=None) -> dict:
    """The field's parameters as leaf tensors with gradients (name -> float tensor, flat as the
    field stores them). ``dtype``: torch dtype (default float32)."""
    import torch

    dtype = dtype or torch.float32
    return {k: torch.tensor(np.asarray(v.numpy(), np.float64), dtype=dtype, requires_grad=True)
            for k, v in field.parameters().items()}


def _rotate(w, v):
    """Rotate rows of ``v`` [N, 3] by the rotation vector ``w`` [3] (Rodrigues)."""
    import torch

    th = torch.sqrt((w * w).sum() + 1e-24)
    k = w / th
    c, s = torch.cos(th), torch.sin(th)
    kv = v @ k
    return v * c + torch.cross(k.expand_as(v), v, dim=1) * s + k[None, :] * kv[:, None] * (1 - c)


def channels(params: dict, field, views) -> tuple:
    """Calibrated channels at the 16 elements: (re, im), float tensors [B, 16].

    Args:
        params: :func:`parameters_from` of ``field`` (or tensors of the same names and sizes).
        field: the :class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField` whose fixed
            geometry (image maps, wavefront, carrier) is used.
        views: :class:`~rfmitsuba.models.base.Views`.
    """
    import torch

    dt = params["img_amp"].dtype
    x, y, q = (torch.tensor(np.asarray(a, np.float64).reshape(-1, 3), dtype=dt)
               for a in (views.view_pos, views.transmitter, views.antenna_pos))
    R = np.eye(3) if views.rx_to_world is None else np.asarray(views.rx_to_world, np.float64).reshape(3, 3)
    e_world = torch.tensor(antenna.element_positions(field.frequency_hz) @ R.T, dtype=dt)     # [M, 3]
    kw = 2.0 * np.pi / antenna.wavelength(field.frequency_hz)
    pose = params["pose"]
    r = _rotate(pose[:3], e_world)                                                          # [M, 3]
    cen = x + pose[3:]                                                                      # [B, 3]
    S, P = field.num_images, field.num_scatterers
    A = torch.tensor(field.A, dtype=dt)
    src = [torch.einsum("sij,bj->bsi", A, y) + params["img_offset"].reshape(S, 3)[None]]  # [B, S, 3]
    lead = [torch.zeros(len(x), S, dtype=dt)]
    spread = [torch.ones(len(x), S, dtype=dt)]
    amps = [params["img_amp"].reshape(S, 2)]
    if P:
        pos = params["sc_pos"].reshape(P, 3)
        src.append(pos[None].expand(len(x), P, 3))
        d = torch.sqrt(((y[:, None, :] - pos[None]) ** 2).sum(-1) + 1e-12)                  # [B, P]
        lead.append(d)
        spread.append(d)
        amps.append(params["sc_amp"].reshape(P, 2))
    s, lead, spread, amp = (torch.cat(t, 1 if t is not amps else 0) for t in (src, lead, spread, amps))
    el = cen[:, None, :] + r[None]                                                          # [B, M, 3]
    if field.wavefront == "spherical":
        L = torch.sqrt(((s[:, None, :, :] - el[:, :, None, :]) ** 2).sum(-1) + 1e-12)       # [B, M, K]
        phase = -kw * (L + lead[:, None, :])
    else:
        dv = s - cen[:, None, :]                                                            # [B, K, 3]
        L0 = torch.sqrt((dv * dv).sum(-1) + 1e-12)                                          # [B, K]
        u = dv / L0[..., None]
        phase = kw * torch.einsum("mi,bki->bmk", r, u) - kw * (L0 + lead)[:, None, :]
        L = L0[:, None, :]
    vc = params["vis_center"].reshape(-1, 3)
    ext = torch.exp(params["vis_log_extent"])
    d2 = ((q[:, None, :] - vc[None]) ** 2).sum(-1)                                          # [B, K]
    win = torch.exp(-0.5 * d2 / (ext * ext)[None])                                          # [B, K]
    if field.grid_cells:
        win = win * _grid_factor(params, field, q)
    w = win[:, None, :] / (spread[:, None, :] * L)                                          # [B, M, K]
    ar, ai = amp[:, 0], amp[:, 1]
    c, sn = torch.cos(phase), torch.sin(phase)
    hr = (w * (ar * c - ai * sn)).sum(-1)                                                  # [B, M]
    hi = (w * (ar * sn + ai * c)).sum(-1)
    if "coupling" in params:   # mutual coupling h + K h, K [M, M] complex: (K h)_m = sum_n K[m, n] h_n
        index = torch.as_tensor(coupling_index())           # [M, M], -1: none
        coef = params["coupling"].reshape(-1, 2)
        K = torch.where((index >= 0)[..., None], coef[index.clamp(min=0)], torch.zeros_like(coef[:1]))
        kr, ki = K[..., 0], K[..., 1]
        hr, hi = hr + hr @ kr.T - hi @ ki.T, hi + hi @ kr.T + hr @ ki.T
    cal = params["cal"].reshape(-1, 2)
    return hr * cal[:, 0] - hi * cal[:, 1], hr * cal[:, 1] + hi * cal[:, 0]


def _grid_factor(params: dict, field, q):
    """``2 sigmoid(v(q))`` of every source's visibility grid: tensor [B, K] (q: [B, 3] m, clamped into
    the box; v trilinear in the cells, each source's cells x-major, then y, then z)."""
    import torch

    n = [int(c) for c in field.cfg.vis_grid]
    box = params["vis_grid_box"].detach()
    v = params["vis_grid"].reshape(-1, *n)                                                  # [K, nx, ny, nz]
    t = ((q - box[:3]) / (box[3:] - box[:3])).clamp(0.0, 1.0) * torch.tensor([c - 1 for c in n], dtype=q.dtype)
    c0 = torch.minimum(torch.floor(t).long(), torch.tensor([max(c - 2, 0) for c in n]))       # [B, 3]
    fr = t - c0.to(q.dtype)
    out = torch.zeros(len(q), v.shape[0], dtype=q.dtype)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                d = (dx, dy, dz)
                if any(d[i] and n[i] < 2 for i in range(3)):
                    continue
                w = torch.ones(len(q), dtype=q.dtype)
                for i in range(3):
                    w = w * (fr[:, i] if d[i] else 1.0 - fr[:, i])
                out = out + w[:, None] * v[:, c0[:, 0] + dx, c0[:, 1] + dy, c0[:, 2] + dz].T
    return 2.0 * torch.sigmoid(out)


def bartlett(h_re, h_im, *, frequency_hz: float, height: int = 90, width: int = 360, normalize: bool = True,
             phase_only: bool = False):
    """Bartlett PAS of channels [B, 16] (re, im tensors): tensor [B, height, width], min-max
    normalised per image with ``normalize``; ``phase_only`` uses ``h / |h|``."""
    import torch

    if phase_only:
        mag = torch.sqrt(h_re * h_re + h_im * h_im + 1e-20)
        h_re, h_im = h_re / mag, h_im / mag
    wb = beamformer(frequency_hz=frequency_hz, resolution_deg=90.0 / height)                # [H*W, 16]
    wr = torch.tensor(wb.real, dtype=h_re.dtype)
    wi = torch.tensor(wb.imag, dtype=h_re.dtype)
    yr = h_re @ wr.T - h_im @ wi.T
    yi = h_re @ wi.T + h_im @ wr.T
    p = torch.sqrt(yr * yr + yi * yi)
    if normalize:
        lo, hi = p.min(1, keepdim=True).values, p.max(1, keepdim=True).values
        p = (p - lo) / torch.clamp(hi - lo, min=1e-30)
    return p.reshape(-1, height, width)


def render(params: dict, field, views, *, height: int = 90, width: int = 360, normalize: bool = True):
    """PAS of the field alone, as :func:`rfmitsuba.models.base.render` draws it: tensor [B, H, W]."""
    hr, hi = channels(params, field, views)
    return bartlett(hr, hi, frequency_hz=views.frequency_hz, height=height, width=width, normalize=normalize,
                    phase_only=field.readout == "phase_only")
