"""Random argument lists, files and TOML values for every command: exit 0 or 2, no traceback.

Each example runs under a time budget; a command still running when it ends
gets a KeyboardInterrupt (as Ctrl-C would), which must be clean too (exit 130).
"""

import json
import os
import signal
import tomllib
from dataclasses import fields
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rwlab.cli import main
from rwlab.data import IOData
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.wheel import WheelParams
from tests.test_bad_inputs import MODEL

BUDGET_S = 1.0  # a valid command line runs until this Ctrl-C: 12 demos took 26 s at 2 s


def _commands(group: click.Group, prefix=()) -> list[tuple[tuple[str, ...], click.Command]]:
    out = []
    for name, cmd in sorted(group.commands.items()):
        if isinstance(cmd, click.Group):
            out += _commands(cmd, (*prefix, name))
        else:
            out.append(((*prefix, name), cmd))
    return out


COMMANDS = _commands(main)
TOML_KEYS = sorted(
    {f.name for f in fields(ExperimentConfig)}
    | {f.name for f in fields(WheelParams)}
    | {"base", "inertia", "seed", "initial_axis", "wheel_max_torque", "experiment", "scenario"}
)
toml_scalar = st.one_of(
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=False),
    st.booleans(),
    st.text(max_size=8),
    st.sampled_from(["geo-smallsat", "geo-smalsat", "prbs", "speed", "virtual"]),
)
toml_value = st.one_of(toml_scalar, st.lists(toml_scalar, max_size=4))


json_value = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(10**6), 10**6)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=5),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=3)
    ),
    max_leaves=8,
)
MODEL_KEYS = ["format", "structure", "Ts", "input", "output", "model", "saturation", "preferred"]
POLY_KEYS = ["A", "B", "C", "D", "F", "nk", "nb", "nf", "Ts", "structure", "noise_variance"]


@st.composite
def model_json(draw):
    """A wheel model file: a plausible one with some fields replaced by anything."""
    model = json.loads(json.dumps(MODEL))
    for key in draw(st.lists(st.sampled_from(MODEL_KEYS), max_size=2)):
        model[key] = draw(json_value)
    if isinstance(model.get("model"), dict):
        for key in draw(st.lists(st.sampled_from(POLY_KEYS), max_size=2)):
            model["model"][key] = draw(json_value)
    return draw(st.sampled_from([model, [model], "model"])) if draw(st.booleans()) else model


@st.composite
def dispersion_toml(draw):
    from rwlab.campaign.dispersions import FIELDS

    lines = []
    for name in draw(st.lists(st.sampled_from([*FIELDS, "inertia.xw", "dt"]), max_size=3)):
        spec = {"distribution": draw(st.sampled_from(["normal", "uniform", "lognormal"]))}
        if draw(st.booleans()):
            spec["sigma"] = draw(toml_scalar)
        if draw(st.booleans()):
            spec["bounds"] = draw(st.lists(toml_scalar, max_size=3))
        if draw(st.booleans()):
            spec["relative"] = draw(toml_scalar)
        body = ", ".join(
            f"{k} = {_toml({k: v}).split(' = ', 1)[1].strip()}" for k, v in spec.items()
        )
        lines.append(f"{json.dumps(name)} = {{ {body} }}")
    return "\n".join(lines) + "\n"


@st.composite
def scenario_toml(draw):
    """A scenario file in sections, or now and then in the old flat format."""
    from rwlab.attitude.scenario import LEGACY_NAMES, SECTIONS

    section = draw(st.sampled_from([*SECTIONS, "scenario"]))
    keys = sorted(
        {f.name for f in fields(SECTIONS[section])} if section in SECTIONS else LEGACY_NAMES
    )
    table = draw(st.dictionaries(st.sampled_from(keys), toml_value, max_size=4))
    text = f"[{section}]\n" + _toml(table) if table else ""
    if draw(st.booleans()):
        base = draw(st.sampled_from(["geo-smallsat", "geo-comsat", "geo-moon"]))
        text = f'[scenario]\nbase = "{base}"\n' + text.replace("[scenario]\n", "")
    tomllib.loads(text)
    return text


