"""Stage 2 in the coherent Gaussian family: the walking person as scatterers attached to the body
plus the blockage of the background's own paths, on a frozen
:class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField`.

The person stands with its feet at ``h`` [m] (the position the framework passes to every person
field, :meth:`rfmitsuba.data.samples.SampleData.features` with ``raw=True``). Two effects:

* **Scattering.** ``K`` points attached to the body, at ``s_k = h + c + e * tanh(o_k)``: ``c = (0,
  0, H/2)`` the middle of the body axis (``H`` = ``body_height``), ``e = (max_offset, max_offset,
  H/2)`` the bound of the offset, ``o_k`` learned. Each re-radiates with a learned complex gain
  ``g_k`` along the two-leg path transmitter -> ``s_k`` -> element, exactly as a background
  scatterer does (:meth:`CoherentGaussianField._propagate`: spreading ``|y - s| |s - e_m|``, phase
  from the path length, the background's ``wavefront``), with no visibility window.
* **Blockage.** Every background source's term is multiplied by ``prod_legs (1 - a exp(-d^2 / (2
  r^2)))``, ``d`` the distance [m] between the person's body axis (the vertical segment from ``h``
  to ``h + (0, 0, H)``) and a leg of the source's path: the last leg (source or image point ->
  array centre) and the first (transmitter -> scatterer; for a reflected image, transmitter ->
  the image of the array centre, ``A^T (x - b)``, with ``first_leg``; the direct path has one
  leg). A leg segment is restricted by the body axis's heights, so an image leg's part outside the
  room (below the floor, behind a wall) does not count. ``d`` is taken where the leg passes
  closest to the axis horizontally (exact for legs that are not near vertical). The strength
  ``a = sigmoid(block_logit)`` in [0, 1] and the radius ``r = exp(block_log_radius)`` [m] are
  global or per background source (``strength_per_source``, ``radius_per_source``).

The field's channels are (blocked background - background) + scatterers, passed through the
background's array (its pose) and calibration ``cal``; added to the frozen background's channels
they give the person-present scene, read out by the background's Bartlett. With ``a = 0`` and no
scatterers (or zero gains) they are exactly zero; Stage 2 starts near that (``init_strength``,
``init_gain``).

Parameters (Dr.Jit ``Float``; name, size, unit, optimizer group), ``S + P`` the background's
images plus scatterers:

====================  ===================  =====================  ==============
``sc_offset``         K*3                  1 (tanh argument)      means
``sc_amp``            K*2 (re, im)         1                      amp
``block_logit``       1 or S+P             1 (logit of ``a``)     opacity_logits
``block_log_radius``  1 or S+P             log m                  log_scales
====================  ===================  =====================  ==============

The frozen background's state is stored with this field (``bg.*``), so its ``.npz`` (no pickle)
is self-contained. tests/models/test_coherent_gaussians_person.py checks every parameter against
finite differences.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import backend as B
from ..core.config import from_dict, to_dict
from ..core.errors import ConfigError, RunError
from ..data.samples import num_person_features
from .base import FlatParameterField, Views, register
from ._points import columns32, write_points_ply
from .coherent_gaussians import CoherentGaussianField
from .coherent_gaussians.field import _jit_arrays

FORMAT = "rfmitsuba-coherent-gaussians-person/1"

#: optimizer group of every parameter (rfmitsuba.train.trainer's learning rates)
LR_GROUPS = {"sc_offset": "means", "sc_amp": "amp", "block_logit": "opacity_logits",
             "block_log_radius": "log_scales"}


@dataclass
class CoherentGaussianPersonConfig:
    """The Stage-2 person field of the coherent Gaussian family (:class:`CoherentGaussianPersonField`).

    num_points: scatterers attached to the body (0 = blockage only); max_offset: horizontal bound
    of their offset from the body axis [m]; body_height: height of the body axis above the feet
    [m] (also the scatterers' vertical range); init_radius / init_height: initial horizontal radius
    and (lo, hi) height of the scatterers around the feet [m]; init_gain: initial |gain| of each
    scatterer relative to the background's direct path times its scatterer scale (phases random;
    0: none at the start); init_strength: initial blockage strength ``a`` in [0, 1);
    init_block_radius: initial blockage radius ``r`` [m]; strength_per_source /
    radius_per_source: one ``a`` / ``r`` per background source instead of one for all;
    first_leg: block the first leg of reflected images too (not only the last);
    person_octaves: octaves of the person features the framework passes before the position
    (only the position is read); people: people drawn at once, each with the same body (its own
    scatterers, its own blockage: the blockages multiply), their feet positions the last
    ``3 * people`` extra inputs.
    """

    num_points: int = 8
    max_offset: float = 0.3
    body_height: float = 1.8
    init_radius: float = 0.15
    init_height: tuple[float, float] = (0.3, 1.6)
    init_gain: float = 0.02
    init_strength: float = 0.05
    init_block_radius: float = 0.3
    strength_per_source: bool = False
    radius_per_source: bool = False
    first_leg: bool = True
    person_octaves: int = 3
    people: int = 1

    def __post_init__(self) -> None:
        self.init_height = tuple(float(v) for v in self.init_height)
        if self.num_points < 0 or self.person_octaves < 0:
            raise ConfigError("CoherentGaussianPersonConfig: num_points and person_octaves must be >= 0")
        if self.people < 1:
            raise ConfigError(f"CoherentGaussianPersonConfig.people must be >= 1, got {self.people}")
        if not (self.max_offset > 0 and self.body_height > 0 and self.init_block_radius > 0):
            raise ConfigError("CoherentGaussianPersonConfig: max_offset, body_height and init_block_radius must be > 0")
        if not 0 <= self.init_radius < self.max_offset:
            raise ConfigError("CoherentGaussianPersonConfig: init_radius must be in [0, max_offset)")
        lo, hi = self.init_height
        if not 0 < lo <= hi < self.body_height:
            raise ConfigError("CoherentGaussianPersonConfig: init_height (lo, hi) must satisfy 0 < lo <= hi < "
                              "body_height")
        if not (0 <= self.init_strength < 1 and self.init_gain >= 0):
            raise ConfigError("CoherentGaussianPersonConfig: init_strength in [0, 1) and init_gain >= 0 required")


def _logit(a: float) -> float:
    """logit of ``a``; a = 0 gives -200 (sigmoid exactly 0 in float32)."""
    return -200.0 if a <= 0 else float(np.log(a / (1.0 - a)))


def axis_distance2(p0, p1, hx, hy, z0, z1):
    """Squared distance [m^2] between the segment ``p0 -> p1`` (3 Dr.Jit ``Float`` each) and the
    vertical segment at ``(hx, hy)`` from height ``z0`` to ``z1``, taken where the segment passes
    closest to the vertical line horizontally (exact unless the segment is near vertical)."""
    import drjit as dr

    dx, dy, dz = p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]
    wx, wy = hx - p0[0], hy - p0[1]
    t = dr.clip((wx * dx + wy * dy) / dr.maximum(dx * dx + dy * dy, 1e-9), 0.0, 1.0)
    rx, ry = wx - t * dx, wy - t * dy
    z = p0[2] + t * dz
    ex = dr.maximum(z0 - z, 0.0) + dr.maximum(z - z1, 0.0)
    return rx * rx + ry * ry + ex * ex


@register
class CoherentGaussianPersonField(FlatParameterField):
    """The person on a frozen coherent Gaussian background (see the module docstring).

    Args:
        bg: the trained :class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField` (kept
            as it is; freeze it for Stage 2).
        cfg: :class:`CoherentGaussianPersonConfig`; reference_amplitude: the initial scatterer
            gain's unit (the background's direct-path gain times its scatterer scale); seed, name:
            as the other fields; params: stored parameters instead of the initial ones.

    Per-view input ``extra``: float [B, F + 3], the person features (F =
    ``num_person_features(person_octaves)``) followed by the feet position in metres.
    """

    LR_GROUPS = LR_GROUPS
    kind = "coherent_gaussians_person"
    family = "coherent_gaussians"
    format = FORMAT
    person = True

    def __init__(self, bg: CoherentGaussianField, *, cfg: CoherentGaussianPersonConfig | None = None,
                 reference_amplitude: float = 1.0, seed: int = 0, name: str = "person", params: dict | None = None):
        if not isinstance(bg, CoherentGaussianField):
            raise ConfigError(f"the coherent Gaussian person field needs a coherent_gaussians background, got "
                              f"{type(bg).__name__}")
        B.ensure()
        self.bg = bg
        self.cfg = c = cfg or CoherentGaussianPersonConfig()
        self.readout, self.frequency_hz = bg.readout, bg.frequency_hz
        self.reference_amplitude = float(reference_amplitude)
        self.seed, self.name = int(seed), name
        self.extra_inputs = num_person_features(c.person_octaves) + 3 * c.people
        self.frozen = False
        #: 1 for a reflected image (two legs to block), 0 for the direct path; scatterers always two
        self._two_legs = B.Float(np.asarray(bg.order > 0, np.float32))
        if params is None:
            rng = np.random.default_rng([self.seed, 7])
            K, H = c.num_points, c.body_height
            rad = c.init_radius * np.sqrt(rng.uniform(0, 1, K))
            phi = rng.uniform(0, 2 * np.pi, K)
            z = rng.uniform(*c.init_height, K)
            off = np.stack([rad * np.cos(phi) / c.max_offset, rad * np.sin(phi) / c.max_offset, 2 * z / H - 1], 1)
            ph = rng.uniform(0, 2 * np.pi, K)
            g = c.init_gain * self.reference_amplitude
            sizes = self._sizes()
            params = {"sc_offset": np.arctanh(off).ravel(), "sc_amp": np.stack([g * np.cos(ph), g * np.sin(ph)], 1).ravel(),
                      "block_logit": np.full(sizes["block_logit"], _logit(c.init_strength)),
                      "block_log_radius": np.full(sizes["block_log_radius"], np.log(c.init_block_radius))}
        self.params: dict = {}
        self.load_state_dict(params)

    @classmethod
    def for_background(cls, bg: CoherentGaussianField, *, cfg: CoherentGaussianPersonConfig | None = None,
                       seed: int = 0, name: str = "person", walk: np.ndarray | None = None,
                       rng: np.random.Generator | None = None) -> "CoherentGaussianPersonField":
        """A fresh person field on a trained background: scatterer gains start at ``init_gain``
        of its direct path's gain times its scatterer scale (``walk`` and ``rng`` are not needed)."""
        if not isinstance(bg, CoherentGaussianField):
            raise ConfigError(f"the coherent Gaussian person field needs a coherent_gaussians background, got "
                              f"{type(bg).__name__}")
        a = np.asarray(bg.params["img_amp"].numpy(), np.float64).reshape(-1, 2)
        direct = int(np.flatnonzero(bg.order == 0)[0]) if (bg.order == 0).any() \
            else int(np.argmax(np.hypot(a[:, 0], a[:, 1])))
        ref = float(np.hypot(*a[direct])) * bg.scatterer_scale
        return cls(bg, cfg=cfg, reference_amplitude=max(ref, 1e-12), seed=seed, name=name)

    # ---- parameters ------------------------------------------------------------------------
    def _sizes(self) -> dict:
        c, n = self.cfg, self.bg.num_primitives
        return {"sc_offset": 3 * c.num_points, "sc_amp": 2 * c.num_points,
                "block_logit": n if c.strength_per_source else 1,
                "block_log_radius": n if c.radius_per_source else 1}

    @property
    def feature_octaves(self) -> int:
        return self.cfg.person_octaves

    @property
    def num_primitives(self) -> int:
        """The scatterers attached to the body."""
        return self.cfg.num_points

    # ---- state -------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        out = {k: np.array(v.numpy(), np.float32, copy=True) for k, v in self.params.items()}
        out.update({f"bg.{k}": v for k, v in self.bg.state_dict().items()})
        out["meta"] = np.asarray(json.dumps({
            "format": FORMAT, "config": to_dict(self.cfg), "reference_amplitude": self.reference_amplitude,
            "seed": self.seed, "name": self.name, "frozen": self.frozen}))
        return out

    @classmethod
    def from_state_dict(cls, state: dict) -> "CoherentGaussianPersonField":
        try:
            meta = json.loads(str(state["meta"]))
            if meta.get("format") != FORMAT:
                raise RunError(f"not a CoherentGaussianPersonField state (format {meta.get('format')!r})")
            bg = CoherentGaussianField.from_state_dict({k[3:]: v for k, v in state.items() if k.startswith("bg.")})
            bg.freeze()
            f = cls(bg, cfg=from_dict(CoherentGaussianPersonConfig, meta["config"], saved=True),
                    reference_amplitude=meta["reference_amplitude"], seed=meta["seed"],
                    name=meta.get("name", "person"), params=state)
        except KeyError as e:
            raise RunError(f"CoherentGaussianPersonField state lacks {e}") from None
        if meta.get("frozen"):
            f.freeze()
        return f

    # ---- evaluation --------------------------------------------------------------------------
    @property
    def people(self) -> int:
        """People drawn at once (:attr:`CoherentGaussianPersonConfig.people`)."""
        return self.cfg.people

    def person_position(self, views: Views) -> np.ndarray:
        """Every person's feet position for every view from its extra inputs: float64 [B, 3 *
        people] m (x, y, z of person 1, then of person 2, ...; ConfigError naming a missing,
        misshapen or non-finite input)."""
        e = views.extra(self)
        nb = views.count
        if e is None:
            raise ConfigError("the coherent Gaussian person field needs the person's features and position of "
                              "every view (Views.inputs)")
        e = np.asarray(e, np.float64)
        if e.ndim != 2 or e.shape != (nb, self.extra_inputs):
            raise ConfigError(f"coherent Gaussian person field: extra inputs must be [B, {self.extra_inputs}] "
                              f"(features, then the feet position in metres of each of {self.people} people) for "
                              f"B = {nb} views, got {e.shape}")
        h = e[:, -3 * self.people:]
        if not np.isfinite(h).all():
            raise ConfigError(f"coherent Gaussian person field: person position must be finite, got "
                              f"{h[~np.isfinite(h).all(axis=1)][0].tolist()}")
        return h

    def _blockage(self, h_cols):
        """``weight`` of :meth:`CoherentGaussianField.channels`: per lane, the blocked term's factor
        minus 1 (so the background's channels times it are the blockage's change)."""
        import drjit as dr

        bg, c = self.bg, self.cfg
        H = c.body_height
        logit, logr = self.params["block_logit"], self.params["block_log_radius"]

        def weight(group, ln, s):
            b, k = ln["b"], ln["k"]
            src = k if group == "img" else k + bg.num_images
            zero = dr.zeros(B.UInt32, dr.width(k))
            a = dr.rcp(1.0 + dr.exp(-dr.gather(B.Float, logit, src if c.strength_per_source else zero)))
            r = dr.exp(dr.gather(B.Float, logr, src if c.radius_per_source else zero))
            inv = -0.5 / (r * r)
            hx, hy, hz = (dr.gather(B.Float, col, b) for col in h_cols)
            z0, z1 = hz, hz + H
            g1 = a * dr.exp(axis_distance2(s, ln["cen"], hx, hy, z0, z1) * inv)          # last leg
            if group == "sc":
                g2 = a * dr.exp(axis_distance2(ln["y"], s, hx, hy, z0, z1) * inv)        # first leg
            elif c.first_leg:
                Ak = [dr.gather(B.Float, col, k) for col in bg._A_cols]
                off = bg.params["img_offset"]
                v = [ln["cen"][i] - dr.gather(B.Float, off, 3 * k + i) for i in range(3)]
                back = [Ak[j] * v[0] + Ak[3 + j] * v[1] + Ak[6 + j] * v[2] for j in range(3)]   # A^T (x - b)
                g2 = a * dr.gather(B.Float, self._two_legs, k) * dr.exp(
                    axis_distance2(ln["y"], back, hx, hy, z0, z1) * inv)
            else:
                return -g1
            return g1 * g2 - g1 - g2                 # (1 - g1)(1 - g2) - 1

        return weight

    def channels(self, views: Views, *, with_background: np.ndarray | None = None) -> tuple:
        """What the person changes at the 16 elements, through the background's array and
        calibration: (re, im) ``Float`` [B*16] (see the module docstring). ConfigError on a missing,
        misshapen or non-finite person position or view position.

        ``with_background``: None, or float [B] person presence (1 present, 0 absent): then the
        channels are the background's plus, where present, the person's change, in one pass over
        the background's sources (each term weighted ``1 + presence * (blockage - 1)``), not two."""
        return self.channels_prepared(self.prepare(views, with_background=with_background))

    # ---- :meth:`channels` in its host part and its device part (rfmitsuba.train.frozen_step) ---
    freezable = True

    def prepare(self, views: Views, *, with_background: np.ndarray | None = None) -> dict:
        """The host part of :meth:`channels`: the background's (``"bg"``), the person's position
        columns (``"h"``) and, with ``with_background``, the presence (``"pres"``, ``Float`` [B])."""
        prep = {"bg": self.bg.prepare(views)}
        prep["h"] = columns32(self.person_position(views))
        if with_background is not None:
            prep["pres"] = B.Float(np.asarray(with_background, np.float32).reshape(prep["bg"]["nb"]))
        return prep

    def device_inputs(self, prep: dict) -> list:
        """Every Dr.Jit array :meth:`channels_prepared` and :meth:`penalty` read: this field's
        parameters, the background's (its blockage reads them) and ``prep``'s arrays."""
        return (_jit_arrays(self.params) + [self._two_legs] + self.bg.device_inputs(prep["bg"])
                + _jit_arrays([prep["h"], prep.get("pres")]))

    def structure(self, prep: dict) -> tuple:
        """As :meth:`CoherentGaussianField.structure`, with this field's own settings."""
        return ("person", self.bg.structure(prep["bg"]), "pres" in prep, tuple(sorted(self.params)), repr(self.cfg))

    def channels_at(self, prep: dict, position) -> tuple:
        """:meth:`channels_prepared` with the person's feet at ``position`` instead of where the
        views put them: three Dr.Jit ``Float`` [B] columns x, y, z [m], one value per view. They may
        carry gradients: the channels are differentiable in the person's position (the blockage
        and the scatterers both follow it), which is what localisation descends on
        (:mod:`rfmitsuba.eval.locate`). Returns (re, im) ``Float`` [B*16]."""
        return self.channels_prepared({**prep, "h": list(position)})

    def channels_prepared(self, prep: dict) -> tuple:
        """The device part of :meth:`channels` from :meth:`prepare`'s ``prep``: (re, im) ``Float`` [B*16]."""
        import drjit as dr

        bg, c = self.bg, self.cfg
        hc = prep["h"]
        prep, pres = prep["bg"], prep.get("pres")
        bodies = [hc[3 * j:3 * j + 3] for j in range(len(hc) // 3)]       # each person's (x, y, z) columns
        each = [self._blockage(b) for b in bodies]

        def product(group, ln, s):                   # the blockages multiply: prod_j (1 + w_j) - 1
            total = 1.0
            for w in each:
                total = total * (1.0 + w(group, ln, s))
            return total - 1.0

        weight = each[0] if len(each) == 1 else product
        if pres is not None:
            change = weight

            def weight(group, ln, s):
                return 1.0 + dr.gather(B.Float, pres, ln["b"]) * change(group, ln, s)
        hr, hi = bg._paths(prep, weight=weight)
        K = c.num_points
        if K:
            ln = bg._lanes(prep, K)
            k, yb = ln["k"], ln["y"]
            o = self.params["sc_offset"]
            ext = (c.max_offset, c.max_offset, 0.5 * c.body_height)
            mid = (0.0, 0.0, 0.5 * c.body_height)
            amp = self.params["sc_amp"]
            on = 1.0 if pres is None else dr.gather(B.Float, pres, ln["b"])
            for body in bodies:                      # every person carries the same scatterers
                s = [dr.gather(B.Float, body[i], ln["b"]) + mid[i] + ext[i] * dr.tanh(dr.gather(B.Float, o, 3 * k + i))
                     for i in range(3)]
                lead = dr.sqrt(sum((yb[i] - s[i]) ** 2 for i in range(3)) + 1e-12)
                cr, ci = bg._propagate(prep, ln, s, lead, lead, dr.gather(B.Float, amp, 2 * k),
                                       dr.gather(B.Float, amp, 2 * k + 1), on)
                hr, hi = hr + cr, hi + ci
        return bg._calibrate(prep, hr, hi)

    @classmethod
    def render_family(cls, fields: list, views: Views, *, height: int, width: int, normalize: bool):
        """As :meth:`CoherentGaussianField.render_family` (channels summed, one Bartlett read-out)."""
        return CoherentGaussianField.render_family(fields, views, height=height, width=width, normalize=normalize)

    # ---- export ------------------------------------------------------------------------------
    def offsets(self) -> np.ndarray:
        """Where the scatterers are relative to the feet: float64 [K, 3] m."""
        c = self.cfg
        o = np.asarray(self.params["sc_offset"].numpy(), np.float64).reshape(-1, 3)
        return np.tanh(o) * [c.max_offset, c.max_offset, 0.5 * c.body_height] + [0, 0, 0.5 * c.body_height]

    def blockage(self) -> dict:
        """The learned blockage: {"strength": float64 [1 or S+P], "radius_m": float64 [1 or S+P]}."""
        lg = np.asarray(self.params["block_logit"].numpy(), np.float64)
        return {"strength": 1.0 / (1.0 + np.exp(-lg)),
                "radius_m": np.exp(np.asarray(self.params["block_log_radius"].numpy(), np.float64))}

    def export_ply(self, folder: str | Path, *, views: Views) -> list[Path]:
        """``sources.ply``: the body's scatterers at their offsets from the feet (metres), opacity
        their |gain| relative to the largest (none when there are no scatterers)."""
        if not self.cfg.num_points:
            return []
        a = np.asarray(self.params["sc_amp"].numpy(), np.float64).reshape(-1, 2)
        return [write_points_ply(Path(folder) / "sources.ply", self.offsets(), np.hypot(a[:, 0], a[:, 1]))]
