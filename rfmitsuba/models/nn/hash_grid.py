"""A 3-D multiresolution hash-grid encoding with one parameter array (:class:`HashGrid`)."""
from __future__ import annotations

import numpy as np

from ...core import backend as B
from .config import NetConfig


class HashGrid:
    """A 3-D multiresolution hash-grid encoding (``drjit.nn.HashGridEncoding``) with one
    parameter array :attr:`weights` (``Float`` [num_parameters]); inputs in [0, 1]^3."""

    def __init__(self, cfg: NetConfig, *, seed: int):
        import drjit as dr
        from drjit.hashgrid import HashGridEncoding

        self.enc = HashGridEncoding(
            B.Float, 3, n_levels=cfg.hash_levels, n_features_per_level=cfg.hash_features,
            hashmap_size=2 ** cfg.hash_log2_size, base_resolution=cfg.hash_base_resolution,
            per_level_scale=cfg.hash_per_level_scale, rng=dr.rng(seed=int(seed) + 0x2000))
        self.n_out = cfg.hash_levels * cfg.hash_features

    @property
    def weights(self):
        return self.enc.data

    def set_weights(self, value) -> None:
        if isinstance(value, np.ndarray):
            value = B.Float(value.astype(np.float32))
        self.enc.data = value

    @property
    def num_parameters(self) -> int:
        return int(self.enc.n_params)

    #: Length of :attr:`weights` (no padding in a hash table).
    buffer_size = num_parameters

    def __call__(self, inputs: list) -> list:
        return list(self.enc(inputs))