def _toml(table: dict) -> str:
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            # JSON's escapes are TOML's; TOML also wants DEL escaped
            return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
        if isinstance(v, float) and not np.isfinite(v):
            return "inf" if v > 0 else "-inf"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    return "\n".join(f"{k} = {value(v)}" for k, v in table.items()) + "\n"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Valid, truncated and random files of every kind a command reads."""
    root = tmp_path_factory.mktemp("fuzz")
    rec = root / "r.mcap"
    run_experiment(ExperimentConfig(duration=60, Ts=0.1, seed=1), rec)
    rng = np.random.default_rng(0)
    data = IOData(rng.standard_normal(300), rng.standard_normal(300), 0.1)
    made = {"record": rec, "csv": data.write(root / "d.csv"), "mat": data.write(root / "d.mat")}
    made["parquet"] = data.write(root / "d.parquet")
    for name, path in list(made.items()):
        cut = root / f"cut{path.suffix}"
        cut.write_bytes(path.read_bytes()[: path.stat().st_size // 3])
        made[f"cut-{name}"] = cut
    (root / "junk.csv").write_bytes(rng.bytes(200))
    (root / "junk.mcap").write_bytes(rng.bytes(200))
    (root / "file").write_text("")
    made |= {"junk.csv": root / "junk.csv", "junk.mcap": root / "junk.mcap", "dir": root}
    made["under-a-file"] = root / "file" / "x"
    made["missing"] = root / "missing.csv"
    return root, made


def _value(param: click.Parameter, files: dict, root: Path):
    """A strategy for one value of ``param``: often plausible, sometimes nonsense."""
    nonsense = st.sampled_from(["", "nan", "inf", "-1", "abc", "1e9", "0"]) | st.text(max_size=6)
    kind = param.type
    if isinstance(kind, click.Choice):
        plausible = st.sampled_from(list(kind.choices))
    elif isinstance(kind, (click.types.IntParamType, click.IntRange)):
        plausible = st.integers(-2, 12).map(str)
    elif isinstance(kind, (click.types.FloatParamType, click.FloatRange)):
        plausible = st.sampled_from(["0", "-5", "0.1", "0.5", "1", "2", "30", "1e-9", "1e12"])
    else:
        outs = st.integers(0, 10**6).map(lambda k: str(root / "out" / f"o{k}"))
        names = st.sampled_from(["dryer", "gas_furnace", "geo-smallsat", "command", "speed_rpm"])
        plausible = st.sampled_from([str(p) for p in files.values()]) | outs | names
    return st.one_of(plausible, plausible, nonsense)


@st.composite
def invocations(draw, path, cmd, files, root):
    """``cmd`` with its arguments and a few options, sometimes shuffled or cut short."""
    args = [draw(_value(p, files, root)) for p in cmd.params if isinstance(p, click.Argument)]
    options = [p for p in cmd.params if isinstance(p, click.Option)]
    for opt in draw(st.lists(st.sampled_from(options), max_size=6)) if options else []:
        args.append(opt.opts[0])
        if not opt.is_flag:
            args.append(draw(_value(opt, files, root)))
    if draw(st.booleans()):  # a random TOML file in place of one argument
        toml = root / "out" / f"t{draw(st.integers(0, 10**6))}.toml"
        toml.parent.mkdir(exist_ok=True)
        table = draw(st.dictionaries(st.sampled_from(TOML_KEYS), toml_value, max_size=4))
        section = draw(st.sampled_from(["", "[experiment]\n", "[scenario]\n"]))
        text = section + _toml(table)
        tomllib.loads(text)  # the generator writes valid TOML; its values are the test
        toml.write_text(text)
        where = draw(st.sampled_from([k for k, a in enumerate(args) if a.startswith("/")] or [0]))
        args[where : where + 1] = [str(toml)]
    if draw(st.integers(0, 2)) == 0:  # a random model, dispersion or scenario file
        kind = draw(st.sampled_from(["model", "dispersions", "scenario"]))
        made = root / "out" / f"{kind}{draw(st.integers(0, 10**6))}"
        made.parent.mkdir(exist_ok=True)
        if kind == "model":
            made = made.with_suffix(".json")
            made.write_text(json.dumps(draw(model_json()), allow_nan=True))
            flags = ("--model", "--wheel-model")
        else:
            made = made.with_suffix(".toml")
            made.write_text(draw(dispersion_toml() if kind == "dispersions" else scenario_toml()))
            flags = ("--dispersions",) if kind == "dispersions" else ("--scenario", "--config")
        own = [k + 1 for k, a in enumerate(args[:-1]) if a in flags]
        if own:
            args[own[0]] = str(made)
        elif any(o.opts[0] in flags for o in options):
            args += [next(o.opts[0] for o in options if o.opts[0] in flags), str(made)]
    if draw(st.integers(0, 4)) == 0:  # a random argument list
        args = draw(st.permutations(args))[: draw(st.integers(0, len(args)))]
    return [*path, *args]


class _Budget:
    """Press Ctrl-C (SIGINT to this process) when the command runs past ``BUDGET_S``.

    A KeyboardInterrupt raised straight from the alarm's handler lands anywhere, also
    inside python-can's queue, whose lock it can leave taken (the run's clean-up then
    hung for ever); SIGINT goes through the command's own handler, as Ctrl-C does."""

    def __enter__(self):
        self.fired = False

        def interrupt(signum, frame):
            self.fired = True
            os.kill(os.getpid(), signal.SIGINT)

        self.previous = signal.signal(signal.SIGALRM, interrupt)
        signal.setitimer(signal.ITIMER_REAL, BUDGET_S)
        return self

    def __exit__(self, *exc):
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, self.previous)


@pytest.mark.slow
@pytest.mark.parametrize(("path", "cmd"), COMMANDS, ids=[" ".join(p) for p, _ in COMMANDS])
def test_random_command_lines_exit_0_or_2_without_traceback(files, path, cmd):
    root, made = files

    @settings(
        max_examples=int(os.environ.get("RWLAB_FUZZ_EXAMPLES", 12)),
        derandomize="RWLAB_FUZZ_EXAMPLES" not in os.environ,  # CI: the same examples each run
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(args=invocations(path, cmd, made, root))
    def check(args):
        cwd = os.getcwd()
        os.chdir(root)  # a command's default --out lands in the scratch folder
        try:
            with _Budget() as budget:
                r = CliRunner().invoke(main, args)
        finally:
            os.chdir(cwd)
        allowed = {0, 2, 130} if budget.fired else {0, 2}
        assert r.exit_code in allowed, (args, r.output, r.exception)
        assert r.exception is None or isinstance(r.exception, SystemExit), (args, r.exception)
        assert "Traceback" not in r.output, (args, r.output)
        if r.exit_code == 2:
            assert r.output.rstrip().splitlines()[-1].startswith("error: "), (args, r.output)

    check()
