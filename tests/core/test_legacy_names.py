"""Files written when the walking body was called "human" still read (rfmitsuba.core.legacy_names)."""
import shutil

import numpy as np
import pytest

from rfmitsuba.core import config as C
from rfmitsuba.core.errors import ConfigError
from rfmitsuba.core.legacy_names import current_keys, current_name


def test_current_name_replaces_the_old_words_inside_names():
    assert current_name("human_pos") == "person_pos"
    assert current_name("num_humans") == "num_people"
    assert current_name("--human-positions") == "--person-positions"
    assert current_name("rfmitsuba-coherent-human-field/1") == "rfmitsuba-coherent-person-field/1"
    assert current_name("person_pos") == "person_pos"
    assert current_name(3) == 3


def test_current_keys_renames_keys_at_every_depth_and_keeps_values():
    old = {"human_positions": [[1, 2, 0]], "config": {"human_margin": 0.1, "scene": "human"}, "l": [{"human": 1}]}
    assert current_keys(old) == {"person_positions": [[1, 2, 0]], "config": {"person_margin": 0.1, "scene": "human"},
                                 "l": [{"person": 1}]}


def test_a_saved_config_with_old_option_names_loads_and_a_users_file_is_told_the_new_name():
    from rfmitsuba.experiments.methods import MethodConfig

    saved = {"human": {"human_octaves": 2, "anchor": "human"}, "coherent_gaussians_human": {"human_octaves": 4}}
    cfg = C.from_dict(MethodConfig, saved, saved=True)
    assert cfg.person.person_octaves == 2 and cfg.person.anchor == "person"
    assert cfg.coherent_gaussians_person.person_octaves == 4
    with pytest.raises(ConfigError, match="'person' now"):
        C.from_dict(MethodConfig, {"human": {}})
    with pytest.raises(ConfigError, match="is called 'person' now"):
        C.from_dict(MethodConfig, {"person": {"anchor": "human"}})
    with pytest.raises(ConfigError, match="'human_octaves' is called 'person_octaves' now"):
        C.override(MethodConfig(), ["person.human_octaves=2"])


def test_a_dataset_written_with_the_old_keys_opens_with_the_same_positions_and_split(synthetic_ds, tmp_path):
    from rfmitsuba.data.store import open_dataset

    new = open_dataset(synthetic_ds)
    old_path = tmp_path / "old"
    shutil.copytree(synthetic_ds, old_path)
    for name in ("meta.json", "split.json"):
        f = old_path / name
        text = f.read_text().replace("person_", "human_").replace('"person"', '"human"')
        assert "human_" in text
        f.write_text(text)
    old = open_dataset(old_path)
    np.testing.assert_array_equal(old.person_pos, new.person_pos)
    np.testing.assert_array_equal(old.split.person_test, new.split.person_test)
    assert old.num_states == new.num_states


def test_the_cli_names_the_new_spelling_of_a_renamed_flag(capsys, tmp_path):
    from rfmitsuba.cli import main

    assert main(["generate", "bedroom", "--human-positions", "3", "--out", str(tmp_path / "x")]) == 2
    assert "--human-positions is called --person-positions now" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_folder_written_before_finds_the_old_spelling_at_any_depth(tmp_path):
    from rfmitsuba.core.legacy_names import folder_written_before

    new = tmp_path / "jobs" / "bedroom_rx" / "baseline_person_s0"
    assert folder_written_before(new) == new                       # nothing there: the new name
    old = tmp_path / "jobs" / "bedroom_rx" / "baseline_human_s0"
    old.mkdir(parents=True)
    assert folder_written_before(new) == old
    new.mkdir()
    assert folder_written_before(new) == new                       # the new name wins once it exists
