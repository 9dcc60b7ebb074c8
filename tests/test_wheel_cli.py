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


def test_serve_runs_for_a_set_duration():
    r = run("wheel", "serve", "--channel", "cli-serve", "--duration", "1")
    assert r.exit_code == 0 and "simulated wheel 0" in r.output


def test_unknown_interface_is_a_usage_error():
    assert run("wheel", "serve", "--interface", "carrier-pigeon").exit_code == 2


@pytest.mark.parametrize("cmd", [["wheel"], ["wheel", "serve"], ["wheel", "cmd"]])
def test_wheel_commands_have_help(cmd):
    r = run(*cmd, "--help")
    assert r.exit_code == 0 and "Usage:" in r.output
