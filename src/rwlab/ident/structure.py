"""Structure selection: ``delayest``, ``arxstruc``, ``selstruc`` (MATLAB semantics).

Losses are mean squared one-step prediction errors of ARX models. Within one
scan every model is evaluated on the same rows (those where the largest
structure of the scan has all its regressors), so losses are comparable.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from rwlab.data import IOData
from rwlab.errors import DataError
from rwlab.ident.arx import arx_loss, check_order, first_row

__all__ = ["StructureLoss", "arxstruc", "delay_scan", "delayest", "selstruc", "struc"]


def _siso(data: IOData, what: str) -> None:
    if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
        raise DataError(f"{what} works on single-input single-output IOData")


def delay_scan(
    data: IOData, na: int = 2, nb: int = 2, nk_min: int = 0, nk_max: int | None = None
) -> dict[int, float]:
    """Loss of ARX(na, nb, nk) for every nk in nk_min..nk_max (paper A, Fig. 16).

    Parameters
    ----------
    data : IOData
        SISO record.
    na, nb : int
        ARX orders (MATLAB ``delayest``'s defaults: 2 and 2).
    nk_min, nk_max : int
        Delays to scan, in samples; ``nk_max`` defaults to ``nk_min + 20`` as in MATLAB.

    Returns
    -------
    dict
        nk → mean squared one-step prediction error on ``data``, every loss on the
        same rows.

    Raises
    ------
    DataError
        When the record has too few samples for ARX(na, nb, nk_max).
    """
    _siso(data, "delay_scan")
    na, nb = check_order("na", na), check_order("nb", nb, 1)
    nk_min = check_order("nk_min", nk_min)
    nk_max = nk_min + 20 if nk_max is None else check_order("nk_max", nk_max)
    if nk_max < nk_min:
        raise DataError(f"nk_max ({nk_max}) must be ≥ nk_min ({nk_min})")
    n0 = first_row(na, [nb], [nk_max])
    if data.N - n0 <= 2 * (na + nb):
        raise DataError(
            f"the record ({data.N} samples) is too short to scan delays up to nk_max = {nk_max} "
            f"with ARX({na}, {nb}): it needs more than {n0 + 2 * (na + nb)} samples; "
            "pass a smaller nk_max"
        )
    return {nk: arx_loss(data, None, na, nb, nk, n0) for nk in range(nk_min, nk_max + 1)}


def delayest(
    data: IOData, na: int = 2, nb: int = 2, nk_min: int = 0, nk_max: int | None = None
) -> int:
    """Input delay in samples that minimises the ARX(na, nb, nk) loss (MATLAB ``delayest``).

    Scans nk_min..nk_max (default ``nk_min + 20``, MATLAB's); see :func:`delay_scan`.

    Parameters
    ----------
    data : IOData
        Single-input record.
    na, nb : int
        Orders of the ARX model scanned.
    nk_min, nk_max : int
        Delays scanned, samples.

    Returns
    -------
    int
        The delay, samples.
    """
    losses = delay_scan(data, na, nb, nk_min, nk_max)
    return min(losses, key=lambda k: losses[k])


def struc(na: Iterable[int], nb: Iterable[int], nk: Iterable[int]) -> list[tuple[int, int, int]]:
    """All (na, nb, nk) combinations, as MATLAB's ``struc``.

    Parameters
    ----------
    na, nb, nk : iterable of int
        The values of each order to combine.

    Returns
    -------
    list of (na, nb, nk)
        Every combination, na slowest.
    """
    return [(a, b, k) for a in na for b in nb for k in nk]


@dataclass(frozen=True)
class StructureLoss:
    """One row of ``arxstruc``: orders, parameter count and validation loss.

    Parameters
    ----------
    na, nb, nk : int
        ARX orders and delay.
    loss : float
        Validation loss (mean squared prediction error).
    n_samples : int
        Number of samples the loss is measured on.
    """

    na: int
    nb: int
    nk: int
    loss: float
    n_samples: int

    @property
    def n_params(self) -> int:
        return self.na + self.nb


def arxstruc(
    est: IOData, val: IOData, orders: Iterable[tuple[int, int, int]]
) -> list[StructureLoss]:
    """Validation loss of ARX(na, nb, nk) models fitted on ``est`` (MATLAB ``arxstruc``).

    Parameters
    ----------
    est, val : IOData
        Estimation and validation records.
    orders : iterable of (na, nb, nk)
        The structures to try (see :func:`struc`).

    Returns
    -------
    list of StructureLoss
        One per structure, in the given order.
    """
    _siso(est, "arxstruc")
    _siso(val, "arxstruc")
    orders = [
        (check_order("na", a), check_order("nb", b, 1), check_order("nk", k)) for a, b, k in orders
    ]
    if not orders:
        raise DataError("arxstruc needs at least one (na, nb, nk) structure")
    n0 = max(first_row(a, [b], [k]) for a, b, k in orders)
    n_est = est.N - n0
    return [StructureLoss(a, b, k, arx_loss(est, val, a, b, k, n0), n_est) for a, b, k in orders]


def selstruc(losses: list[StructureLoss], criterion: str | float = 0) -> tuple[int, int, int]:
    """Pick a structure from ``arxstruc`` losses (MATLAB ``selstruc``).

    Parameters
    ----------
    losses : list of StructureLoss
    criterion : {0, 'aic', 'mdl'} or float
        0: the smallest validation loss V. 'aic': minimise log(V) + 2d/N.
        'mdl': minimise V·(1 + d·log(N)/N). A number c: minimise V·(1 + c·d/N).

    Returns
    -------
    (na, nb, nk) : tuple of int
        The chosen structure.
    """
    if not losses:
        raise DataError("selstruc needs the output of arxstruc")

    def score(s: StructureLoss) -> float:
        V, d, N = s.loss, s.n_params, s.n_samples
        if criterion == "aic":
            return math.log(V) + 2 * d / N
        if criterion == "mdl":
            return V * (1 + d * math.log(N) / N)
        if isinstance(criterion, (int, float)) and not isinstance(criterion, bool):
            return V * (1 + float(criterion) * d / N)
        raise DataError(f"criterion must be 0, 'aic', 'mdl' or a number; got {criterion!r}")

    best = min(losses, key=lambda s: (score(s), s.n_params))
    return best.na, best.nb, best.nk


def loss_table(losses: list[StructureLoss]) -> np.ndarray:
    """Rows [loss, na, nb, nk] (the layout of MATLAB's ``arxstruc`` matrix, transposed)."""
    return np.array([[s.loss, s.na, s.nb, s.nk] for s in losses])
