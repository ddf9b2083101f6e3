"""Coherent image-source field: the channel as a sum of virtual sources, read out by Bartlett.

Why: a simulated (or measured) PAS is the Bartlett response of the array to the *coherent*
sum of all paths, ``P = |sum_m w_m h_m|``. Paths that arrive together interfere and draw
the dark arcs of the PAS; a sum of splats, which adds intensities, cannot draw them, and the
interference pattern changes every few centimetres, faster than any smooth interpolator of
the PAS can follow (see docs/lab-notes/paper-tables.md, "Stage 1"). This field models what the array actually sees:

    h_m(x, y) = sum_i  g_i(x, y) * exp(-j k L_i) / L_i * exp(+j k r_m . u_i),
    L_i = |M_i(y) - x|,  u_i = (M_i(y) - x) / L_i,

with the array centre ``x``, the transmitter ``y``, the image maps ``M_i`` of the room's
planes (:mod:`rfmitsuba.rf.images`; ``M_0`` = identity is the direct path), the element offsets
``r_m`` and ``k = 2 pi / lambda``. Propagation phase and direction are exact geometry; what
is learned is each image's complex gain

    g_i(x, y) = a_i * (1 + s * net(enc(q), e_i, u_i)),

a constant complex amplitude ``a_i`` (reflection coefficients, 1/(4 pi) factors) times a
position-dependent modulation from a small Dr.Jit network: ``q`` is the moving device's
position (``x`` in the moving-RX task, ``y`` in the moving-TX task), ``e_i`` a learned
per-image embedding. The modulation learns where an image is visible (finite faces,
furniture in the way), the angle dependence of reflection, and what the geometry misses.
The PAS comes from :func:`rfmitsuba.rf.bartlett.bartlett`, differentiable end to end.

Both tasks use the same formula: moving RX (``x`` moves, ``y`` = the fixed
corner transmitter) and moving TX (``y`` moves, ``x`` = the fixed array), by the
synthetic-array rule of :mod:`rfmitsuba.sim.simulate` (plane-wave phase per element, about the
array centre).

Parameters (Dr.Jit ``Float`` arrays, :meth:`CoherentField.parameters`): ``amp`` [S*2]
(re, im per image), ``embed`` [S*E] and ``net.gain`` (packed MLP weights).
State is plain NumPy (npz, no pickle).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import backend as B
from ..core.config import from_dict, to_dict
from ..core.encoding import sin_encoding
from ..core.errors import ConfigError, RunError
from ..core.legacy_names import current_name
from ..rf import array as antenna
from ..rf.bartlett import bartlett
from ..rf.images import ImageMaps, scene_image_maps
from .base import Field, Views, flat_parameters, register
from .nn import MLP
from ._points import columns32, write_points_ply


@dataclass
class CoherentConfig:
    """Architecture of a :class:`CoherentField`.

    room_order: reflections on the room's planes alone (image maps up to this order).
    furniture_order: 0, 1 or 2 (one furniture reflection, alone or with one room reflection).
    min_face_area: furniture faces smaller than this (m^2) make no image.
    width / layers: hidden width and hidden layers of the gain network; embed: size of each
    image's learned embedding; octaves: sine octaves of the position encoding.
    modulation: scale ``s`` of the network's output (its initial size relative to ``a_i``).
    init_reflection: initial amplitude of an image is ``init_reflection ** order``.
    """

    room_order: int = 3
    furniture_order: int = 2
    min_face_area: float = 0.05
    width: int = 32
    layers: int = 2
    embed: int = 16
    octaves: int = 4
    modulation: float = 0.3
    init_reflection: float = 0.5

    def __post_init__(self) -> None:
        if self.room_order < 0 or self.furniture_order not in (0, 1, 2):
            raise ConfigError(f"CoherentConfig: room_order must be >= 0 and furniture_order 0, 1 or 2, got "
                              f"{self.room_order}, {self.furniture_order}")
        if self.width < 1 or self.embed < 1 or self.layers < 0 or self.octaves < 0 or self.min_face_area < 0:
            raise ConfigError("CoherentConfig: width, embed >= 1, layers, octaves, min_face_area >= 0 required")
        if not (0 < self.init_reflection <= 1) or not (self.modulation > 0):
            raise ConfigError("CoherentConfig: init_reflection in (0, 1] and modulation > 0 required")


FORMAT = "rfmitsuba-coherent-field/1"


def _pair_inputs(view: np.ndarray, embed, n: int, e: int, *, repeat: int = 1) -> list:
    """Network inputs of every (view b, item i[, family c]) lane, view-major
    ``(b*n + i)*repeat + c``: the view's inputs (host data float [nb, D], no gradient) followed by
    the item's learned embedding (``Float`` [n*e], differentiable): D + e ``Float`` arrays.

    The networks run on these lanes directly. (Evaluating a network once per view and gathering
    its outputs made Dr.Jit 1.5 return wrong gradients for that network's weights once the
    loss gradient reached it through a scatter.)"""
    import drjit as dr

    view = np.asarray(view, np.float32)
    per_pair = n * repeat
    lane = dr.arange(B.UInt32, len(view) * per_pair)
    b = lane // per_pair                  # literal divisors: multiplications, not vector divisions
    i = (lane // repeat) % n
    cols = [dr.gather(B.Float, c, b) for c in columns32(view)] if view.shape[1] else []
    return cols + [dr.gather(B.Float, embed, i * e + c) for c in range(e)]


def _extra_array(extra, nb: int, n: int) -> np.ndarray:
    """The first ``n`` columns of the per-view extra inputs (float [nb, >= n]): float32 [nb, n]."""
    if n == 0:
        return np.zeros((nb, 0), np.float32)
    if extra is None:
        raise ConfigError(f"this field needs {n} extra inputs per view (person-position features), got none")
    e = np.asarray(extra, np.float32).reshape(nb, -1)
    if e.shape[1] < n or not np.isfinite(e[:, :n]).all():
        raise ConfigError(f"extra inputs must be finite [B, >= {n}], got shape {e.shape}")
    return e[:, :n]


def _cmul(ar, ai, br, bi) -> tuple:
    """Complex product ``(ar + j ai)(br + j bi)`` of real/imaginary parts: (re, im)."""
    return ar * br - ai * bi, ar * bi + ai * br


def sum_terms(wr, wi, ur: list, nb: int, t: int, *, frequency_hz: float) -> tuple:
    """Channel at the 16 elements from T plane-wave terms per view.

    ``h_{b,m} = sum_t w_{b,t} exp(+j k r_m . u_{b,t})``

    Args:
        wr, wi: ``Float`` [nb*t], complex term weights (view-major); ur: 3 ``Float`` [nb*t], unit
            arrival directions (world frame = array frame).
    Returns:
        (re, im) ``Float`` [nb*16].
    """
    import drjit as dr

    M = 16
    k = 2.0 * np.pi / antenna.wavelength(frequency_hz)
    e = antenna.element_positions(frequency_hz)
    lane = dr.arange(B.UInt32, nb * M * t)
    ti = lane % t                         # t a literal: the divisions compile to multiplications
    bm = lane // t
    m = bm % M
    b = bm // M
    src = b * t + ti
    ex, ey, ez = (dr.gather(B.Float, c, m) for c in columns32(e))
    ph = k * (ex * dr.gather(B.Float, ur[0], src) + ey * dr.gather(B.Float, ur[1], src)
              + ez * dr.gather(B.Float, ur[2], src))
    c, s = dr.cos(ph), dr.sin(ph)
    a, bb = dr.gather(B.Float, wr, src), dr.gather(B.Float, wi, src)
    vr, vi = a * c - bb * s, a * s + bb * c
    dr.eval(vr, vi)                       # both parts in one kernel
    return dr.block_sum(vr, t), dr.block_sum(vi, t)


class CoherentFamily(Field):
    """What every coherent field shares: named parameters (plain ``Float`` arrays in
    :attr:`params` plus the packed networks of :meth:`_modules`), freezing, and an npz state of
    the parameters, the geometry arrays (``_geometry_prefix`` + name) and a JSON ``meta``.

    Subclasses define ``_modules``, ``_sizes``, ``_meta``, ``_geometry``, ``_from_state``,
    ``kind``, ``format`` and ``_geometry_prefix``.

    Coherent fields render together by adding their channels before one Bartlett read-out
    (:meth:`render_family`).
    """

    def parameters(self) -> dict:
        """Name -> Dr.Jit ``Float`` of every parameter."""
        return {**self.params, **{k: m.weights for k, m in self._modules().items()}}

    def assign(self, values: dict) -> None:
        """Set parameters from ``values`` (name -> ``Float``), e.g. the optimizer's copies."""
        mods = self._modules()
        for k, v in values.items():
            if k in mods:
                mods[k].set_weights(v)
            elif k in self.params:
                self.params[k] = v
            else:
                raise ConfigError(f"{type(self).__name__} has no parameter {k!r}")

    family = "coherent"

    def freeze(self) -> None:
        """Exclude every parameter from training (values detached)."""
        import drjit as dr

        self.frozen = True
        for k in list(self.params):
            self.params[k] = dr.detach(self.params[k])
        for m in self._modules().values():
            m.set_weights(dr.detach(m.weights))

    def load_state_dict(self, state: dict) -> None:
        """Load parameter arrays (as written by :meth:`state_dict`); RunError on a size mismatch."""
        self.params.update(flat_parameters(state, self._sizes(), owner=type(self).__name__))
        for k, m in self._modules().items():
            if k in state:
                w = np.asarray(state[k], np.float32).ravel()
                if w.shape != (m.buffer_size,):
                    raise RunError(f"{type(self).__name__} state {k!r}: expected {m.buffer_size} weights, "
                                   f"got {w.shape[0]}")
                m.set_weights(w)

    def state_dict(self) -> dict:
        """NumPy arrays of everything needed to rebuild the field (``meta`` is a JSON string)."""
        out = {k: np.array(v.numpy(), np.float32, copy=True) for k, v in self.parameters().items()}
        out.update({f"{self._geometry_prefix}{k}": v for k, v in self._geometry().items()})
        out["box"] = self.box.copy()
        out["meta"] = np.asarray(json.dumps({**self._meta(), "seed": self.seed, "name": self.name,
                                             "frequency_hz": self.frequency_hz, "frozen": self.frozen}))
        return out

    @classmethod
    def from_state_dict(cls, state: dict):
        """Rebuild a field written by :meth:`state_dict` (RunError naming what is missing or wrong)."""
        try:
            meta = json.loads(str(state["meta"]))
            if current_name(meta.get("format")) != cls.format:
                raise RunError(f"not a {cls.__name__} state (format {meta.get('format')!r})")
            n = len(cls._geometry_prefix)
            f = cls._from_state({k[n:]: state[k] for k in state if k.startswith(cls._geometry_prefix)}, state, meta)
        except KeyError as e:
            raise RunError(f"{cls.__name__} state lacks {e}") from None
        if meta.get("frozen"):
            f.freeze()
        return f

    @classmethod
    def render_family(cls, fields: list, views: Views, *, height: int, width: int, normalize: bool):
        """PAS of coherent fields together: their channels add (linear superposition), then one
        Bartlett read-out (:func:`rfmitsuba.rf.bartlett.bartlett`).

        Returns:
            ``TensorXf`` [B, height, width], min-max normalised per image when ``normalize``.
        """

        hr = hi = None
        for f in fields:
            fr, fi = f.channels(views.view_pos, views.transmitter, views.antenna_pos, extra=views.extra(f),
                                rx_to_world=views.rx_to_world)
            hr, hi = (fr, fi) if hr is None else (hr + fr, hi + fi)
        return bartlett(hr, hi, frequency_hz=views.frequency_hz, height=height, width=width, normalize=normalize)


