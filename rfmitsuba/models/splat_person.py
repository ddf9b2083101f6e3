"""Stage 2: a sparse set of "person" Gaussians conditioned on the person position.

A :class:`SplatPersonField` is a :class:`~rfmitsuba.models.splat.SplatField` whose EM-feature
network takes the person position as extra per-view input

    F_man: (P(G_man), P(antenna), P(man)) -> signal, attenuation

plus a **deformation network**

    D_man: (P(G_man), P(man)) -> (position offset, rotation offset, log-scale offset)

evaluated for every (view, Gaussian) pair, so the person Gaussians move, turn and grow with
the person. Rendering (:meth:`SplatPersonField.splats`) returns per-view geometry (size B*N) that
:meth:`rfmitsuba.models.splat.Splats.concat` joins with a frozen background into one splatting
call (the paper's linear superposition); only the person field's parameters train.

Positions are in metres (world frame), the person position is given as the feature vector of
:func:`rfmitsuba.data.samples.person_features` (NaN-free, already normalised).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import ClassVar
from dataclasses import field as dc_field

import numpy as np

from ..core import backend as B
from ..core.config import from_dict, to_dict
from ..core.errors import ConfigError, RunError
from ..core.legacy_names import current_keys
from ..data.samples import num_person_features
from .base import register
from .nn import MLP, NetConfig, encode
from .splat import GAUSSIAN_KEYS, SplatConfig, SplatField, Splats, _logit, columns


@dataclass
class DeformConfig:
    """Deformation network: octaves of the Gaussian-position encoding, width and hidden layers;
    offsets bounded by ``max_offset`` metres (position), ``max_log_scale`` (log-scale) and
    ``max_rotation`` (quaternion components)."""

    enabled: bool = True
    octaves: int = 3
    width: int = 32
    layers: int = 1
    max_offset: float = 0.5
    max_log_scale: float = 1.0
    max_rotation: float = 0.3
    gain: float = 0.1

    def __post_init__(self) -> None:
        if self.octaves < 0 or self.width < 1 or self.layers < 0:
            raise ConfigError("DeformConfig: octaves and layers must be >= 0, width >= 1")
        if min(self.max_offset, self.max_log_scale, self.max_rotation, self.gain) < 0:
            raise ConfigError("DeformConfig: bounds and gain must be >= 0")


@dataclass
class SplatPersonConfig:
    """The person Gaussian set of Stage 2.

    num_gaussians: size of the sparse set; init_radius: horizontal standard deviation (metres)
    of the initial positions around the training person positions; init_height: (lo, hi)
    metres above the person's feet; init_scale: initial isotropic scale (metres, or radians
    with ``splat.scale_mode = "angular"``); init_opacity: initial attenuation delta;
    person_octaves: octaves of the person-position encoding.
    anchor: "person" - Gaussian positions are stored relative to the person's feet and follow the
    person (world position = person position + stored position + deformation); "world" - stored
    positions are world positions (the deformation network alone moves them).
    """

    num_gaussians: int = 300
    init_radius: float = 0.4
    init_height: tuple[float, float] = (0.1, 1.8)
    init_scale: float = 0.1
    init_opacity: float = 0.1
    person_octaves: int = 3
    anchor: str = "person"
    net: NetConfig = dc_field(default_factory=lambda: NetConfig(width=32, signal_bias=-4.0))
    deform: DeformConfig = dc_field(default_factory=DeformConfig)

    #: values that changed name (saved files load; :mod:`rfmitsuba.core.config`)
    renamed_values: ClassVar[dict] = {"anchor": {"human": "person"}}

    def __post_init__(self) -> None:
        if self.num_gaussians < 1:
            raise ConfigError(f"SplatPersonConfig.num_gaussians must be >= 1, got {self.num_gaussians}")
        if self.init_radius < 0 or self.init_scale <= 0 or not 0 < self.init_opacity < 1:
            raise ConfigError("SplatPersonConfig: init_radius >= 0, init_scale > 0, init_opacity in (0, 1)")
        if self.anchor not in ("person", "world"):
            raise ConfigError(f"SplatPersonConfig.anchor must be 'person' or 'world', got {self.anchor!r}")


@register
class SplatPersonField(SplatField):
    """Person Gaussians with a position-conditioned EM network and a deformation network.

    Args:
        params: per-Gaussian numpy arrays (as :class:`SplatField`).
        box: float [2, 3] metres, normalisation box.
        hcfg: :class:`SplatPersonConfig`.
        field_cfg: the field configuration (scale mode of the background it joins).
        seed: network seed.
        name: optimizer key prefix.
    """

    kind = "splat_person"
    family = "splat"
    format = "rfmitsuba-person-field/1"
    person = True

    def __init__(self, params: dict, *, box: np.ndarray, hcfg: SplatPersonConfig, field_cfg: SplatConfig,
                 seed: int = 0, name: str = "person"):
        import dataclasses

        self.hcfg = hcfg
        cfg = dataclasses.replace(field_cfg, net=hcfg.net, scale_net=False, num_gaussians=hcfg.num_gaussians)
        super().__init__(params, box=box, cfg=cfg, extra_inputs=num_person_features(hcfg.person_octaves),
                         seed=seed, name=name)
        d = hcfg.deform
        n_in = 3 * (1 + 2 * d.octaves) + num_person_features(hcfg.person_octaves)
        self.deform = MLP(n_in, 10, width=d.width, layers=d.layers, seed=seed + 17) if d.enabled else None

    @property
    def feature_octaves(self) -> int:
        """Octaves of the person-position features (:func:`rfmitsuba.data.samples.person_features`)."""
        return self.hcfg.person_octaves

    # ---- construction ---------------------------------------------------------------
    @classmethod
    def for_background(cls, bg: SplatField, *, cfg: SplatPersonConfig, walk: np.ndarray, rng: np.random.Generator,
                       seed: int = 0, name: str = "person") -> "SplatPersonField":
        """Fresh person Gaussians joining background ``bg`` (its scale mode and box), placed
        around the training walk ``walk`` (float [H, 3] metres) by :meth:`near_walk`."""
        return cls.near_walk(walk, hcfg=cfg, field_cfg=bg.cfg, box=bg.box, rng=rng, seed=seed, name=name)

    @classmethod
    def near_walk(cls, person_positions: np.ndarray, *, hcfg: SplatPersonConfig, field_cfg: SplatConfig,
                  box: np.ndarray, rng: np.random.Generator, seed: int = 0, name: str = "person") -> "SplatPersonField":
        """Random initial person Gaussians around the (training) person positions.

        Args:
            person_positions: float [H, 3] metres, feet positions of the training walk.
            hcfg, field_cfg: configurations; box: float [2, 3] normalisation box (metres).
            rng: numpy generator (the only randomness of the positions).
        """
        hp = np.asarray(person_positions, np.float64).reshape(-1, 3)
        hp = hp[np.isfinite(hp).all(1)]
        if len(hp) == 0:
            raise ConfigError("SplatPersonField.near_walk: no finite person positions to initialise around")
        n = hcfg.num_gaussians
        pick = hp[rng.integers(0, len(hp), n)]
        pts = pick.copy()
        pts[:, :2] += rng.normal(0.0, hcfg.init_radius, (n, 2))
        lo_h, hi_h = hcfg.init_height
        pts[:, 2] += lo_h + rng.random(n) * (hi_h - lo_h)
        box = np.asarray(box, np.float64).reshape(2, 3)
        pts = np.clip(pts, box[0] + 1e-3, box[1] - 1e-3)
        if hcfg.anchor == "person":
            pts = pts - pick
        params = {
            "means": pts.astype(np.float32),
            "log_scales": np.full((n, 3), np.log(hcfg.init_scale), np.float32),
            "rotations": np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
            "opacity_logits": np.full(n, _logit(hcfg.init_opacity), np.float32),
        }
        return cls(params, box=box, hcfg=hcfg, field_cfg=field_cfg, seed=seed, name=name)

    # ---- parameters -----------------------------------------------------------------
    def parameters(self) -> dict:
        """Per-Gaussian arrays, ``net.<module>`` and ``deform.mlp`` weights."""
        out = super().parameters()
        if self.deform is not None:
            out["deform.mlp"] = self.deform.weights
        return out

    @property
    def num_parameters(self) -> int:
        return super().num_parameters + (self.deform.num_parameters if self.deform is not None else 0)

    def assign(self, values: dict) -> None:
        rest = {}
        for k, v in values.items():
            if k == "deform.mlp" and self.deform is not None:
                self.deform.set_weights(v)
            else:
                rest[k] = v
        super().assign(rest)

    def freeze(self) -> None:
        import drjit as dr

        super().freeze()
        if self.deform is not None:
            self.deform.set_weights(dr.detach(self.deform.weights))

    # ---- evaluation -----------------------------------------------------------------
    def splats(self, antenna_pos: np.ndarray, *, extra: np.ndarray | None = None,
               view_pos: np.ndarray | None = None):
        """Person Gaussians for B views.

        Args:
            antenna_pos: float [B, 3] metres (moving antenna per view).
            extra: float32 [B, num_person_features + 3]: :func:`rfmitsuba.data.samples.person_features`
                followed by the person position in metres (``SampleData.features(..., raw=True)``).
            view_pos: float [B, 3] metres, array position per view (default antenna_pos).

        Returns:
            :class:`rfmitsuba.models.splat.Splats` with every array of size B*N (view-major).
        """
        import drjit as dr


        if extra is None:
            raise ValueError(f"person field {self.name!r} needs the person inputs of every view")
        nf = self.extra_inputs
        e_all = np.asarray(extra, np.float32).reshape(len(np.asarray(antenna_pos).reshape(-1, 3)), -1)
        if e_all.shape[1] != nf + 3:
            raise ValueError(f"person field {self.name!r}: extra must be [B, {nf} + 3] (features, position), "
                             f"got {e_all.shape}")
        e, hpos = e_all[:, :nf], e_all[:, nf:]
        s = super().splats(antenna_pos, extra=e, view_pos=view_pos)
        n, nb = s.n, s.b
        idx = dr.arange(B.UInt32, n * nb)
        n_op = dr.opaque(B.UInt32, n)
        gi, bi = idx % n_op, idx // n_op
        means = s.means
        if self.hcfg.anchor == "person":
            hp = columns(hpos)
            shift = dr.gather(B.Array3f, B.Array3f(hp[0], hp[1], hp[2]), bi)
            m_world = dr.gather(B.Array3f, means, gi) + shift
        else:
            m_world = dr.gather(B.Array3f, means, gi)
        if self.deform is None:
            ls = dr.gather(B.Array3f, s.log_scales, gi) if dr.width(s.log_scales) == n else s.log_scales
            return Splats(means=m_world, log_scales=ls, rotations=dr.gather(B.Array4f, s.rotations, gi),
                          opacities=s.opacities, signals=s.signals, n=n, b=nb)
        d = self.hcfg.deform
        lo = self.box[0].astype(np.float32)
        ext = (self.box[1] - self.box[0]).astype(np.float32)
        if self.hcfg.anchor == "person":
            pos01 = [means[k] / float(ext[k]) * 0.5 + 0.25 for k in range(3)]
        else:
            pos01 = [(means[k] - float(lo[k])) / float(ext[k]) * 0.5 for k in range(3)]
        enc = encode(pos01, octaves=d.octaves)
        ex = columns(e)
        inputs = [dr.gather(B.Float, x, gi) for x in enc] + [dr.gather(B.Float, x, bi) for x in ex]
        out = self.deform(inputs)
        t = [dr.tanh(d.gain * o) for o in out]
        m = m_world + d.max_offset * B.Array3f(t[0], t[1], t[2])
        q = (dr.gather(B.Array4f, s.rotations, gi) if dr.width(s.rotations) == n else s.rotations) \
            + d.max_rotation * B.Array4f(t[3], t[4], t[5], t[6])
        q = q / dr.sqrt(dr.squared_norm(q) + 1e-12)
        ls = dr.gather(B.Array3f, s.log_scales, gi) if dr.width(s.log_scales) == n else s.log_scales
        ls = ls + d.max_log_scale * B.Array3f(t[7], t[8], t[9])
        return Splats(means=m, log_scales=ls, rotations=q, opacities=s.opacities, signals=s.signals, n=n, b=nb)

    # ---- state ----------------------------------------------------------------------
    def state_dict(self) -> dict:

        out = super().state_dict()
        if self.deform is not None:
            out["deform.mlp"] = np.array(self.deform.weights.numpy(), dtype=np.float32, copy=True)
        meta = json.loads(str(out["meta"]))
        meta.update({"format": self.format, "person_config": to_dict(self.hcfg)})
        out["meta"] = np.array(json.dumps(meta))
        return out

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        if self.deform is not None:
            if "deform.mlp" not in state:
                raise RunError("person field state has no deformation weights 'deform.mlp'")
            w = np.asarray(state["deform.mlp"], np.float32)
            if w.shape != (self.deform.buffer_size,):
                raise RunError(f"person field state 'deform.mlp' has {w.shape[0]} weights, "
                               f"this network needs {self.deform.buffer_size}")
            self.deform.set_weights(w)

    @classmethod
    def from_state_dict(cls, state: dict) -> "SplatPersonField":

        if "meta" not in state:
            raise RunError("person field state has no 'meta' entry")
        meta = current_keys(json.loads(str(state["meta"])))
        if meta.get("format") != cls.format:
            raise RunError(f"not a person field state (format {meta.get('format')!r})")
        hcfg = from_dict(SplatPersonConfig, meta["person_config"], saved=True)
        fcfg = from_dict(SplatConfig, meta["config"], saved=True)
        g = {k: state[k] for k in GAUSSIAN_KEYS}
        f = cls(g, box=state["box"], hcfg=hcfg, field_cfg=fcfg, seed=meta["seed"], name=meta["name"])
        f.load_state_dict(state)
        if meta.get("frozen"):
            f.freeze()
        return f

