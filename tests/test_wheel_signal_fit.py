"""A protocol whose signals cannot carry a wheel's numbers is refused, not clipped (issue 41)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.errors import ConfigError
from rwlab.testbed import ExperimentConfig
from rwlab.testbed.record import read_record
from rwlab.wheel.link import get_protocol
from rwlab.wheel.physics import WheelParams
from rwlab.wheel.signal_fit import misfits


def test_the_dbc_ranges_are_cantools_reading_of_rw_dbc():
    ranges = get_protocol("rwlab").signal_ranges()
    assert ranges["current_a"][:2] == (-2.048, 2.047)
    assert ranges["bus_voltage_v"][:2] == (10.0, 41.5)
    assert not misfits(ranges, WheelParams.load("rw90"))


@pytest.mark.parametrize(
    ("wheel", "words"),
    [  # the T6's 11 A overcurrent trip; the RW-0.01's 5 V bus (the DBC read 10.00 V)
        ("nrwa-t6", r"overcurrent_fault 11 A is outside the rw\.dbc RW_Telemetry\.Current"),
        ("rw-0.01", r"bus_voltage 5 V is outside the rw\.dbc RW_Heartbeat\.BusVoltage"),
    ],
)
def test_a_wheel_the_dbc_cannot_carry_is_refused_on_it(wheel, words):
    cfg = ExperimentConfig(wheel=wheel, protocol="rwlab", duration=10.0)
    with pytest.raises(ConfigError, match=words):
        cfg.check_limits(cfg.wheel_params())
    r = CliRunner().invoke(
        main,
        [
            "experiment",
            "--wheel",
            wheel,
            "--protocol",
            "rwlab",
            "--duration",
            "10",
            "--out",
            "x.mcap",
        ],
    )
    assert r.exit_code == 2 and "--protocol nsp" in r.output, r.output


@pytest.mark.parametrize(
    ("wheel", "protocol"), [("rw90", "rwlab"), ("nrwa-t6", "nsp"), ("rw-0.01", "nsp")]
)
def test_by_default_a_simulated_wheel_gets_a_protocol_that_carries_it(wheel, protocol):
    assert ExperimentConfig(wheel=wheel).protocol == protocol
    assert ExperimentConfig(wheel=wheel, interface="socketcan").protocol == "rwlab"


def test_the_t6_current_above_the_dbc_range_reaches_the_record(tmp_path):
    from rwlab.ident.study import load_current

    out = tmp_path / "t6.mcap"
    args = ["experiment", "--wheel", "nrwa-t6", "--duration", "60", "--seed", "2"]
    r = CliRunner().invoke(main, [*args, "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert read_record(out).metadata["protocol"] == "nsp"
    current = load_current(str(out), 0.5)
    assert np.max(np.abs(current)) > 2.5  # the DBC would have clipped it at 2.047 A
