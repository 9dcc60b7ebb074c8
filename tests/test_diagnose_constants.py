"""The detectors' measured constants: the data file and the code agree, and a bad file
says so with a typed error."""

import ast
import math
import re
from pathlib import Path

import pytest

from rwlab.diagnose import blocktests, isolate, motion
from rwlab.diagnose.constants import DEFAULT_FILE, FORMAT, measured, parse, read
from rwlab.errors import FileFormatError

SRC = Path(__file__).resolve().parent.parent / "src" / "rwlab"
# the grep the project's stop hook runs: no source line cites a tuning or evaluation case
CASE = re.compile(
    r"\bunits? [0-9]{1,4}\b|\beval[0-9]\b|\btune[ _]set|\bheld[- ]out\b|reviewer", re.I
)


def _measured_calls() -> dict[str, list[str]]:
    """Each ``measured("NAME")`` in the package's source: name → the files that call it."""
    calls: dict[str, list[str]] = {}
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "measured":
                (arg,) = node.args
                assert isinstance(arg, ast.Constant), f"{path}: measured() of a non-literal"
                calls.setdefault(arg.value, []).append(path.name)
    return calls


def test_every_constant_in_the_file_is_used_and_every_use_is_in_the_file():
    in_file = set(read())
    calls = _measured_calls()
    assert in_file - set(calls) == set(), "constants in the file that no code reads"
    assert set(calls) - in_file == set(), "measured() calls the file lacks"
    assert all(len(files) == 1 for files in calls.values()), calls  # one home each


def test_each_constant_is_a_finite_number_with_a_unit_and_its_measurement():
    constants = read()
    assert len(constants) >= 10
    for name, c in constants.items():
        assert c.name == name and math.isfinite(c.value), name
        assert c.unit and c.what and len(c.measured) > 20, name


def test_the_modules_hold_the_files_values():
    constants = read()
    for name, c in constants.items():
        module = next(m for m in (motion, isolate, blocktests) if hasattr(m, name))
        assert getattr(module, name) == c.value == measured(name)
    # a few as they were before they moved (bit for bit)
    assert motion.SLEW_SIGMA == 0.3 and isolate.CHARGE_SD == 0.015
    assert blocktests.CHARGE_EXCESS == 0.08


def test_no_source_line_cites_a_tuning_or_evaluation_case():
    cited = [
        f"{path.relative_to(SRC)}:{i}"
        for path in sorted(SRC.rglob("*.py"))
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if CASE.search(line)
    ]
    assert not cited, cited


GOOD = f"""format = "{FORMAT}"
[constants.X]
value = 0.5
unit = "rpm"
what = "a thing"
measured = "on some records"
"""


def test_a_well_formed_text_parses():
    (c,) = parse(GOOD).values()
    assert (c.name, c.value, c.unit) == ("X", 0.5, "rpm")


@pytest.mark.parametrize(
    "text, says",
    [
        ("format = ", "not TOML"),
        (GOOD.replace(FORMAT, "rwlab.DetectorConstants/9"), "is not"),
        (f'format = "{FORMAT}"\n', "no [constants"),
        (GOOD.replace("value = 0.5", "value = nan"), "finite"),
        (GOOD.replace("value = 0.5", 'value = "0.5"'), "finite"),
        (GOOD.replace("value = 0.5\n", ""), "finite"),
        (GOOD.replace('unit = "rpm"', 'unit = ""'), "unit"),
        (GOOD.replace('measured = "on some records"\n', ""), "measured"),
        (GOOD + "units = 3\n", "unknown keys"),
    ],
)
def test_a_malformed_text_is_a_file_format_error(text, says):
    with pytest.raises(FileFormatError, match=re.escape(says)):
        parse(text, "x.toml")


def test_a_missing_file_and_a_missing_name_are_file_format_errors(tmp_path):
    with pytest.raises(FileFormatError, match="cannot read"):
        read(tmp_path / "none.toml")
    with pytest.raises(FileFormatError, match="NO_SUCH_CONSTANT"):
        measured("NO_SUCH_CONSTANT")


def test_the_file_is_shipped_as_package_data():
    pyproject = (SRC.parent.parent / "pyproject.toml").read_text(encoding="utf-8")
    assert DEFAULT_FILE.exists() and DEFAULT_FILE.suffix == ".toml"
    assert '"diagnose/*.toml"' in pyproject
