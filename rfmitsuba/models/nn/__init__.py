"""Small Dr.Jit neural networks: encodings, packed MLPs and the EM-feature network.

Everything here is part of one Dr.Jit AD graph with the splatting kernels. The MLPs run as
cooperative vectors (``drjit.nn``); on the LLVM backend the EM network's matrix products run on
the host's BLAS inside a custom AD op instead (:class:`HostMLP` per MLP, :class:`HostEMNet` for
the whole EM network; :attr:`NetConfig.host_products`), because the cooperative-vector backward
there adds weight gradients atomically (a Stage-1 splat step at batch 4 and 10 000 Gaussians:
354 -> 194 ms of kernel time, plus about 70 ms of host products). The host passes' element-wise
steps are fused loops (:mod:`rfmitsuba.models.nn.host_loops`).

The EM-feature network of a Gaussian field maps (Gaussian position, antenna
position[, extra inputs such as a person position]) to each Gaussian's signal and
attenuation *per view*. It is factorised so that the cost of the wide layers is
paid once per Gaussian and once per view, and only a small head runs on the
B*N (view, Gaussian) pairs::

    g_i = MLP_g(enc(p_i))                  # N evaluations
    a_b = MLP_a(enc(q_b), extra_b)         # B evaluations
    (s, d)_{b,i} = head(act(g_i + a_b))    # B*N evaluations (view-major, b*N + i)

``g_i + a_b`` is exactly a first linear layer on the concatenated inputs, so the
network is an ordinary MLP on ``[enc(p_i), enc(q_b), extra_b]``.

The package holds one step per module: :mod:`.config` (the architecture and number format),
:mod:`.encoding`, :mod:`.grad_barrier`, :mod:`.mlp`, :mod:`.em_network`, and
the host path of the LLVM backend: :mod:`.host_columns` (host arrays behind uploads),
:mod:`.host_pass` (one MLP call in NumPy) and :mod:`.host_ops` (the custom AD ops around it).
"""
from .config import PRECISIONS, NetConfig, config_dict, resolve_precision
from .em_network import EMNetwork
from .encoding import encode
from .grad_barrier import grad_barrier
from .mlp import MLP

__all__ = ["EMNetwork", "MLP", "NetConfig", "PRECISIONS", "config_dict", "encode", "grad_barrier",
           "resolve_precision"]
