"""The Field protocol every model implements, the views it renders, and the registry by name.

A *field* is a trainable model of what the array sees. Every model family implements
:class:`Field`; the trainer, the renderers and the experiments use only this protocol, so a
new model is one file in :mod:`rfmitsuba.models` that subclasses :class:`Field` (or a family
base) and is decorated with :func:`register`.

==========================  ====================================================================
member                      meaning
==========================  ====================================================================
``kind`` (class)            registry name, e.g. ``"splat"``, ``"coherent_perturb"``
``family`` (class)          fields of one family render together (:func:`render`): ``"splat"``
                            (Gaussians splatted into one image) or ``"coherent"`` (channels
                            summed at the elements, one Bartlett read-out)
``format`` (class)          the ``format`` tag of the saved ``.npz`` (:func:`load_field`)
``densify`` (class)         adaptive density control (clone, split, prune) applies
``person`` (class)          True for a Stage-2 person field: rendered only where a person is
                            present, its extra inputs are the person's features followed by
                            the feet position in metres
``position_input`` (class)  a field that is not a person field but takes the same extra inputs
                            (person features, then the feet position in metres), e.g. the
                            coherent Gaussian End-to-End model; it is rendered for every sample
``name``                    optimizer key prefix (``"bg"``, ``"person"``)
``extra_inputs``            number of per-view extra network inputs (0 = none)
``feature_octaves``         octaves of the person-position features it was trained with, or None
``frozen``                  True after :meth:`Field.freeze`
``num_primitives``          Gaussians, image sources or scatterers (what tables count)
``num_parameters``          trainable scalars, networks included
``network_parameters``      of which network weights
``parameters()``            name -> Dr.Jit ``Float`` of every parameter
``trainable()``             the same, empty after :meth:`Field.freeze`
``assign(values)``          set parameters (e.g. the optimizer's copies, keeping the AD link)
``freeze()``                exclude every parameter from training (values detached)
``state_dict()``            NumPy arrays that rebuild the field (``meta`` is a JSON string)
``load_state_dict(state)``  load such arrays into a field of the same architecture
``from_state_dict(state)``  (classmethod) rebuild a field
``save(path)`` / ``load``   one ``.npz`` file, written atomically; no pickle
``export_ply(folder, views=)``  PLY files a 3DGS viewer opens; returns their paths
``render_family(...)``      (classmethod) render fields of this family together (:func:`render`)
==========================  ====================================================================
"""
from __future__ import annotations

import importlib
import json
import pkgutil
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, ClassVar

import numpy as np

from ..core.atomic import write_npz
from ..core.errors import ConfigError, RunError
from ..core.legacy_names import current_name

#: registry name -> field class
FIELD_CLASSES: dict[str, type] = {}
#: saved-file format tag -> field class
FIELD_FORMATS: dict[str, type] = {}


def register(cls: type) -> type:
    """Class decorator: add a :class:`Field` subclass to the registry under ``cls.kind``."""
    for attr in ("kind", "family", "format"):
        if not isinstance(getattr(cls, attr, None), str):
            raise TypeError(f"{cls.__name__} must define the class attribute {attr!r} (a string) to be registered")
    FIELD_CLASSES[cls.kind] = cls
    FIELD_FORMATS[cls.format] = cls
    return cls


def _discover() -> None:
    """Import every module of :mod:`rfmitsuba.models`, so that each registers its fields."""
    from .. import models

    for m in pkgutil.iter_modules(models.__path__):
        importlib.import_module(f"{models.__name__}.{m.name}")


def field_class(kind: str) -> type:
    """The registered field class ``kind`` (ConfigError listing the known ones)."""
    _discover()
    if kind not in FIELD_CLASSES:
        raise ConfigError(f"unknown field kind {kind!r}; known: {', '.join(sorted(FIELD_CLASSES))}")
    return FIELD_CLASSES[kind]


def read_field_state(path: str | Path) -> dict:
    """The arrays of a saved field file (name -> array), every one read (RunError naming the file
    and the way out where it is missing or damaged, e.g. truncated)."""
    path = Path(path)
    if not path.is_file():
        raise RunError(f"field file {path} does not exist")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:
        raise RunError(f"{path}: not a readable field file ({type(e).__name__}: {e}); if it is a run's "
                       f"final field, delete {path.parent} and run the same `rfmitsuba train` again to write it "
                       "from the run's checkpoint") from None


