"""Coherent image-source field: the channel as a sum of virtual sources, read out by Bartlett.

Why: a simulated (or measured) PAS is the Bartlett response of the array to the *coherent*
sum of all paths, ``P = |sum_m w_m h_m|``. Paths that arrive together interfere and draw
the dark arcs of the PAS; a sum of splats, which adds intensities, cannot draw them, and the
interference pattern changes every few centimetres, faster than any smooth interpolator of
the PAS can follow (see README, "Stage 1"). This field models what the array actually sees:

    h_m(x, y) = sum_i  g_i(x, y) * exp(-j k L_i) / L_i * exp(+j k r_m . u_i),
    L_i = |M_i(y) - x|,  u_i = (M_i(y) - x) / L_i,

with the array centre ``x``, the transmitter ``y``, the image maps ``M_i`` of the room's
planes (:mod:`rfmitsuba.images`; ``M_0`` = identity is the direct path), the element offsets
``r_m`` and ``k = 2 pi / lambda``. Propagation phase and direction are exact geometry; what
is learned is each image's complex gain

    g_i(x, y) = a_i * (1 + s * head(act(V(enc(q)) + e_i), u_i)),

a constant complex amplitude ``a_i`` (reflection coefficients, 1/(4 pi) factors) times a
position-dependent modulation from a small Dr.Jit network: ``q`` is the moving device's
position (``x`` in the moving-RX task, ``y`` in the moving-TX task), ``e_i`` a learned
per-image embedding. The modulation learns where an image is visible (finite faces,
furniture in the way), the angle dependence of reflection, and what the geometry misses.
The PAS comes from :func:`rfmitsuba.bartlett.pas`, differentiable end to end.

Both tasks of the SPEC use the same formula: moving RX (``x`` moves, ``y`` = the fixed
corner transmitter) and moving TX (``y`` moves, ``x`` = the fixed array), by the
synthetic-array rule of :mod:`rfmitsuba.simulate` (plane-wave phase per element, about the
array centre).

Parameters (Dr.Jit ``Float`` arrays, :meth:`CoherentField.parameters`): ``amp`` [S*2]
(re, im per image), ``embed`` [S*W], ``net.view`` and ``net.head`` packed MLP weights.
State is plain NumPy (npz, no pickle).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import antenna
from . import backend as B
from .errors import ConfigError, RunError
from .images import ImageMaps


@dataclass
class CoherentConfig:
    """Architecture of a :class:`CoherentField`.

    room_order: reflections on the room's planes alone (image maps up to this order).
    furniture_order: 0, 1 or 2 (one furniture reflection, alone or with one room reflection).
    min_face_area: furniture faces smaller than this (m^2) make no image.
    width: hidden width of the gain network; octaves: sine octaves of the position encoding.
    modulation: scale ``s`` of the network's output (its initial size relative to ``a_i``).
    init_reflection: initial amplitude of an image is ``init_reflection ** order``.
    """

    room_order: int = 2
    furniture_order: int = 2
    min_face_area: float = 0.05
    width: int = 32
    octaves: int = 4
    modulation: float = 0.3
    init_reflection: float = 0.5

    def __post_init__(self) -> None:
        if self.room_order < 0 or self.furniture_order not in (0, 1, 2):
            raise ConfigError(f"CoherentConfig: room_order must be >= 0 and furniture_order 0, 1 or 2, got "
                              f"{self.room_order}, {self.furniture_order}")
        if self.width < 1 or self.octaves < 0 or self.min_face_area < 0:
            raise ConfigError("CoherentConfig: width >= 1, octaves >= 0, min_face_area >= 0 required")
        if not (0 < self.init_reflection <= 1) or not (self.modulation > 0):
            raise ConfigError("CoherentConfig: init_reflection in (0, 1] and modulation > 0 required")


def geometry_factors(maps: ImageMaps, x: np.ndarray, y: np.ndarray, *, frequency_hz: float) -> tuple:
    """Exact propagation of every image to every element, no gains.

    Args:
        maps: S image maps.
        x: float [B, 3] metres, array centres; y: float [B, 3] metres, transmitters.
        frequency_hz: carrier, Hz.
    Returns:
        (G complex64 [B, 16, S] = exp(-j k L)/L * exp(+j k r_m . u), u float32 [B, S, 3]).
    """
    x = np.asarray(x, np.float64).reshape(-1, 3)
    y = np.asarray(y, np.float64).reshape(-1, 3)
    if x.shape != y.shape:
        raise ConfigError(f"array and transmitter positions differ in shape: {x.shape} vs {y.shape}")
    k = 2.0 * np.pi / antenna.wavelength(frequency_hz)
    s = maps.apply(y)                                   # [B, S, 3]
    d = s - x[:, None, :]
    L = np.maximum(np.linalg.norm(d, axis=-1), 1e-3)    # [B, S]
    u = d / L[..., None]
    e = antenna.element_positions(frequency_hz)         # [16, 3]
    G = (np.exp(-1j * k * L) / L)[:, None, :] * np.exp(1j * k * np.einsum("bsc,mc->bms", u, e))
    return G.astype(np.complex64), u.astype(np.float32)


class CoherentField:
    """Image sources with learned complex gains (see the module docstring).

    Args:
        maps: the image maps (:func:`rfmitsuba.images.scene_image_maps`).
        box: float [2, 3] metres, box that maps moving positions into [0, 1] for the encoding.
        cfg: :class:`CoherentConfig`.
        frequency_hz: carrier, Hz.
        seed: weight initialisation.
    """

    def __init__(self, maps: ImageMaps, *, box: np.ndarray, cfg: CoherentConfig | None = None,
                 frequency_hz: float = 2.4e9, seed: int = 0, params: dict | None = None):
        from .nn import MLP

        B.ensure()
        self.maps = maps
        self.cfg = cfg or CoherentConfig()
        self.frequency_hz = float(frequency_hz)
        self.box = np.asarray(box, np.float64).reshape(2, 3)
        self.seed = int(seed)
        S, W = len(maps), self.cfg.width
        n_in = 3 * (1 + 2 * self.cfg.octaves)
        self.view = MLP(n_in, W, width=W, layers=1, seed=seed + 11)
        self.head = MLP(W + 3, 2, width=W, layers=1, seed=seed + 12, out_bias=[0.0, 0.0])
        rng = np.random.default_rng(seed)
        if params is None:
            a = self.cfg.init_reflection ** maps.order.astype(np.float64)
            amp = np.stack([a, np.zeros_like(a)], 1).astype(np.float32)
            embed = (0.1 * rng.standard_normal((S, W))).astype(np.float32)
            params = {"amp": amp.ravel(), "embed": embed.ravel()}
        self.params = {"amp": B.Float(np.asarray(params["amp"], np.float32).ravel()),
                       "embed": B.Float(np.asarray(params["embed"], np.float32).ravel())}
        if "net.view" in params:
            self.view.set_weights(np.asarray(params["net.view"], np.float32))
            self.head.set_weights(np.asarray(params["net.head"], np.float32))
        self.frozen = False

    # ---- parameters ------------------------------------------------------------------------
    @property
    def num_sources(self) -> int:
        return len(self.maps)

    @property
    def num_parameters(self) -> int:
        return 2 * self.num_sources + self.num_sources * self.cfg.width + self.view.num_parameters \
            + self.head.num_parameters

    def parameters(self) -> dict:
        """Name -> Dr.Jit ``Float`` of every parameter."""
        return {"amp": self.params["amp"], "embed": self.params["embed"],
                "net.view": self.view.weights, "net.head": self.head.weights}

    def trainable(self) -> dict:
        return {} if self.frozen else self.parameters()

    def assign(self, values: dict) -> None:
        """Set parameters from ``values`` (name -> ``Float``), e.g. the optimizer's copies."""
        for k, v in values.items():
            if k in ("amp", "embed"):
                self.params[k] = v
            elif k == "net.view":
                self.view.set_weights(v)
            elif k == "net.head":
                self.head.set_weights(v)
            else:
                raise ConfigError(f"CoherentField has no parameter {k!r}")

    def freeze(self) -> None:
        self.frozen = True

    # ---- evaluation ------------------------------------------------------------------------
    def gains(self, q: np.ndarray, u: np.ndarray) -> tuple:
        """Complex gain of every (view, image): two ``Float`` [B*S] (view-major ``b*S + i``).

        Args:
            q: float [B, 3] metres, moving device positions; u: float [B, S, 3] unit directions.
        """
        import drjit as dr

        from .nn import encode

        S, W = self.num_sources, self.cfg.width
        q01 = (np.asarray(q, np.float64).reshape(-1, 3) - self.box[0]) / (self.box[1] - self.box[0])
        nb = len(q01)
        cols = [B.Float(np.ascontiguousarray(q01[:, c] * 0.5, np.float32)) for c in range(3)]
        a = self.view(encode(cols, octaves=self.cfg.octaves))          # W x Float [B]
        lane = dr.arange(B.UInt32, nb * S)
        s_op = dr.opaque(B.UInt32, S)
        i = lane % s_op
        b = lane // s_op
        hid = []
        for c in range(W):
            z = dr.gather(B.Float, a[c], b) + dr.gather(B.Float, self.params["embed"], i * W + c)
            hid.append(dr.maximum(z, 0) + 0.01 * dr.minimum(z, 0))
        uu = np.asarray(u, np.float32).reshape(nb * S, 3)
        hid += [B.Float(np.ascontiguousarray(uu[:, c])) for c in range(3)]
        o = self.head(hid)
        s = self.cfg.modulation
        ar = dr.gather(B.Float, self.params["amp"], 2 * i)
        ai = dr.gather(B.Float, self.params["amp"], 2 * i + 1)
        mr, mi = 1.0 + s * o[0], s * o[1]
        return ar * mr - ai * mi, ar * mi + ai * mr

    def channels(self, x: np.ndarray, y: np.ndarray, q: np.ndarray) -> tuple:
        """Channels at the 16 elements: (re, im) ``Float`` [B*16], differentiable in the parameters.

        Args:
            x: float [B, 3] array centres; y: float [B, 3] transmitters; q: float [B, 3] the
                moving device (x or y), all metres.
        """
        import drjit as dr

        G, u = geometry_factors(self.maps, x, y, frequency_hz=self.frequency_hz)
        nb, M, S = G.shape
        gr, gi = self.gains(q, u)
        lane = dr.arange(B.UInt32, nb * M * S)
        s_op = dr.opaque(B.UInt32, S)
        i = lane % s_op
        b = lane // dr.opaque(B.UInt32, M * S)
        Gr = B.Float(np.ascontiguousarray(G.real.ravel()))
        Gi = B.Float(np.ascontiguousarray(G.imag.ravel()))
        wr = dr.gather(B.Float, gr, b * s_op + i)
        wi = dr.gather(B.Float, gi, b * s_op + i)
        return dr.block_sum(Gr * wr - Gi * wi, S), dr.block_sum(Gr * wi + Gi * wr, S)

    def render(self, x: np.ndarray, y: np.ndarray, q: np.ndarray, *, normalize: bool = True,
               height: int = 90, width: int = 360):
        """PAS of B views: ``TensorXf`` [B, height, width] (min-max normalised by default)."""
        from .bartlett import pas

        hr, hi = self.channels(x, y, q)
        return pas(hr, hi, frequency_hz=self.frequency_hz, height=height, width=width, normalize=normalize)

    # ---- state -----------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """NumPy arrays of everything needed to rebuild the field (``meta`` is a JSON string)."""
        from .config import to_dict

        out = {k: np.asarray(v.numpy() if hasattr(v, "numpy") else v, np.float32)
               for k, v in self.parameters().items()}
        out.update({f"maps.{k}": v for k, v in self.maps.to_arrays().items()})
        out["box"] = self.box
        out["meta"] = np.asarray(json.dumps({"kind": "coherent", "config": to_dict(self.cfg), "seed": self.seed,
                                             "frequency_hz": self.frequency_hz, "frozen": self.frozen}))
        return out

    @classmethod
    def from_state_dict(cls, state: dict) -> "CoherentField":
        from .config import from_dict

        try:
            meta = json.loads(str(state["meta"]))
            maps = ImageMaps.from_arrays({k[5:]: state[k] for k in state if k.startswith("maps.")})
            f = cls(maps, box=state["box"], cfg=from_dict(CoherentConfig, meta["config"]),
                    frequency_hz=meta["frequency_hz"], seed=meta["seed"],
                    params={k: state[k] for k in ("amp", "embed", "net.view", "net.head")})
        except KeyError as e:
            raise RunError(f"coherent field state lacks {e}") from None
        if meta.get("frozen"):
            f.freeze()
        return f

    def save(self, path: str | Path) -> Path:
        from .atomic import write_npz

        return write_npz(Path(path), self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> "CoherentField":
        p = Path(path)
        try:
            with np.load(p, allow_pickle=False) as z:
                state = {k: z[k] for k in z.files}
        except (OSError, ValueError) as e:
            raise RunError(f"{p}: not a readable field file ({e})") from None
        return cls.from_state_dict(state)


def is_finite(x) -> bool:
    return bool(np.isfinite(np.asarray(x)).all()) and not math.isnan(float(np.sum(np.asarray(x))))
