"""A fully connected network in one packed weight buffer (:class:`MLP`): Dr.Jit cooperative
vectors, or host matrix products on the LLVM backend (:mod:`.host_ops`)."""
from __future__ import annotations

import numpy as np

from ...core import backend as B
from ...core.errors import ConfigError
from .config import resolve_precision
from .grad_barrier import grad_barrier
from .host_ops import HostMLP


def _tensor_type(*, half: bool = False):
    return B.ensure().TensorXf16 if half else B.ensure().TensorXf


class MLP:
    """A fully connected network stored as one packed weight buffer.

    Layers: ``n_in -> width (x layers, activation) -> n_out``, LeakyReLU(0.01) between
    layers, linear output. Weights are Xavier-uniform from a seeded Dr.Jit generator,
    so equal ``seed`` gives equal weights; ``zero_output`` zeroes the last layer's weights
    (the network starts as the constant ``out_bias``).

    The single parameter is :attr:`weights` (``Float`` [num_parameters]); assign a new
    value with :meth:`set_weights` (e.g. the optimizer's copy) before evaluating.

    With ``host=True`` on the LLVM backend the products run on the host's BLAS
    (:class:`HostMLP`, a custom AD op: weight gradients as one product instead of atomic
    adds); otherwise (the default, and always on CUDA) as Dr.Jit cooperative vectors. Both give
    the same values and gradients (tests/models/nn/test_nn_host_ops.py). ``precision="half"`` (the default on
    CUDA, where Dr.Jit 1.5 packs only half-precision matrices for training) keeps float32
    master weights as :attr:`weights` and runs the products on float16 copies of weights and
    inputs (outputs back in float32; gradients flow to the master through the casts); outputs
    and gradients agree with single precision within 2% of their largest value
    (test_half_precision_matches_single). The host pays off for the splat
    field's EM network (40 000 rows per call; :attr:`NetConfig.host_products`), not for small
    networks called often: the coherent model's gain network trained its test run in 52-57 s on
    the host against 34 s as cooperative vectors.
    """

    def __init__(self, n_in: int, n_out: int, *, width: int, layers: int, seed: int,
                 out_bias: list[float] | None = None, input_layer: bool = True, zero_output: bool = False,
                 host: bool = False, precision: str = "auto"):
        import drjit as dr
        import drjit.nn as nn

        self.n_in, self.n_out = n_in, n_out
        #: "single" or "half" (:func:`resolve_precision`)
        self.precision = resolve_precision(precision)
        half = self.precision == "half"
        mods = []
        for _ in range(layers):
            mods += [nn.Linear(-1, width), nn.LeakyReLU(0.01)]
        mods.append(nn.Linear(-1, n_out))
        tensor = _tensor_type(half=half)
        net = nn.Sequential(*mods).alloc(tensor, n_in, rng=dr.rng(seed=int(seed) + 0x1000))
        if out_bias is not None:
            net.layers[-1].bias = tensor(np.asarray(out_bias, dtype=np.float16 if half else np.float32))
        if zero_output:  # the network starts as the constant out_bias (its last layer learns first)
            net.layers[-1].weights = dr.zeros(tensor, net.layers[-1].weights.shape)
        self._num_parameters = sum(int(np.prod(m.weights.shape)) + int(m.bias.shape[0])
                                   for m in net.layers if isinstance(m, nn.Linear))
        self.net = nn.pack(net, layout="training")
        #: half precision: the float32 master copy of the packed buffer (the trainable parameter)
        self._master = None
        if half:
            self._master = B.Float(self.net["weights"])
            dr.eval(self._master)
        #: (weight offset, out, in, row stride, bias offset) per linear layer where host matrix
        #: products run this network (:class:`HostMLP`: LLVM backend, ``host``), else None
        self._host_layers = None
        if host and not B.is_cuda() and not half:
            lin = [m for m in self.net.layers if isinstance(m, nn.Linear)]
            self._host_layers = tuple((int(m.weights.offset), int(m.weights.shape[0]), int(m.weights.shape[1]),
                                       int(m.weights.stride), int(m.bias.offset)) for m in lin)

    @property
    def weights(self):
        """The packed weights and biases: ``Float`` [buffer_size] (float32 in either precision)."""
        return self._master if self._master is not None else self.net["weights"]

    def set_weights(self, value) -> None:
        """Replace the weights (``Float`` or float32 numpy [buffer_size]); keeps AD links."""
        n = self.buffer_size
        if isinstance(value, np.ndarray):
            if value.shape != (n,):
                raise ConfigError(f"MLP weights: expected shape ({n},), got {value.shape}")
            value = B.Float(value.astype(np.float32))
        import drjit as dr

        if self._master is not None:
            self._master = value
            dr.eval(self._master)
            return
        self.net["weights"] = value
        dr.eval(self.net["weights"])  # flush the in-place copy before any kernel reads it

    @property
    def num_parameters(self) -> int:
        """Trainable scalars: every layer's weights and biases (the buffer's padding not counted)."""
        return self._num_parameters

    @property
    def buffer_size(self) -> int:
        """Length of :attr:`weights`, the packed buffer: :attr:`num_parameters` on LLVM, more on
        CUDA, whose training-optimal layout pads the matrices."""
        return int(self.weights.shape[0])

    def _cast_master(self, *, detach: bool = False) -> None:
        """Half precision: put the float16 copy of the float32 master weights into the packed
        network (a differentiable cast, so gradients reach the master, unless ``detach``)."""
        import drjit as dr

        self.net["weights"] = B.ensure().Float16(dr.detach(self._master) if detach else self._master)

    def layer_arrays(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The current weights as ``(W [out, in], b [out])`` float32 arrays per linear layer, read
        back from the packed buffer whatever its layout (row-major on LLVM; on CUDA the
        training-optimal layout is padded and reordered, so :attr:`weights` is no plain matrix);
        in half precision, the float16 values the products use."""
        import drjit.nn as nn

        if self._master is not None:
            self._cast_master(detach=True)
        out = []
        for layer in (m for m in self.net.layers if isinstance(m, nn.Linear)):
            W, b = nn.unpack(layer.weights, layer.bias)
            rows, cols = W.shape
            wbuf = np.asarray(W.buffer.numpy(), np.float32)
            bbuf = np.asarray(b.buffer.numpy(), np.float32)
            out.append((wbuf[W.offset:W.offset + rows * W.stride].reshape(rows, W.stride)[:, :cols].copy(),
                        bbuf[b.offset:b.offset + rows].copy()))
        return out

    def __call__(self, inputs: list) -> list:
        """Evaluate on ``inputs``: list of n_in ``Float`` [M] -> list of n_out ``Float`` [M]."""
        import drjit.nn as nn

        if len(inputs) != self.n_in:
            raise ValueError(f"MLP expects {self.n_in} inputs, got {len(inputs)}")
        if self._host_layers is not None:
            import drjit as dr

            return list(dr.custom(HostMLP.op(), list(inputs), [], self.net["weights"], self._host_layers))
        if self._master is not None:
            self._cast_master()
            out = self.net(nn.CoopVec(*[B.ensure().Float16(x) for x in inputs]))
            return grad_barrier([B.Float(o) for o in out])
        return grad_barrier(list(self.net(nn.CoopVec(*inputs))))

    def pairs(self, per_item: list, per_view: list) -> list:
        """Evaluate on every (view, item) pair: ``MLP(LeakyReLU(per_item_i + per_view_b))``.

        Args:
            per_item: n_in ``Float`` [N]; per_view: n_in ``Float`` [B].
        Returns:
            n_out ``Float`` [B*N], view-major (``b * N + i``).
        """
        import drjit as dr

        if len(per_item) != self.n_in or len(per_view) != self.n_in:
            raise ValueError(f"MLP.pairs expects {self.n_in} inputs per item and per view, "
                             f"got {len(per_item)} and {len(per_view)}")
        if self._host_layers is not None:
            return list(dr.custom(HostMLP.op(), list(per_item), list(per_view), self.net["weights"],
                                  self._host_layers))
        n, b = dr.width(per_item[0]), dr.width(per_view[0])
        idx = dr.arange(B.UInt32, n * b)
        n_op = dr.opaque(B.UInt32, n)  # opaque: a new N must not trigger a kernel recompilation
        gi, bi = idx % n_op, idx // n_op
        h = [dr.gather(B.Float, gg, gi) + dr.gather(B.Float, aa, bi) for gg, aa in zip(per_item, per_view)]
        return self([dr.maximum(x, 0) + 0.01 * dr.minimum(x, 0) for x in h])
