"""Unknown keys in a user's TOML file are named, with the nearest known key for a typo."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rwlab._toml import unknown_keys
from rwlab.attitude.scenario import load_scenario
from rwlab.errors import ConfigError
from rwlab.testbed import ExperimentConfig
from rwlab.wheel.physics import WheelParams

KEY = st.text(alphabet="abcdefghij_.", min_size=1, max_size=12)


@given(st.sets(KEY, max_size=6), st.sets(KEY, max_size=6))
def test_every_unknown_key_is_named_once_and_only_known_keys_are_suggested(keys, known):
    text = unknown_keys(keys, known)
    unknown = keys - known
    assert (text == "") == (not unknown)
    for key in unknown:
        assert text.count(f"{key!r}") == 1
    suggested = [part.split("'")[1] for part in text.split("did you mean ")[1:]]
    assert set(suggested) <= known and len(suggested) <= len(unknown)


@pytest.mark.parametrize(
    ("table", "read", "typo", "meant"),
    [
        ("experiment", lambda p: ExperimentConfig.from_toml(p), "duraton = 10", "duration"),
        ("wheel", lambda p: WheelParams.from_toml(p), "current_limt = 0.3", "current_limit"),
        ("wheels", lambda p: load_scenario(str(p)), "max_torqe = 0.1", "wheels.max_torque"),
    ],
)
def test_a_typo_in_a_file_gets_the_key_it_meant(tmp_path, table, read, typo, meant):
    path = tmp_path / "typo.toml"
    path.write_text(f"[{table}]\n{typo}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=f"did you mean '{meant}'"):
        read(path)


def test_a_key_far_from_every_known_key_gets_no_guess(tmp_path):
    path = tmp_path / "far.toml"
    path.write_text("[wheels]\nno_such_key = 1\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\['wheels.no_such_key'\]$"):
        load_scenario(str(path))
