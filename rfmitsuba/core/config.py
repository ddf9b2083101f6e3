"""Typed configuration dataclasses that round-trip to TOML and JSON.

Every config in rfmitsuba is a (possibly nested) ``@dataclass``. Fields may be
``bool``, ``int``, ``float``, ``str``, ``Optional[...]``, ``list[...]``/``tuple[...]``
of those, or another dataclass. :func:`from_dict` checks types and rejects
unknown keys with a :class:`~rfmitsuba.core.errors.ConfigError` naming the key; no
``eval`` and no pickle are involved.

Renamed and removed options: a config class may name the options it renamed in a class
attribute ``renamed_options`` (old name -> new name), and list the options it no longer has in
``removed_options`` (option -> the value under which it behaved as the code does now, or None
where the option only steered training) and the values it no longer takes in
``removed_values`` (option -> {old value: the value that rebuilds the same thing}), and the values it
renamed in ``renamed_values`` (option -> {old value: new value}). An option or section whose name
holds a word that changed (:mod:`rfmitsuba.core.legacy_names`: ``human`` is ``person`` now) is
renamed the same way. A saved file
(``saved=True``: a run's ``config.toml``, a field's state) that names them loads without them
where that is exact, and is refused, naming the option, where it is not; a user's file that names
a removed option is told so.

Example::

    @dataclass
    class Train:
        iterations: int = 3000
        lr: float = 1e-3

    cfg = from_toml(Train, 'iterations = 10')
    assert from_toml(Train, to_toml(cfg)) == cfg
"""
from __future__ import annotations

import contextvars
import dataclasses
import json
import math
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import tomli_w
import tomllib

from .atomic import write_text
from .errors import ConfigError
from .legacy_names import current_name

T = TypeVar("T")

#: True while a saved file is read (:func:`from_dict` with ``saved=True``): removed options load
_READING_SAVED = contextvars.ContextVar("rfmitsuba_reading_saved", default=False)


def to_dict(cfg: Any) -> dict:
    """Plain ``dict`` of a config dataclass (tuples become lists, ``None`` fields are kept)."""
    if not dataclasses.is_dataclass(cfg):
        raise ConfigError(f"expected a dataclass instance, got {type(cfg).__name__}")
    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = _plain(v)
    return out


def _plain(v: Any) -> Any:
    if dataclasses.is_dataclass(v):
        return to_dict(v)
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    return v


