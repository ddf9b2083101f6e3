"""Tests of rfmitsuba.core.progress: bars show unless asked to be quiet."""
import pytest

from rfmitsuba.core.progress import bar


def test_bar_counts_and_shows_by_default(monkeypatch):
    monkeypatch.delenv("RFMITSUBA_QUIET", raising=False)
    with bar(3, desc="work", unit="job") as b:
        for _ in range(3):
            b.update(1)
        assert not b.disable and b.n == 3 and b.unit == "job" and b.desc == "work"


@pytest.mark.parametrize("env, quiet, disabled", [("1", False, True), ("0", False, False), ("", False, False),
                                                  (None, True, True), ("yes", False, True)])
def test_quiet_by_keyword_or_environment(monkeypatch, env, quiet, disabled):
    if env is None:
        monkeypatch.delenv("RFMITSUBA_QUIET", raising=False)
    else:
        monkeypatch.setenv("RFMITSUBA_QUIET", env)
    with bar(2, quiet=quiet) as b:
        assert b.disable is disabled
