"""The EM-feature network's architecture (:class:`NetConfig`) and the number format of its
products (:func:`resolve_precision`)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Literal

from ...core import backend as B
from ...core.errors import ConfigError


@dataclass
class NetConfig:
    """Architecture of the EM-feature network.

    gaussian_octaves / antenna_octaves: octaves of the sine encodings of the Gaussian and the
        antenna positions (0 = raw input only; :func:`rfmitsuba.models.nn.encode`).
    width: hidden width of every layer; branch_layers: hidden layers of each branch;
    head_layers: hidden layers of the head that runs on every (view, Gaussian) pair.
    signal_bias: initial bias of the signal output (signal = sigmoid(out)), so training
        starts from a dim field.
    host_products: on the LLVM backend, run the MLPs' matrix products on the host's BLAS
        (:class:`MLP`); False: Dr.Jit cooperative vectors, as on CUDA. Same values and
        gradients; ``rfmitsuba bench splat`` times a Stage-1 step both ways.
    precision: number format of the cooperative-vector products, "auto" (half on CUDA, where
        Dr.Jit 1.5 packs only half-precision matrices; single on LLVM), "single" or "half"
        (float16 products and inputs, float32 master weights: :class:`MLP`).
    """

    #: options this class no longer has (:mod:`rfmitsuba.core.config`): the triangle-wave and
    #: hash-grid encodings, never measured to help; None: only read with the hash grid
    removed_options: ClassVar[dict] = {"encoding": "sin", "hash_levels": None, "hash_features": None,
                                       "hash_log2_size": None, "hash_base_resolution": None,
                                       "hash_per_level_scale": None}

    gaussian_octaves: int = 6
    antenna_octaves: int = 6
    width: int = 64
    branch_layers: int = 1
    head_layers: int = 1
    signal_bias: float = -2.0
    host_products: bool = True
    precision: Literal["auto", "single", "half"] = "auto"

    def __post_init__(self) -> None:
        if self.precision not in PRECISIONS:
            raise ConfigError(f"NetConfig.precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}")
        for name in ("gaussian_octaves", "antenna_octaves", "branch_layers", "head_layers"):
            if getattr(self, name) < 0:
                raise ConfigError(f"NetConfig.{name} must be >= 0, got {getattr(self, name)}")
        if self.width < 1:
            raise ConfigError(f"NetConfig.width must be >= 1, got {self.width}")


#: Number formats of :class:`MLP`'s products ("auto": :func:`resolve_precision`).
PRECISIONS = ("auto", "single", "half")


def resolve_precision(precision: str = "auto") -> str:
    """The number format an :class:`MLP` runs in: "auto" is "half" on CUDA and "single" on LLVM.

    Raises:
        ConfigError: an unknown name, or "single" on CUDA (Dr.Jit 1.5 converts only half-precision
            matrices to the layout its CUDA cooperative vectors need for training).
    """
    if precision not in PRECISIONS:
        raise ConfigError(f"MLP precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        return "half" if B.is_cuda() else "single"
    if precision == "single" and B.is_cuda():
        raise ConfigError("MLP precision 'single' is not available on CUDA: Dr.Jit 1.5 packs only half-precision "
                          "matrices for cooperative vectors there; use 'half' or 'auto'")
    return precision


def config_dict(cfg: NetConfig) -> dict:
    """Plain dict of a :class:`NetConfig` (for metadata)."""
    return dataclasses.asdict(cfg)
