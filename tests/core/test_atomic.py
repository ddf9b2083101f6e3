"""Tests of rfmitsuba.core.atomic: whole-file replacement, no temporary file left behind."""
import json

import pytest

from rfmitsuba.core import atomic


def test_write_text_replaces_and_leaves_no_tmp(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    assert atomic.write_text(p, "new") == p
    assert p.read_text() == "new"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]


def test_write_json_options_pass_through(tmp_path):
    p = atomic.write_json(tmp_path / "m.json", {"b": 1, "a": 2}, sort_keys=True, end="\n")
    text = p.read_text()
    assert text == '{\n "a": 2,\n "b": 1\n}\n'
    assert json.loads(text) == {"a": 2, "b": 1}
    with pytest.raises(ValueError):
        atomic.write_json(tmp_path / "n.json", {"x": float("nan")}, allow_nan=False)
    assert not (tmp_path / "n.json").exists()
