"""The End-to-End model of the coherent Gaussian family: one field, background and person trained
together in a single stage on person-present data, the person's position as its input.

It is the paper's End-to-End comparison (a single-stage model trained on person-present data with
the person location as a direct input) built from the same two parts as Ours, so that the
comparison isolates the training strategy and nothing else:

* the background, a :class:`~rfmitsuba.models.coherent_gaussians.CoherentGaussianField`
  (image sources, scatterers, calibration, pose), **trainable**;
* the person, a :class:`~rfmitsuba.models.coherent_gaussians_person.CoherentGaussianPersonField`
  on that same background (body scatterers and blockage of the background's paths), also
  trainable.

Ours trains the first on the empty room, freezes it and trains the second on the walk; this field
trains both at once on every sample, empty room and walk alike. Its channels are the background's
plus, where a person is present, the person field's change::

    h = h_bg + present * (h_bg,blocked - h_bg + h_scatterers)

``present`` is the presence flag of the person features (1 with a person, 0 in the empty room,
:func:`rfmitsuba.data.samples.person_features`), so an empty-room view renders the background alone.
It is computed in one pass over the background's sources, each term weighted ``1 + present *
(blockage - 1)`` (:meth:`CoherentGaussianPersonField.channels` with ``with_background``), not as
two renders of them.

Parameters: the background's, named ``room.<name>``, and the person field's, named
``person.<name>``, each in its own part's optimizer group (the module tables of
:mod:`~rfmitsuba.models.coherent_gaussians` and
:mod:`~rfmitsuba.models.coherent_gaussians_person` give units). All are differentiable;
tests/models/test_coherent_gaussians_joint.py checks both parts against finite differences.

Per-view input ``extra``: float [B, F + 3], the person features (F =
``num_person_features(person_octaves)``, presence flag last) followed by the feet position [m],
as for the person field (:attr:`Field.position_input`).
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np

from ..core.config import from_dict
from ..core.errors import ConfigError, RunError
from .base import Field, Views, register
from .coherent_gaussians import CoherentGaussianField
from .coherent_gaussians_person import CoherentGaussianPersonConfig, CoherentGaussianPersonField

FORMAT = "rfmitsuba-coherent-gaussians-joint/1"
#: parameter name prefixes of the two parts
ROOM, PERSON = "room.", "person."


@register
class CoherentGaussianJointField(Field):
    """Background and person trained together (see the module docstring).

    Args:
        bg: the background field (trainable; its ``name`` is ignored).
        person: a person field on ``bg`` (``person.bg is bg``).
        name: optimizer key prefix.
    """

    kind = "coherent_gaussians_joint"
    family = "coherent_gaussians"
    format = FORMAT
    position_input = True

    def __init__(self, bg: CoherentGaussianField, person: CoherentGaussianPersonField, *, name: str = "bg"):
        if not isinstance(bg, CoherentGaussianField) or not isinstance(person, CoherentGaussianPersonField):
            raise ConfigError("the joint coherent Gaussian field needs a coherent_gaussians background and a "
                              f"coherent_gaussians_person field, got {type(bg).__name__} and {type(person).__name__}")
        if person.bg is not bg:
            raise ConfigError("the joint coherent Gaussian field's person field must be built on its background")
        self.bg, self.person_field = bg, person
        self.readout, self.frequency_hz = bg.readout, bg.frequency_hz
        self.extra_inputs = person.extra_inputs
        self.name = name
        self.frozen = False

    @classmethod
    def for_training(cls, cfg, data, *, scene_xml=None, rng: np.random.Generator | None = None,
                     extra_inputs: int = 0, name: str = "bg",
                     person: CoherentGaussianPersonConfig | None = None) -> "CoherentGaussianJointField":
        """The initial joint field: the background as Stage 1 starts it
        (:meth:`CoherentGaussianField.for_training` on ``data``'s training samples) and a fresh
        person field on it (:meth:`CoherentGaussianPersonField.for_background`, config ``person``).

        ``extra_inputs``: 0, or the person field's width (features + 3); anything else is a
        ConfigError naming both."""
        bg = CoherentGaussianField.for_training(cfg, data, scene_xml=scene_xml, rng=rng, name=name)
        pf = CoherentGaussianPersonField.for_background(bg, cfg=person, seed=cfg.seed)
        if extra_inputs and extra_inputs != pf.extra_inputs:
            raise ConfigError(f"joint coherent Gaussian field: {extra_inputs} extra inputs given, its person field "
                              f"takes {pf.extra_inputs} (features with {pf.cfg.person_octaves} octaves + position)")
        return cls(bg, pf, name=name)

    @classmethod
    def from_person(cls, person: CoherentGaussianPersonField, *, name: str = "bg") -> "CoherentGaussianJointField":
        """Stage 3: a trained person field and its (frozen) background, both made trainable again
        as one joint field (their values kept)."""
        if not isinstance(person, CoherentGaussianPersonField):
            raise ConfigError(f"from_person needs a coherent_gaussians_person field, got {type(person).__name__}")
        person.frozen = person.bg.frozen = False
        return cls(person.bg, person, name=name)

    # ---- parameters ------------------------------------------------------------------------
    @property
    def feature_octaves(self) -> int:
        return self.person_field.cfg.person_octaves

    @property
    def num_primitives(self) -> int:
        """Background sources plus body scatterers."""
        return self.bg.num_primitives + self.person_field.num_primitives

    @property
    def num_parameters(self) -> int:
        return self.bg.num_parameters + self.person_field.num_parameters

    @property
    def network_parameters(self) -> int:
        return 0

    def _parts(self):
        return ((ROOM, self.bg), (PERSON, self.person_field))

    def parameters(self) -> dict:
        return {p + k: v for p, f in self._parts() for k, v in f.parameters().items()}

    def trainable(self) -> dict:
        if self.frozen:
            return {}
        return {p + k: v for p, f in self._parts() for k, v in f.trainable().items()}

    def _split(self, name: str):
        for p, f in self._parts():
            if name.startswith(p):
                return f, name[len(p):]
        raise ConfigError(f"CoherentGaussianJointField has no parameter {name!r} (names start with "
                          f"{ROOM!r} or {PERSON!r})")

    def lr_group(self, name: str) -> str:
        """The optimizer group of parameter ``name``: its part's own group."""
        f, k = self._split(name)
        return f.lr_group(k)

    def assign(self, values: dict) -> None:
        for name, v in values.items():
            f, k = self._split(name)
            f.assign({k: v})

    def freeze(self) -> None:
        self.frozen = True
        self.bg.freeze()
        self.person_field.freeze()

    # ---- state -------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        out = {ROOM + k: v for k, v in self.bg.state_dict().items()}
        out.update({PERSON + k: v for k, v in self.person_field.state_dict().items() if not k.startswith("bg.")})
        out["meta"] = np.asarray(json.dumps({"format": FORMAT, "name": self.name, "frozen": self.frozen}))
        return out

    def load_state_dict(self, state: dict) -> None:
        self.bg.load_state_dict({k[len(ROOM):]: v for k, v in state.items() if k.startswith(ROOM)})
        self.person_field.load_state_dict({k[len(PERSON):]: v for k, v in state.items() if k.startswith(PERSON)})

    @classmethod
    def from_state_dict(cls, state: dict) -> "CoherentGaussianJointField":
        try:
            meta = json.loads(str(state["meta"]))
            if meta.get("format") != FORMAT:
                raise RunError(f"not a CoherentGaussianJointField state (format {meta.get('format')!r})")
            bg = CoherentGaussianField.from_state_dict({k[len(ROOM):]: v for k, v in state.items()
                                                        if k.startswith(ROOM)})
            pst = {k[len(PERSON):]: v for k, v in state.items() if k.startswith(PERSON)}
            pmeta = json.loads(str(pst["meta"]))
            pf = CoherentGaussianPersonField(bg, cfg=from_dict(CoherentGaussianPersonConfig, pmeta["config"], saved=True),
                                             reference_amplitude=pmeta["reference_amplitude"], seed=pmeta["seed"],
                                             name=pmeta.get("name", "person"), params=pst)
        except KeyError as e:
            raise RunError(f"CoherentGaussianJointField state lacks {e}") from None
        f = cls(bg, pf, name=meta.get("name", "bg"))
        if meta.get("frozen"):
            f.freeze()
        return f

    # ---- evaluation --------------------------------------------------------------------------
    def person_inputs(self, views: Views) -> np.ndarray:
        """The views' person inputs, checked: float32 [B, F + 3] (ConfigError on missing or
        misshapen inputs)."""
        e = views.extra(self)
        if e is None or np.shape(e) != (views.count, self.extra_inputs):
            raise ConfigError(f"joint coherent Gaussian field: extra inputs must be [B, {self.extra_inputs}] "
                              f"(person features, then the feet position in metres) for B = {views.count} views, "
                              f"got {None if e is None else np.shape(e)}")
        return np.asarray(e, np.float32)

    def presence(self, inputs: np.ndarray) -> np.ndarray:
        """1 where a person is present, 0 in the empty room: float32 [B], from
        :meth:`person_inputs` (the presence flag, the last person feature)."""
        return (inputs[:, self.extra_inputs - 4] > 0.5).astype(np.float32)

    def channels(self, views: Views) -> tuple:
        """Calibrated channels at the 16 elements (see the module docstring): (re, im) ``Float``
        [B*16], differentiable in both parts' parameters."""
        return self.channels_prepared(self.prepare(views))

    # ---- :meth:`channels` in its host part and its device part (rfmitsuba.train.frozen_step) ---
    freezable = True

    def prepare(self, views: Views) -> dict:
        """The host part of :meth:`channels`: the background's alone (``"bg"``) where nobody is
        present in any view, else the person field's with the presence (``"person"``)."""
        e = self.person_inputs(views)
        present = self.presence(e)
        if not present.any():
            return {"bg": self.bg.prepare(views)}
        # one pass over the background's sources: each term weighted 1 + presence * (blockage - 1)
        pv = dataclasses.replace(views, inputs=lambda field: e)
        return {"person": self.person_field.prepare(pv, with_background=present)}

    def _part(self, prep: dict) -> tuple:
        """The field :meth:`prepare` handed the views to and its ``prep``: (field, prep)."""
        return (self.bg, prep["bg"]) if "bg" in prep else (self.person_field, prep["person"])

    def channels_prepared(self, prep: dict) -> tuple:
        """The device part of :meth:`channels` from :meth:`prepare`'s ``prep``."""
        field, sub = self._part(prep)
        return field.channels_prepared(sub)

    def device_inputs(self, prep: dict) -> list:
        """Every Dr.Jit array :meth:`channels_prepared` and :meth:`penalty` read."""
        field, sub = self._part(prep)
        return field.device_inputs(sub)

    def structure(self, prep: dict) -> tuple:
        """The background's or the person field's structure, and which."""
        field, sub = self._part(prep)
        return ("joint", type(field).__name__, field.structure(sub))

    def read_out_channels(self, h_re, h_im, **kw):
        """The background's read-out (:meth:`CoherentGaussianField.read_out_channels`)."""
        return self.bg.read_out_channels(h_re, h_im, **kw)

    def read_out_inputs(self, **kw) -> list:
        return self.bg.read_out_inputs(**kw)

    @classmethod
    def render_family(cls, fields: list, views: Views, *, height: int, width: int, normalize: bool):
        """As :meth:`CoherentGaussianField.render_family` (channels summed, one Bartlett read-out)."""
        return CoherentGaussianField.render_family(fields, views, height=height, width=width, normalize=normalize)

    def export_ply(self, folder, *, views: Views) -> list:
        """The background's ``sources.ply`` (the body's scatterers move with the person)."""
        return self.bg.export_ply(folder, views=views)