def _check(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _check(a, value, where)
            except ConfigError as e:
                errors.append(str(e))
        raise ConfigError(f"{where}: {value!r} matches none of {tp}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: {value!r} is not one of {list(args)}")
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{where}: expected {len(args)} items, got {len(value)}")
            return tuple(_check(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
        item = args[0] if args else Any
        seq = [_check(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(seq) if origin is tuple else seq
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {type(value).__name__}")
        kt, vt = args if args else (Any, Any)
        return {k: _check(vt, v, f"{where}.{k}") for k, v in value.items()}
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table for {tp.__name__}, got {type(value).__name__}")
        return from_dict(tp, value, where=where)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if isinstance(tp, type) and not isinstance(value, tp):
        raise ConfigError(f"{where}: expected {tp.__name__}, got {type(value).__name__}")
    return value


def _new_name(owner: type | None, name: str) -> str | None:
    """What option ``name`` of config class ``owner`` is called now, or None where it was not
    renamed (``renamed_options``, or a changed word: :func:`rfmitsuba.core.legacy_names.current_name`)."""
    new = getattr(owner, "renamed_options", {}).get(name)
    if new is None and current_name(name) != name:
        new = current_name(name)
    return new


def _without_removed(cls: type, data: dict, where: str) -> dict:
    """``data`` without the options ``cls`` removed, and with its removed values replaced (the
    module docstring); ConfigError where that would not rebuild the same thing, or where a user's
    file names a removed option."""
    removed = getattr(cls, "removed_options", {})
    values = getattr(cls, "removed_values", {})
    renamed_values = getattr(cls, "renamed_values", {})
    saved = _READING_SAVED.get()
    out = {}
    for k, v in data.items():
        new = _new_name(cls, k)
        if new is not None:
            if not saved:
                raise ConfigError(f"{where}.{k}: this option is called {new!r} now (see the changelog)")
            if new in data:
                raise ConfigError(f"{where}: both {k!r} and its new name {new!r}")
            k = new
        if k in renamed_values:
            v = _renamed_value(v, renamed_values[k], saved=saved, where=f"{where}.{k}")
        if k in removed:
            same = removed[k]
            if not saved:
                raise ConfigError(f"{where}.{k}: this option was removed (it did not help; see the changelog); "
                                  f"delete it from the configuration")
            if same is not None and v != same:
                raise ConfigError(f"{where}.{k} = {v!r}: this saved file used an option that was removed; this "
                                  f"version cannot rebuild what it made (only {same!r} loads)")
            continue
        if k in values and _hashable_scalar(v) and v in values[k]:
            if not saved:
                raise ConfigError(f"{where}.{k} = {v!r}: this value was removed (it did not help; see the "
                                  f"changelog)")
            v = values[k][v]
        out[k] = v
    return out


def _renamed_value(v, renamed: dict, *, saved: bool, where: str):
    """``v`` (a value, or a list of values) with the values in ``renamed`` (old -> new) replaced
    where reading a saved file; ConfigError naming the new value in a user's file."""
    if isinstance(v, list):
        return [_renamed_value(x, renamed, saved=saved, where=where) for x in v]
    if _hashable_scalar(v) and v in renamed:
        if not saved:
            raise ConfigError(f"{where} = {v!r}: this value is called {renamed[v]!r} now (see the changelog)")
        return renamed[v]
    return v


def _hashable_scalar(v) -> bool:
    return v is None or (isinstance(v, (int, float, str)) and not isinstance(v, bool))


def from_dict(cls: type[T], data: dict, *, where: str | None = None, saved: bool | None = None) -> T:
    """Build config ``cls`` from ``data``, checking every type; unknown keys are an error.

    ``saved``: ``data`` comes from a file this package wrote (removed options load, the module
    docstring); None: as the enclosing call says (False at the top).
    """
    if saved is not None:
        token = _READING_SAVED.set(saved)
        try:
            return from_dict(cls, data, where=where)
        finally:
            _READING_SAVED.reset(token)
    where = where or cls.__name__
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {type(data).__name__}")
    data = _without_removed(cls, data, where)
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"{where}: unknown option(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}")
    kwargs = {k: _check(hints[k], v, f"{where}.{k}") for k, v in data.items()}
    try:
        return cls(**kwargs)
    except TypeError as e:  # missing required field
        raise ConfigError(f"{where}: {e}") from None


def _drop_none(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _drop_none(v) for k, v in d.items() if v is not None}
    if isinstance(d, list):
        return [_drop_none(v) for v in d]
    return d


def to_toml(cfg: Any) -> str:
    """TOML text of a config (``None`` fields are omitted: they take their default when read)."""
    return tomli_w.dumps(_drop_none(to_dict(cfg)))


def from_toml(cls: type[T], text: str, *, saved: bool = False) -> T:
    """Parse TOML text into config ``cls`` (``saved``: as :func:`from_dict`)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{cls.__name__}: malformed TOML: {e}") from None
    return from_dict(cls, data, saved=saved)


def to_json(cfg: Any) -> str:
    """JSON text of a config."""
    return json.dumps(to_dict(cfg), indent=2, sort_keys=True, allow_nan=False)


def from_json(cls: type[T], text: str, *, saved: bool = False) -> T:
    """Parse JSON text into config ``cls`` (``saved``: as :func:`from_dict`)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(f"{cls.__name__}: malformed JSON: {e}") from None
    return from_dict(cls, data, saved=saved)


def load(cls: type[T], path: str | Path, *, saved: bool = False) -> T:
    """Read a ``.toml`` or ``.json`` file into config ``cls`` (``saved``: a file this package
    wrote, such as a run's ``config.toml``: as :func:`from_dict`)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file {path} does not exist")
    text = path.read_text()
    return from_json(cls, text, saved=saved) if path.suffix == ".json" else from_toml(cls, text, saved=saved)


def save(cfg: Any, path: str | Path) -> None:
    """Write a config to ``.toml`` or ``.json`` atomically (write, then rename)."""
    path = Path(path)
    write_text(path, to_json(cfg) if path.suffix == ".json" else to_toml(cfg))


def override(cfg: T, assignments: list[str]) -> T:
    """Apply ``key.sub=value`` overrides (values parsed as TOML literals) to a config.

    Used by the CLI's ``--set`` option, e.g. ``--set train.iterations=500``.
    """
    data = to_dict(cfg)
    for item in assignments:
        if "=" not in item:
            raise ConfigError(f"override {item!r} is not of the form key=value")
        key, raw = item.split("=", 1)
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw  # bare strings need no quotes on the command line
        node, owner = data, type(cfg)
        parts = key.strip().split(".")
        for p in parts[:-1]:
            if not isinstance(node.get(p), dict):
                if _new_name(owner, p) is not None:
                    raise ConfigError(f"override {key!r}: the section {p!r} is called "
                                      f"{_new_name(owner, p)!r} now (see the changelog)")
                raise ConfigError(f"override {key!r}: {p!r} is not a section of {type(cfg).__name__}")
            node, owner = node[p], typing.get_type_hints(owner).get(p)
        if parts[-1] not in node:
            if _new_name(owner, parts[-1]) is not None:
                raise ConfigError(f"override {key!r}: {parts[-1]!r} is called "
                                  f"{_new_name(owner, parts[-1])!r} now (see the changelog)")
            if parts[-1] in getattr(owner, "removed_options", {}):
                raise ConfigError(f"override {key!r}: {parts[-1]}: this option was removed (it did not help; see "
                                  "the changelog)")
            raise ConfigError(f"override {key!r}: unknown option {parts[-1]!r}")
        node[parts[-1]] = value
    return from_dict(type(cfg), data)


def differences(a: Any, b: Any, prefix: str = "", *, first: tuple = (), into_lists: bool = False):
    """(dotted key, value in ``a``, value in ``b``) for every place where two nested dicts differ:
    keys in ``first`` (in that order) before the others (sorted); "<missing>" where one lacks a key.
    ``into_lists``: lists of the same length are compared element by element (``key[i]``), else
    as values."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = sorted(set(a) | set(b))
        for k in [k for k in first if k in keys] + [k for k in keys if k not in first]:
            va, vb = a.get(k, "<missing>"), b.get(k, "<missing>")
            yield from differences(va, vb, f"{prefix}{k}.", first=first, into_lists=into_lists)
        return
    key = prefix.rstrip(".") or "<root>"
    if into_lists and isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            yield from differences(x, y, f"{key}[{i}].", first=first, into_lists=True)
    elif a != b:
        yield key, a, b


def finite(value: float, name: str) -> float:
    """Return ``value`` or raise :class:`ConfigError` if it is NaN or infinite."""
    if not math.isfinite(value):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    return value
