"""System identification with MATLAB System Identification Toolbox semantics.

Estimators: :func:`arx`, :func:`armax`, :func:`oe`, :func:`bj`, :func:`pem`;
time series (no input): :func:`ar`, and ``arx``/``armax`` on an output-only record.
Structure: :func:`delayest`, :func:`delay_scan`, :func:`arxstruc`, :func:`selstruc`.
Validation: :func:`compare`, :func:`resid`, :func:`fit_percent`, :func:`mse`.
Non-parametric: :func:`spa`, :func:`etfe`, :func:`impulseest`.
Recursive: :class:`RecursiveARX`, :class:`RecursiveARMAX`, :func:`rarx`.
State space: :func:`n4sid`, :func:`ssest`, :class:`SSModel` (``idss``).
Models: :class:`PolyModel` (``idpoly``) and :func:`c2d`.
"""

from rwlab.ident.ar import ar
from rwlab.ident.arx import arx
from rwlab.ident.models import PolyModel, c2d
from rwlab.ident.nonparametric import FIRModel, FrequencyResponse, etfe, impulseest, spa

# ``pem`` here is the estimator, a plain function (its module is still importable as
# ``from rwlab.ident.pem import ...``)
from rwlab.ident.pem import armax, bj, oe, pem
from rwlab.ident.recursive import RecursiveARMAX, RecursiveARX, rarx
from rwlab.ident.ssmodel import SSModel
from rwlab.ident.sspem import ssest
from rwlab.ident.structure import arxstruc, delay_scan, delayest, selstruc, struc
from rwlab.ident.subspace import n4sid
from rwlab.ident.validation import compare, fit_percent, fpe, mse, resid

__all__ = [
    "FIRModel",
    "FrequencyResponse",
    "PolyModel",
    "RecursiveARMAX",
    "RecursiveARX",
    "SSModel",
    "ar",
    "armax",
    "arx",
    "arxstruc",
    "bj",
    "c2d",
    "compare",
    "delay_scan",
    "delayest",
    "etfe",
    "fit_percent",
    "fpe",
    "impulseest",
    "mse",
    "n4sid",
    "oe",
    "pem",
    "rarx",
    "resid",
    "selstruc",
    "spa",
    "ssest",
    "struc",
]
