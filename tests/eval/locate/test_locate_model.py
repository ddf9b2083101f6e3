"""rfmitsuba.eval.locate.model: opening a two-stage job, and refusing other folders by name."""
from __future__ import annotations

import pytest

from rfmitsuba.core.errors import RunError


def test_open_two_stage_refuses_other_folders(tmp_path):
    from rfmitsuba.eval.locate import open_two_stage

    (tmp_path / "train").mkdir()
    with pytest.raises(RunError, match="another method's job"):
        open_two_stage(tmp_path)
    (tmp_path / "stage1.json").write_text("{}")
    with pytest.raises(RunError, match="Stage 2 has not finished"):
        open_two_stage(tmp_path)
