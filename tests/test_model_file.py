"""model.json's owner class refuses a file whose top-level copies are not numbers."""

import json
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.errors import FileFormatError
from rwlab.ident import arx
from rwlab.ident.model_file import Channel, WheelModelFile
from rwlab.wheel import IdentifiedWheel


@pytest.fixture(scope="module")
def model_dict():
    u = np.random.default_rng(0).standard_normal(400)
    y = lfilter([0, 0.2], [1, -0.8], u)
    m = arx(IOData(u, y, 0.5), 1, 1, 1)
    f = WheelModelFile(m, Channel("command", "rpm", 0.0), Channel("speed_rpm", "rpm", 0.0))
    return f.to_dict()


def test_a_valid_file_round_trips(model_dict, tmp_path):
    path = tmp_path / "model.json"
    path.write_text(json.dumps(model_dict))
    assert WheelModelFile.load(path).Ts == 0.5
    assert IdentifiedWheel.from_json(path).Ts == 0.5


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("Ts", math.nan),
        ("Ts", math.inf),
        ("Ts", -1.0),
        ("Ts", 0.25),
        ("Ts", "0.5"),
        ("validation_fit_percent", math.nan),
        ("validation_fit_percent", "high"),
    ],
)
def test_a_bad_top_level_copy_is_refused(model_dict, tmp_path, key, value):
    path = tmp_path / "model.json"
    path.write_text(json.dumps({**model_dict, key: value}))  # json writes NaN / Infinity
    with pytest.raises(FileFormatError, match=key):
        WheelModelFile.load(path)
    with pytest.raises(FileFormatError):
        IdentifiedWheel.from_json(path)
