"""Stage 2 in the coherent family: the person as a change of the channel the background
(:class:`~rfmitsuba.models.coherent.CoherentField`) already draws.

Two person fields, chosen by :class:`CoherentPersonConfig` ``kind``:

* "scatter" - :class:`CoherentPersonField`: a few scattering points that move with the person;
  each adds the two-leg paths transmitter -> (image of) the point -> array (via the room's
  planes up to ``scatter_order``), with learned complex gains modulated by a network of the
  person's features.
* "perturb" - :class:`CoherentPerturbField`: the person modulates the background's own image
  paths (blockage and change of each path's gain), from the person's features and where the
  person stands relative to each path's legs (:func:`leg_features`); zero at initialisation,
  so Stage 2 starts from the background.

Both are person fields (``Field.person``): rendered only where a person is present, their
channels added to the background's before one Bartlett read-out.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import backend as B
from ..core.config import from_dict, to_dict
from ..core.encoding import sin_encoding
from ..core.errors import ConfigError
from ..data.samples import num_person_features
from ..rf import array as antenna
from ..rf.images import ImageMaps
from .base import Views, register
from .coherent import (
    CoherentFamily,
    CoherentField,
    _cmul,
    _pair_inputs,
    sum_terms,
)
from ._points import columns32, write_points_ply
from .nn import MLP

PERSON_FORMAT = "rfmitsuba-coherent-person-field/1"


@dataclass
class CoherentPersonConfig:
    """The Stage-2 person scatterers of a coherent model (:class:`CoherentPersonField`).

    num_points: scattering points that move with the person; init_radius / init_height: their
    initial horizontal radius and (lo, hi) height, metres, around the feet position;
    person_octaves: octaves of the person-position features (:func:`rfmitsuba.data.samples.person_features`);
    octaves: octaves of the moving device's position encoding; width / layers: the gain
    network's hidden width and layers; embed: size of each point's learned embedding;
    max_offset: bound of the deformation network's position offset, metres;
    init_amplitude: initial |amplitude| of each (point, path) term, relative to the
    background's direct path; modulation: scale of the gain network's output;
    scatter_order: most wall reflections on the path before and after the person (0 or 1);
    scatter_furniture: also paths that meet a furniture face before or after the person.
    kind: "scatter" (:class:`CoherentPersonField`, scattering points that move with the person)
    or "perturb" (:class:`CoherentPerturbField`, the person changes the background's own paths;
    uses person_octaves, width, layers, embed, modulation; the position encoding is the background's).
    """

    num_points: int = 24
    init_radius: float = 0.2
    init_height: tuple[float, float] = (0.2, 1.6)
    person_octaves: int = 3
    octaves: int = 3
    width: int = 32
    layers: int = 2
    embed: int = 16
    max_offset: float = 0.15
    init_amplitude: float = 0.03
    modulation: float = 0.3
    scatter_order: int = 1
    scatter_furniture: bool = True
    kind: str = "perturb"

    def __post_init__(self) -> None:
        if min(self.num_points, self.width, self.embed) < 1 or min(self.octaves, self.person_octaves, self.layers) < 0:
            raise ConfigError("CoherentPersonConfig: num_points, width, embed >= 1 and octaves, layers >= 0 required")
        if self.kind not in ("scatter", "perturb"):
            raise ConfigError(f"CoherentPersonConfig.kind must be 'scatter' or 'perturb', got {self.kind!r}")
        if self.scatter_order not in (0, 1):
            raise ConfigError(f"CoherentPersonConfig.scatter_order must be 0 or 1, got {self.scatter_order}")
        if self.init_radius < 0 or self.max_offset < 0 or not self.init_amplitude > 0:
            raise ConfigError("CoherentPersonConfig: init_radius, max_offset >= 0 and init_amplitude > 0 required")


def scatter_paths(maps: ImageMaps, order: int, *, furniture: bool = True) -> dict:
    """The path families through a scattering point ``s`` between ``y`` and ``x``.

    "in" families reflect before the person: length ``|s - M_i(y)| + |s - x|``; "out" families
    reflect after it: ``|s - y| + |M_j(s) - x|``, for every map of ``maps`` with at most
    ``order`` reflections (the direct family once; with ``furniture`` False only the room's own
    planes, not furniture faces, whose labels read ``object:plane``). Returns float64 arrays ``pre_A`` [C, 3, 3],
    ``pre_b`` [C, 3] (applied to y) and ``post_A``, ``post_b`` (applied to s).
    """
    keep = np.flatnonzero((maps.order <= order)
                          & np.array([furniture or ":" not in lab for lab in maps.label], bool))
    eye, zero = np.eye(3), np.zeros(3)
    pre_A, pre_b, post_A, post_b = [], [], [], []
    for i in keep:
        pre_A.append(maps.A[i]), pre_b.append(maps.b[i]), post_A.append(eye), post_b.append(zero)
    for i in keep:
        if maps.order[i] == 0:
            continue
        pre_A.append(eye), pre_b.append(zero), post_A.append(maps.A[i]), post_b.append(maps.b[i])
    return {k: np.asarray(v, np.float64) for k, v in
            (("pre_A", pre_A), ("pre_b", pre_b), ("post_A", post_A), ("post_b", post_b))}


@register
class CoherentPersonField(CoherentFamily):
    """Stage 2 of the coherent model: scattering points that move with the person.

    Each of K points sits at ``s = h + o_k + D(h)_k`` (feet position ``h``, learned offset
    ``o_k``, deformation network ``D`` conditioned on the person position, bounded by
    ``max_offset``) and adds, for every path family ``c`` of :func:`scatter_paths`, a term

        g_kc(q, h) * exp(-j k (L1 + L2)) / (L1 L2) * exp(+j k r_m . u)

    (bistatic point scattering: ``L1`` from the transmitter's image to ``s``, ``L2`` from ``s``
    or its image to the array, ``u`` the arrival direction). A term whose point lies on a
    background path has that path's length: with a negative gain it is the person's shadow. The
    complex gain ``g_kc = a_kc (1 + s * head(act(V(enc(q), f(h)) + e_k), u))`` is learned like the
    background's. The channels add to the frozen background's (linear superposition of the
    fields), then one Bartlett readout makes the PAS.

    Args:
        paths: :func:`scatter_paths` arrays; box: float [2, 3] metres (encoding box);
        cfg: :class:`CoherentPersonConfig`; frequency_hz: carrier; reference_amplitude: |amp| of
        the background's direct path (scales the initial amplitudes); seed; name;
        params: stored parameters instead of the initial ones.

    Per-view input ``extra``: float [B, F + 3], the person features (F =
    ``num_person_features(person_octaves)``) followed by the feet position in metres, as
    :meth:`rfmitsuba.data.samples.SampleData.features` with ``raw=True`` gives them.
    """

    def __init__(self, paths: dict, *, box: np.ndarray, cfg: CoherentPersonConfig | None = None,
                 frequency_hz: float = 2.4e9, reference_amplitude: float = 1.0, seed: int = 0,
                 name: str = "person", params: dict | None = None):

        B.ensure()
        self.cfg = cfg or CoherentPersonConfig(kind="scatter")
        self.paths = {k: np.asarray(v, np.float64) for k, v in paths.items()}
        self.frequency_hz = float(frequency_hz)
        self.box = np.asarray(box, np.float64).reshape(2, 3)
        self.reference_amplitude = float(reference_amplitude)
        self.seed, self.name = int(seed), name
        c = self.cfg
        self.num_features = num_person_features(c.person_octaves)
        self.extra_inputs = self.num_features + 3
        n_gain = 3 * (1 + 2 * c.octaves) + self.num_features + c.embed + 3
        self.gain = MLP(n_gain, 2, width=c.width, layers=c.layers, seed=seed + 21, out_bias=[0.0, 0.0])
        self.deform = MLP(self.num_features + c.embed, 3, width=c.width, layers=1, seed=seed + 23,
                          out_bias=[0.0, 0.0, 0.0])
        if params is None:
            rng = np.random.default_rng([seed, 5])
            K, C = c.num_points, self.num_paths
            r = c.init_radius * np.sqrt(rng.uniform(0, 1, K))
            phi = rng.uniform(0, 2 * np.pi, K)
            z = rng.uniform(*c.init_height, K)
            ph = rng.uniform(0, 2 * np.pi, K * C)
            a = c.init_amplitude * self.reference_amplitude
            params = {"offsets": np.stack([r * np.cos(phi), r * np.sin(phi), z], 1).ravel(),
                      "amp": np.stack([a * np.cos(ph), a * np.sin(ph)], 1).ravel(),
                      "embed": 0.1 * rng.standard_normal(K * c.embed)}
        self.params = {}
        self.load_state_dict(params)
        self.frozen = False

    num_paths = property(lambda self: len(self.paths["pre_b"]))
    num_primitives = property(lambda self: self.cfg.num_points)
    network_parameters = property(lambda self: self.cfg.num_points * self.cfg.embed
                                  + sum(m.num_parameters for m in self._modules().values()))
    num_parameters = property(lambda self: self.cfg.num_points * (3 + 2 * self.num_paths) + self.network_parameters)

    def _modules(self) -> dict:
        return {"net.gain": self.gain, "deform.net": self.deform}

    def _sizes(self) -> dict:
        K = self.cfg.num_points
        return {"offsets": 3 * K, "amp": 2 * K * self.num_paths, "embed": K * self.cfg.embed}

    def channels(self, x: np.ndarray, y: np.ndarray, q: np.ndarray, *, extra=None, rx_to_world=None) -> tuple:
        """Channels the person adds at the 16 elements: (re, im) ``Float`` [B*16].

        Args:
            x, y, q: float [B, 3] metres: array centres, transmitters, moving device.
            extra: float [B, F + 3]: person features, then the feet position in metres.
            rx_to_world: must be None or the identity (Stage 2 runs on the project's horizontal array).
        """
        if rx_to_world is not None and not np.allclose(rx_to_world, np.eye(3)):
            raise ConfigError("the coherent person field supports the horizontal array only (rx_to_world = I)")
        import drjit as dr

        x = np.asarray(x, np.float64).reshape(-1, 3)
        y = np.asarray(y, np.float64).reshape(-1, 3)
        nb, K, C, E, F = len(x), self.cfg.num_points, self.num_paths, self.cfg.embed, self.num_features
        if extra is None:
            raise ConfigError("the person field needs the person features and position of every view (extra)")
        e = np.asarray(extra, np.float64).reshape(nb, -1)
        if e.shape[1] != F + 3 or not np.isfinite(e).all():
            raise ConfigError(f"person field extra inputs must be finite [B, {F + 3}], got {e.shape}")
        feats, hpos = e[:, :F], e[:, F:]
        k = 2.0 * np.pi / antenna.wavelength(self.frequency_hz)
        # per (view, point): position s = h + o_k + D(f(h), e_k)
        off = [self.cfg.max_offset * dr.tanh(v) for v in self.deform(_pair_inputs(feats, self.params["embed"], K, E))]
        lane = dr.arange(B.UInt32, nb * K)
        ki, bi = lane % dr.opaque(B.UInt32, K), lane // dr.opaque(B.UInt32, K)
        hp = columns32(hpos)
        s = [dr.gather(B.Float, hp[c], bi) + dr.gather(B.Float, self.params["offsets"], 3 * ki + c) + off[c]
             for c in range(3)]
        # per (view, point, path family) lanes: t = (b*K + k)*C + c
        T = K * C
        lane = dr.arange(B.UInt32, nb * T)
        ci = lane % dr.opaque(B.UInt32, C)
        bk = lane // dr.opaque(B.UInt32, C)
        bi = bk // dr.opaque(B.UInt32, K)
        ki = bk % dr.opaque(B.UInt32, K)
        P = np.einsum("cij,bj->bci", self.paths["pre_A"], y) + self.paths["pre_b"]  # [B, C, 3]
        Pc = columns32(P.reshape(-1, 3))
        Ac = columns32(self.paths["post_A"].reshape(C, 9))
        bc = columns32(self.paths["post_b"])
        xc = columns32(x)
        bcx = bi * dr.opaque(B.UInt32, C) + ci
        st = [dr.gather(B.Float, s[c], bk) for c in range(3)]
        d1 = [st[c] - dr.gather(B.Float, Pc[c], bcx) for c in range(3)]
        sp = [sum(dr.gather(B.Float, Ac[3 * r + j], ci) * st[j] for j in range(3)) + dr.gather(B.Float, bc[r], ci)
              for r in range(3)]
        d2 = [sp[c] - dr.gather(B.Float, xc[c], bi) for c in range(3)]
        L1 = dr.maximum(dr.sqrt(d1[0] ** 2 + d1[1] ** 2 + d1[2] ** 2), 0.05)
        L2 = dr.maximum(dr.sqrt(d2[0] ** 2 + d2[1] ** 2 + d2[2] ** 2), 0.05)
        u = [d / L2 for d in d2]
        q01 = (np.asarray(q, np.float64).reshape(-1, 3) - self.box[0]) / (self.box[1] - self.box[0])
        view = np.concatenate([sin_encoding(q01, self.cfg.octaves), feats], axis=1)
        o = self.gain(_pair_inputs(view, self.params["embed"], K, E, repeat=C) + u)
        ar = dr.gather(B.Float, self.params["amp"], 2 * (ki * C + ci))
        ai = dr.gather(B.Float, self.params["amp"], 2 * (ki * C + ci) + 1)
        sc = self.cfg.modulation
        gr, gi = _cmul(ar, ai, 1.0 + sc * o[0], sc * o[1])
        ph = -k * (L1 + L2)
        inv = 1.0 / (L1 * L2)
        s, c = B.sincos_phase(ph)
        return sum_terms(*_cmul(gr, gi, c * inv, s * inv), u, nb, T, frequency_hz=self.frequency_hz)

    def write_ply(self, path: str | Path, **_) -> Path:
        """The scattering points as small Gaussians in the 3DGS PLY layout, at their learned
        offsets from the person's feet (metres; the deformation is left out), opacity and signal
        from the mean |amplitude| of each point relative to the largest."""
        off = np.asarray(self.params["offsets"].numpy(), np.float64).reshape(-1, 3)
        a = np.asarray(self.params["amp"].numpy(), np.float64).reshape(len(off), -1, 2)
        return write_points_ply(path, off, np.hypot(a[..., 0], a[..., 1]).mean(axis=1))

    kind = "coherent_person"
    format = PERSON_FORMAT
    person = True

    @property
    def feature_octaves(self) -> int:
        return self.cfg.person_octaves

    def export_ply(self, folder: str | Path, *, views: Views) -> list[Path]:
        """``sources.ply`` in ``folder``: the scattering points (:meth:`write_ply`)."""
        return [self.write_ply(Path(folder) / "sources.ply")]

    _geometry_prefix = "paths."

    def _geometry(self) -> dict:
        return self.paths

    def _meta(self) -> dict:

        return {"format": PERSON_FORMAT, "config": to_dict(self.cfg), "reference_amplitude": self.reference_amplitude}

    @classmethod
    def _from_state(cls, geometry: dict, state: dict, meta: dict) -> "CoherentPersonField":

        return cls(geometry, box=state["box"], cfg=from_dict(CoherentPersonConfig, meta["config"], saved=True),
                   frequency_hz=meta["frequency_hz"], reference_amplitude=meta["reference_amplitude"],
                   seed=meta["seed"], name=meta.get("name", "person"), params=state)

    @classmethod
    def for_background(cls, bg: CoherentField, *, cfg: CoherentPersonConfig | None = None, seed: int = 0,
                       name: str = "person", walk: np.ndarray | None = None,
                       rng: np.random.Generator | None = None) -> "CoherentPersonField":
        """A fresh person field on a trained background: its image maps, box and frequency, and
        initial amplitudes relative to its direct path (``walk`` and ``rng`` are not needed)."""
        cfg = cfg or CoherentPersonConfig(kind="scatter")
        a = np.asarray(bg.params["amp"].numpy(), np.float64).reshape(-1, 2)
        direct = int(np.flatnonzero(bg.maps.order == 0)[0]) if (bg.maps.order == 0).any() else int(np.argmax(
            np.hypot(a[:, 0], a[:, 1])))
        ref = float(np.hypot(*a[direct]))
        return cls(scatter_paths(bg.maps, cfg.scatter_order, furniture=cfg.scatter_furniture), box=bg.box, cfg=cfg, frequency_hz=bg.frequency_hz,
                   reference_amplitude=max(ref, 1e-12), seed=seed, name=name)


def leg_features(maps: ImageMaps, x: np.ndarray, y: np.ndarray, person: np.ndarray) -> np.ndarray:
    """Where a standing person is relative to each image path's first and last leg.

    For the last leg (a ray from the array centre ``x`` towards the image ``M_i(y)``) and the first
    leg (a ray from the transmitter ``y`` towards ``M_i^-1(x)``), both as long as the path: the
    horizontal distance of the person's vertical axis from the ray, and the height of the ray
    where it passes closest (metres). A leg that passes within a body radius, below head
    height, is shadowed.

    Args:
        maps: S image maps; x, y, person: float [B, 3] metres (person = feet position).
    Returns:
        float32 [B*S, 4]: (distance last, height last, distance first, height first), view-major.
    """
    x, y, h = (np.asarray(a, np.float64).reshape(-1, 3) for a in (x, y, person))
    img = maps.apply(y)                                                       # [B, S, 3]
    back = np.einsum("sji,bsj->bsi", maps.A, x[:, None, :] - maps.b)          # M^-1(x) = A^T (x - b)
    out = []
    for p, target in ((x, img), (y, back)):
        d = target - p[:, None, :]
        L = np.maximum(np.linalg.norm(d, axis=-1), 1e-9)
        d = d / L[..., None]
        dxy = d[..., :2]
        w = h[:, None, :2] - p[:, None, :2]
        t = np.clip(np.sum(w * dxy, -1) / np.maximum(np.sum(dxy * dxy, -1), 1e-9), 0.0, L)
        rho = np.linalg.norm(w - t[..., None] * dxy, axis=-1)
        z = p[:, None, 2] + t * d[..., 2] - h[:, None, 2]
        out += [rho, z]
    return np.stack(out, -1).reshape(-1, 4).astype(np.float32)


@register
class CoherentPerturbField(CoherentFamily):
    """Stage 2 of the coherent model as a perturbation of the background's own paths.

    The person mostly shadows paths (and bends them a little). This field adds, for every image
    path ``i`` of the frozen background ``bg``,

        h_person = sum_i g_i^bg(q) * m_i(q, h) * exp(-j k L_i) / L_i * exp(+j k r_m . u_i),

    a complex modulation ``m_i = s * net(enc(q), f(h), e_i, u_i, legs_i)`` of that path (so the
    total is ``g_i^bg (1 + m_i)``: ``m_i = -1`` blocks it). ``legs_i`` are the
    :func:`leg_features` (how close the person stands to the path's first and last leg). The
    network's last layer starts at zero, so Stage 2 starts from the background exactly. Channels
    add to the background's (linear superposition); the background stays frozen, and its state is
    stored with this field (``bg.*``) so the file is self-contained.

    Per-view input ``extra``: float [B, F + 3] (person features, then the feet position in metres).
    """

    kind = "coherent_perturb"
    format = "rfmitsuba-coherent-perturb-field/1"
    person = True

    @property
    def feature_octaves(self) -> int:
        return self.cfg.person_octaves

    def export_ply(self, folder: str | Path, *, views: Views) -> list[Path]:
        """Nothing: this field has no points of its own."""
        return []
    _geometry_prefix = "bg."

    def __init__(self, bg: CoherentField, *, cfg: CoherentPersonConfig | None = None, seed: int = 0,
                 name: str = "person", params: dict | None = None):

        self.bg = bg
        self.cfg = cfg or CoherentPersonConfig()
        self.box, self.frequency_hz = bg.box, bg.frequency_hz
        self.seed, self.name = int(seed), name
        c = self.cfg
        self.num_features = num_person_features(c.person_octaves)
        self.extra_inputs = self.num_features + 3
        n_in = 3 * (1 + 2 * bg.cfg.octaves) + self.num_features + c.embed + 3 + 4
        self.net = MLP(n_in, 2, width=c.width, layers=c.layers, seed=seed + 31, out_bias=[0.0, 0.0], zero_output=True)
        if params is None:
            params = {"embed": 0.1 * np.random.default_rng([seed, 6]).standard_normal(bg.num_sources * c.embed)}
        self.params = {}
        self.load_state_dict(params)
        self.frozen = False

    num_primitives = property(lambda self: 0)
    network_parameters = property(lambda self: self.bg.num_sources * self.cfg.embed + self.net.num_parameters)
    num_parameters = network_parameters

    @classmethod
    def for_background(cls, bg: CoherentField, *, cfg: CoherentPersonConfig | None = None, seed: int = 0,
                       name: str = "person", walk: np.ndarray | None = None,
                       rng: np.random.Generator | None = None) -> "CoherentPerturbField":
        """A fresh (zero) perturbation of a trained background's paths (``walk`` and ``rng`` are
        not needed)."""
        return cls(bg, cfg=cfg, seed=seed, name=name)

    def _modules(self) -> dict:
        return {"net.perturb": self.net}

    def _sizes(self) -> dict:
        return {"embed": self.bg.num_sources * self.cfg.embed}

    def channels(self, x: np.ndarray, y: np.ndarray, q: np.ndarray, *, extra=None, rx_to_world=None) -> tuple:
        """Channels the person adds at the 16 elements: (re, im) ``Float`` [B*16] (see the class)."""
        import drjit as dr

        x = np.asarray(x, np.float64).reshape(-1, 3)
        y = np.asarray(y, np.float64).reshape(-1, 3)
        nb, S, F = len(x), self.bg.num_sources, self.num_features
        if extra is None:
            raise ConfigError("the person field needs the person features and position of every view (extra)")
        e = np.asarray(extra, np.float64).reshape(nb, -1)
        if e.shape[1] != F + 3 or not np.isfinite(e).all():
            raise ConfigError(f"person field extra inputs must be finite [B, {F + 3}], got {e.shape}")
        gr, gi, pr, pi, u = self.bg._terms(x, y, q, rx_to_world=rx_to_world)
        gr, gi = dr.detach(gr), dr.detach(gi)
        view = np.concatenate([self.bg._enc(q), e[:, :F]], axis=1)
        legs = leg_features(self.bg.maps, x, y, e[:, F:]) * np.array([1.0, 0.5, 1.0, 0.5], np.float32)
        o = self.net(_pair_inputs(view, self.params["embed"], S, self.cfg.embed) + u + columns32(legs))
        sc = self.cfg.modulation
        wr, wi = _cmul(gr, gi, sc * o[0], sc * o[1])
        return sum_terms(*_cmul(wr, wi, pr, pi), u, nb, S, frequency_hz=self.frequency_hz)

    def _geometry(self) -> dict:
        return self.bg.state_dict()

    def _meta(self) -> dict:

        return {"format": self.format, "config": to_dict(self.cfg)}

    @classmethod
    def _from_state(cls, geometry: dict, state: dict, meta: dict) -> "CoherentPerturbField":

        bg = CoherentField.from_state_dict(geometry)
        bg.freeze()
        return cls(bg, cfg=from_dict(CoherentPersonConfig, meta["config"], saved=True), seed=meta["seed"],
                   name=meta.get("name", "person"), params=state)
