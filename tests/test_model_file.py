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


def _greybox(Ts=0.5):
    from rwlab.ident.greybox import WheelGreyBox

    rw90 = dict(inertia=4.2e-4, torque_constant=0.0214, current_limit=0.7, coulomb=2e-4)
    return WheelGreyBox(
        Ts=Ts,
        **rw90,
        breakaway=3e-4,
        stribeck_speed=1.05,
        viscous=1e-6,
        accel_limit=32.9,
        kp=0.5,
        ki=0.1,
        nominal_torque_constant=0.0214,
        nominal_coulomb=2e-4,
        nominal_viscous=1e-6,
        max_speed=816.8,
    ).to_dict()


@pytest.mark.parametrize("Ts", [math.nan, 0.25])
def test_a_bad_nonlinear_model_is_refused_when_the_file_is_loaded(model_dict, tmp_path, Ts):
    """Every command reads model.json through the owner class: a NaN (or another Ts) in
    the grey box is refused there, not only by the command that simulates it."""
    good, path = tmp_path / "good.json", tmp_path / "model.json"
    good.write_text(json.dumps({**model_dict, "greybox": _greybox()}))
    assert WheelModelFile.load(good).Ts == 0.5  # the valid grey box loads
    path.write_text(json.dumps({**model_dict, "greybox": {**_greybox(), "Ts": Ts}}))
    with pytest.raises(FileFormatError, match="greybox"):
        WheelModelFile.load(path)


def test_a_nonlinear_model_that_is_not_an_object_is_refused(model_dict, tmp_path):
    path = tmp_path / "model.json"
    path.write_text(json.dumps({**model_dict, "greybox": [1.0, 2.0]}))
    with pytest.raises(FileFormatError, match=r"greybox: \[1\.0, 2\.0\] is not of type .object."):
        WheelModelFile.load(path)
