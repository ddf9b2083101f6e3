"""The EM-feature network of a Gaussian field (:class:`EMNetwork`): per-Gaussian and per-view
branches and a head on every (view, Gaussian) pair."""
from __future__ import annotations

from .config import NetConfig
from .encoding import encode
from .host_ops import HostEMNet
from .mlp import MLP


class EMNetwork:
    """EM-feature network: (Gaussian position, antenna position, extra inputs) ->
    per-view signal, attenuation offset and log-scale offset of every Gaussian.

    Args:
        cfg: architecture.
        extra_inputs: number of extra per-view inputs (0 for the background; 3 for a person
            position in Stage 2), given to :meth:`__call__` already normalised to about [0, 1].
        seed: weight initialisation seed.

    Parameters (see :meth:`modules`): the ``"gaussian"``, ``"antenna"`` and ``"head"`` packed MLP
    weights.
    """

    def __init__(self, cfg: NetConfig, *, extra_inputs: int = 0, seed: int = 0):
        self.cfg = cfg
        self.extra_inputs = int(extra_inputs)
        w = cfg.width
        n_g = 3 * (1 + 2 * cfg.gaussian_octaves)
        n_a = 3 * (1 + 2 * cfg.antenna_octaves) + self.extra_inputs
        kw = {"host": cfg.host_products, "precision": cfg.precision}
        self.gaussian = MLP(n_g, w, width=w, layers=cfg.branch_layers, seed=seed + 1, **kw)
        self.antenna = MLP(n_a, w, width=w, layers=cfg.branch_layers, seed=seed + 2, **kw)
        self.head = MLP(w, 3, width=w, layers=cfg.head_layers, seed=seed + 3, out_bias=[cfg.signal_bias, 0.0, 0.0],
                        **kw)

    def modules(self) -> dict:
        """Name -> module (each has ``weights``, ``set_weights``, ``num_parameters``)."""
        return {"gaussian": self.gaussian, "antenna": self.antenna, "head": self.head}

    @property
    def num_parameters(self) -> int:
        return sum(m.num_parameters for m in self.modules().values())

    def gaussian_features(self, pos01: list) -> list:
        """Per-Gaussian branch: pos01 list of 3 ``Float`` [N] in [0, 1] -> ``width`` ``Float`` [N]."""
        return self.gaussian(self._gaussian_inputs(pos01))

    def _gaussian_inputs(self, pos01: list) -> list:
        """The Gaussian branch's inputs: the encoded positions."""
        return encode([p * 0.5 for p in pos01], octaves=self.cfg.gaussian_octaves)

    def antenna_features(self, ant01: list, extra: list | None = None) -> list:
        """Per-view branch: ant01 list of 3 ``Float`` [B] in [0, 1], extra list of
        ``extra_inputs`` ``Float`` [B] -> ``width`` ``Float`` [B]."""
        return self.antenna(self._antenna_inputs(ant01, extra))

    def _antenna_inputs(self, ant01: list, extra: list | None) -> list:
        """The antenna branch's inputs: the encoded antenna position, then the extra inputs."""
        x = encode([a * 0.5 for a in ant01], octaves=self.cfg.antenna_octaves)
        extra = list(extra or [])
        if len(extra) != self.extra_inputs:
            raise ValueError(f"EMNetwork expects {self.extra_inputs} extra inputs, got {len(extra)}")
        return x + extra

    def __call__(self, pos01: list, ant01: list, extra: list | None = None) -> tuple:
        """Signal and attenuation offsets for every (view, Gaussian) pair.

        Args:
            pos01: 3 ``Float`` [N], Gaussian positions mapped into [0, 1] (scene box).
            ant01: 3 ``Float`` [B], antenna positions mapped into [0, 1].
            extra: ``extra_inputs`` ``Float`` [B] or None.

        Returns:
            (signal_logit, attenuation_logit, log_scale_offset): ``Float`` [B*N] each,
            view-major (b*N + i).
        """
        mods = (self.gaussian, self.antenna, self.head)
        if all(m._host_layers is not None for m in mods):
            # the whole network in one host op (:class:`HostEMNet`)
            import drjit as dr

            xs = self._gaussian_inputs(pos01)
            ants = self._antenna_inputs(ant01, extra)
            for m, inputs in ((self.gaussian, xs), (self.antenna, ants)):
                if len(inputs) != m.n_in:
                    raise ValueError(f"MLP expects {m.n_in} inputs, got {len(inputs)}")
            out = dr.custom(HostEMNet.op(), list(xs), list(ants), self.gaussian.weights, self.antenna.weights,
                            self.head.weights, tuple(m._host_layers for m in mods))
            return out[0], out[1], out[2]
        out = self.head.pairs(self.gaussian_features(pos01), self.antenna_features(ant01, extra))
        return out[0], out[1], out[2]
