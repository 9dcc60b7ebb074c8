"""At least 95 % of the exported callables have numpydoc Parameters and Returns sections
(as python-control's docstring test); ``python tools/doccheck.py`` lists the rest."""

import sys
from pathlib import Path

import pytest

pytest.importorskip("numpydoc", reason="the docs extra: pip install -e '.[docs]'")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import doccheck


def test_exported_callables_have_parameters_and_returns():
    share, lacking = doccheck.coverage()
    assert share >= 0.95, f"{share:.1%}; lacking: {sorted(lacking)}"


def test_the_check_sees_a_missing_section():
    def documented(x: float) -> float:
        """Twice x.

        Parameters
        ----------
        x : float
            A value.

        Returns
        -------
        float
        """
        return 2 * x

    def undocumented(x: float) -> float:
        """Twice x."""
        return 2 * x

    def returns_nothing(x: float) -> None:
        """Nothing.

        Parameters
        ----------
        x : float
            Ignored.
        """

    assert doccheck.missing(documented) == []
    assert doccheck.missing(undocumented) == ["Parameters", "Returns"]
    assert doccheck.missing(returns_nothing) == []
