"""Tests of rfmitsuba.core.config: typed dataclass configs round-trip to TOML and JSON."""
from dataclasses import dataclass, field
from typing import Literal, Optional

import pytest

from rfmitsuba.core import config
from rfmitsuba.core.errors import ConfigError


@dataclass
class Inner:
    lr: float = 1e-3
    schedule: Literal["const", "exp"] = "exp"


@dataclass
class Outer:
    name: str = "run"
    iterations: int = 100
    seeds: list[int] = field(default_factory=lambda: [0, 1])
    shape: tuple[int, int] = (90, 360)
    limit: Optional[float] = None
    inner: Inner = field(default_factory=Inner)


def test_round_trip_toml_json():
    cfg = Outer(name="x", iterations=5, seeds=[3], limit=2.5, inner=Inner(lr=0.1, schedule="const"))
    assert config.from_toml(Outer, config.to_toml(cfg)) == cfg
    assert config.from_json(Outer, config.to_json(cfg)) == cfg
    assert config.from_toml(Outer, config.to_toml(Outer())) == Outer()


def test_file_round_trip(tmp_path):
    cfg = Outer(iterations=7)
    for suffix in (".toml", ".json"):
        config.save(cfg, tmp_path / f"c{suffix}")
        assert config.load(Outer, tmp_path / f"c{suffix}") == cfg


@pytest.mark.parametrize("text, match", [
    ("iterations = 'ten'", "Outer.iterations: expected an integer"),
    ("bogus = 1", "unknown option"),
    ("[inner]\nschedule = 'cosine'", "Outer.inner.schedule"),
    ("shape = [1, 2, 3]", "expected 2 items"),
    ("iterations = ", "malformed TOML"),
])
def test_bad_input_names_key(text, match):
    with pytest.raises(ConfigError, match=match):
        config.from_toml(Outer, text)


def test_override():
    cfg = config.override(Outer(), ["inner.lr=0.5", "name=abc", "seeds=[4,5]"])
    assert cfg.inner.lr == 0.5 and cfg.name == "abc" and cfg.seeds == [4, 5]
    with pytest.raises(ConfigError, match="unknown option 'nope'"):
        config.override(Outer(), ["inner.nope=1"])


def test_differences_walks_nested_dicts_first_keys_first_and_lists_when_asked():
    from rfmitsuba.core.config import differences

    a = {"z": 1, "a": {"x": [1, 2], "y": 0}, "task": "rx"}
    b = {"z": 2, "a": {"x": [1, 3]}, "task": "tx"}
    assert list(differences(a, b)) == [("a.x", [1, 2], [1, 3]), ("a.y", 0, "<missing>"), ("task", "rx", "tx"),
                                       ("z", 1, 2)]
    assert list(differences(a, b, first=("task",), into_lists=True))[:2] == [("task", "rx", "tx"), ("a.x[1]", 2, 3)]
    assert list(differences(a, a)) == []
    assert list(differences([1, 2], [1, 2, 3], into_lists=True)) == [("<root>", [1, 2], [1, 2, 3])]
