"""A set of 3-D Gaussians with an EM-feature network: the radio field model.

A :class:`SplatField` owns

* per-Gaussian parameters (flat ``Float`` arrays, row-major per Gaussian):
  ``means`` [N*3] metres (world frame), ``log_scales`` [N*3] natural log of metres,
  ``rotations`` [N*4] quaternion (w, x, y, z; normalised before rendering),
  ``opacity_logits`` [N] (the view-independent part of the attenuation delta);
* an :class:`~rfmitsuba.models.nn.EMNetwork` whose weights are parameters ``net.<module>``;
* a fixed normalisation box (``box`` [2, 3], metres) mapping world positions into [0, 1]
  for the encodings.

:meth:`SplatField.splats` evaluates the network for a batch of B views and returns
a :class:`Splats` bundle in the argument layout of :func:`rfmitsuba.splat.render`:
geometry of size N (shared by all views) and signal/opacity of size B*N (per view,
view-major index ``b*N + i``). :meth:`Splats.concat` joins several sets (e.g. a frozen
background and a trainable person set of Stage 2) into one render call.

State is plain numpy (``state_dict`` / ``load_state_dict`` / ``save`` / ``load``, npz without
pickle); :meth:`freeze` excludes every parameter from training.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import Literal

import numpy as np

from ..core import backend as B
from ..core.config import from_dict, to_dict
from ..core.errors import ConfigError, RunError, SceneError
from ..core.upload import upload, upload_columns
from ..data.scene_xml import read_shapes
from ..rf.readout import BartlettReadout
from ..splat import render
from ..splat.per_view import per_view
from .base import Field, Views, register
from .nn import EMNetwork, NetConfig

#: Per-Gaussian parameters and their number of components.
GAUSSIAN_KEYS = {"means": 3, "log_scales": 3, "rotations": 4, "opacity_logits": 1}


@dataclass
class SplatConfig:
    """How a Gaussian field is initialised and parameterised.

    init: "mesh" (points sampled on the scene's meshes, area-weighted) or "random"
        (uniform in the scene box).
    num_gaussians: number of Gaussians at initialisation.
    init_opacity: initial attenuation delta of every Gaussian, in (0, 1).
    init_scale: initial isotropic scale in metres (radians with scale_mode "angular"); 0 = mean
        distance to the 3 nearest initial neighbours (3DGS rule), clipped to [min_scale,
        max_init_scale] (0.15 rad with scale_mode "angular").
    source_points: how many of the num_gaussians are placed within 0.1 m of the fixed
        transmitter (moving-RX task only; the direct path starts there).
    box_margin: margin (metres) added around the scene bounds for the normalisation box.
    scale_mode: "metric" (log_scales are log metres, as 3DGS) or "angular" (log_scales are the log
        of the angular size in radians: each view's metric scale is that times the Gaussian's
        distance from the array, so a Gaussian keeps its angular width - the beam width of the
        array - from every viewpoint).
    scale_net: let the network add a per-view isotropic log-scale offset (bounded by +-1).
    readout: "direct" (the splatted image is the PAS, as WRF-GS) or "bartlett" (the splatted image,
        rendered on ``arrival_grid`` (rows, columns), is the arrival spectrum and the PAS is the
        array's Bartlett response to it; see :mod:`rfmitsuba.rf.readout`).
    net: EM-feature network architecture.
    """

    init: Literal["mesh", "random"] = "mesh"
    num_gaussians: int = 3000
    init_opacity: float = 0.1
    init_scale: float = 0.0
    min_scale: float = 0.005
    max_init_scale: float = 0.3
    source_points: int = 16
    box_margin: float = 0.3
    scale_mode: Literal["metric", "angular"] = "metric"
    scale_net: bool = False
    readout: Literal["direct", "bartlett"] = "direct"
    arrival_grid: tuple[int, int] = (30, 120)
    net: NetConfig = dc_field(default_factory=NetConfig)

    def __post_init__(self) -> None:
        if self.num_gaussians < 1:
            raise ConfigError(f"SplatConfig.num_gaussians must be >= 1, got {self.num_gaussians}")
        if not 0.0 < self.init_opacity < 1.0:
            raise ConfigError(f"SplatConfig.init_opacity must be in (0, 1), got {self.init_opacity}")
        if self.init_scale < 0 or self.min_scale <= 0:
            raise ConfigError("SplatConfig: init_scale must be >= 0 and min_scale > 0")


# --------------------------------------------------------------------------- geometry input

def scene_meshes(xml_path: str | Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """Triangle meshes of a Mitsuba scene XML, in world coordinates.

    Args:
        xml_path: path of the scene XML; read by :func:`rfmitsuba.data.scene_xml.read_shapes`
            (ply/obj shapes, ``to_world`` transforms, ``$name`` defaults).

    Returns:
        list of (vertices float64 [V, 3] metres, faces int64 [F, 3]).

    Raises:
        SceneError: missing file, malformed XML, missing mesh file, or no mesh.
    """

    meshes = [(np.asarray(s.mesh.vertices, dtype=np.float64), np.asarray(s.mesh.faces, dtype=np.int64))
              for s in read_shapes(xml_path)]
    if not meshes:
        raise SceneError(f"{xml_path}: no mesh shapes found")
    return meshes


def sample_surface(meshes: list[tuple[np.ndarray, np.ndarray]], n: int, *,
                   rng: np.random.Generator) -> np.ndarray:
    """Area-weighted uniform samples on triangle meshes.

    Args:
        meshes: list of (vertices [V, 3], faces [F, 3]).
        n: number of points.
        rng: numpy generator (the only source of randomness).

    Returns:
        float64 [n, 3] points, metres.
    """
    tris = np.concatenate([v[f] for v, f in meshes], axis=0)  # [T, 3, 3]
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    if not np.isfinite(area).all() or area.sum() <= 0:
        raise SceneError("scene meshes have no area to sample Gaussians from")
    t = rng.choice(len(tris), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
    return a + u[:, None] * (b - a) + v[:, None] * (c - a)


def knn_scale(points: np.ndarray, *, k: int = 3) -> np.ndarray:
    """Mean distance to the k nearest other points: float64 [N] metres (3DGS initial scale)."""
    from scipy.spatial import cKDTree

    if len(points) <= k:
        return np.full(len(points), 0.1)
    d, _ = cKDTree(points).query(points, k=k + 1)
    return d[:, 1:].mean(axis=1)


def _sigmoid(x):
    import drjit as dr

    return dr.rcp(1 + dr.exp(-x))


def columns(x: np.ndarray) -> list:
    """Columns of a host array float [M, D] as D ``Float`` [M] read from one device buffer.

    Creating D small arrays separately made Dr.Jit 1.5 (LLVM) bake their values into the kernels
    of the networks that read them (a recompilation at every step for D of about 8 or more);
    gathering from one buffer keeps the kernels value-independent.
    """
    import drjit as dr

    x = np.asarray(x, dtype=np.float32)
    m, d = x.shape
    buf = upload(B.Float, x.ravel())   # aligned: the kernels that read it compile once
    i = dr.arange(B.UInt32, m) * d
    return [dr.gather(B.Float, buf, i + k) for k in range(d)]


def _logit(p):
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


# --------------------------------------------------------------------------- splats

@dataclass
class Splats:
    """Gaussians ready for :func:`rfmitsuba.splat.render` for B views.

    means Array3f, log_scales Array3f, rotations Array4f (size N or B*N), opacities and
    signals Float (size N or B*N, view-major), ``n`` Gaussians, ``b`` views.
    """

    means: object
    log_scales: object
    rotations: object
    opacities: object
    signals: object
    n: int
    b: int

    @staticmethod
    def concat(sets: list["Splats"]) -> "Splats":
        """Join several Gaussian sets rendered from the same B views into one.

        Arrays of size N_k are broadcast to B*N_k where another set is per view; the result
        is view-major over N = sum N_k (set k's Gaussians occupy offsets
        [sum_{j<k} N_j, sum_{j<=k} N_j) of every view). Differentiable in every input.
        """
        import drjit as dr

        if len(sets) == 1:
            return sets[0]
        b = sets[0].b
        if any(s.b != b for s in sets):
            raise ValueError("Splats.concat: all sets must be rendered for the same number of views")
        n_tot = sum(s.n for s in sets)
        offsets = np.cumsum([0] + [s.n for s in sets])
        names = ("means", "log_scales", "rotations", "opacities", "signals")
        out = {}
        for name in names:
            arrays = [getattr(s, name) for s in sets]
            per_view = b > 1 and any(dr.width(a) == s.n * b for a, s in zip(arrays, sets))
            size = n_tot * b if per_view else n_tot
            j = dr.arange(B.UInt32, size)
            r = j % n_tot
            bv = j // n_tot
            res = None
            for k, (a, s) in enumerate(zip(arrays, sets)):
                a_per_view = dr.width(a) == s.n * b and b > 1
                local = dr.clip(B.Int32(r) - int(offsets[k]), 0, s.n - 1)
                idx = B.UInt32(local) + (bv * s.n if a_per_view else 0)
                tp = type(a)
                val = dr.gather(tp, a, idx)
                res = val if res is None else dr.select(r >= int(offsets[k]), val, res)
            out[name] = res
        return Splats(n=n_tot, b=b, **out)


# --------------------------------------------------------------------------- the field

@register
class SplatField(Field):
    """Gaussian set + EM-feature network (see module docstring): the paper's model family.

    Build with :meth:`from_points`, :meth:`initialize` or :meth:`load`.

    Args:
        params: per-Gaussian arrays (numpy float32, shapes [N, 3], [N, 3], [N, 4], [N]).
        box: float [2, 3] metres, the normalisation box (lo, hi).
        cfg: field configuration (its ``net`` gives the network architecture).
        extra_inputs: number of extra per-view network inputs (e.g. 3 for a person position).
        seed: network initialisation seed.
        name: prefix of this field's keys in an optimizer (e.g. "bg", "person").
    """

    kind = "splat"
    family = "splat"
    format = "rfmitsuba-field/1"
    #: adaptive density control (clone, split, prune) applies
    densify = True

    def __init__(self, params: dict, *, box: np.ndarray, cfg: SplatConfig, extra_inputs: int = 0,
                 seed: int = 0, name: str = "bg"):
        self.cfg = cfg
        self.name = name
        self.extra_inputs = int(extra_inputs)
        self.seed = int(seed)
        self.box = np.asarray(box, dtype=np.float64).reshape(2, 3)
        if not np.all(self.box[1] > self.box[0]):
            raise ConfigError(f"SplatField: box {self.box.tolist()} is empty")
        self.net = EMNetwork(cfg.net, extra_inputs=extra_inputs, seed=seed)
        self.params: dict = {}
        self.frozen = False
        self.set_gaussians(params)

    # ---- construction ---------------------------------------------------------------
    @classmethod
    def from_points(cls, points: np.ndarray, *, cfg: SplatConfig, box: np.ndarray | None = None,
                    extra_inputs: int = 0, seed: int = 0, name: str = "bg") -> "SplatField":
        """Gaussians centred on ``points`` (float [N, 3] metres), isotropic scale (cfg.init_scale
        or the 3-NN rule), identity rotation, opacity cfg.init_opacity. ``box`` defaults to the
        points' bounds plus cfg.box_margin."""
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise ConfigError(f"SplatField.from_points: points must be finite [N, 3], got {points.shape}")
        n = len(points)
        if cfg.init_scale > 0:
            s = np.full(n, cfg.init_scale)
        elif cfg.scale_mode == "angular":
            s = np.full(n, 0.15)  # radians, about the half-power half-width of a 4x4 array's beam
        else:
            s = np.clip(knn_scale(points), cfg.min_scale, cfg.max_init_scale)
        params = {
            "means": points.astype(np.float32),
            "log_scales": np.repeat(np.log(s)[:, None], 3, axis=1).astype(np.float32),
            "rotations": np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
            "opacity_logits": np.full(n, _logit(cfg.init_opacity), np.float32),
        }
        if box is None:
            box = np.stack([points.min(0) - cfg.box_margin, points.max(0) + cfg.box_margin])
        return cls(params, box=box, cfg=cfg, extra_inputs=extra_inputs, seed=seed, name=name)

    @classmethod
    def initialize(cls, *, cfg: SplatConfig, rng: np.random.Generator, meshes=None,
                   bounds: tuple | None = None, source: np.ndarray | None = None,
                   extra_inputs: int = 0, seed: int = 0, name: str = "bg") -> "SplatField":
        """Initial field from scene meshes (cfg.init == "mesh") or uniform in ``bounds``.

        Args:
            cfg: configuration.
            rng: numpy generator.
            meshes: list of (vertices [V, 3], faces [F, 3]) (needed for "mesh").
            bounds: (lo [3], hi [3]) metres; default: the meshes' bounds.
            source: float [3] metres or None; cfg.source_points extra Gaussians near it.
        """
        n_src = min(cfg.source_points, cfg.num_gaussians - 1) if source is not None else 0
        n_main = cfg.num_gaussians - n_src
        if cfg.init == "mesh":
            if not meshes:
                raise ConfigError("SplatConfig.init = 'mesh' needs scene meshes; use init = 'random' without a scene")
            pts = sample_surface(meshes, n_main, rng=rng)
            if bounds is None:
                allv = np.concatenate([v for v, _ in meshes])
                bounds = (allv.min(0), allv.max(0))
        else:
            if bounds is None:
                raise ConfigError("SplatConfig.init = 'random' needs scene bounds")
            lo, hi = (np.asarray(x, dtype=np.float64) for x in bounds)
            pts = lo + rng.random((n_main, 3)) * (hi - lo)
        if n_src > 0:
            src = np.asarray(source, dtype=np.float64) + rng.normal(0, 0.05, (n_src, 3))
            pts = np.concatenate([pts, src])
        lo, hi = (np.asarray(x, dtype=np.float64) for x in bounds)
        box = np.stack([np.minimum(lo, pts.min(0)) - cfg.box_margin, np.maximum(hi, pts.max(0)) + cfg.box_margin])
        return cls.from_points(pts, cfg=cfg, box=box, extra_inputs=extra_inputs, seed=seed, name=name)

    @classmethod
    def for_training(cls, cfg, data, *, scene_xml: Path | None, rng: np.random.Generator, extra_inputs: int = 0,
                     name: str = "bg") -> "SplatField":
        """The Stage-1 initial field of a training configuration: Gaussians on the scene's mesh
        surfaces (``cfg.splat.init == "mesh"``) or random in the known bounds padded by 0.5 m.
        A dataset without a scene (a measured NeRF2 folder) gets the random initialisation
        whatever ``init`` says, with a warning.

        Args:
            cfg: the :class:`~rfmitsuba.train.config.TrainConfig` (``field``, ``seed``).
            data: the :class:`~rfmitsuba.data.views.TrainData` (bounds, meshes, the fixed source).
            scene_xml: the room's XML, or None when it is unknown.
            rng: initialisation randomness; extra_inputs: extra per-view network inputs; name:
                optimizer key prefix.
        """
        fc = cfg.splat
        meshes = data.meshes(scene_xml) if fc.init == "mesh" else None
        if fc.init == "mesh" and meshes is None:
            # a measured folder names no room: the scene-free initialisation is the only one there is
            import warnings
            from dataclasses import replace

            warnings.warn(f"dataset {data.path} names no scene: Gaussians start uniform in the known bounds "
                          "(splat.init = 'random')", stacklevel=2)
            fc = replace(fc, init="random")
        bounds = data.bounds
        if meshes:
            allv = np.concatenate([v for v, _ in meshes])
            bounds = (np.minimum(bounds[0], allv.min(0)), np.maximum(bounds[1], allv.max(0)))
        else:
            pad = 0.5
            bounds = (bounds[0] - pad, bounds[1] + pad)
        return cls.initialize(cfg=fc, rng=rng, meshes=meshes, bounds=bounds, source=data.transmitter,
                              extra_inputs=extra_inputs, seed=cfg.seed, name=name)

    # ---- parameters -----------------------------------------------------------------
    @property
    def num_gaussians(self) -> int:
        import drjit as dr

        return dr.width(self.params["opacity_logits"])

    @property
    def num_primitives(self) -> int:
        """Gaussians."""
        return self.num_gaussians

    @property
    def network_parameters(self) -> int:
        """Weights of the EM-feature network."""
        return self.net.num_parameters

    @property
    def num_parameters(self) -> int:
        """Trainable scalars: per-Gaussian ones (11 per Gaussian) plus network weights."""
        return self.num_gaussians * sum(GAUSSIAN_KEYS.values()) + self.net.num_parameters

    def parameters(self) -> dict:
        """All parameters, ``key -> Float`` (keys: GAUSSIAN_KEYS and ``net.<module>``)."""
        out = dict(self.params)
        for k, m in self.net.modules().items():
            out[f"net.{k}"] = m.weights
        return out

    def assign(self, values: dict) -> None:
        """Set parameters from ``key -> Float`` (e.g. an optimizer's current values, which keeps
        the AD link so that gradients reach the optimizer). Unknown keys are an error."""
        mods = self.net.modules()
        for k, v in values.items():
            if k in GAUSSIAN_KEYS:
                self.params[k] = v
            elif k.startswith("net.") and k[4:] in mods:
                mods[k[4:]].set_weights(v)
            else:
                raise KeyError(f"SplatField has no parameter {k!r}")

    def freeze(self) -> None:
        """Exclude every parameter from training (values detached)."""
        import drjit as dr

        self.frozen = True
        for k in list(self.params):
            self.params[k] = dr.detach(self.params[k])
        for m in self.net.modules().values():
            m.set_weights(dr.detach(m.weights))

    def gaussians_numpy(self) -> dict:
        """Per-Gaussian parameters as numpy float32 arrays of shape [N, k] (or [N])."""
        out = {}
        for k, d in GAUSSIAN_KEYS.items():
            a = np.array(self.params[k].numpy(), dtype=np.float32, copy=True)
            out[k] = a.reshape(-1, d) if d > 1 else a
        return out

    def set_gaussians(self, arrays: dict) -> None:
        """Replace the Gaussian set from numpy arrays (shapes as :meth:`gaussians_numpy`)."""
        n = None
        for k, d in GAUSSIAN_KEYS.items():
            if k not in arrays:
                raise ConfigError(f"SplatField: missing per-Gaussian array {k!r}")
            a = np.asarray(arrays[k], dtype=np.float32)
            m = a.shape[0]
            if (d > 1 and a.shape != (m, d)) or (d == 1 and a.shape != (m,)) or (n is not None and m != n):
                raise ConfigError(f"SplatField: array {k!r} has shape {a.shape}, expected ({n or 'N'}, {d})")
            if not np.isfinite(a).all():
                raise ConfigError(f"SplatField: array {k!r} has non-finite values")
            n = m
            self.params[k] = B.Float(a.ravel())
        if n == 0:
            raise ConfigError("SplatField: no Gaussians")

    # ---- evaluation -----------------------------------------------------------------
    def normalize(self, p: np.ndarray) -> np.ndarray:
        """World positions float [M, 3] metres -> [0, 1] box coordinates (float32 [M, 3])."""
        p = np.asarray(p, dtype=np.float64)
        return ((p - self.box[0]) / (self.box[1] - self.box[0])).astype(np.float32)

    def splats(self, antenna_pos: np.ndarray, *, extra: np.ndarray | None = None,
               view_pos: np.ndarray | None = None) -> Splats:
        """Gaussians as seen for B views.

        Args:
            antenna_pos: float [B, 3] metres, the moving antenna's position per view (the RX in
                the moving-RX task, the TX in the moving-TX task).
            extra: float [B, extra_inputs] already scaled to about [0, 1], or None.
            view_pos: float [B, 3] metres, where the array is in each view (needed with
                scale_mode "angular"; default antenna_pos).

        Returns:
            :class:`Splats` with geometry of size N and signal/opacity of size B*N, where
            signal = sigmoid(net) and opacity = sigmoid(opacity_logit_i + net).
        """
        import drjit as dr

        ant = np.asarray(antenna_pos, dtype=np.float64).reshape(-1, 3)
        nb = len(ant)
        n = self.num_gaussians
        means = dr.unravel(B.Array3f, self.params["means"])
        lo = self.box[0].astype(np.float32)
        ext = (self.box[1] - self.box[0]).astype(np.float32)
        pos01 = [(means[k] - float(lo[k])) / float(ext[k]) for k in range(3)]
        a01 = self.normalize(ant)
        ant01 = columns(a01)
        ex = None
        if self.extra_inputs:
            if extra is None:
                raise ValueError(f"field {self.name!r} needs {self.extra_inputs} extra inputs per view")
            e = np.asarray(extra, dtype=np.float32).reshape(nb, self.extra_inputs)
            ex = columns(e)
        sig_logit, att, dscale = self.net(pos01, ant01, ex)
        op_logit = per_view([self.params["opacity_logits"]], views=nb, n=n)[0] + att
        q = dr.unravel(B.Array4f, self.params["rotations"])
        q = q / dr.sqrt(dr.squared_norm(q) + 1e-12)
        log_scales = dr.unravel(B.Array3f, self.params["log_scales"])
        if self.cfg.scale_mode == "angular" or self.cfg.scale_net:
            angular = self.cfg.scale_mode == "angular"
            # one per-view op for both arrays (its backward is one kernel)
            ls, *rest = per_view([log_scales] + ([means] if angular else []), views=nb, n=n)
            if angular:
                vp = np.asarray(antenna_pos if view_pos is None else view_pos, dtype=np.float32).reshape(nb, 3)
                vpa = dr.gather(B.Array3f, B.Array3f(*upload_columns(B.Float, vp)),
                                dr.arange(B.UInt32, n * nb) // dr.opaque(B.UInt32, n))
                dist = dr.norm(rest[0] - vpa)
                ls = ls + dr.log(dr.maximum(dist, 0.05))
            if self.cfg.scale_net:
                ls = ls + dr.tanh(dscale)
            log_scales = ls
        return Splats(
            means=means,
            log_scales=log_scales,
            rotations=q,
            opacities=_sigmoid(op_logit),
            signals=_sigmoid(sig_logit),
            n=n, b=nb)

    # ---- state ----------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything needed to rebuild this field: numpy arrays (no objects).

        Keys: per-Gaussian arrays, ``net.<module>`` weights, ``box``, and ``meta`` (a JSON
        string as a 0-d unicode array: config, extra_inputs, seed, name, frozen)."""

        out = self.gaussians_numpy()
        for k, m in self.net.modules().items():
            out[f"net.{k}"] = np.array(m.weights.numpy(), dtype=np.float32, copy=True)
        out["box"] = self.box.copy()
        meta = {"format": self.format, "config": to_dict(self.cfg), "extra_inputs": self.extra_inputs,
                "seed": self.seed, "name": self.name, "frozen": self.frozen}
        out["meta"] = np.array(json.dumps(meta))
        return out

    def load_state_dict(self, state: dict) -> None:
        """Load arrays written by :meth:`state_dict` into this (same-architecture) field."""
        if not all(k in state for k in GAUSSIAN_KEYS):
            _missing(state)
        self.set_gaussians({k: state[k] for k in GAUSSIAN_KEYS})
        for k, m in self.net.modules().items():
            key = f"net.{k}"
            if key not in state:
                raise RunError(f"field state has no network weights {key!r}")
            w = np.asarray(state[key], dtype=np.float32)
            if w.shape != (m.buffer_size,):
                raise RunError(f"field state {key!r} has {w.shape[0]} weights, this network needs {m.buffer_size}")
            m.set_weights(w)
        if "box" in state:
            self.box = np.asarray(state["box"], dtype=np.float64).reshape(2, 3)

    @classmethod
    def from_state_dict(cls, state: dict) -> "SplatField":
        """Rebuild a field (architecture from the stored metadata)."""

        if "meta" not in state:
            raise RunError("field state has no 'meta' entry")
        meta = json.loads(str(state["meta"]))
        cfg = from_dict(SplatConfig, meta["config"], saved=True)
        g = {k: state[k] for k in GAUSSIAN_KEYS if k in state}
        if len(g) != len(GAUSSIAN_KEYS):
            _missing(state)
        f = cls(g, box=state["box"], cfg=cfg, extra_inputs=meta["extra_inputs"], seed=meta["seed"],
                name=meta["name"])
        f.load_state_dict(state)
        if meta.get("frozen"):
            f.freeze()
        return f

    # ---- rendering and export ---------------------------------------------------------
    @classmethod
    def render_family(cls, fields: list, views: Views, *, height: int, width: int, normalize: bool):
        """Splat fields together: their Gaussians for every view are joined (:meth:`Splats.concat`)
        and rasterised into one image per view (:func:`rfmitsuba.splat.render`); with read-out
        "bartlett" (of every field) the image is an arrival image resampled through the Bartlett
        beam (:class:`rfmitsuba.rf.readout.BartlettReadout`). ``normalize`` is ignored: the splat
        output is trained directly against the min-max normalised PAS, as in WRF-GS.

        Returns:
            ``TensorXf`` [B, height, width].
        """

        readouts = {f.cfg.readout for f in fields}
        if len(readouts) != 1:
            raise ConfigError(f"splat fields with different read-outs cannot be rendered together: {sorted(readouts)}")
        s = Splats.concat([f.splats(views.antenna_pos, view_pos=views.view_pos, extra=views.extra(f)) for f in fields])
        if readouts.pop() == "bartlett":

            ha, wa = fields[0].cfg.arrival_grid
            arr = render(s.means, s.log_scales, s.rotations, s.opacities, s.signals, views.view_pos,
                         rx_to_world=views.rx_to_world, height=ha, width=wa, num_gaussians=s.n)
            return BartlettReadout(ha, wa, height, width)(arr)
        return render(s.means, s.log_scales, s.rotations, s.opacities, s.signals, views.view_pos,
                      rx_to_world=views.rx_to_world, height=height, width=width, num_gaussians=s.n)

    def export_ply(self, folder: str | Path, *, views: Views) -> list[Path]:
        """``gaussians.ply`` (3DGS layout, with each Gaussian's mean signal over ``views``) and
        ``network.npz`` (the network weights and the box) in ``folder``."""
        import drjit as dr

        folder = Path(folder)
        with dr.suspend_grad():
            s = self.splats(views.antenna_pos, view_pos=views.view_pos, extra=views.extra(self))
            sig = np.asarray(s.signals.numpy(), dtype=np.float32).reshape(views.count, -1).mean(axis=0)
        ply = write_ply(folder / "gaussians.ply", self, signal=sig)
        net = folder / "network.npz"
        np.savez(net, **{k: v for k, v in self.state_dict().items() if "." in k or k == "box"})
        return [ply, net]


def _missing(state: dict):
    miss = [k for k in GAUSSIAN_KEYS if k not in state]
    raise RunError(f"field state lacks per-Gaussian arrays {miss}")


# --------------------------------------------------------------------------- PLY export

_C0 = 0.28209479177387814  # SH degree-0 constant used by 3DGS viewers


def write_ply(path: str | Path, field: SplatField, *, signal: np.ndarray | None = None) -> Path:
    """Export a field's Gaussians in the 3D Gaussian Splatting PLY layout (see :func:`write_ply_arrays`).

    Args:
        path: output ``.ply``.
        field: the field.
        signal: float [N] per-Gaussian signal in [0, 1] to store (e.g. the mean over the
            training views); zeros when None.
    """
    g = field.gaussians_numpy()
    return write_ply_arrays(path, g["means"], g["log_scales"], g["rotations"], g["opacity_logits"], signal=signal)


def write_ply_arrays(path: str | Path, means: np.ndarray, log_scales: np.ndarray, rotations: np.ndarray,
                     opacity_logits: np.ndarray, *, signal: np.ndarray | None = None) -> Path:
    """Write N Gaussians in the 3D Gaussian Splatting PLY layout (binary little endian), atomically.

    Properties: x, y, z (metres), nx, ny, nz (0), f_dc_0..2 (grey level from ``signal`` so
    viewers show it), opacity (logit), scale_0..2 (log metres), rot_0..3 (w, x, y, z), and the
    extra property ``signal``.

    Args:
        means: float [N, 3] metres; log_scales: float [N, 3]; rotations: float [N, 4] (w, x, y, z);
        opacity_logits: float [N]; signal: float [N] in [0, 1] or None (zeros).
    """
    n = len(opacity_logits)
    sig = np.zeros(n, np.float32) if signal is None else np.asarray(signal, np.float32).reshape(n)
    names = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
             + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)] + ["signal"])
    data = np.zeros(n, dtype=[(k, "<f4") for k in names])
    means, log_scales, rotations = (np.asarray(a, np.float32).reshape(n, -1) for a in (means, log_scales, rotations))
    for i, k in enumerate("xyz"):
        data[k] = means[:, i]
    dc = (sig - 0.5) / _C0
    for i in range(3):
        data[f"f_dc_{i}"] = dc
        data[f"scale_{i}"] = log_scales[:, i]
    for i in range(4):
        data[f"rot_{i}"] = rotations[:, i]
    data["opacity"] = np.asarray(opacity_logits, np.float32).reshape(n)
    data["signal"] = sig
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {k}\n" for k in names) + "end_header\n"
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(data.tobytes())
    tmp.replace(path)
    return path


def read_ply(path: str | Path) -> dict:
    """Read a binary little-endian PLY of float properties (as written by :func:`write_ply`):
    property name -> float32 [N]."""
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header\n")
    if end < 0:
        raise RunError(f"{path}: not a PLY file (no end_header)")
    header = raw[:end].decode("ascii").splitlines()
    if not header or header[0] != "ply" or "format binary_little_endian 1.0" not in header:
        raise RunError(f"{path}: only binary little-endian PLY files are supported")
    n = next(int(h.split()[2]) for h in header if h.startswith("element vertex"))
    props = [h.split()[2] for h in header if h.startswith("property")]
    if any(h.split()[1] != "float" for h in header if h.startswith("property")):
        raise RunError(f"{path}: only float properties are supported")
    data = np.frombuffer(raw[end + len(b"end_header\n"):], dtype=[(k, "<f4") for k in props], count=n)
    return {k: np.array(data[k]) for k in props}


def scale_of_box(box: np.ndarray) -> float:
    """Diagonal length of a box [2, 3] in metres (the 'scene extent' of density control)."""
    box = np.asarray(box, dtype=np.float64)
    return float(math.sqrt(((box[1] - box[0]) ** 2).sum()))