@register
class CoherentField(CoherentFamily):
    """Image sources with learned complex gains: the static (background) field. See the module
    docstring.

    Args:
        maps: the image maps (:func:`rfmitsuba.rf.images.scene_image_maps`).
        box: float [2, 3] metres, box that maps moving positions into [0, 1] for the encoding.
        cfg: :class:`CoherentConfig`.
        frequency_hz: carrier, Hz.
        seed: weight initialisation; name: the optimizer key prefix of this field.
        params: stored parameters (name -> float32 array) instead of the initial ones.
    """

    def __init__(self, maps: ImageMaps, *, box: np.ndarray, cfg: CoherentConfig | None = None,
                 frequency_hz: float = 2.4e9, seed: int = 0, name: str = "bg", params: dict | None = None,
                 extra_inputs: int = 0):

        B.ensure()
        self.maps = maps
        self.cfg = cfg or CoherentConfig()
        self.frequency_hz = float(frequency_hz)
        antenna.wavelength(self.frequency_hz)
        self.box = np.asarray(box, np.float64).reshape(2, 3)
        if not np.all(self.box[1] > self.box[0]):
            raise ConfigError(f"CoherentField: box must have hi > lo, got {self.box.tolist()}")
        self.seed, self.name = int(seed), name
        self.extra_inputs = int(extra_inputs)
        c = self.cfg
        n_in = 3 * (1 + 2 * c.octaves) + self.extra_inputs + c.embed + 3
        self.gain = MLP(n_in, 2, width=c.width, layers=c.layers, seed=seed + 11, out_bias=[0.0, 0.0])
        if params is None:
            a = c.init_reflection ** maps.order.astype(np.float64)
            params = {"amp": np.stack([a, np.zeros_like(a)], 1).ravel(),
                      "embed": 0.1 * np.random.default_rng(seed).standard_normal(len(maps) * c.embed)}
        self.params = {}
        self.load_state_dict(params)
        self.frozen = False
        #: the image maps as 12 device columns (row r of A_i, then b_i[r], for r = 0, 1, 2), uploaded once
        self._maps_cols = columns32(np.concatenate([maps.A, maps.b[:, :, None]], axis=2).reshape(-1, 12))

    @classmethod
    def for_training(cls, cfg, data, *, scene_xml: Path | None, rng: np.random.Generator | None = None,
                     extra_inputs: int = 0, name: str = "bg") -> "CoherentField":
        """The Stage-1 initial field of a training configuration: the image sources of the
        room's planes (``cfg.coherent``: orders, smallest face), gains at their initial values.

        Args:
            cfg: the :class:`~rfmitsuba.train.config.TrainConfig` (``coherent``, ``seed``).
            data: the :class:`~rfmitsuba.data.views.TrainData` (its path and carrier).
            scene_xml: the room's XML (ConfigError when None: this model needs the room).
            rng: unused (the initialisation is deterministic in ``cfg.seed``); extra_inputs, name:
                as :class:`CoherentField`.
        """
        from ..sim.geometry import RoomGeometry

        if scene_xml is None:
            raise ConfigError(f"model = 'coherent' needs the scene geometry, but dataset {data.path} names no "
                              "scene (NeRF2 folders): give one with --set scene=NAME_OR_XML, or use model = 'splat'")
        c = cfg.coherent
        geo = RoomGeometry.from_xml(scene_xml)
        maps = scene_image_maps(geo, room_order=c.room_order, furniture_order=c.furniture_order,
                                min_face_area=c.min_face_area)
        lo, hi = geo.bounds
        return cls(maps, box=np.stack([lo, hi]), cfg=c, frequency_hz=data.frequency_hz,
                   seed=cfg.seed, name=name, extra_inputs=extra_inputs)

    # ---- parameters ------------------------------------------------------------------------
    @property
    def num_sources(self) -> int:
        return len(self.maps)

    #: the image sources are this field's primitives
    num_primitives = num_sources

    @property
    def network_parameters(self) -> int:
        return self.num_sources * self.cfg.embed + self.gain.num_parameters

    @property
    def num_parameters(self) -> int:
        return 2 * self.num_sources + self.network_parameters

    def _modules(self) -> dict:
        return {"net.gain": self.gain}

    def _sizes(self) -> dict:
        return {"amp": 2 * self.num_sources, "embed": self.num_sources * self.cfg.embed}

    # ---- evaluation ------------------------------------------------------------------------
    def _enc(self, q: np.ndarray) -> np.ndarray:
        """Encoding of the moving device's positions (float [B, 3] metres): float32 [B, D]."""
        q01 = (np.asarray(q, np.float64).reshape(-1, 3) - self.box[0]) / (self.box[1] - self.box[0])
        return sin_encoding(q01, self.cfg.octaves)

    def channels(self, x: np.ndarray, y: np.ndarray, q: np.ndarray, *, extra=None, rx_to_world=None) -> tuple:
        """Channels at the 16 elements: (re, im) ``Float`` [B*16], differentiable in the parameters.

        Args:
            x: float [B, 3] array centres; y: float [B, 3] transmitters; q: float [B, 3] the
                moving device (x or y); all metres.
            extra: float [B, extra_inputs] more inputs of the gain network (the End-to-End
                model's person-position features), or None for a field without them.
            rx_to_world: float [3, 3], the array frame's axes in the world (a NeRF2 gateway's
                orientation), or None for the project's horizontal array (identity).
        """
        gr, gi, pr, pi, u = self._terms(x, y, q, extra=extra, rx_to_world=rx_to_world)
        return sum_terms(*_cmul(gr, gi, pr, pi), u, np.shape(q)[0], self.num_sources, frequency_hz=self.frequency_hz)

    def _terms(self, x: np.ndarray, y: np.ndarray, q: np.ndarray, *, extra=None, rx_to_world=None) -> tuple:
        """Per (view, image) lane ``b*S + i``, each a ``Float`` [B*S]: the complex gain (gr, gi),
        the propagation factor exp(-jkL)/L (pr, pi) and the 3 components of the arrival direction
        in the array frame. Arguments as :meth:`channels`.

        Raises:
            ConfigError: positions of different shapes, or not finite.
        """
        import drjit as dr

        x = np.asarray(x, np.float64).reshape(-1, 3)
        y = np.asarray(y, np.float64).reshape(-1, 3)
        if x.shape != y.shape or np.shape(q) != x.shape:
            raise ConfigError(f"array, transmitter and moving positions must have one shape [B, 3], got {x.shape}, "
                              f"{y.shape}, {np.shape(q)}")
        if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(q).all()):
            raise ConfigError("positions must be finite (a NaN or inf position was given)")
        nb, S = len(x), self.num_sources
        k = 2.0 * np.pi / antenna.wavelength(self.frequency_hz)
        # geometry per (view, image) lane b*S + i in Dr.Jit: image point s = A_i y + b_i, path
        # d = s - x, length L [m], arrival direction u (array frame), propagation exp(-jkL)/L
        lane = dr.arange(B.UInt32, nb * S)
        i = lane % S                                        # S a literal: no vector division
        b = lane // S
        xb = [dr.gather(B.Float, c, b) for c in columns32(x)]
        yb = [dr.gather(B.Float, c, b) for c in columns32(y)]
        A = [dr.gather(B.Float, c, i) for c in self._maps_cols]
        d = [A[4 * r] * yb[0] + A[4 * r + 1] * yb[1] + A[4 * r + 2] * yb[2] + A[4 * r + 3] - xb[r] for r in range(3)]
        L = dr.maximum(dr.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), 1e-3)
        u = [d[r] / L for r in range(3)]
        if rx_to_world is not None:  # arrival directions in the array frame: R^T u
            R = np.asarray(rx_to_world, np.float64).reshape(3, 3)
            u = [sum(float(R[r, j]) * u[r] for r in range(3)) for j in range(3)]
        s, c = B.sincos_phase(k * L)
        pr, pi = c / L, -s / L
        view = np.concatenate([self._enc(q), _extra_array(extra, nb, self.extra_inputs)], axis=1)
        o = self.gain(_pair_inputs(view, self.params["embed"], S, self.cfg.embed) + u)
        ar = dr.gather(B.Float, self.params["amp"], 2 * i)
        ai = dr.gather(B.Float, self.params["amp"], 2 * i + 1)
        sc = self.cfg.modulation
        gr, gi = _cmul(ar, ai, 1.0 + sc * o[0], sc * o[1])
        return gr, gi, pr, pi, u

    def render(self, x: np.ndarray, y: np.ndarray, q: np.ndarray, *, normalize: bool = True,
               height: int = 90, width: int = 360):
        """PAS of B views of this field alone (x, y, q: float [B, 3] metres, as :meth:`channels`;
        horizontal array): ``TensorXf`` [B, height, width] (min-max normalised by default)."""
        views = Views(antenna_pos=q, view_pos=x, transmitter=y, rx_to_world=None, frequency_hz=self.frequency_hz)
        return self.render_family([self], views, height=height, width=width, normalize=normalize)

    # ---- export and state ------------------------------------------------------------------
    def source_points(self, *, x: np.ndarray, y: np.ndarray, task: str) -> np.ndarray:
        """Where the sources are, float64 [S, 3] metres: the images of the transmitter ``y``
        (task "rx"), or, by reciprocity, the images of the fixed array ``x`` (task "tx")."""
        if task == "rx":
            return self.maps.apply(np.asarray(y, np.float64))
        Ainv = np.transpose(self.maps.A, (0, 2, 1))
        return np.einsum("sij,sj->si", Ainv, np.asarray(x, np.float64)[None] - self.maps.b)

    def export_ply(self, folder: str | Path, *, views: Views) -> list[Path]:
        """``sources.ply`` in ``folder``: the sources (:meth:`write_ply`) seen from the first view."""
        return [self.write_ply(Path(folder) / "sources.ply", x=views.view_pos[0], y=views.transmitter[0],
                               task=views.task)]

    def write_ply(self, path: str | Path, *, x: np.ndarray, y: np.ndarray, task: str) -> Path:
        """The sources as small isotropic Gaussians in the 3DGS PLY layout (opacity = |amp| relative
        to the largest, signal = the same), so a splat viewer shows the virtual sources."""
        a = np.asarray(self.params["amp"].numpy(), np.float64).reshape(-1, 2)
        return write_points_ply(path, self.source_points(x=x, y=y, task=task), np.hypot(a[:, 0], a[:, 1]))

    kind = "coherent"
    format = FORMAT
    _geometry_prefix = "maps."

    def _geometry(self) -> dict:
        return self.maps.to_arrays()

    def _meta(self) -> dict:

        return {"format": FORMAT, "config": to_dict(self.cfg), "extra_inputs": self.extra_inputs}

    @classmethod
    def _from_state(cls, geometry: dict, state: dict, meta: dict) -> "CoherentField":

        return cls(ImageMaps.from_arrays(geometry), box=state["box"], cfg=from_dict(CoherentConfig, meta["config"], saved=True),
                   frequency_hz=meta["frequency_hz"], seed=meta["seed"], name=meta.get("name", "bg"), params=state,
                   extra_inputs=meta.get("extra_inputs", 0))