def load_field(path: str | Path) -> "Field":
    """Read any saved field by the ``format`` in its metadata (RunError naming what is wrong)."""
    path = Path(path)
    state = read_field_state(path)
    if "meta" not in state:
        raise RunError(f"{path}: field file has no 'meta' entry")
    try:
        fmt = current_name(json.loads(str(state["meta"])).get("format"))
    except (json.JSONDecodeError, AttributeError):
        raise RunError(f"{path}: the field's 'meta' entry is not a JSON object") from None
    _discover()
    if fmt not in FIELD_FORMATS:
        raise RunError(f"{path}: unknown field format {fmt!r}; known: {', '.join(sorted(FIELD_FORMATS))}")
    return FIELD_FORMATS[fmt].from_state_dict(state)


def flat_parameters(state: dict, sizes: dict, *, owner: str) -> dict:
    """Parameter arrays of a saved state as Dr.Jit ``Float``: name -> ``Float`` [sizes[name]].

    Raises:
        RunError: a name missing from ``state``, a size mismatch or a non-finite value, naming
        ``owner`` (the field class) and the parameter.
    """
    from ..core import backend as B

    out = {}
    for k, n in sizes.items():
        if k not in state:
            raise RunError(f"{owner} state lacks {k!r}")
        v = np.asarray(state[k], np.float32).ravel()
        if v.shape != (n,) or not np.isfinite(v).all():
            raise RunError(f"{owner} state {k!r}: expected {n} finite values, got {v.shape}")
        out[k] = B.Float(v)
    return out


@dataclass
class Views:
    """B views to render: where the array, the transmitter and the moving device are.

    antenna_pos: float64 [B, 3] metres, the moving device (RX in the moving-RX task, TX in the
    moving-TX task); view_pos: float64 [B, 3] metres, the array centre; transmitter: float64
    [B, 3] metres; rx_to_world: float64 [3, 3] (the array frame's axes in the world) or None for
    the horizontal array; frequency_hz: carrier [Hz]; inputs: field -> float32 [B, E] extra
    network inputs of that field, or None (fields with ``extra_inputs == 0`` get None);
    task: "rx" (moving receiver) or "tx" (moving transmitter).
    """

    antenna_pos: np.ndarray
    view_pos: np.ndarray
    transmitter: np.ndarray
    rx_to_world: np.ndarray | None
    frequency_hz: float
    task: str = "rx"
    inputs: Callable[["Field"], np.ndarray | None] = lambda field: None

    @classmethod
    def of(cls, data, idx: np.ndarray, *, inputs: Callable[["Field"], np.ndarray | None] | None = None) -> "Views":
        """The views of indices ``idx`` of ``data`` (a :class:`~rfmitsuba.data.views.TrainData`
        or :class:`~rfmitsuba.data.samples.SampleData`)."""
        x, y, q = data.positions(idx)
        return cls(antenna_pos=q, view_pos=x, transmitter=y, rx_to_world=data.rx_to_world,
                   frequency_hz=float(data.frequency_hz), task=data.task, inputs=inputs or (lambda field: None))

    @property
    def count(self) -> int:
        """B, the number of views."""
        return int(np.shape(self.antenna_pos)[0])

    def extra(self, field: "Field") -> np.ndarray | None:
        """The extra inputs of ``field`` (None when it takes none)."""
        return self.inputs(field) if field.extra_inputs else None

    def moved(self, offsets: np.ndarray) -> "Views":
        """These views with the moving device displaced by ``offsets`` (float [B, 3] m): the
        array with the receiver in the moving-RX task, the transmitter in the moving-TX task.
        The extra inputs stay those of the original views."""
        d = np.asarray(offsets, np.float64).reshape(self.count, 3)
        if self.task == "rx":
            return replace(self, antenna_pos=self.antenna_pos + d, view_pos=self.view_pos + d)
        return replace(self, antenna_pos=self.antenna_pos + d, transmitter=self.transmitter + d)

    @staticmethod
    def concat(parts: list["Views"]) -> "Views":
        """One batch of the views of ``parts`` in order (one array frame, carrier and task)."""
        first = parts[0]
        if any(p.task != first.task or p.frequency_hz != first.frequency_hz
               or not np.array_equal(p.rx_to_world, first.rx_to_world) for p in parts[1:]):   # None too
            raise ValueError("Views.concat: the parts differ in task, carrier or array frame")

        def inputs(field):
            got = [p.inputs(field) for p in parts]
            return None if any(g is None for g in got) else np.concatenate([np.asarray(g) for g in got])

        return Views(antenna_pos=np.concatenate([p.antenna_pos for p in parts]),
                     view_pos=np.concatenate([p.view_pos for p in parts]),
                     transmitter=np.concatenate([p.transmitter for p in parts]), rx_to_world=first.rx_to_world,
                     frequency_hz=first.frequency_hz, task=first.task, inputs=inputs)


