"""Every exported callable's numpydoc docstring has the sections it needs and names every
parameter, none stale (as python-control's docstring test checks); the public methods of
the exported classes are held to the same, their undocumented rest may only shrink.
``python tools/doccheck.py`` lists what lacks what."""

import sys
from pathlib import Path

import pytest

pytest.importorskip("numpydoc", reason="the docs extra: pip install -e '.[docs]'")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import doccheck

# Public methods of exported classes still without a Parameters or Returns section, when
# the per-parameter check came (issue 45). Lower it as they are documented; never raise it.
UNDOCUMENTED_METHODS = 241


@pytest.fixture(scope="module")
def lacking():
    return doccheck.coverage()[1]


def test_every_exported_callable_documents_every_parameter_by_name(lacking):
    exported = set(doccheck.exported())
    found = {name: what for name, what in lacking.items() if name in exported}
    assert not found, found


def test_a_method_that_documents_parameters_names_each_and_no_other(lacking):
    found = {
        name: what
        for name, what in lacking.items()
        if any(w.startswith(("parameter", "stale")) for w in what)
    }
    assert not found, found


def test_the_undocumented_methods_only_shrink(lacking):
    methods = set(doccheck.documented_callables()) - set(doccheck.exported())
    assert len(methods & set(lacking)) <= UNDOCUMENTED_METHODS


def test_an_override_without_a_docstring_is_documented_by_its_base():
    class Base:
        def f(self, x: float) -> float:
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

    class Child(Base):
        def f(self, x: float) -> float:
            return 3 * x

    class Renamed(Base):
        def f(self, y: float) -> float:
            return 3 * y

    assert doccheck.declared(Child, "f") is Base.f
    assert doccheck.missing(Child.f, doccheck.declared(Child, "f")) == []
    assert doccheck.missing(Renamed.f, doccheck.declared(Renamed, "f")) == [
        "parameter 'y'",
        "stale 'x'",
    ]


def test_the_check_sees_a_missing_section_or_name():
    def documented(x: float, *, scale: float = 1.0) -> float:
        """Twice x.

        Parameters
        ----------
        x, scale : float
            A value, and a factor.

        Returns
        -------
        float
        """
        return 2 * x * scale

    def undocumented(x: float) -> float:
        """Twice x."""
        return 2 * x

    def returns_nothing(x: float, **options) -> None:
        """Nothing.

        Parameters
        ----------
        x : float
            Ignored.
        **options
            Ignored too.
        """

    def one_forgotten_one_stale(x: float, y: float) -> None:
        """Nothing.

        Parameters
        ----------
        x : float
            Ignored.
        z : float
            No longer a parameter.
        """

    assert doccheck.missing(documented) == []
    assert doccheck.missing(undocumented) == ["Parameters", "Returns"]
    assert doccheck.missing(returns_nothing) == []
    assert doccheck.missing(one_forgotten_one_stale) == ["parameter 'y'", "stale 'z'"]
