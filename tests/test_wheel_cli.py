import random

import pytest
from click.testing import CliRunner

from rwlab.cli import main


def run(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def test_cmd_speed_on_the_virtual_bus_accelerates_the_simulated_wheel():
    r = run("wheel", "cmd", "--channel", "cli-test", "speed", "2000", "--watch", "1.0")
    assert r.exit_code == 0, r.output
    rows = [line.split() for line in r.output.splitlines() if line[:1] == " " and "SPEED" in line]
    speeds = [float(row[1]) for row in rows]
    assert len(speeds) >= 8 and speeds[-1] > speeds[0] + 200  # ~314 rpm/s


def test_cmd_beyond_the_limit_is_refused_with_status_2():
    r = run("wheel", "cmd", "--channel", "cli-test2", "accel", "400")
    assert r.exit_code == 2 and "limit" in r.output


@pytest.mark.slow  # against a twin on the wall clock (its seconds are real ones)
def test_serve_runs_for_a_set_duration_where_other_processes_reach_it():
    node = str(random.randrange(1, 16))  # apart from any other wheel on the default group
    r = run("wheel", "serve", "--node-id", node, "--duration", "1")
    assert r.exit_code == 0, r.output
    assert f"simulated wheel {node} (rwlab) on udp_multicast:239.74.163.2" in r.output
    assert "wheel model rw90 (rwlab's default; --wheel NAME|FILE for another)" in r.output
    assert f"--interface udp_multicast --channel 239.74.163.2 --node-id {node}" in r.output


@pytest.mark.parametrize("protocol", ["rwlab", "canopen/cia402", "nsp/rw4-12"])
def test_serve_refuses_the_in_process_virtual_bus_and_names_one_that_works(protocol):
    r = run("wheel", "serve", "--protocol", protocol, "--interface", "virtual", "--duration", "1")
    assert r.exit_code == 2 and "inside one process" in r.output
    works = "serial --channel pty" if protocol.startswith("nsp") else "udp_multicast"
    assert f"--interface {works}" in r.output


def test_cmd_takes_the_protocols_own_wheel_and_its_limits():
    r = run("wheel", "cmd", "--protocol", "nsp/nrwa-t6", "speed", "6000")  # an RW90 reaches 7800
    assert r.exit_code == 2 and "beyond the wheel's limit of ±5000 rpm" in r.output
    r = run("wheel", "cmd", "--protocol", "nsp/nrwa-t6", "--wheel", "rw90", "speed", "6000",
            "--watch", "0.2")  # fmt: skip
    assert r.exit_code == 0 and "acknowledged" in r.output  # an RW90 on NRWA-T6 wire takes it


def test_unknown_interface_is_a_usage_error():
    assert run("wheel", "serve", "--interface", "carrier-pigeon").exit_code == 2


@pytest.mark.parametrize("cmd", [["wheel"], ["wheel", "serve"], ["wheel", "cmd"]])
def test_wheel_commands_have_help(cmd):
    r = run(*cmd, "--help")
    assert r.exit_code == 0 and "Usage:" in r.output