class Field:
    """Base class of every model (see the module table). Subclasses set the class attributes
    ``kind``, ``family`` and ``format`` and implement the methods that raise here."""

    kind: ClassVar[str]
    family: ClassVar[str]
    format: ClassVar[str]
    person: ClassVar[bool] = False
    position_input: ClassVar[bool] = False
    densify: ClassVar[bool] = False
    #: the block size of the training images this kind advises (``TrainConfig.downsample = "auto"``):
    #: it trains on (90/d) x (360/d) block means of the PAS; validation and evaluation stay at 90 x 360
    downsample_advised: ClassVar[int] = 1
    name: str = "bg"
    extra_inputs: int = 0
    frozen: bool = False

    @property
    def feature_octaves(self) -> int | None:
        return None

    @property
    def starts_advised(self) -> int:
        """Training starts this initial field advises (``TrainConfig.starts = "auto"``): 1 unless its
        start is known to lead training into local minima now and then (a subclass says why)."""
        return 1

    @property
    def jitter_advised(self) -> float:
        """Spread of the jittered copies of each training view this initial field advises
        (``TrainConfig.jitter = "auto"``), in carrier wavelengths: 0 (none) unless the field is known
        to change faster than its data between the training positions (a subclass says why;
        :mod:`rfmitsuba.train.jitter`)."""
        return 0.0

    @property
    def epochs_advised(self) -> float:
        """Least passes over the fitting positions this initial field advises
        (``TrainConfig.epochs = "auto"``): 0 (none) unless some of its parameters learn only from
        the views of a small part of the data (a subclass says why)."""
        return 0.0

    def decisions(self) -> list[tuple[str, object, str]]:
        """What this field decided for its configuration's "auto" options when it was built for
        training: ``(dotted TrainConfig option, value, reason)`` each, recorded in a run's
        ``resolved.toml`` (:mod:`rfmitsuba.train.resolve`); none unless a subclass sets
        ``self._decisions``."""
        return list(getattr(self, "_decisions", ()))

    def penalty(self):
        """A regularisation term the trainer adds to each step's loss (Dr.Jit ``Float`` [1],
        differentiable in the field's parameters), or None (the default: no term)."""
        return None

    # ---- parameters --------------------------------------------------------------------
    @property
    def num_primitives(self) -> int:
        raise NotImplementedError

    @property
    def num_parameters(self) -> int:
        raise NotImplementedError

    @property
    def network_parameters(self) -> int:
        raise NotImplementedError

    def parameters(self) -> dict:
        raise NotImplementedError

    def trainable(self) -> dict:
        """Parameters the optimizer may change (empty after :meth:`freeze`)."""
        return {} if self.frozen else self.parameters()

    def assign(self, values: dict) -> None:
        raise NotImplementedError

    @staticmethod
    def lr_group(name: str) -> str:
        """The learning-rate schedule of parameter ``name`` (a key of the trainer's learning
        rates: "means", "log_scales", "rotations", "opacity_logits", "amp", "embed", "offsets" or
        "net"). Default: "net" for packed network weights (names with a dot), else the name."""
        return "net" if "." in name else name

    def freeze(self) -> None:
        raise NotImplementedError

    # ---- state -------------------------------------------------------------------------
    def state_dict(self) -> dict:
        raise NotImplementedError

    def load_state_dict(self, state: dict) -> None:
        raise NotImplementedError

    @classmethod
    def from_state_dict(cls, state: dict) -> "Field":
        raise NotImplementedError

    def save(self, path: str | Path) -> Path:
        """Write :meth:`state_dict` to an ``.npz`` file atomically."""

        return write_npz(Path(path), self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> "Field":
        """Read a field of this class written by :meth:`save`."""
        f = load_field(path)
        if not isinstance(f, cls):
            raise RunError(f"{path} holds a {type(f).__name__}, not a {cls.__name__}")
        return f

    # ---- rendering and export -------------------------------------------------------------
    @classmethod
    def render_family(cls, fields: list["Field"], views: Views, *, height: int, width: int, normalize: bool):
        raise NotImplementedError

    def export_ply(self, folder: str | Path, *, views: Views) -> list[Path]:
        raise NotImplementedError


class FlatParameterField(Field):
    """A field whose parameters are plain Dr.Jit ``Float`` arrays in ``self.params`` (name -> array,
    sizes from ``_sizes()``), with one optimizer group per name in the class's ``LR_GROUPS``:
    assignment, freezing and loading shared by such fields."""

    #: parameter name -> optimizer group (the trainer's learning-rate schedule)
    LR_GROUPS: ClassVar[dict] = {}

    @classmethod
    def lr_group(cls, name: str) -> str:
        """The optimizer group (learning-rate schedule) of parameter ``name``."""
        return cls.LR_GROUPS[name]

    @property
    def num_parameters(self) -> int:
        return sum(self._sizes().values())

    @property
    def network_parameters(self) -> int:
        return 0

    def parameters(self) -> dict:
        return dict(self.params)

    def trainable(self) -> dict:
        """Every non-empty parameter (none when frozen)."""
        if self.frozen:
            return {}
        return {k: v for k, v in self.params.items() if self._sizes()[k] > 0}

    def assign(self, values: dict) -> None:
        for k, v in values.items():
            if k not in self.params:
                raise ConfigError(f"{type(self).__name__} has no parameter {k!r}")
            self.params[k] = v

    def freeze(self) -> None:
        import drjit as dr

        self.frozen = True
        for k in list(self.params):
            self.params[k] = dr.detach(self.params[k])

    def load_state_dict(self, state: dict) -> None:
        self.params.update(flat_parameters(state, self._sizes(), owner=type(self).__name__))


def render(fields: list[Field], views: Views, *, height: int = 90, width: int = 360, normalize: bool = True):
    """PAS of ``fields`` rendered together for ``views``: ``TensorXf`` [B, height, width],
    differentiable in every trainable parameter.

    All fields must be of one family: splat fields are splatted into one image, coherent fields
    add their channels before one Bartlett read-out. ``normalize``: the image on the scale the
    training loss compares with the min-max normalised truth (coherent: min-max per image;
    splat: its output already is on that scale and is returned as it is); False: raw.
    """
    if not fields:
        raise ConfigError("render: no fields")
    families = {f.family for f in fields}
    if len(families) != 1:
        raise ConfigError(f"render: fields of different families cannot be rendered together: {sorted(families)}")
    return type(fields[0]).render_family(fields, views, height=height, width=width, normalize=normalize)


class FieldSet:
    """Trained fields rendered together on a dataset's samples: the renderer that a finished
    run (:func:`rfmitsuba.train.trainer.load_run`) or a method's job gives back.

    Args:
        fields: fields of one family, the background first; person fields
            (``Field.person``) are rendered only for samples with a person present.
        octaves: octaves of the person-position features of fields with extra inputs that are
            not person fields (the End-to-End model); person fields and fields with
            ``position_input`` use their own ``feature_octaves``.
    """

    def __init__(self, fields: list[Field], *, octaves: int = 3):
        if not fields:
            raise ConfigError("FieldSet: no fields")
        self.fields = list(fields)
        self.octaves = int(octaves)

    @property
    def num_primitives(self) -> int:
        """Primitives of all fields together."""
        return sum(f.num_primitives for f in self.fields)

    def _inputs(self, data, k: np.ndarray):
        def inputs(field: Field):
            raw = field.person or field.position_input
            octaves = field.feature_octaves if raw else self.octaves
            people = getattr(field, "people", 1)
            if people > 1:
                return data.features(k, octaves=octaves, raw=raw, people=people)
            return data.features(k, octaves=octaves, raw=raw)

        return inputs

    def render(self, data, idx: np.ndarray, *, batch: int = 8, h: int = 90, w: int = 360) -> np.ndarray:
        """Raw predicted PAS at indices ``idx`` of ``data``: float32 [K, h, w].

        ``data`` is a :class:`~rfmitsuba.data.views.TrainData` (one state) or a
        :class:`~rfmitsuba.data.samples.SampleData` (``states``: 0 = the empty room, where
        person fields are left out and extra inputs are the "no person" features)."""
        import drjit as dr

        idx = np.asarray(idx, np.int64)
        out = np.zeros((len(idx), h, w), np.float32)
        states = getattr(data, "states", None)
        empty = states[idx] == 0 if states is not None else np.full(len(idx), getattr(data, "state", 0) == 0)
        for group in (np.flatnonzero(empty), np.flatnonzero(~empty)):
            for i in range(0, len(group), batch):
                sel = group[i:i + batch]
                k = idx[sel]
                fields = [f for f in self.fields if not (f.person and empty[sel[0]])]
                views = Views.of(data, k, inputs=self._inputs(data, k))
                with dr.suspend_grad():
                    img = render(fields, views, height=h, width=w, normalize=False)
                out[sel] = np.asarray(img.numpy(), np.float32).reshape(-1, h, w)
        return out
